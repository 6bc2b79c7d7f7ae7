#pragma once
// Test helper: tracks of a rendered regime's geometry, without rendering images.
#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>
#include <random>
#include <vector>

#include "rsfm/io/summary.hpp"
#include "rsfm/render/scene_render.hpp"
#include "rsfm/track/tracks.hpp"

namespace rsfm::test {

/// Tracks of a rendered regime's geometry without rendering images: a grid of points on its
/// textured faces, followed while the truth's labels show them, projected by the truth camera
/// (distortion and principal point included), with Gaussian noise.
struct RegimeTracks {
  Tracks tracks;
  io::Summary truth;
};
/// `ar_rho` > 0: each track's error drifts as AR(1), e_k = rho e_{k-1} + sqrt(1 - rho^2) g_k (a
/// tracker's error); 0: independent noise (the same draws as before the option existed).
/// `grid`: points per face side (grid x grid points on each face). `later_tracks`: a point out of
/// view in frame 0 is tracked from the frame it comes into view (false: only the points seen in
/// frame 0 are tracked, as before the option existed).
inline RegimeTracks regimeTracks(const render::RenderOptions& o, double noise_px, unsigned seed, double ar_rho = 0.0, int grid = 12,
                                 bool later_tracks = false) {
  render::Scene scene(o);
  RegimeTracks out;
  out.truth = scene.truth();
  Tracks& t = out.tracks;
  t.image = ImageInfo::centred(o.width, o.height);  // the principal point is not given
  t.frames.resize(o.frames);
  std::vector<cv::Mat> labels;
  for (int k = 0; k < o.frames; ++k) labels.push_back(scene.labels(k));
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0.0, noise_px);
  int id = 0;
  for (const auto& f : scene.faces()) {
    if (f.still_body || !f.textured || f.truth_index < 0) continue;
    for (int i = 0; i < grid; ++i)
      for (int j = 0; j < grid; ++j) {
        const Eigen::Vector3d X =
            f.corners[0] + (i + 0.5) / grid * (f.corners[1] - f.corners[0]) + (j + 0.5) / grid * (f.corners[3] - f.corners[0]);
        bool alive = true, any = false;
        Eigen::Vector2d e(0, 0);
        for (int k = 0; k < o.frames && (alive || (later_tracks && !any)); ++k) {
          const auto x = scene.project(X, k);
          alive = x && x->x() > 5 && x->y() > 5 && x->x() < o.width - 6 && x->y() < o.height - 6 &&
                  labels[k].at<uchar>(static_cast<int>(std::lround(x->y())), static_cast<int>(std::lround(x->x()))) ==
                      f.truth_index + 1;
          if (alive) {
            const Eigen::Vector2d gk(g(rng), g(rng));
            e = any ? Eigen::Vector2d(ar_rho * e + std::sqrt(1.0 - ar_rho * ar_rho) * gk) : gk;
            t.frames[k].push_back({id, *x + e});
            any = true;
          }
        }
        if (any) ++id;
      }
  }
  for (auto& fr : t.frames) std::sort(fr.begin(), fr.end(), [](const TrackPoint& a, const TrackPoint& b) { return a.id < b.id; });
  return out;
}


}  // namespace rsfm::test
