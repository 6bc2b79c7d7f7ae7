#include "rsfm/sim/box_scene.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "rsfm/geometry.hpp"
#include "rsfm/sim/orbit.hpp"

namespace rsfm {

BoxScene makeBoxScene(const BoxSceneOptions& o, std::mt19937_64& rng) {
  if (o.frames < 1 || o.points_per_face < 1 || !(o.side > 0) || !(o.scale_px > 0) || !(o.beta > 0))
    throw std::runtime_error("box scene: frames, points, side, scale and beta must be positive");
  BoxScene s;
  s.options = o;
  orbitAboutY(o.frames, o.deg_per_frame, o.centre, &s.R, &s.t);
  const Eigen::Matrix3d Rx =
      Eigen::AngleAxisd(o.pitch_deg * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Eigen::Matrix3d B = Rx * rotationY(o.yaw_deg * M_PI / 180.0);
  // COP of camera k in reference coordinates: R_k^T ((0,0,-1/beta) - t_k).
  std::vector<Eigen::Vector3d> cops;
  for (int k = 0; k <= o.frames; ++k)
    cops.push_back(s.R[k].transpose() * (Eigen::Vector3d(0, 0, -1.0 / o.beta) - s.t[k]));
  struct Face {
    Eigen::Vector3d n, c, a1, a2;
    double min_cos;
  };
  std::vector<Face> faces;
  for (int axis = 0; axis < 3; ++axis)
    for (int sign : {-1, 1}) {
      Face f;
      Eigen::Vector3d nl = Eigen::Vector3d::Zero();
      nl[axis] = sign;
      f.n = B * nl;
      f.c = o.centre + 0.5 * o.side * f.n;
      f.a1 = B.col((axis + 1) % 3);
      f.a2 = B.col((axis + 2) % 3);
      f.min_cos = 1.0;
      for (const auto& cop : cops) f.min_cos = std::min(f.min_cos, f.n.dot((cop - f.c).normalized()));
      if (f.min_cos > 0.1) faces.push_back(f);  // seen from every camera, not too obliquely
    }
  std::sort(faces.begin(), faces.end(), [](const Face& a, const Face& b) { return a.min_cos > b.min_cos; });
  if (static_cast<int>(faces.size()) > o.max_faces) faces.resize(o.max_faces);
  if (faces.size() < 2) throw std::runtime_error("box scene: fewer than 2 faces visible throughout");

  const double lim = o.margin * (o.image_px / 2.0) / o.scale_px;
  auto visible = [&](const Eigen::Vector3d& X) { return visibleInAllFrames(s.R, s.t, o.beta, X, lim); };
  const double half = 0.5 * o.side * (1.0 - 2.0 * o.edge_margin);
  std::uniform_real_distribution<double> U(-half, half);
  for (size_t j = 0; j < faces.size(); ++j) {
    const Face& f = faces[j];
    const double d = f.n.dot(f.c);
    if (!(std::abs(d) > 1e-6)) throw std::runtime_error("box scene: a face plane passes through the origin");
    s.planes.push_back(f.n / d);
    s.normals.push_back(f.n);
    int got = 0, tries = 0;
    while (got < o.points_per_face) {
      if (++tries > 100000) throw std::runtime_error("box scene: a face has no visible region");
      const Eigen::Vector3d X = f.c + U(rng) * f.a1 + U(rng) * f.a2;
      if (!visible(X)) continue;
      s.points.push_back(X);
      s.labels.push_back(static_cast<int>(j));
      ++got;
    }
  }
  s.uv = projectAll(s.R, s.t, o.beta, s.points);
  return s;
}

}  // namespace rsfm
