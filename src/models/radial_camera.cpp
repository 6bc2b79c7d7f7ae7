#include "rsfm/models/radial_camera.hpp"

#include <cmath>
#include <limits>

namespace rsfm {

Eigen::Vector2d RadialCamera::apply(const Eigen::Vector4d& c, double beta, const Eigen::Vector2d& h, Eigen::Matrix2d* J_h,
                                    Eigen::Vector2d* J_beta, Eigen::Matrix<double, 2, 4>* J_camera) {
  const double k1 = c[2], k2 = c[3];
  const Eigen::Vector2d x = beta * h;  // pinhole coordinates X/Z
  const double r2 = x.squaredNorm(), r4 = r2 * r2;
  const double g = 1 + k1 * r2 + k2 * r4;
  // u = D(x) / beta + dc = h g + dc (exactly h + dc when k1 = k2 = 0).
  const Eigen::Vector2d u = (k1 == 0 && k2 == 0 ? h : Eigen::Vector2d(h * g)) + c.head<2>();
  if (J_h) *J_h = g * Eigen::Matrix2d::Identity() + (2 * k1 + 4 * k2 * r2) * x * x.transpose();
  if (J_beta) *J_beta = h * (2 * k1 * r2 + 4 * k2 * r4) / beta;
  if (J_camera) {
    J_camera->leftCols<2>().setIdentity();
    J_camera->col(2) = h * r2;
    J_camera->col(3) = h * r4;
  }
  return u;
}

bool RadialCamera::invert(const Eigen::Vector4d& c, double beta, const Eigen::Vector2d& u, Eigen::Vector2d* h) {
  const Eigen::Vector2d hd = u - c.head<2>();  // = D(x) / beta
  const double k1 = c[2], k2 = c[3];
  if (k1 == 0 && k2 == 0) {
    *h = hd;
    return true;
  }
  // Radii in pinhole units: r_d = |beta hd| = r (1 + k1 r^2 + k2 r^4); solve for r.
  const double rd = beta * hd.norm();
  if (rd == 0) {
    *h = hd;
    return true;
  }
  double r = rd;
  for (int i = 0; i < 60; ++i) {
    const double r2 = r * r;
    const double f = r * (1 + k1 * r2 + k2 * r2 * r2) - rd, df = 1 + 3 * k1 * r2 + 5 * k2 * r2 * r2;
    if (!(df > 1e-9)) return false;
    const double step = f / df;
    r -= step;
    if (!(r > 0)) return false;
    if (std::abs(step) < 1e-15 * rd) break;
  }
  *h = hd * (r / rd);
  return std::isfinite(r);
}

double RadialCamera::monotonicRadius(double k1, double k2) {
  // d r_d / d r = 1 + 3 k1 r^2 + 5 k2 r^4: its first positive root s = r^2 (if any).
  double s = std::numeric_limits<double>::infinity();
  if (k2 == 0) {
    if (k1 < 0) s = -1.0 / (3 * k1);
  } else {
    const double a = 5 * k2, b = 3 * k1, disc = b * b - 4 * a;
    if (disc >= 0) {
      const double sq = std::sqrt(disc);
      for (double root : {(-b - sq) / (2 * a), (-b + sq) / (2 * a)})
        if (root > 0) s = std::min(s, root);
    }
  }
  if (!std::isfinite(s)) return std::numeric_limits<double>::infinity();
  const double r = std::sqrt(s);
  return r * (1 + k1 * s + k2 * s * s);
}

}  // namespace rsfm
