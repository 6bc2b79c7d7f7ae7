#include "rsfm/rotation.hpp"

#include <algorithm>
#include <cmath>

namespace rsfm {

std::string_view toString(RotationReading r) {
  return r == RotationReading::Rate ? "rate" : "reset";
}

bool parseRotationReading(std::string_view s, RotationReading* out) {
  if (s == "rate") {
    *out = RotationReading::Rate;
    return true;
  }
  if (s == "reset") {
    *out = RotationReading::Reset;
    return true;
  }
  return false;
}

double incrementalEpsilon(const Eigen::Vector3d& omega) { return omega.squaredNorm() / 4.0; }

bool incrementalRotationValid(const Eigen::Vector3d& omega) {
  return omega.allFinite() && incrementalEpsilon(omega) < 1.0;
}

Eigen::Quaterniond incrementalQuaternion(const Eigen::Vector3d& omega) {
  const double gamma = std::sqrt(1.0 - incrementalEpsilon(omega));
  return Eigen::Quaterniond(gamma, omega.x() / 2.0, omega.y() / 2.0, omega.z() / 2.0);
}

Eigen::Matrix3d incrementalRotation(const Eigen::Vector3d& omega) {
  return incrementalQuaternion(omega).toRotationMatrix();
}

std::array<Eigen::Matrix3d, 4> rotationMatrixQuaternionPartials(const Eigen::Quaterniond& q) {
  // R = [[1-2(y²+z²), 2(xy-wz), 2(xz+wy)],
  //      [2(xy+wz), 1-2(x²+z²), 2(yz-wx)],
  //      [2(xz-wy), 2(yz+wx), 1-2(x²+y²)]]   (Hamilton, unit q)
  const double w = q.w(), x = q.x(), y = q.y(), z = q.z();
  std::array<Eigen::Matrix3d, 4> d;
  d[0] << 0, -2 * z, 2 * y,  //
      2 * z, 0, -2 * x,      //
      -2 * y, 2 * x, 0;
  d[1] << 0, 2 * y, 2 * z,  //
      2 * y, -4 * x, -2 * w,  //
      2 * z, 2 * w, -4 * x;
  d[2] << -4 * y, 2 * x, 2 * w,  //
      2 * x, 0, 2 * z,           //
      -2 * w, 2 * z, -4 * y;
  d[3] << -4 * z, -2 * w, 2 * x,  //
      2 * w, -4 * z, 2 * y,       //
      2 * x, 2 * y, 0;
  return d;
}

std::array<Eigen::Matrix3d, 3> incrementalRotationDerivatives(const Eigen::Vector3d& omega) {
  const Eigen::Quaterniond q = incrementalQuaternion(omega);
  const auto dR = rotationMatrixQuaternionPartials(q);
  const double gamma = q.w();
  std::array<Eigen::Matrix3d, 3> out;
  for (int j = 0; j < 3; ++j) {
    // d gamma / d omega_j = -omega_j / (4 gamma); d q_{j+1} / d omega_j = 1/2.
    out[j] = dR[0] * (-omega[j] / (4.0 * gamma)) + dR[1 + j] * 0.5;
  }
  return out;
}

Eigen::Quaterniond canonical(const Eigen::Quaterniond& q) {
  return q.w() < 0 ? Eigen::Quaterniond(-q.w(), -q.x(), -q.y(), -q.z()) : q;
}

double rotationAngle(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  const double c = ((a.transpose() * b).trace() - 1.0) / 2.0;
  return std::acos(std::clamp(c, -1.0, 1.0));
}

}  // namespace rsfm
