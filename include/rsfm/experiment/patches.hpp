#pragma once
// Calway's synthetic experiment ([Cal00]; docs/patches.md): the affine-patch filter (exact and
// instantaneous measurements) and the A&P point filter run on the patches' centres, on the SAME
// noisy data, in two scenes: 8 clusters on a moving sphere (200 frames) and the Table 1 plane seen
// through patches (100 frames). Trials run in parallel and are reproducible for a given seed.
#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "rsfm/filters/patch_filter.hpp"
#include "rsfm/sim/patch_scene.hpp"

namespace rsfm {

struct PatchesOptions {
  int trials = 10;
  std::uint64_t seed = 1;
  /// Noise levels rho: each flow parameter j of (h - c, A - I) gets Gaussian noise of standard
  /// deviation rho * max |parameter j| over the scene (Calway's "about 10 % of each parameter's
  /// largest magnitude"); the centres the point filter sees carry the same noise as h.
  std::vector<double> sphere_noise{0.1};
  std::vector<double> plane_noise{0.05, 0.1, 0.2};
  SphereSceneOptions sphere;
  PlanePatchSceneOptions plane;
  // Shared prior (both filters): beta0 with variance beta_var0 (Table 1's 0.5 and 0.1); structure
  // fronto-parallel at the gauge patch's true depth; the gauge (the patch nearest the image
  // centre) holds its true value, like N_Z in Table 1.
  double beta0 = 0.5, beta_var0 = 0.1;
  double normal_var0 = 1.0;   ///< patch filter: variance of p1 and p2
  double depth_rel_sd0 = 0.5;  ///< patch p4 / point alpha: standard deviation relative to the value
  /// Patch filter: initial variance of each inter-frame motion component, and its per-frame
  /// process variances (translation components, rotation components).
  double motion_var0 = 1e-4;
  double q_translation = 1e-6, q_omega = 1e-6;
  /// Patch filter: R annealing over the first frames (PatchFilterOptions::anneal_frames/_factor);
  /// -1: over the first half of each scene's sequence (sphere 100 of 200 frames, plane 50 of 100).
  int anneal_frames = -1;
  double anneal_factor = 100.0;
  PatchCentres centres = PatchCentres::Fused;  ///< PatchFilterOptions::centres (centre_sd = the centres' noise)
  int iterations = 1;            ///< patch filter update iterations (1 = EKF)
  double q_structure = 0.0;      ///< patch filter: per-frame variance of each structure parameter
  /// Point filter (reset reading, refined references as in Table 1): per-frame process variances.
  double point_q_translation = 3e-4, point_q_omega = 1e-4;
  double gate_probability = 0.999;
  /// Convergence thresholds of frames_to_converge (trial-mean normal error and beta error).
  double converge_normal_deg = 5.0, converge_beta_pct = 5.0;
  int threads = 0;
  std::function<void(int, int)> progress;
};

/// One (scene, measurement, noise) row of patches.csv.
struct PatchesRow {
  std::string scene;        ///< "sphere" or "plane"
  std::string measurement;  ///< "exact", "instantaneous" (patch filter) or "point-centres"
  double noise = 0;         ///< rho
  double rms_t = 0, rms_q = 0;  ///< RMS error of camera position (first-frame units) / quaternion components, frames 1..F
  /// Normal error at the last frame, mean over trials. Sphere: the patch filter's mean over
  /// patches of each patch normal's angle error (NA for the point filter: a point has no normal).
  /// Plane: the plane fitted to the filter's 3-D patch centres (the Table 1 protocol) for every method.
  double normal_err_deg = 0;
  double patch_normal_err_deg = 0;  ///< patch filter: mean over patches of each patch normal's error
  double max_normal_err_deg = 0;    ///< patch filter: largest patch normal error (mean over trials)
  double worst_normal_err_deg = 0;  ///< patch filter: largest patch normal error over all trials
  double normal_err_frame100 = 0;   ///< normal_err_deg's series at frame 100 (plane scene: the last frame)
  double beta_err_pct = 0;
  double worst_beta_err_pct = 0;  ///< largest beta error over the trials (%)
  int trials_beta_within = 0;     ///< trials whose last-frame beta error is within converge_beta_pct
  int frames_to_converge = -1;   ///< first frame from which both thresholds hold to the end (-1: never)
  int trials = 0, failed = 0;
  std::string first_failure;
  std::vector<double> normal_by_frame, beta_by_frame;  ///< trial means per frame
};

struct PatchesResult {
  PatchesOptions options;
  std::vector<PatchesRow> rows;
  double seconds = 0;
};

std::string validatePatchesOptions(const PatchesOptions& o);
/// Throws std::invalid_argument on bad options.
PatchesResult runPatches(const PatchesOptions& o);

}  // namespace rsfm
