#include "rsfm/sim/table1_scene.hpp"

#include <cmath>
#include <stdexcept>

#include "rsfm/camera.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/sim/orbit.hpp"

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
  orbitAboutY(o.frames, o.deg_per_frame, o.centre, &s.R, &s.t);
  // In-plane basis around the plane's intersection with the optical axis.
  const Eigen::Vector3d n = o.plane.normalized();
  const Eigen::Vector3d p0(0.0, 0.0, 1.0 / o.plane.z());
  Eigen::Vector3d e1 = Eigen::Vector3d::UnitY().cross(n).normalized();
  Eigen::Vector3d e2 = n.cross(e1).normalized();
  const double lim = o.margin * (o.image_px / 2.0) / o.scale_px;  // normalized half-width
  auto visible = [&](const Eigen::Vector3d& X) { return visibleInAllFrames(s.R, s.t, o.beta, X, lim); };
  std::uniform_real_distribution<double> U(-3.0, 3.0);
  int tries = 0;
  while (static_cast<int>(s.points.size()) < o.points) {
    if (++tries > 200000)
      throw std::runtime_error("table1 scene: no visible region on the plane for these options");
    const Eigen::Vector3d X = p0 + U(rng) * e1 + U(rng) * e2;
    if (visible(X)) s.points.push_back(X);
  }
  s.uv = projectAll(s.R, s.t, o.beta, s.points);
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
