#include "rsfm/sim/two_object_scene.hpp"

#include <Eigen/Geometry>
#include <cmath>
#include <stdexcept>
#include <string>

#include "rsfm/sim/orbit.hpp"

namespace rsfm {

TwoObjectScene makeTwoObjectScene(const TwoObjectSceneOptions& o, std::mt19937_64& rng) {
  if (o.frames < 1 || o.points_per_object < 1 || !(o.half_size > 0))
    throw std::runtime_error("two-object scene: frames, points and size must be positive");
  TwoObjectScene s;
  s.options = o;
  const Eigen::Vector3d n1(0.0, std::sin(o.tilt1_rad), std::cos(o.tilt1_rad));
  s.N = {Eigen::Vector3d(2.0 / std::sqrt(3.0), 0.0, 2.0), n1 / n1.dot(o.centre1)};
  s.R.resize(2);
  s.t.resize(2);
  orbitAboutY(o.frames, o.deg_per_frame0, Eigen::Vector3d(0, 0, 2), &s.R[0], &s.t[0]);
  for (int k = 0; k <= o.frames; ++k) {
    const Eigen::Matrix3d Rk =
        Eigen::AngleAxisd(k * o.deg_per_frame1 * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
    s.R[1].push_back(Rk);
    s.t[1].push_back((Eigen::Matrix3d::Identity() - Rk) * o.centre1 + k * o.drift1);
  }
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  for (int j = 0; j < 2; ++j) {
    const Eigen::Vector3d n = s.N[j].normalized();
    const Eigen::Vector3d p0 =
        j == 0 ? Eigen::Vector3d(-0.25, 0.0, (1.0 + 0.25 * s.N[0].x()) / s.N[0].z()) : o.centre1;
    const Eigen::Vector3d e1 = Eigen::Vector3d::UnitY().cross(n).normalized(), e2 = n.cross(e1);
    int got = 0, tries = 0;
    while (got < o.points_per_object) {
      if (++tries > 20000)
        throw std::runtime_error("two-object scene: object " + std::to_string(j) +
                                 " has no region visible in every frame");
      const Eigen::Vector3d X = p0 + o.half_size * U(rng) * e1 + o.half_size * U(rng) * e2;
      if (!visibleInAllFrames(s.R[j], s.t[j], 1.0, X, o.lim)) continue;
      s.points.push_back(X);
      s.labels.push_back(j);
      ++got;
    }
  }
  s.uv.resize(o.frames + 1);
  for (int k = 0; k <= o.frames; ++k)
    for (size_t i = 0; i < s.points.size(); ++i) {
      const int j = s.labels[i];
      const Eigen::Vector3d Xc = s.R[j][k] * s.points[i] + s.t[j][k];
      s.uv[k].push_back(Xc.head<2>() / (1.0 + Xc.z()));
    }
  return s;
}

}  // namespace rsfm
