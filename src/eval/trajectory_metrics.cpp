#include "rsfm/eval/trajectory_metrics.hpp"

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <tuple>

namespace rsfm::eval {

UmeyamaResult umeyama(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst,
                      bool with_scale) {
  if (src.size() != dst.size()) throw std::invalid_argument("umeyama: point sets differ in size");
  UmeyamaResult res;
  const std::size_t n = src.size();
  if (n < 2) return res;
  Eigen::Vector3d ms = Eigen::Vector3d::Zero(), md = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    ms += src[i];
    md += dst[i];
  }
  ms /= static_cast<double>(n);
  md /= static_cast<double>(n);
  double var_s = 0;
  Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d a = src[i] - ms, b = dst[i] - md;
    var_s += a.squaredNorm();
    C += b * a.transpose();
  }
  var_s /= static_cast<double>(n);
  C /= static_cast<double>(n);
  if (!(var_s > 0)) return res;
  // The transform is Eigen's Umeyama (reflection-corrected, Umeyama 1991 [Ume91]); the singular
  // values of the cross-covariance C tell the caller whether the rotation is determined.
  Eigen::Matrix3Xd S(3, static_cast<Eigen::Index>(n)), D(3, static_cast<Eigen::Index>(n));
  for (std::size_t i = 0; i < n; ++i) {
    S.col(static_cast<Eigen::Index>(i)) = src[i];
    D.col(static_cast<Eigen::Index>(i)) = dst[i];
  }
  const Eigen::Matrix4d T = Eigen::umeyama(S, D, with_scale);
  res.T.s = with_scale ? T.block<3, 1>(0, 0).norm() : 1.0;
  res.T.R = T.block<3, 3>(0, 0) / res.T.s;
  res.T.t = T.block<3, 1>(0, 3);
  res.singular_values = Eigen::JacobiSVD<Eigen::Matrix3d>(C).singularValues();
  res.ok = std::isfinite(res.T.s) && res.T.s > 0;
  return res;
}

ErrorStats errorStats(std::vector<double> e) {
  ErrorStats s;
  s.n = static_cast<int>(e.size());
  if (e.empty()) return s;
  double sq = 0, sum = 0;
  for (double v : e) {
    sq += v * v;
    sum += v;
    s.max = std::max(s.max, v);
  }
  s.rmse = std::sqrt(sq / s.n);
  s.mean = sum / s.n;
  std::sort(e.begin(), e.end());
  s.median = (s.n % 2) ? e[s.n / 2] : 0.5 * (e[s.n / 2 - 1] + e[s.n / 2]);
  return s;
}

AteResult absoluteTrajectoryError(const std::vector<Pose>& est, const std::vector<Pose>& truth,
                                  bool with_scale) {
  if (est.size() != truth.size()) throw std::invalid_argument("ATE: trajectories differ in length");
  std::vector<Eigen::Vector3d> a, b;
  for (std::size_t i = 0; i < est.size(); ++i) {
    a.push_back(est[i].p);
    b.push_back(truth[i].p);
  }
  AteResult r;
  r.alignment = umeyama(a, b, with_scale);
  for (std::size_t i = 0; i < a.size(); ++i) r.errors.push_back((b[i] - r.alignment.T.apply(a[i])).norm());
  r.stats = errorStats(r.errors);
  return r;
}

namespace {
double rotationAngleDeg(const Eigen::Matrix3d& R) {
  const double c = std::clamp(0.5 * (R.trace() - 1.0), -1.0, 1.0);
  // acos loses precision near 0: use atan2 of the skew part's norm.
  const Eigen::Vector3d w(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1));
  return std::atan2(0.5 * w.norm(), c) * 180.0 / M_PI;
}
}  // namespace

RpeResult relativePoseError(const std::vector<Pose>& est, const std::vector<Pose>& truth,
                            const std::vector<long long>& frame, long long delta, double scale) {
  if (est.size() != truth.size() || frame.size() != est.size())
    throw std::invalid_argument("RPE: inputs differ in length");
  std::vector<double> et, er;
  std::size_t j = 0;
  for (std::size_t i = 0; i < frame.size(); ++i) {
    if (delta > std::numeric_limits<long long>::max() - frame[i]) break;  // no frame that far ahead (no overflow)
    const long long want = frame[i] + delta;
    if (j < i) j = i;
    while (j < frame.size() && frame[j] < want) ++j;
    if (j >= frame.size()) break;
    if (frame[j] != want) continue;
    const Eigen::Matrix3d Rq = truth[i].R.transpose() * truth[j].R;
    const Eigen::Vector3d tq = truth[i].R.transpose() * (truth[j].p - truth[i].p);
    const Eigen::Matrix3d Rp = est[i].R.transpose() * est[j].R;
    const Eigen::Vector3d tp = scale * (est[i].R.transpose() * (est[j].p - est[i].p));
    et.push_back((Rq.transpose() * (tp - tq)).norm());
    er.push_back(rotationAngleDeg(Rq.transpose() * Rp));
  }
  RpeResult r;
  r.pairs = static_cast<int>(et.size());
  r.translation = errorStats(et);
  r.rotation_deg = errorStats(er);
  return r;
}

double angleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b)) * 180.0 / M_PI;
}

std::vector<int> minCostAssignment(const std::vector<std::vector<double>>& cost) {
  const int m = static_cast<int>(cost.size());
  const int k = m > 0 ? static_cast<int>(cost[0].size()) : 0;
  std::vector<int> best(m, -1);
  if (m == 0 || k == 0) return best;
  const int pairs = std::min(m, k);
  if (std::max(m, k) <= 9) {
    // Exhaustive: each row gets a column or nothing, with exactly `pairs` matches.
    std::vector<int> cur(m, -1);
    std::vector<char> used(k, 0);
    double best_cost = std::numeric_limits<double>::infinity();
    auto rec = [&](auto&& self, int i, int matched, double c) -> void {
      if (c >= best_cost) return;
      if (matched + (m - i) < pairs) return;
      if (i == m) {
        if (matched == pairs) {
          best_cost = c;
          best = cur;
        }
        return;
      }
      for (int j = 0; j < k; ++j) {
        if (used[j]) continue;
        used[j] = 1;
        cur[i] = j;
        self(self, i + 1, matched + 1, c + cost[i][j]);
        used[j] = 0;
        cur[i] = -1;
      }
      self(self, i + 1, matched, c);  // leave row i unmatched
    };
    rec(rec, 0, 0, 0.0);
  } else {
    std::vector<std::tuple<double, int, int>> all;
    for (int i = 0; i < m; ++i)
      for (int j = 0; j < k; ++j) all.emplace_back(cost[i][j], i, j);
    std::sort(all.begin(), all.end());
    std::vector<char> used(k, 0);
    for (const auto& [c, i, j] : all)
      if (best[i] < 0 && !used[j]) {
        best[i] = j;
        used[j] = 1;
      }
  }
  return best;
}

namespace {
PlaneMatch matchWithCost(const std::vector<Eigen::Vector3d>& truth, const std::vector<Eigen::Vector3d>& est,
                         const std::vector<std::vector<double>>& cost) {
  const int m = static_cast<int>(truth.size()), k = static_cast<int>(est.size());
  PlaneMatch pm;
  pm.estimate_of_truth.assign(m, -1);
  pm.truth_of_estimate.assign(k, -1);
  pm.angle_deg.assign(m, std::numeric_limits<double>::quiet_NaN());
  const std::vector<int> best = minCostAssignment(cost);
  for (int i = 0; i < m; ++i) {
    if (best[i] < 0) continue;
    pm.estimate_of_truth[i] = best[i];
    pm.truth_of_estimate[best[i]] = i;
    pm.angle_deg[i] = angleDeg(truth[i].normalized(), est[best[i]].normalized());
  }
  return pm;
}
}  // namespace

PlaneMatch matchPlanes(const std::vector<Eigen::Vector3d>& truth, const std::vector<Eigen::Vector3d>& est) {
  std::vector<std::vector<double>> cost(truth.size(), std::vector<double>(est.size()));
  for (std::size_t i = 0; i < truth.size(); ++i)
    for (std::size_t j = 0; j < est.size(); ++j) cost[i][j] = angleDeg(truth[i].normalized(), est[j].normalized());
  return matchWithCost(truth, est, cost);
}

PlaneMatch matchPlanes(const std::vector<Eigen::Vector3d>& truth, const std::vector<double>& truth_d,
                       const std::vector<Eigen::Vector3d>& est, const std::vector<double>& est_d, double scale,
                       double deg_per_log) {
  if (truth_d.size() != truth.size() || est_d.size() != est.size())
    throw std::invalid_argument("matchPlanes: one distance per plane");
  std::vector<std::vector<double>> cost(truth.size(), std::vector<double>(est.size()));
  for (std::size_t i = 0; i < truth.size(); ++i)
    for (std::size_t j = 0; j < est.size(); ++j) {
      const double r = scale * est_d[j] / truth_d[i];
      const double log_err = (r > 0 && std::isfinite(r)) ? std::abs(std::log(r)) : 1.0;
      cost[i][j] = angleDeg(truth[i].normalized(), est[j].normalized()) + deg_per_log * log_err;
    }
  return matchWithCost(truth, est, cost);
}

}  // namespace rsfm::eval
