#include "rsfm/chi2.hpp"

#include <boost/math/distributions/chi_squared.hpp>
#include <boost/math/special_functions/gamma.hpp>

#include <limits>

namespace rsfm {

namespace {
// Out-of-domain arguments give NaN instead of an exception (the documented contract below).
using Policy = boost::math::policies::policy<boost::math::policies::domain_error<boost::math::policies::ignore_error>,
                                             boost::math::policies::overflow_error<boost::math::policies::ignore_error>>;
}  // namespace

double regularizedGammaP(double a, double x) {
  if (x <= 0.0) return 0.0;
  return boost::math::gamma_p(a, x, Policy());
}

double chi2Cdf(double x, double dof) {
  if (!(dof > 0.0)) return std::numeric_limits<double>::quiet_NaN();
  if (x <= 0.0) return 0.0;
  return boost::math::cdf(boost::math::chi_squared_distribution<double, Policy>(dof), x);
}

double chi2Quantile(double p, double dof) {
  if (!(p > 0.0 && p < 1.0) || !(dof > 0.0)) return std::numeric_limits<double>::quiet_NaN();
  return boost::math::quantile(boost::math::chi_squared_distribution<double, Policy>(dof), p);
}

}  // namespace rsfm
