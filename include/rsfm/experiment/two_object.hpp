#pragma once
// Two-object experiment (issue 3): the independent-motion planes filter (IndependentPlanesModel,
// state 1 + 9m, shared beta) on the two-object scene (sim/two_object_scene.hpp), over trials and
// noise levels. Noise protocol as Table 1: zero-mean uniform pixel noise of the given standard
// deviation on every frame, the reference frame included (the references are taken as exact by
// the model, as published). No I/O (report: io/two_object_report.hpp).
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "rsfm/sim/two_object_scene.hpp"

namespace rsfm {

struct TwoObjectOptions {
  int trials = 20;
  std::uint64_t seed = 1;
  std::vector<double> noise_px{0.5, 1.0, 2.0};  ///< uniform noise standard deviations (px)
  TwoObjectSceneOptions scene;
  double scale_px = 256.0;  ///< s: pixels per normalized unit (512 px image, 90 deg field of view)
  double beta0 = 0.5, beta_var0 = 0.1;  ///< as Table 1
  /// Initial planes: truth + N(0, (n_rel |N|)^2) on each free component (seeded per trial), the
  /// same prior variance; each plane's largest component is its gauge, at its true value.
  double n_rel = 0.1;
  /// Per-frame process variances of each object's (t_X, t_Y, t_Z beta) and omega (docs/filter.md).
  double q_translation = 3e-4, q_omega = 1e-4;
  double gate_probability = 0.999;
  /// Noise on the reference frame too (Table 1's protocol); false: exact reference positions.
  bool reference_noise = true;
  /// Treatment of the reference positions: exact | inflate | refine (ReferenceModel,
  /// docs/filter.md); refine as Table 1's default.
  std::string reference_model = "refine";
  int threads = 0;
  std::function<void(int, int)> progress;
};

/// Errors of one noise level: means over the successful trials at the last frame.
struct TwoObjectRow {
  double noise_px = 0;
  double rot_err_deg[2] = {0, 0};     ///< angle of R_est R_true^T per object
  double t_err_pct[2] = {0, 0};       ///< |t_est - t_true| / |t_true| x 100 per object
  double normal_err_deg[2] = {0, 0};  ///< angle between estimated and true plane normals
  double beta_err_pct = 0;            ///< |beta - 1| x 100 (shared beta)
  int trials = 0, failed = 0;
  std::string first_failure;
  /// Per frame 0..F, mean over successful trials: rotation error (deg) and translation error
  /// (scene units) per object, normal error (deg) per object, beta error (%).
  std::vector<double> rot_by_frame[2], t_by_frame[2], normal_by_frame[2], beta_by_frame;
};

struct TwoObjectResult {
  TwoObjectOptions options;
  double motion_rot_deg[2] = {0, 0};  ///< each object's total rotation (trial 0's scene)
  double motion_t[2] = {0, 0};        ///< |t| at the last frame per object
  std::vector<TwoObjectRow> rows;     ///< per noise level, in the order given
  double seconds = 0;
};

/// Empty when the options are valid, else a one-line message.
std::string validateTwoObjectOptions(const TwoObjectOptions& options);
/// Throws std::invalid_argument on invalid options.
TwoObjectResult runTwoObject(const TwoObjectOptions& options);

}  // namespace rsfm
