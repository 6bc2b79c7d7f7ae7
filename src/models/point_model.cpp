#include "rsfm/models/point_model.hpp"

#include "rsfm/models/linearize.hpp"

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
  if (i < 0 || i >= numPoints()) return MeasureStatus::UnknownFeature;
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
                           const std::vector<Eigen::Matrix2d>* ref_cov, BlockBatch* batch,
                           int* invalid, MeasureStatus* first_problem,
                           std::vector<int>* used, int reference_index) const {
  linearizeObservations(*this, x, Rg, obs, sigma, ref_cov, batch, invalid, first_problem, used, reference_index);
}

}  // namespace rsfm
