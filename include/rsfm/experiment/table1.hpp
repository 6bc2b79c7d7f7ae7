#pragma once
// The paper's synthetic experiment ([AS99] §4, Table 1, Fig. 1; docs/table1.md): the point
// (A&P) and plane (Alon-Sclaroff) filters run on the SAME noisy tracks of the Table 1 scene,
// trials in parallel, reproducible for a given seed whatever the thread count.
#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "rsfm/filters/recursive_filter.hpp"
#include "rsfm/rotation.hpp"
#include "rsfm/sim/table1_scene.hpp"

namespace rsfm {

/// Every choice the paper leaves open is here with its default (written into table1.md).
struct Table1Options {
  int trials = 20;                           ///< trials per noise level (paper: 20)
  std::uint64_t seed = 1;  ///< base seed: scene per trial, noise per (trial, level value)
  std::vector<double> noise_px{2.0, 6.0, 10.0};  ///< uniform-noise standard deviations (px)
  Table1SceneOptions scene;                  ///< geometry, motion, image size, s
  RotationReading reading = RotationReading::Reset;  ///< how omega is read between frames
  double beta0 = 0.5;                        ///< initial beta (paper)
  double beta_var0 = 0.1;                    ///< its variance (paper)
  Eigen::Vector3d N0{1.5, 0.5, 2.0};         ///< initial plane (paper)
  Eigen::Vector3d N_var0{0.1, 0.1, 0.0};     ///< its variances (paper; N_Z = gauge)
  double q_translation = 3e-4;   ///< per-frame variance of t_X, t_Y, t_Z beta (scene units^2)
  double q_omega = 1e-4;         ///< per-frame variance of each omega component (rad^2)
  double q_beta = 0.0;           ///< per-frame variance of beta
  double q_structure = 0.0;      ///< per-frame variance of each free structure component
  double r_scale = 1.0;          ///< R = r_scale * (noise_px / s)^2 per coordinate
  /// Noise on the reference frame too (its noisy positions become the filters' first-frame
  /// coordinates, which the A&P models treat as exact: [AS99] §2's "known weakness").
  bool reference_noise = true;
  double gate_probability = 0.999;  ///< per-point chi2 gate (<= 0 disables)
  int iterations = 1;            ///< measurement-update iterations (1 = EKF, > 1 = iterated EKF)
  /// The "plane-iekf" row: the plane filter with this many update iterations (<= 1: no row).
  int iekf_iterations = 5;
  /// FilterOptions::iterate_after_frames of the iterated rows: the first frames use the plain
  /// update, since one frame's MAP there fits the noise in beta (docs/filter.md).
  int iekf_after = 10;
  /// The "batch" row: Ceres bundle adjustment over all frames started from the plane filter,
  /// reference positions estimated (maximum likelihood; include/rsfm/batch/plane_batch.hpp).
  bool batch = true;
  /// Treatment of the noisy reference positions (exact = as published; see ReferenceModel).
  std::string reference_model = "refine";
  /// Point model: initial depths from the initial plane N0 with beta0 ("plane") or all equal to
  /// the initial plane's depth on the optical axis ("constant").
  std::string alpha_init = "plane";
  /// Point model: initial depth variance; <= 0 means "propagate": each alpha gets the variance
  /// that the plane prior (beta_var0, N_var0) implies for its depth (no cross-correlation).
  double alpha_var = -1.0;
  /// Point model gauge: index of the fixed alpha; -1 = the point nearest the image centre.
  /// The fixed alpha is set to that point's true depth (as N_Z is set to its true value).
  int point_gauge = -1;
  int threads = 0;  ///< worker threads (0 = all cores)
  /// Progress callback (done, total); called from worker threads, serialized.
  std::function<void(int, int)> progress;
};

/// Trial-averaged estimates of one formulation at one noise level, per frame 0..F.
struct Table1Series {
  std::string formulation;  ///< "plane", "plane-iekf", "batch" or "point"
  double noise_px = 0.0;
  std::vector<double> t_x, t_zb, q0, q2, n_x, n_y, beta;  ///< means over successful trials
  std::vector<double> normal_err_deg;  ///< mean over trials of each trial's normal error
};

struct Table1Row {
  static constexpr int kNotComputed = -2;  ///< r_s / r_c when every trial stopped (written NA)
  std::string formulation;
  double noise_px = 0.0;
  double m_t = 0, sigma_t = 0, m_q = 0, sigma_q = 0;  ///< mean / RMS error (all comps, frames 1..F)
  /// Median over trials of each trial's own RMS error: robust to the rare divergent trial that
  /// dominates sigma_t / sigma_q.
  double median_trial_sigma_t = 0, median_trial_sigma_q = 0;
  int r_s = -1;  ///< first frame from which the mean normal stays within 0.5 deg (-1: never)
  int r_c = -1;  ///< first frame from which the mean beta stays within 5 % (-1: never)
  double final_normal_err_deg = 0;  ///< mean over trials, last frame
  double final_beta_err_pct = 0;    ///< mean |beta - beta_true| / beta_true over trials, last frame
  double nees_static = 0;           ///< mean NEES of (beta, N_X, N_Y) at the last frame (plane filters)
  /// Batch only: mean over trials of the Cramer-Rao bounds at the optimum: beta's standard
  /// deviation (% of beta) and the RMS angle of the unit normal (deg); -1 when not computed.
  double crb_beta_pct = -1, crb_normal_deg = -1;
  int nees_dof = 0;                 ///< its dof per trial (0 when not computed)
  double mean_nis_per_dof = 0;      ///< mean NIS / dof over frames and trials
  long gated = 0;                   ///< points gated, summed over frames and trials
  long invalid = 0;                 ///< observations whose prediction failed (left out), summed
  int trials = 0, failed = 0;       ///< trials run, trials stopped by numerical trouble
  std::string first_failure;        ///< description of the first failure, if any
};

struct Table1Truth {
  std::vector<double> t_x, t_zb, q0, q2;  ///< per frame
  double n_x = 0, n_y = 0, beta = 1;
};

struct Table1Result {
  Table1Options options;
  std::vector<Table1Row> rows;        ///< plane then point for each noise level... (see order)
  std::vector<Table1Series> series;   ///< same order as rows
  Table1Truth truth;
  double seconds = 0;
};

/// Runs the whole experiment. Throws std::invalid_argument on bad options.
Table1Result runTable1(const Table1Options& options);

/// Validates options; returns an empty string when they are fine, else a one-line message.
std::string validateTable1Options(const Table1Options& options);

}  // namespace rsfm
