#pragma once
// `rsfm bench regimes`: the regime suite's scoreboard (docs/regimes.md).
//
// Renders every selected sequence of the suite that is not yet in the cache, runs `rsfm run` with
// DEFAULT estimation options on each (a subprocess per run: its exit code, message and time are
// part of the score), evaluates the result against the truth, and adds the real rows: opencv-doc's
// box.mp4 in ten 150-frame windows, and the ViSP cube (and the rendered sequences COLMAP was run
// on) against the COLMAP references stored in the repository (bench/reference/colmap/). Writes
// DIR/scoreboard.csv, DIR/scoreboard.md and DIR/scoreboard.json, all-or-nothing, plus each run's
// outputs under DIR/runs/ and logs under DIR/logs/.
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "rsfm/render/truth_check.hpp"

namespace rsfm::regimes {

struct BenchOptions {
  std::filesystem::path out;             ///< DIR
  std::string suite;                     ///< suite file; empty: the built-in bench/regimes.json
  std::filesystem::path cache;           ///< rendered sequences; empty: $XDG_CACHE_HOME/rsfm/regimes or ~/.cache/rsfm/regimes
  std::vector<std::string> only;         ///< sequence names (and real rows: "box-mp4", "cube"); empty: all
  int jobs = 0;                          ///< concurrent jobs; 0: the number of cores
  bool real = true;                      ///< add the real rows (box.mp4 windows, the ViSP cube)
  std::string rsfm;                      ///< the rsfm binary to score; empty: this one (/proc/self/exe)
  std::vector<std::string> run_args;     ///< extra `rsfm run` arguments (default: none; for experiments only)
  std::string reference_dir;             ///< COLMAP references; empty: the ones built into the binary
};

/// One row of the scoreboard: a sequence (rendered or real) and what rsfm made of it.
struct Row {
  std::string sequence;
  std::string kind;         ///< "rendered", "real", "colmap" (COLMAP's own result against a rendered truth)
  std::string axes;         ///< the regime's axes, ';'-separated
  int frames = 0;           ///< frames in the input (the window)
  int exit_code = 0;        ///< of `rsfm run` (0 for COLMAP rows)
  std::string message;      ///< the error line, or warnings, or notes
  int frames_processed = 0; ///< poses in the estimate's trajectory
  double seconds = 0;       ///< wall time of `rsfm run` (tracking included)
  std::optional<double> truth_check_px;   ///< median |Lucas-Kanade track - truth| on the decoded video
  std::optional<double> focal_true, focal_est, focal_sd;
  /// A focal length reported not determined: the interval the data support (summary.json's
  /// focal_interval_px; a side the data do not limit is missing).
  std::optional<double> focal_interval_lo, focal_interval_hi;
  std::optional<double> focal_err_pct;
  std::optional<bool> focal_in_95;        ///< |f - f_true| <= 1.96 sd
  bool focal_determinable = true;         ///< from the truth (render/determinacy.hpp)
  bool focal_marked = false;              ///< the estimate reports the focal length not determined
  bool structure_determinable = true;
  int planes_true = 0, planes_found = 0, planes_matched = 0;
  std::optional<double> worst_normal_err_deg;
  int normals_in_95 = 0;                  ///< matched planes whose normal error is inside the 95 % region
  int reported_undetermined = 0;          ///< determinable quantities the estimate reports not determined
  /// The recursive filter's own estimate (summary.json's "online"; the main one without a refinement).
  std::optional<double> online_focal_err_pct;
  std::optional<bool> online_focal_in_95;
  std::optional<double> online_worst_normal_err_deg;
  int online_normals_in_95 = 0;
  /// The same with the online section's sds as reported: against the refinement when it ran
  /// (OnlineAccuracy, docs/estimate.md section 3) - the filter alone's above use the filter's
  /// own calibrated sds (summary.json online.filter_*).
  std::optional<bool> online_reported_focal_in_95;
  int online_reported_normals_in_95 = 0;
  std::optional<double> face_angle_err_deg;  ///< worst |angle between two estimated planes - true angle|
  std::optional<double> face_angle_deg;   ///< real rows: the angle between the two planes with the most tracks
  std::optional<double> face_angle_sd_deg;  ///< its reported sd (summary.json angles_between_planes_deg; determined only)
  /// Angles between planes with a determined angle and a 95 % interval, and how many of those
  /// intervals hold the truth: rendered rows, every pair of matched planes (the true angle between
  /// the truth's planes); box.mp4 windows, the two planes with the most tracks (two faces of a box:
  /// 90 deg).
  int face_angle_pairs = 0, face_angles_in_95 = 0;
  std::optional<double> ate_pct;          ///< ATE RMSE, % of the scene size (or of the trajectory's extent)
  std::optional<double> rpe_trans_pct, rpe_rot_deg;
  std::string undetermined;               ///< "-", "marked", "no output", "confident" (docs/regimes.md)
  std::optional<double> k1_true, k1_est;  ///< the render's k1 (rendered rows), the reference's (real rows); rsfm's or COLMAP's
  /// The rolling shutter's readout the refinement estimated and its sd (frame intervals;
  /// summary.json camera.readout, docs/estimate.md section 6), and the render's
  /// (RenderOptions::readout; 0 a global shutter; rendered rows only).
  std::optional<double> readout_est, readout_sd, readout_true;
  /// Rendered rows: rsfm's tracks (the run's tracks.csv) against the truth over their whole lives
  /// (render::tracksAgainstTruth): median and 95th percentile of |track - truth|, and the mean
  /// radial component of track - truth (> 0: outward), pixels.
  std::optional<double> track_err_median_px, track_err_p95_px, track_err_radial_px;
  /// scoreboard.json only: the radial component's median (the bulk's bias; the mean above mixes
  /// it with the tails) and the error by track age (render::TracksTruthError::by_age).
  std::optional<double> track_err_radial_median_px;
  std::vector<render::TracksTruthError::AgeBucket> track_err_by_age;
};

struct BenchResult {
  std::vector<Row> rows;
  double seconds = 0;
  std::vector<std::string> notes;
};

/// Checks the options without writing anything (the suite readable, --only's names known, --jobs
/// in range). Throws io::InputError with a one-line reason.
void checkBenchOptions(const BenchOptions& o);

/// Runs the bench; `progress` receives one line per finished step. Throws io::InputError on bad
/// options (unknown sequence, unreadable suite), std::runtime_error on failures of the bench itself
/// (a failing `rsfm run` is a row, not a failure).
BenchResult runBench(const BenchOptions& o, const std::function<void(const std::string&)>& progress);

/// The scoreboard files' text.
std::string scoreboardCsv(const BenchResult& r);
std::string scoreboardMarkdown(const BenchResult& r, const std::string& invocation);
std::string scoreboardJson(const BenchResult& r, const std::string& invocation);

}  // namespace rsfm::regimes
