#pragma once
// The A&P camera model ([AP95] in the notation of [AS99], eqs. 5-7; docs/conventions.md).
// Citation keys: docs/bibliography.md.
//
// Frames and units:
//  - Normalized image coordinates (u, v) = ((x_px - c_x)/s, (y_px - c_y)/s), s in pixels per unit.
//  - beta = 1/f is the inverse focal length in those units, so f_px = s / beta.
//  - 3-D coordinates have their origin ON THE IMAGE PLANE; the centre of projection (COP) is
//    at (0, 0, -1/beta). Projection: u = X_C / (1 + beta Z_C), v = Y_C / (1 + beta Z_C).
//  - Motion reference frame -> frame k: (X_C, Y_C, beta Z_C) = (t_X, t_Y, beta t_Z) + diag(1,1,beta) R X.
#include <Eigen/Core>
#include <Eigen/Geometry>

namespace rsfm {

/// Layout of the motion/camera part of every state vector ([AS99] eq. 1).
namespace idx {
inline constexpr int kTx = 0;    ///< t_X (scene units)
inline constexpr int kTy = 1;    ///< t_Y (scene units)
inline constexpr int kTzB = 2;   ///< t_Z * beta (dimensionless)
inline constexpr int kWx = 3;    ///< omega_X (incremental rotation, ~rad)
inline constexpr int kWy = 4;    ///< omega_Y
inline constexpr int kWz = 5;    ///< omega_Z
inline constexpr int kBeta = 6;  ///< beta = 1/f (per normalized image unit)
inline constexpr int kStructure = 7;  ///< first structure parameter
}  // namespace idx

/// Pixel <-> normalized image coordinates. `scale_px` (s) is explicit, never guessed.
struct ImageGeometry {
  double scale_px = 256.0;  ///< s: pixels per normalized unit
  double cx = 256.0;        ///< principal point x (px)
  double cy = 256.0;        ///< principal point y (px)
  Eigen::Vector2d toNormalized(const Eigen::Vector2d& px) const {
    return {(px.x() - cx) / scale_px, (px.y() - cy) / scale_px};
  }
  Eigen::Vector2d toPixels(const Eigen::Vector2d& uv) const {
    return {uv.x() * scale_px + cx, uv.y() * scale_px + cy};
  }
};

/// Camera-frame point in A&P form: q = (X_C, Y_C, beta Z_C) for reference point X ([AS99] eq. 6).
inline Eigen::Vector3d apTransform(const Eigen::Vector3d& X, const Eigen::Matrix3d& R,
                                   const Eigen::Vector3d& t_apbeta, double beta) {
  Eigen::Vector3d q = R * X;
  q.z() *= beta;
  return q + t_apbeta;
}

/// Projection of q = (X_C, Y_C, beta Z_C) ([AS99] eq. 7). Caller checks 1 + q.z() > 0.
inline Eigen::Vector2d apProject(const Eigen::Vector3d& q) {
  return q.head<2>() / (1.0 + q.z());
}

/// Pose of camera k in the reference camera frame, both COP-centred (ordinary pinhole frames,
/// x right, y down, z forward), as used for TUM output: p_wc (position) and q_wc (Hamilton).
struct CameraPose {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
};

/// Converts the A&P motion (R, t = (t_X, t_Y, t_Z) with origin on the image plane) to the
/// COP-centred camera pose. With Y = X + e_z/beta: Y_C = R Y + t + (I - R) e_z / beta, so the
/// camera-from-reference transform is (R, t'), and the pose is (R^T, -R^T t').
CameraPose copCentredPose(const Eigen::Matrix3d& R, const Eigen::Vector3d& t, double beta);

}  // namespace rsfm
