#pragma once
// Multi-plane experiment on the box scene (issue 3): the same noisy tracks of a cube's 2-3 faces
// estimated by
//   point             the A&P filter on all points (faces' planes fitted to its 3-D points),
//   plane-per-face    one independent plane filter per face (own motion, beta and gauge),
//   planes-rigid      the rigid multi-plane filter ([AS99] eq. 13: shared motion and beta, one N
//                     per face, one gauge),
//   planes-rigid-iekf the same with iterated updates,
//   batch             Ceres bundle adjustment over all frames, multi-plane, references estimated,
//                     started from planes-rigid (the maximum-likelihood reference).
#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "rsfm/rotation.hpp"
#include "rsfm/sim/box_scene.hpp"

namespace rsfm {

struct PlanesOptions {
  int trials = 20;
  std::uint64_t seed = 1;
  std::vector<double> noise_px{2.0, 6.0, 10.0};  ///< uniform noise standard deviations (px)
  /// Passes of the plane filters over the sequence (1: purely recursive; p > 1 restarts from
  /// the previous pass's final planes and beta with the original prior width, as
  /// `rsfm estimate --passes`, whose default is also 2). docs/planes.md has both.
  int passes = 2;
  BoxSceneOptions scene;
  RotationReading reading = RotationReading::Reset;
  double beta0 = 0.5, beta_var0 = 0.1;  ///< as Table 1
  /// Initial planes: truth + N(0, (n_rel |N|)^2) on each free component (seeded per trial), the
  /// same prior variance; the gauge component (largest |N| of the plane) is set to its true value.
  /// Relative to |N| (= 1 / distance), so near and far faces start equally far off in angle
  /// (~n_rel rad).
  double n_rel = 0.1;
  /// Per-frame process variances (docs/filter.md: identity dynamics must cover one frame's
  /// motion). The box orbit moves the camera by |c| theta = 3 x 0.0087 = 0.026 units and 0.5 deg
  /// per frame, always the same way. A random walk just wide enough for that step (1e-3 / 1e-4,
  /// sd 0.032 / 0.57 deg, the old default) pulls every pose back towards the previous one: the
  /// poses lag and bias the planes (ratio_to_batch 2.9 at 2 px). q_translation 3e-2 (sd 0.17)
  /// and q_omega 1e-3 (sd 1.8 deg) leave each pose to its frame's measurements, as in the batch
  /// (docs/planes.md).
  double q_translation = 3e-2, q_omega = 1e-3, q_beta = 0.0;
  /// Per-frame process variance of each plane (or point depth) component (0: none; fading memory).
  double q_structure = 0.0;
  double gate_probability = 0.999;
  std::string reference_model = "refine";  ///< exact | inflate | refine (docs/filter.md)
  int iekf_iterations = 5;                  ///< planes-rigid-iekf
  /// FilterOptions::iterate_after_frames of the iterated rows: the first frames use the plain
  /// update, since one frame's MAP there fits the noise in beta (docs/filter.md).
  int iekf_after = 10;
  /// FilterOptions::beta_min of every filter: 0.1 (f <= 10 normalized units, a field of view of
  /// at least 11 deg) keeps beta away from the t_Z = (t_Z beta) / beta pole (docs/planes.md).
  double beta_min = 0.1;
  /// FilterOptions::warmup_frames of every filter (iterated updates, warmup_iterations = 5, in the
  /// first frames): 0 by default; it fixes noise-free starts but not noisy ones (docs/planes.md).
  int warmup_frames = 0;
  bool batch = true;
  int threads = 0;
  std::function<void(int, int)> progress;
};

struct PlanesRow {
  std::string method;
  double noise_px = 0;
  double rms_t = 0, rms_q = 0;  ///< RMS over components, frames 1..F and trials (faces pooled)
  double normal_err_deg = 0;    ///< last frame, mean over faces and trials
  double face_angle_err_deg = 0;  ///< last frame, mean over face pairs and trials of |angle - 90|
  double beta_err_pct = 0;      ///< last frame, mean over trials (and faces) of |beta - 1| / 1
  double ratio_to_batch = -1;   ///< rms_t / batch rms_t on the same trials (-1: no batch)
  double crb_normal_deg = -1, crb_beta_pct = -1;  ///< batch only: Cramer-Rao bounds (mean)
  int trials = 0, failed = 0;
  std::string first_failure;
  std::vector<double> normal_err_by_frame;  ///< mean over trials and faces
  std::vector<double> t_err_by_frame;       ///< RMS over trials of |t error|
};

struct PlanesResult {
  PlanesOptions options;
  int faces = 0;
  std::vector<PlanesRow> rows;  ///< per method (in the order above) and noise level
  double seconds = 0;
};

std::string validatePlanesOptions(const PlanesOptions& options);
PlanesResult runPlanes(const PlanesOptions& options);

}  // namespace rsfm
