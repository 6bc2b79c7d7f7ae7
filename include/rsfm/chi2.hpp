#pragma once
// Chi-square distribution: CDF and quantile, for gating (NIS per measurement block) and for
// consistency bands (NEES/NIS averaged over runs). Boost.Math underneath (header-only); arguments
// outside the domain give NaN.

namespace rsfm {

/// Regularized lower incomplete gamma P(a, x), a > 0, x >= 0.
double regularizedGammaP(double a, double x);

/// P(X <= x) for X ~ chi2(dof).
double chi2Cdf(double x, double dof);

/// x such that chi2Cdf(x, dof) = p, 0 < p < 1 (Boost.Math's quantile, near double precision).
double chi2Quantile(double p, double dof);

}  // namespace rsfm
