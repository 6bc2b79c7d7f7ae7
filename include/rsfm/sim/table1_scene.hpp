#pragma once
// Synthetic scene of the paper's first experiment ([AS99] §4; docs/table1.md).
// A plane N . X = 1 with N = 2 (1/sqrt(3), 0, 1) (unit normal 30 degrees off the optical axis,
// distance 0.433 from the image-plane origin), ~30 points scattered uniformly on it, camera
// motion = rotation about the y axis through c = (0, 0, 2): R_k = R_y(k * theta), t_k = (I - R_k) c,
// beta = 1. Coordinates are A&P's (origin on the image plane, COP at (0, 0, -1/beta)).
#include <Eigen/Core>
#include <cstdint>
#include <random>
#include <vector>

namespace rsfm {

struct Table1SceneOptions {
  int frames = 100;              ///< frames after the reference frame 0 (frames 0..frames)
  int points = 30;               ///< points on the plane
  double deg_per_frame = -0.5;   ///< rotation about y per frame (deg); 50 deg total: the plane's
                                 ///< normal goes from 30 deg off-axis through frontal to 20 deg
  Eigen::Vector3d centre{0.0, 0.0, 2.0};  ///< point on the rotation axis (A&P coordinates)
  Eigen::Vector3d plane{2.0 / 1.7320508075688772, 0.0, 2.0};  ///< true N (N . X = 1)
  double beta = 1.0;             ///< true inverse focal length (normalized units)
  double image_px = 512.0;       ///< square image side (px)
  double scale_px = 256.0;       ///< s: pixels per normalized unit (256 -> 90 deg field of view)
  double margin = 0.9;           ///< points stay within this fraction of the half-image in every frame
};

struct Table1Scene {
  Table1SceneOptions options;
  std::vector<Eigen::Vector3d> points;                ///< reference-frame 3-D points
  std::vector<Eigen::Matrix3d> R;                     ///< per frame: reference -> camera k
  std::vector<Eigen::Vector3d> t;                     ///< per frame: (t_X, t_Y, t_Z), A&P coords
  std::vector<std::vector<Eigen::Vector2d>> uv;       ///< [frame][point] noiseless, normalized
  Eigen::Vector3d unitNormal() const { return options.plane.normalized(); }
};

/// Samples points uniformly on the plane (rejection: visible within the margin in every frame).
/// Throws std::runtime_error if the options leave no visible region.
Table1Scene makeTable1Scene(const Table1SceneOptions& options, std::mt19937_64& rng);

/// Adds zero-mean uniform noise of standard deviation sigma_px (pixels) to both coordinates:
/// U(-a, a) with a = sqrt(3) sigma. Returns noisy normalized coordinates [frame][point].
std::vector<std::vector<Eigen::Vector2d>> addUniformNoise(
    const std::vector<std::vector<Eigen::Vector2d>>& uv, double sigma_px, double scale_px,
    std::mt19937_64& rng);

/// Deterministic seed for (base seed, stream a, stream b) (SplitMix64 mixing).
std::uint64_t mixSeed(std::uint64_t seed, std::uint64_t a, std::uint64_t b = 0);

}  // namespace rsfm
