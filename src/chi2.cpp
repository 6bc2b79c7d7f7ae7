#include "rsfm/chi2.hpp"

#include <cmath>
#include <limits>

namespace rsfm {

double regularizedGammaP(double a, double x) {
  if (x <= 0.0) return 0.0;
  const double gln = std::lgamma(a);
  if (x < a + 1.0) {
    // Series representation.
    double ap = a, sum = 1.0 / a, del = sum;
    for (int n = 0; n < 10000; ++n) {
      ap += 1.0;
      del *= x / ap;
      sum += del;
      if (std::abs(del) < std::abs(sum) * 1e-15) break;
    }
    return sum * std::exp(-x + a * std::log(x) - gln);
  }
  // Continued fraction (modified Lentz) for Q, then P = 1 - Q.
  const double tiny = 1e-300;
  double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
  for (int i = 1; i < 10000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < tiny) d = tiny;
    c = b + an / c;
    if (std::abs(c) < tiny) c = tiny;
    d = 1.0 / d;
    const double del = d * c;
    h *= del;
    if (std::abs(del - 1.0) < 1e-15) break;
  }
  return 1.0 - std::exp(-x + a * std::log(x) - gln) * h;
}

double chi2Cdf(double x, double dof) { return regularizedGammaP(dof / 2.0, x / 2.0); }

double chi2Quantile(double p, double dof) {
  if (!(p > 0.0 && p < 1.0) || !(dof > 0.0)) return std::numeric_limits<double>::quiet_NaN();
  double lo = 0.0, hi = dof + 10.0 * std::sqrt(2.0 * dof) + 50.0;
  while (chi2Cdf(hi, dof) < p) hi *= 2.0;
  for (int i = 0; i < 200 && (hi - lo) > 1e-12 * hi; ++i) {
    const double mid = 0.5 * (lo + hi);
    (chi2Cdf(mid, dof) < p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace rsfm
