#include "rsfm/geometry.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

namespace rsfm {

bool fitPlane(const std::vector<Eigen::Vector3d>& pts, Eigen::Vector3d* n, double* d) {
  if (pts.size() < 3) return false;
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const auto& p : pts) {
    if (!p.allFinite()) return false;
    c += p;
  }
  c /= static_cast<double>(pts.size());
  Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
  for (const auto& p : pts) S += (p - c) * (p - c).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(S);
  Eigen::Vector3d nn = es.eigenvectors().col(0);  // smallest eigenvalue
  if (nn.z() < 0) nn = -nn;
  *n = nn;
  *d = nn.dot(c);
  return true;
}

bool planeFromNormalOffset(const Eigen::Vector3d& n, double d, Eigen::Vector3d* N) {
  if (!(std::abs(d) > 1e-12)) return false;
  *N = n / d;
  return true;
}

double normalAngle(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const double c = std::abs(a.normalized().dot(b.normalized()));
  return std::acos(std::clamp(c, 0.0, 1.0));
}

Eigen::Matrix3d rotationY(double theta) {
  const double c = std::cos(theta), s = std::sin(theta);
  Eigen::Matrix3d R;
  R << c, 0, s, 0, 1, 0, -s, 0, c;
  return R;
}

}  // namespace rsfm
