#include "rsfm/sim/orbit.hpp"

#include <cmath>

#include "rsfm/geometry.hpp"

namespace rsfm {

void orbitAboutY(int frames, double deg_per_frame, const Eigen::Vector3d& centre,
                 std::vector<Eigen::Matrix3d>* R, std::vector<Eigen::Vector3d>* t) {
  const double theta = deg_per_frame * M_PI / 180.0;
  R->clear();
  t->clear();
  for (int k = 0; k <= frames; ++k) {
    const Eigen::Matrix3d Rk = rotationY(k * theta);
    R->push_back(Rk);
    t->push_back((Eigen::Matrix3d::Identity() - Rk) * centre);
  }
}

bool visibleInAllFrames(const std::vector<Eigen::Matrix3d>& R, const std::vector<Eigen::Vector3d>& t,
                        double beta, const Eigen::Vector3d& X, double lim) {
  for (size_t k = 0; k < R.size(); ++k) {
    const Eigen::Vector3d Xc = R[k] * X + t[k];
    const double w = 1.0 + beta * Xc.z();
    if (w < 0.1) return false;
    if (std::abs(Xc.x() / w) > lim || std::abs(Xc.y() / w) > lim) return false;
  }
  return true;
}

std::vector<std::vector<Eigen::Vector2d>> projectAll(const std::vector<Eigen::Matrix3d>& R,
                                                     const std::vector<Eigen::Vector3d>& t, double beta,
                                                     const std::vector<Eigen::Vector3d>& points) {
  std::vector<std::vector<Eigen::Vector2d>> uv(R.size());
  for (size_t k = 0; k < R.size(); ++k)
    for (const auto& X : points) {
      const Eigen::Vector3d Xc = R[k] * X + t[k];
      uv[k].push_back(Xc.head<2>() / (1.0 + beta * Xc.z()));
    }
  return uv;
}

}  // namespace rsfm
