#pragma once
// Synthetic scenes observed through affine patches (Calway's experiment, [Cal00]; docs/patches.md).
// A patch is a cluster of 3-D surface points around a centre point; its measurement in frame k is
// the least-squares affine map of the cluster's images from frame k-1 to frame k about the centre's
// image in frame k-1 (so curvature of the surface within the cluster is in the data, as with
// Calway's clusters of points). Coordinates: A&P (origin on the image plane, COP at (0, 0, -1/beta)).
//   - Sphere scene: 8 clusters on a sphere that translates along all three axes and rotates about
//     x and y (sinusoidally); f = 1 (beta = 1) with a 53-degree field of view (image half-width 0.5).
//   - Plane scene: the Table 1 scene ([AS99] §4) with a cluster around each of its points.
#include <Eigen/Core>
#include <random>
#include <vector>

#include "rsfm/models/patch_model.hpp"
#include "rsfm/sim/table1_scene.hpp"

namespace rsfm {

struct SphereSceneOptions {
  int frames = 200;                 ///< frames after the first (0..frames)
  int patches = 8;                  ///< clusters
  double beta = 1.0;                ///< f = 1
  double radius = 1.0;              ///< sphere radius (scene units)
  Eigen::Vector3d centre{0.0, 0.0, 1.5};  ///< sphere centre in frame 0 (A&P; 2.5 from the COP)
  /// Motion of the sphere, one period over the sequence (phase 2 pi k / frames): its centre moves
  /// by (a_x sin, a_y sin(. + 1), a_z (1 - cos)) and it turns about its centre by angle_x sin about
  /// the camera's x axis and angle_y sin(. + 1) about its y axis. A sinusoid keeps the clusters in
  /// view while the views span +-angle; identity dynamics must follow the changing velocity.
  Eigen::Vector3d amplitude{0.25, 0.15, 0.4};
  double angle_x_deg = 15.0, angle_y_deg = 20.0;
  /// Clusters are centred within this angle (deg) of the sphere point facing the camera.
  double max_off_axis_deg = 35.0;
  /// A cluster is re-drawn unless, in every frame, all its points are in the image and its surface
  /// is seen no more obliquely than this (deg, between the normal and the line of sight): beyond
  /// 75 deg a patch is foreshortened about 4x and a tracker would lose it. Without this rule the
  /// scene kept patches that turned nearly edge-on (docs/patches.md).
  double max_obliquity_deg = 75.0;
  /// Minimum angle between two cluster centres as seen from the sphere centre (deg).
  double min_separation_deg = 15.0;
  double cluster_deg = 6.5;         ///< cluster diameter as seen from the camera (deg)
  int cluster_points = 12;          ///< points per cluster (plus the centre)
};

struct PlanePatchSceneOptions {
  Table1SceneOptions table1;        ///< the Table 1 scene (100 frames, beta 1, s = 256)
  int patches = 20;                 ///< clusters (patch centres are Table 1 points)
  double cluster_deg = 6.5;         ///< cluster diameter as seen from the camera (deg)
  int cluster_points = 12;
};

/// A scene's truth and its noise-free patch measurements.
struct PatchScene {
  double beta = 1.0;
  double scale_px = 256.0;  ///< pixels per normalized unit (for reporting in pixels)
  /// Per frame k: reference (frame 0) -> camera k, X_k = R[k] X_0 + t[k] (A&P coordinates).
  std::vector<Eigen::Matrix3d> R;
  std::vector<Eigen::Vector3d> t;
  /// Per frame k >= 1: the true inter-frame motion as the patch state's first 7 components
  /// (t_X, t_Y, t_Z beta, omega, beta); [0] is zero motion.
  std::vector<Eigen::Matrix<double, 7, 1>> motion;
  std::vector<std::vector<Eigen::Vector2d>> centre;   ///< [frame][patch] centre image (normalized)
  std::vector<std::vector<Vector6d>> affine;          ///< [frame >= 1][patch] (h, A) fitted k-1 -> k
  std::vector<std::vector<Eigen::Vector3d>> structure;  ///< [frame][patch] true (p1, p2, p4), frame k
  std::vector<std::vector<Eigen::Vector3d>> normal;     ///< [frame][patch] true unit normal, frame k (away from the camera)
  Eigen::Vector3d plane_normal0 = Eigen::Vector3d::Zero();  ///< plane scene: unit normal in frame 0
  std::vector<Eigen::Vector3d> centre_points0;              ///< centres' 3-D points, frame 0
  int frames() const { return static_cast<int>(R.size()) - 1; }
  int patches() const { return centre.empty() ? 0 : static_cast<int>(centre[0].size()); }
};

/// Throws std::runtime_error when the options leave no valid scene (e.g. a patch leaves the view).
PatchScene makeSphereScene(const SphereSceneOptions& options, std::mt19937_64& rng);
PatchScene makePlanePatchScene(const PlanePatchSceneOptions& options, std::mt19937_64& rng);

/// Calway's noise model ("about 10 % of each affine parameter's largest magnitude"): standard
/// deviation rho * max |.| over all frames and patches, with the largest magnitude taken over the
/// centre's displacement (both coordinates) for h and over the four entries of A - I for A (a
/// parameter that never moves, A_12 when the camera turns about y, would get a zero deviation).
Vector6d relativeNoiseSd(const PatchScene& scene, double rho);

}  // namespace rsfm
