#pragma once
// Two planar objects moving independently in front of one camera (issue 3; docs/planes.md):
// object 0 is the Table 1 plane N = 2(1/sqrt3, 0, 1) turning about the y axis through (0, 0, 2);
// object 1 is a plane tilted about x, centred at `centre1`, turning about the x axis through its
// centre while drifting. A&P coordinates; camera-k coordinates of object j: R_k^j X + t_k^j.
#include <Eigen/Core>
#include <random>
#include <vector>

namespace rsfm {

struct TwoObjectSceneOptions {
  int frames = 100;
  int points_per_object = 30;
  double deg_per_frame0 = -0.4;                  ///< object 0: about y through (0, 0, 2)
  double deg_per_frame1 = 0.35;                  ///< object 1: about x through its centre
  double tilt1_rad = 0.35;                       ///< object 1's normal: (0, sin, cos) of this
  Eigen::Vector3d centre1{0.45, 0.0, 1.2};
  Eigen::Vector3d drift1{-0.002, 0.003, 0.002};  ///< object 1's extra translation per frame
  double half_size = 0.35;                       ///< half side of each object's square patch
  double lim = 0.9;                              ///< visible within |u|, |v| <= lim in every frame
};

struct TwoObjectScene {
  TwoObjectSceneOptions options;
  std::vector<Eigen::Vector3d> N;               ///< per object (N . X = 1)
  std::vector<std::vector<Eigen::Matrix3d>> R;  ///< [object][frame]
  std::vector<std::vector<Eigen::Vector3d>> t;  ///< [object][frame], (t_X, t_Y, t_Z)
  std::vector<Eigen::Vector3d> points;
  std::vector<int> labels;                      ///< object of each point
  std::vector<std::vector<Eigen::Vector2d>> uv;  ///< [frame][point], noise-free (beta = 1)
};

/// Throws std::runtime_error if an object has no region visible in every frame.
TwoObjectScene makeTwoObjectScene(const TwoObjectSceneOptions& options, std::mt19937_64& rng);

}  // namespace rsfm
