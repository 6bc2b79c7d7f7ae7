#pragma once
// `rsfm evaluate`: an estimate directory against a truth directory (docs/evaluate.md).
// Each directory holds trajectory.tum (rsfm::io::readTum) and summary.json (rsfm::io::readSummary).
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "rsfm/eval/trajectory_metrics.hpp"
#include "rsfm/io/input_error.hpp"
#include "rsfm/io/summary.hpp"

namespace rsfm::report {

struct EvaluateOptions {
  long long rpe_delta = 1;  ///< RPE frame distance (frames, >= 1)
  /// Association (as evo's --t_max_diff): a truth pose and the estimate pose nearest in time are
  /// one pair when their timestamps differ by at most this (seconds, or frames when neither
  /// summary states a frame rate).
  double t_max_diff = 0.01;
};

struct PlaneEvaluation {
  std::string name;             ///< truth plane name (or "plane<i>")
  int estimate = -1;            ///< matched estimated plane, -1 = unmatched
  double angle_deg = 0;         ///< normal angle error (matched only)
  double distance_truth = 0;
  double distance_est_scaled = 0;  ///< estimated distance times the Sim(3) scale (matched only)
  double distance_err_pct = 0;     ///< 100 (scaled - truth) / truth (matched only)
};

struct Evaluation {
  std::filesystem::path estimate_dir, truth_dir;
  int truth_poses = 0, estimate_poses = 0, matched = 0;
  eval::AteResult ate;
  bool relative_to_scene_size = true;  ///< false: relative to the truth trajectory's extent
  double scale_ref = 0;                ///< scene_size or trajectory extent (truth units)
  eval::RpeResult rpe;
  long long rpe_delta = 1;
  std::string timestamps = "frame";  ///< "seconds" (a summary states fps) or "frame"
  double t_max_diff = 0.01;
  double alignment_rotation_deg = 0;
  std::optional<double> focal_truth, focal_est, focal_err_pct;
  std::vector<PlaneEvaluation> planes;   ///< one per truth plane
  std::vector<int> unmatched_estimates;  ///< estimated planes with no truth plane
  std::vector<std::string> notes;        ///< warnings (image size mismatch, degenerate alignment...)
};

/// Association by timestamp (docs/evaluate.md): `truth` and `est` are increasing times; each truth
/// time is a candidate pair with the estimate times on either side of it that lie within
/// `max_diff`; the nearest pairs are taken first, each time used once (evo's nearest-in-time rule,
/// one to one). Returns (truth index, estimate index) pairs in time order.
std::vector<std::pair<std::size_t, std::size_t>> associateByTime(const std::vector<double>& truth,
                                                                const std::vector<double>& est, double max_diff);

/// Reads both directories and computes every metric. `truth_dir` may also be a bare TUM
/// trajectory file (timestamps in seconds; the estimate must be in seconds too): poses only.
/// Throws InputError on unreadable or invalid files and when fewer than 3 poses are associated
/// by timestamp.
Evaluation evaluateDirectories(const std::filesystem::path& estimate_dir, const std::filesystem::path& truth_dir,
                               const EvaluateOptions& opt);

std::string evaluationJson(const Evaluation& e);
/// The readable table printed on stdout (also the body of evaluation.md).
std::string evaluationTable(const Evaluation& e);
std::string evaluationMarkdown(const Evaluation& e, const std::string& invocation);

/// Writes out_dir/evaluation.json and out_dir/evaluation.md all-or-nothing (io::AtomicFileSet).
void writeEvaluation(const Evaluation& e, const std::filesystem::path& out_dir, const std::string& invocation);

}  // namespace rsfm::report
