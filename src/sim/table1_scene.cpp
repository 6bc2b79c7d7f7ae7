#include "rsfm/sim/table1_scene.hpp"

#include <cmath>
#include <stdexcept>

#include "rsfm/camera.hpp"
#include "rsfm/geometry.hpp"

namespace rsfm {

std::uint64_t mixSeed(std::uint64_t seed, std::uint64_t a, std::uint64_t b) {
  auto mix = [](std::uint64_t z) {
    z += 0x9e3779b97f4a7c15ULL;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
  };
  return mix(mix(mix(seed) ^ a) ^ (b * 0x632be59bd9b4e019ULL));
}

Table1Scene makeTable1Scene(const Table1SceneOptions& o, std::mt19937_64& rng) {
  if (o.frames < 1 || o.points < 1 || !(o.scale_px > 0) || !(o.beta > 0) || !(o.image_px > 0))
    throw std::runtime_error("table1 scene: frames, points, scale and beta must be positive");
  Table1Scene s;
  s.options = o;
  const double theta = o.deg_per_frame * M_PI / 180.0;
  for (int k = 0; k <= o.frames; ++k) {
    const Eigen::Matrix3d R = rotationY(k * theta);
    s.R.push_back(R);
    s.t.push_back((Eigen::Matrix3d::Identity() - R) * o.centre);
  }
  // In-plane basis around the plane's intersection with the optical axis.
  const Eigen::Vector3d n = o.plane.normalized();
  const Eigen::Vector3d p0(0.0, 0.0, 1.0 / o.plane.z());
  Eigen::Vector3d e1 = Eigen::Vector3d::UnitY().cross(n).normalized();
  Eigen::Vector3d e2 = n.cross(e1).normalized();
  const double lim = o.margin * (o.image_px / 2.0) / o.scale_px;  // normalized half-width
  auto visible = [&](const Eigen::Vector3d& X) {
    for (int k = 0; k <= o.frames; ++k) {
      const Eigen::Vector3d Xc = s.R[k] * X + s.t[k];
      const double w = 1.0 + o.beta * Xc.z();
      if (w < 0.1) return false;
      if (std::abs(Xc.x() / w) > lim || std::abs(Xc.y() / w) > lim) return false;
    }
    return true;
  };
  std::uniform_real_distribution<double> U(-3.0, 3.0);
  int tries = 0;
  while (static_cast<int>(s.points.size()) < o.points) {
    if (++tries > 200000)
      throw std::runtime_error("table1 scene: no visible region on the plane for these options");
    const Eigen::Vector3d X = p0 + U(rng) * e1 + U(rng) * e2;
    if (visible(X)) s.points.push_back(X);
  }
  s.uv.resize(o.frames + 1);
  for (int k = 0; k <= o.frames; ++k)
    for (const auto& X : s.points) {
      const Eigen::Vector3d Xc = s.R[k] * X + s.t[k];
      s.uv[k].push_back(Xc.head<2>() / (1.0 + o.beta * Xc.z()));
    }
  return s;
}

std::vector<std::vector<Eigen::Vector2d>> addUniformNoise(
    const std::vector<std::vector<Eigen::Vector2d>>& uv, double sigma_px, double scale_px,
    std::mt19937_64& rng) {
  const double a = std::sqrt(3.0) * sigma_px / scale_px;
  std::uniform_real_distribution<double> U(-a, a);
  auto out = uv;
  if (a > 0)
    for (auto& frame : out)
      for (auto& p : frame) p += Eigen::Vector2d(U(rng), U(rng));
  return out;
}

}  // namespace rsfm
