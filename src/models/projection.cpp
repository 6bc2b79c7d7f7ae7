#include "rsfm/models/projection.hpp"

#include "rsfm/camera.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {

std::string_view toString(MeasureStatus s) {
  switch (s) {
    case MeasureStatus::Ok: return "ok";
    case MeasureStatus::InvalidRotation: return "incremental rotation undefined (|omega| >= 2)";
    case MeasureStatus::BehindCamera: return "point behind the camera";
    case MeasureStatus::HorizonSingular: return "ray parallel to the plane (horizon)";
    case MeasureStatus::PlaneThroughOrigin: return "plane through the image-plane origin";
    case MeasureStatus::NonFinite: return "non-finite value";
    case MeasureStatus::UnknownFeature: return "observation of an unknown feature id";
  }
  return "unknown";
}

MotionContext MotionContext::fromState(const Eigen::Ref<const Eigen::VectorXd>& x,
                                       const Eigen::Matrix3d& Rg) {
  MotionContext m;
  if (!x.head<7>().allFinite() || !Rg.allFinite()) {
    m.status = MeasureStatus::NonFinite;
    return m;
  }
  m.t = x.segment<3>(idx::kTx);
  m.beta = x[idx::kBeta];
  const Eigen::Vector3d omega = x.segment<3>(idx::kWx);
  if (!incrementalRotationValid(omega)) {
    m.status = MeasureStatus::InvalidRotation;
    return m;
  }
  m.R = incrementalRotation(omega) * Rg;
  const auto dRi = incrementalRotationDerivatives(omega);
  for (int j = 0; j < 3; ++j) m.dR[j] = dRi[j] * Rg;
  return m;
}

MeasureStatus projectWithJacobian(const MotionContext& m, const Eigen::Vector3d& p,
                                  const Eigen::Vector3d& dp_dbeta, Eigen::Vector2d* h,
                                  Eigen::Matrix<double, 2, 7>* H_motion,
                                  Eigen::Matrix<double, 2, 3>* dh_dp) {
  if (m.status != MeasureStatus::Ok) return m.status;
  if (!p.allFinite()) return MeasureStatus::NonFinite;
  const double beta = m.beta;
  const Eigen::Vector3d Rp = m.R * p;
  const Eigen::Vector3d q(m.t.x() + Rp.x(), m.t.y() + Rp.y(), m.t.z() + beta * Rp.z());
  const double w = 1.0 + q.z();
  if (!(w > 1e-12)) return MeasureStatus::BehindCamera;
  if (h) *h = q.head<2>() / w;
  // dh/dq = [1/w, 0, -q1/w^2; 0, 1/w, -q2/w^2]  (appendix: the t_X, t_Y, t_Z beta partials)
  Eigen::Matrix<double, 2, 3> dhdq;
  dhdq << 1.0 / w, 0.0, -q.x() / (w * w), 0.0, 1.0 / w, -q.y() / (w * w);
  Eigen::Matrix3d DR = m.R;
  DR.row(2) *= beta;  // D R
  if (H_motion) {
    H_motion->leftCols<3>() = dhdq;
    for (int j = 0; j < 3; ++j) {
      Eigen::Vector3d dq = m.dR[j] * p;  // D dR_j p
      dq.z() *= beta;
      H_motion->col(3 + j) = dhdq * dq;
    }
    // dq/dbeta = e3 e3^T R p + D R dp/dbeta
    Eigen::Vector3d dqb = DR * dp_dbeta;
    dqb.z() += Rp.z();
    H_motion->col(6) = dhdq * dqb;
  }
  if (dh_dp) *dh_dp = dhdq * DR;
  return MeasureStatus::Ok;
}

}  // namespace rsfm
