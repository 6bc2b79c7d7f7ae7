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
  const double iw = 1.0 / w, hx = q.x() * iw, hy = q.y() * iw;
  if (h) *h = Eigen::Vector2d(hx, hy);
  // dh/dq = [1/w, 0, -q1/w^2; 0, 1/w, -q2/w^2] ([AS99] appendix: the t_X, t_Y, t_Z beta partials),
  // applied to a vector v as ((v1 - h1 v3) / w, (v2 - h2 v3) / w): written out, this runs for every
  // point.
  auto dhdq = [&](double v0, double v1, double v2) { return Eigen::Vector2d((v0 - hx * v2) * iw, (v1 - hy * v2) * iw); };
  if (H_motion) {
    H_motion->col(0) << iw, 0.0;
    H_motion->col(1) << 0.0, iw;
    H_motion->col(2) << -hx * iw, -hy * iw;
    for (int j = 0; j < 3; ++j) {
      const Eigen::Vector3d dq = m.dR[j] * p;  // D dR_j p with D = diag(1, 1, beta)
      H_motion->col(3 + j) = dhdq(dq.x(), dq.y(), beta * dq.z());
    }
    // dq/dbeta = e3 e3^T R p + D R dp/dbeta
    const Eigen::Vector3d Rdb = m.R * dp_dbeta;
    H_motion->col(6) = dhdq(Rdb.x(), Rdb.y(), beta * Rdb.z() + Rp.z());
  }
  if (dh_dp) {  // dh/dq D R
    dh_dp->row(0) = (m.R.row(0) - (hx * beta) * m.R.row(2)) * iw;
    dh_dp->row(1) = (m.R.row(1) - (hy * beta) * m.R.row(2)) * iw;
  }
  return MeasureStatus::Ok;
}

}  // namespace rsfm
