#pragma once
// Incremental-rotation utilities of Azarbayejani & Pentland (A&P 1995, [AP95]) as used by
// Alon & Sclaroff 1999 ([AS99] eqs. 2-3 and appendix; keys: docs/bibliography.md).
//
// Conventions (docs/conventions.md, "Rotations"):
//  - Quaternions are Hamilton, stored as Eigen::Quaterniond (w, x, y, z).
//  - A rotation R maps reference-frame coordinates into camera-frame coordinates.
//  - The incremental rotation is delta_q(omega) = (sqrt(1 - eps), omega/2), eps = |omega|^2/4,
//    so |omega| < 2 is required (a rotation of less than 180 degrees). omega is in radians
//    to first order (|omega| small: delta_q is a rotation of ~|omega| rad about omega/|omega|).
//  - The global rotation is kept outside the state and composed as R^{k+1} = R(dq^k) R^k.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <string>
#include <string_view>

namespace rsfm {

/// How the state's omega is read between frames (docs/conventions.md, "Rotations").
enum class RotationReading {
  /// omega is kept after each step: it is the per-frame rotation (constant angular velocity).
  Rate,
  /// omega is folded into the global rotation and zeroed after each update (error-state
  /// reading, as in A&P's code and OSVR's externalizeRotation); its process noise must cover
  /// one frame's rotation.
  Reset,
};

std::string_view toString(RotationReading r);
/// Parses "rate" or "reset"; returns false on anything else.
bool parseRotationReading(std::string_view s, RotationReading* out);

/// eps = |omega|^2 / 4 ([AS99] eq. 3).
double incrementalEpsilon(const Eigen::Vector3d& omega);

/// True when delta_q(omega) is defined (eps < 1, finite).
bool incrementalRotationValid(const Eigen::Vector3d& omega);

/// delta_q = (sqrt(1-eps), omega/2) ([AS99] eq. 2). Requires incrementalRotationValid(omega).
Eigen::Quaterniond incrementalQuaternion(const Eigen::Vector3d& omega);

/// R(delta_q(omega)).
Eigen::Matrix3d incrementalRotation(const Eigen::Vector3d& omega);

/// dR(delta_q(omega))/d omega_j for j = 0,1,2 ([AS99] appendix; identical to the matrices printed
/// there, derived here by the chain rule through the Hamilton rotation matrix).
std::array<Eigen::Matrix3d, 3> incrementalRotationDerivatives(const Eigen::Vector3d& omega);

/// Hamilton rotation matrix of a unit quaternion and its partials with respect to (w, x, y, z).
std::array<Eigen::Matrix3d, 4> rotationMatrixQuaternionPartials(const Eigen::Quaterniond& q);

/// Quaternion with non-negative scalar part (q and -q are the same rotation).
Eigen::Quaterniond canonical(const Eigen::Quaterniond& q);

/// Angle in radians between two rotations.
double rotationAngle(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b);

}  // namespace rsfm
