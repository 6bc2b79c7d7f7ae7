#include "rsfm/geometry.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>

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

Eigen::Matrix3d unitDirectionJacobian(const Eigen::Vector3d& N) {
  const double r = N.norm();
  if (!(r > 0.0) || !std::isfinite(r)) return Eigen::Matrix3d::Zero();
  const Eigen::Vector3d n = N / r;
  return (Eigen::Matrix3d::Identity() - n * n.transpose()) / r;
}

double directionRmsAngle(const Eigen::Vector3d& N, const Eigen::Matrix3d& C) {
  if (!C.allFinite() || !N.allFinite() || !(N.norm() > 0.0)) return std::numeric_limits<double>::infinity();
  const Eigen::Matrix3d J = unitDirectionJacobian(N);
  return std::sqrt(std::max(0.0, (J * C * J.transpose()).trace()));
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

double normalAngle(const Eigen::Vector3d& a, const Eigen::Vector3d& b, Eigen::Matrix<double, 1, 6>* J) {
  if (J) J->setZero();
  const Eigen::Vector3d x = a.cross(b);
  const double s = x.norm(), c = a.dot(b);
  if (!std::isfinite(s) || !std::isfinite(c) || (s == 0.0 && c == 0.0)) return 0.0;
  const double sign = c < 0 ? -1.0 : 1.0;  // the lines' angle: b's sign follows a's
  const double theta = std::atan2(s, sign * c);
  if (J && s > 0.0) {
    // d theta = (|c| ds - s sign dc) / (s^2 + c^2), with ds = (a x b) . d(a x b) / s:
    // ds/da = b x (a x b) / s, ds/db = (a x b) x a / s; dc/da = b, dc/db = a.
    const double q = s * s + c * c;
    J->leftCols<3>() = ((sign * c / s) * b.cross(x) - s * sign * b).transpose() / q;
    J->rightCols<3>() = ((sign * c / s) * x.cross(a) - s * sign * a).transpose() / q;
  }
  return theta;
}

Eigen::Matrix3d rotationY(double theta) {
  const double c = std::cos(theta), s = std::sin(theta);
  Eigen::Matrix3d R;
  R << c, 0, s, 0, 1, 0, -s, 0, c;
  return R;
}

}  // namespace rsfm
