#include "rsfm/models/point_model.hpp"

#include <cmath>

namespace rsfm {

Eigen::Vector3d PointModel::point(const Eigen::Vector2d& uv1, double alpha, double beta) {
  const double s = 1.0 + alpha * beta;
  return {uv1.x() * s, uv1.y() * s, alpha};
}

MeasureStatus PointModel::measure(const MotionContext& m, const Eigen::VectorXd& x, int i,
                                  Eigen::Vector2d* h, Eigen::Matrix<double, 2, 7>* Hm,
                                  Eigen::Vector2d* Ha) const {
  const Eigen::Vector2d& uv = ref_[i];
  const double alpha = x[alphaIndex(i)];
  const double beta = m.beta;
  if (!std::isfinite(alpha)) return MeasureStatus::NonFinite;
  if (!(1.0 + alpha * beta > 1e-12)) return MeasureStatus::BehindCamera;
  const Eigen::Vector3d p = point(uv, alpha, beta);
  const Eigen::Vector3d dp_dbeta(uv.x() * alpha, uv.y() * alpha, 0.0);
  Eigen::Matrix<double, 2, 3> dhdp;
  const MeasureStatus s = projectWithJacobian(m, p, dp_dbeta, h, Hm, Ha ? &dhdp : nullptr);
  if (s != MeasureStatus::Ok) return s;
  if (Ha) *Ha = dhdp * Eigen::Vector3d(uv.x() * beta, uv.y() * beta, 1.0);  // dp/dalpha
  return s;
}

MeasureStatus PointModel::measure(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i,
                                  Eigen::Vector2d* h, Eigen::MatrixXd* H) const {
  const MotionContext m = MotionContext::fromState(x, Rg);
  Eigen::Matrix<double, 2, 7> Hm;
  Eigen::Vector2d Ha;
  const MeasureStatus s = measure(m, x, i, h, H ? &Hm : nullptr, H ? &Ha : nullptr);
  if (s == MeasureStatus::Ok && H) {
    H->setZero(2, x.size());
    H->leftCols<7>() = Hm;
    H->col(alphaIndex(i)) = Ha;
  }
  return s;
}

void PointModel::linearize(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg,
                           const std::vector<Observation>& obs, double sigma,
                           MeasurementBatch* batch, int* invalid,
                           MeasureStatus* first_problem) const {
  const MotionContext m = MotionContext::fromState(x, Rg);
  const int n = static_cast<int>(x.size());
  std::vector<int> ok;
  std::vector<Eigen::Vector2d> hs;
  std::vector<Eigen::Matrix<double, 2, 7>> hms;
  std::vector<Eigen::Vector2d> has;
  *invalid = 0;
  *first_problem = MeasureStatus::Ok;
  for (int k = 0; k < static_cast<int>(obs.size()); ++k) {
    Eigen::Vector2d h, Ha;
    Eigen::Matrix<double, 2, 7> Hm;
    const MeasureStatus s = measure(m, x, obs[k].id, &h, &Hm, &Ha);
    if (s != MeasureStatus::Ok || !obs[k].uv.allFinite()) {
      if (*invalid == 0) *first_problem = s == MeasureStatus::Ok ? MeasureStatus::NonFinite : s;
      ++*invalid;
      continue;
    }
    ok.push_back(k);
    hs.push_back(h);
    hms.push_back(Hm);
    has.push_back(Ha);
  }
  const int nb = static_cast<int>(ok.size());
  batch->resize(nb, n, 2);
  for (int b = 0; b < nb; ++b) {
    const Observation& o = obs[ok[b]];
    batch->residual.segment<2>(2 * b) = o.uv - hs[b];
    batch->H.block<2, 7>(2 * b, 0) = hms[b];
    batch->H.block<2, 1>(2 * b, alphaIndex(o.id)) = has[b];
    batch->R.block<2, 2>(2 * b, 0) = Eigen::Matrix2d::Identity() * sigma * sigma;
  }
}

}  // namespace rsfm
