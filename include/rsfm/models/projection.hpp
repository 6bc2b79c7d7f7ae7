#pragma once
// The projection chain shared by every point-based model ([AS99] eqs. 6-7 and appendix):
//   q = (X_C, Y_C, beta Z_C) = t + D R p,   D = diag(1, 1, beta),   R = R(dq(omega)) R_g
//   h = (q_1, q_2) / (1 + q_3)
// where p is the reference-frame 3-D point (origin on the image plane) produced by the model's
// structure parameters, and t = (t_X, t_Y, t_Z beta).
#include <Eigen/Core>
#include <array>
#include <string_view>

namespace rsfm {

/// Why a measurement could not be predicted. Such observations are excluded and counted.
enum class MeasureStatus {
  Ok = 0,
  InvalidRotation,      ///< |omega| >= 2 or non-finite: dq(omega) undefined
  BehindCamera,         ///< 1 + beta Z <= 0 in the reference or current camera
  HorizonSingular,      ///< the first-frame ray is (nearly) parallel to the plane
  PlaneThroughOrigin,   ///< |N| too large: the plane (nearly) contains the image-plane origin
  NonFinite,            ///< NaN/Inf in the state or the prediction
  UnknownFeature,       ///< the observation's id is not a point of the model
};
std::string_view toString(MeasureStatus s);

/// Motion quantities evaluated once per frame and shared by all points.
struct MotionContext {
  Eigen::Vector3d t = Eigen::Vector3d::Zero();  ///< (t_X, t_Y, t_Z beta)
  double beta = 1.0;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  ///< R(dq(omega)) R_g: reference -> current
  std::array<Eigen::Matrix3d, 3> dR{};              ///< dR/d omega_j = dR(dq)/d omega_j R_g
  MeasureStatus status = MeasureStatus::Ok;
  /// From the first 7 state components and the global rotation R_g (kept outside the state).
  static MotionContext fromState(const Eigen::Ref<const Eigen::VectorXd>& x,
                                 const Eigen::Matrix3d& Rg);
};

/// Projects the reference point p and returns the measurement Jacobians:
///   H_motion (2x7) with respect to (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z, beta), where the
///   beta column includes the model's dp/dbeta, and dh/dp (2x3) for the structure chain rule
///   dh/ds = dh_dp * dp/ds. Either output may be null.
MeasureStatus projectWithJacobian(const MotionContext& m, const Eigen::Vector3d& p,
                                  const Eigen::Vector3d& dp_dbeta, Eigen::Vector2d* h,
                                  Eigen::Matrix<double, 2, 7>* H_motion,
                                  Eigen::Matrix<double, 2, 3>* dh_dp);

/// One observation of a tracked feature in the current frame.
struct Observation {
  int id = 0;                                   ///< feature index in the model
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();  ///< normalized image coordinates
};

}  // namespace rsfm
