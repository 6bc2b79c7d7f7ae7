#include "rsfm/models/point_model.hpp"

#include <cmath>

namespace rsfm {

Eigen::Vector3d PointModel::point(const Eigen::Vector2d& uv1, double alpha, double beta) {
  const double s = 1.0 + alpha * beta;
  return {uv1.x() * s, uv1.y() * s, alpha};
}

MeasureStatus PointModel::measure(const MotionContext& m, const Eigen::VectorXd& x, int i,
                                  Eigen::Vector2d* h, Eigen::Matrix<double, 2, 7>* Hm,
                                  Eigen::Vector2d* Ha, Eigen::Matrix2d* Hu) const {
  const Eigen::Vector2d& uv = ref_[i];
  const double alpha = x[alphaIndex(i)];
  const double beta = m.beta;
  if (!std::isfinite(alpha)) return MeasureStatus::NonFinite;
  if (!(1.0 + alpha * beta > 1e-12)) return MeasureStatus::BehindCamera;
  const Eigen::Vector3d p = point(uv, alpha, beta);
  const Eigen::Vector3d dp_dbeta(uv.x() * alpha, uv.y() * alpha, 0.0);
  Eigen::Matrix<double, 2, 3> dhdp;
  const bool need = Ha || Hu;
  const MeasureStatus s = projectWithJacobian(m, p, dp_dbeta, h, Hm, need ? &dhdp : nullptr);
  if (s != MeasureStatus::Ok) return s;
  if (Ha) *Ha = dhdp * Eigen::Vector3d(uv.x() * beta, uv.y() * beta, 1.0);  // dp/dalpha
  if (Hu) *Hu = dhdp.leftCols<2>() * (1.0 + alpha * beta);                 // dp/du = (1+ab) e_x
  return s;
}

MeasureStatus PointModel::measure(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i,
                                  Eigen::Vector2d* h, Eigen::MatrixXd* H) const {
  const MotionContext m = MotionContext::fromState(x, Rg);
  Eigen::Matrix<double, 2, 7> Hm;
  Eigen::Vector2d Ha;
  const MeasureStatus s = measure(m, x, i, h, H ? &Hm : nullptr, H ? &Ha : nullptr, nullptr);
  if (s == MeasureStatus::Ok && H) {
    H->setZero(2, x.size());
    H->leftCols<7>() = Hm;
    H->col(alphaIndex(i)) = Ha;
  }
  return s;
}

void PointModel::linearize(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg,
                           const std::vector<Observation>& obs, double sigma,
                           const std::vector<Eigen::Matrix2d>* ref_cov, MeasurementBatch* batch,
                           int* invalid, MeasureStatus* first_problem,
                           std::vector<int>* used) const {
  const MotionContext m = MotionContext::fromState(x, Rg);
  const int n = static_cast<int>(x.size());
  batch->resize(static_cast<int>(obs.size()), n, 2);
  if (used) used->clear();
  *invalid = 0;
  *first_problem = MeasureStatus::Ok;
  int b = 0;
  for (int k = 0; k < static_cast<int>(obs.size()); ++k) {
    const Observation& o = obs[k];
    Eigen::Vector2d h, Ha;
    Eigen::Matrix<double, 2, 7> Hm;
    Eigen::Matrix2d Hu;
    const MeasureStatus s = measure(m, x, o.id, &h, &Hm, &Ha, ref_cov ? &Hu : nullptr);
    if (s != MeasureStatus::Ok || !o.uv.allFinite()) {
      if (*invalid == 0) *first_problem = s == MeasureStatus::Ok ? MeasureStatus::NonFinite : s;
      ++*invalid;
      continue;
    }
    batch->residual.segment<2>(2 * b) = o.uv - h;
    batch->H.block<2, 7>(2 * b, 0) = Hm;
    batch->H.block<2, 1>(2 * b, alphaIndex(o.id)) = Ha;
    Eigen::Matrix2d R = Eigen::Matrix2d::Identity() * sigma * sigma;
    if (ref_cov) R += Hu * (*ref_cov)[o.id] * Hu.transpose();
    batch->R.block<2, 2>(2 * b, 0) = R;
    if (used) used->push_back(k);
    ++b;
  }
  batch->residual.conservativeResize(2 * b);
  batch->H.conservativeResize(2 * b, Eigen::NoChange);
  batch->R.conservativeResize(2 * b, Eigen::NoChange);
}

}  // namespace rsfm
