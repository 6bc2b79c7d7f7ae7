#pragma once
// Calway's patch filter on real affine-patch tracks (docs/patches.md). No I/O, no OpenCV.
//
// Pixels -> normalized units as the point/plane pipeline (u = (x - c_x) / s, s = max(W, H) / 2 by
// default; A is unitless). Frame k's measurement of patch p, present in frames k-1 and k, is its
// centre in frame k and the inter-frame map A_k A_{k-1}^-1 (the tracker's maps are from the
// patch's first appearance). Patches present in the first frame start the filter; patches that
// end leave the state (the gauge moves if it was the gauge patch); patches that start later join
// after the frame in which they are first seen, fronto-parallel at the median depth of the live
// patches (PatchFilter::addPatch; no cross-covariance). Scale gauge: the patch nearest the image
// centre in the first frame, its p4 fixed at the start depth g0 = Z0 / (1 + beta0 Z0) with
// Z0 = depth0 / beta0 (depth0 focal lengths beyond the image plane), so translations are in those
// units (first-frame units; PatchFilter::scale()).
#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <optional>

#include "rsfm/filters/patch_filter.hpp"
#include "rsfm/track/patches.hpp"

namespace rsfm {

struct PatchPipelineOptions {
  double scale_px = 0.0;     ///< s (<= 0: max(width, height) / 2)
  double focal_px = 0.0;     ///< known focal length (px): beta fixed (<= 0: estimated)
  double focal0_px = 0.0;    ///< initial focal guess (px) (<= 0: max(width, height), ~53 deg across)
  /// Initial sd of beta relative to beta0. Unset: 0.3 for a guessed focal length, 0.1 after a
  /// homography start (estimatePatches(), pipeline/estimate.hpp).
  std::optional<double> beta_sd0;
  static constexpr double kGuessBetaSd0 = 0.3;
  double depth0 = 10.0;      ///< start depth of every patch in focal lengths beyond the image plane
  double normal_sd0 = 1.0;   ///< initial sd of p1, p2 of every patch
  double depth_rel_sd0 = 0.5;  ///< initial sd of p4 relative to g0
  double motion_sd0 = 0.01;  ///< initial sd of each inter-frame motion component
  /// Measurement noise: centre position (px) and each entry of the inter-frame map A (unitless).
  /// The inter-frame map's entries are differences of two tracker outputs, and real sequences add
  /// blur and non-planarity, hence the margin on A.
  /// Measured on the rendered box and the ViSP cube (second differences of the tracks): centres
  /// 0.02-0.05 px, cumulative A entries 0.001-0.0017 (robust sd), with heavier tails.
  double sigma_px = 0.05;
  double sigma_affine = 0.008;
  /// Per-frame process variances of the inter-frame translation (t_X, t_Y relative to the start
  /// depth Z0, squared; t_Z beta likewise) and rotation (rad^2): hand-held motion changes from frame
  /// to frame. q_omega 1e-4 (sd 0.57 deg per frame of change in the inter-frame rotation): with
  /// 1e-5 (0.18 deg) the filter could not follow the ViSP cube's rotation starting after 17 still
  /// frames, and the floor patches took the other branch of the planar two-fold ambiguity (floor
  /// 55 deg off the first view's axis, rotation 13 deg instead of ~35; docs/patches.md).
  double q_trans_rel = 0.003;
  double q_omega = 1e-4;
  int anneal_frames = 30;
  double anneal_factor = 100.0;
  PatchCentres centres = PatchCentres::Fused;
  /// The tracker's maps are from each patch's first appearance, so inter-frame maps
  /// A_k A_{k-1}^-1 have noise correlated from frame to frame (each A appears in two of them),
  /// and used as independent they waste most of the deformation's information. With fused_maps
  /// each patch's cumulative map is estimated beside the filter (its prediction through the
  /// posterior's inter-frame map, fused with the tracker's map of noise sd sigma_map), and the
  /// measurement is A_k Ahat_{k-1}^-1 with Ahat's uncertainty added to R.
  bool fused_maps = false;
  double sigma_map = 0.003;
  AffineMeasurement measurement = AffineMeasurement::Exact;
  int min_patch_frames = 3;  ///< patches seen in fewer frames are left out
  /// A still start: until the live patches' median displacement from the first frame exceeds
  /// still_px, frames are taken as still (pose identity, no filter step), and the first step
  /// maps the first frame to the first moving one. Stepping through still frames spent the
  /// start-up (R annealing, a wide motion prior) on them and left the filter too confident of
  /// zero motion when it began: on the ViSP cube (17 still frames, 0.01 px jitter) the floor then
  /// took the wrong branch of the planar two-fold ambiguity under several settings (docs/patches.md).
  /// <= 0: every frame is stepped.
  double still_px = 0.25;
  double gate_probability = 0.999;
};

/// One patch's estimate after a frame (current camera frame).
struct PatchEstimate {
  int id = 0;
  Eigen::Vector2d px = Eigen::Vector2d::Zero();  ///< centre used by the filter (pixels)
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< unit normal, current camera frame, away from the camera
  double normal_sd_deg = 0.0;  ///< first-order sd of the normal's direction (sqrt of trace), degrees
  double depth = 0.0;          ///< Z of the patch centre (A&P, current frame; gauge units)
};

struct PatchRunFrame {
  int frame = 0;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  ///< first camera -> camera k (COP-centred frames)
  Eigen::Vector3d T = Eigen::Vector3d::Zero();      ///< X_k = R X_0 + T (first-frame units)
  double beta = 0.0, var_beta = 0.0;
  std::vector<PatchEstimate> patches;
  int observed = 0, used = 0, gated = 0;
  double nis_per_dof = 0.0;
  double rms_px = 0.0;  ///< posterior RMS of the accepted centre residuals (px)
};

struct PatchRunResult {
  std::vector<PatchRunFrame> frames;  ///< frames[0] is the first frame (prior)
  double scale_px = 0.0;
  int entered = 0;   ///< patches that entered the filter
  int joined = 0;    ///< of which after the first frame
  int left = 0;      ///< patches removed when their track ended
  int still_frames = 0;  ///< frames after the first taken as still (PatchPipelineOptions::still_px)
  std::string stopped;  ///< empty when every frame was processed, else why not
  bool ok() const { return stopped.empty(); }
};

/// Agreement of the live patches' normals in one frame, in the first camera's frame: the median
/// normal (component-wise median, normalized) and each patch's angle to it.
struct NormalAgreement {
  Eigen::Vector3d median = Eigen::Vector3d::UnitZ();
  std::vector<int> ids;
  std::vector<double> angle_deg;  ///< per patch, same order as ids
  double median_deg = 0, p90_deg = 0, max_deg = 0;
  int within_5deg = 0;
};
NormalAgreement normalAgreement(const PatchRunFrame& f);

/// Throws std::invalid_argument for options out of range or fewer than PatchModel::kMinPatches
/// usable patches in the first frame.
PatchRunResult runPatchTracks(const PatchTracks& tracks, const PatchPipelineOptions& options,
                              const std::function<void(int, int)>& progress = {});

}  // namespace rsfm
