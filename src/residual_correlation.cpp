#include "rsfm/residual_correlation.hpp"

namespace rsfm {

double alongTrackCorrelationInflation(const std::vector<std::vector<double>>& per, int max_lag) {
  double c0 = 0;
  for (const auto& v : per)
    for (double x : v) c0 += x * x;
  double sum_rho = 0;
  for (int lag = 1; lag <= max_lag && c0 > 0; ++lag) {
    const std::size_t step = 2 * static_cast<std::size_t>(lag);
    double c = 0;
    for (const auto& v : per)  // v = (x0, y0, x1, y1, ...)
      for (std::size_t i = 0; i + step + 1 < v.size(); i += 2) c += v[i] * v[i + step] + v[i + 1] * v[i + step + 1];
    const double rho = c / c0;
    if (!(rho > 0)) break;
    sum_rho += rho;
  }
  return 1 + 2 * sum_rho;
}

}  // namespace rsfm
