#pragma once
// Outputs of `rsfm estimate` / `rsfm run` (docs/outputs.md, "rsfm estimate"): trajectory.tum,
// planes.csv, summary.json, labels.csv, poses.csv and the plots motion/normals/focal/process_noise
// (.png, .svg);
// with a refinement (pipeline/refine.hpp) its result is the main one and the filter's is kept in
// trajectory_online.tum, planes.csv's per-frame rows and summary.json's "online" section.
#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

#include "rsfm/io/atomic_file.hpp"
#include "rsfm/io/tum.hpp"
#include "rsfm/pipeline/refine.hpp"
#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/report/report.hpp"
#include "rsfm/track/tracks.hpp"

namespace rsfm::report {

/// A calibration the user gave (`--camera`): the tracks were undistorted onto its pinhole before
/// the estimation, so it is reported as given, not as estimated.
struct GivenCamera {
  double focal_px = 0, cx = 0, cy = 0;
  std::vector<double> distortion;  ///< OpenCV's order: k1, k2, p1, p2[, k3, ...]
  std::string source;              ///< the file
};

struct EstimateReport {
  const Tracks* tracks = nullptr;
  const std::vector<int>* labels = nullptr;  ///< per track id: plane, -1 outlier, -2 unused
  /// Per track id: the index in `tracks` of the last frame whose observation the estimate used
  /// (before the track's last for one that left its plane, PlaneFinding::cut_after; an estimate
  /// that ended early; a held still stretch); -1: none. Null: each track's last frame.
  const std::vector<int>* last_used = nullptr;
  const TrackFilterResult* result = nullptr;  ///< the online filter's run
  const RefineResult* refined = nullptr;      ///< the refinement (null or not ok: none)
  const GivenCamera* given_camera = nullptr;  ///< --camera (null: none given)
  bool focal_given = false;                   ///< the focal length was given (--focal-px or --camera): held, not estimated
  TrackModel model = TrackModel::Planes;
  std::string command;
  double seconds = 0.0;
  nlohmann::json extra = nlohmann::json::object();  ///< merged into summary.json (e.g. plane finding)
};

/// Camera pose of one frame in the reference camera frame (TUM convention: position of the
/// centre, Hamilton rotation camera -> reference).
void poseOf(const TrackFrame& f, Eigen::Vector3d* position, Eigen::Quaterniond* q);

/// The summary keys every estimator writes first: format, version, model, frames, first/last
/// frame, image, principal point, scale_px, focal_px (= s / beta), focal_sd_px, beta.
nlohmann::json summaryHead(const std::string& model, int frames, int first_frame, int last_frame, const ImageInfo& image,
                           double scale_px, double beta, double var_beta);

/// The summary keys every estimator writes last: stopped, command, seconds, conventions, then the
/// caller's extra keys.
void summaryTail(nlohmann::json* j, const std::string& stopped, const std::string& command, double seconds,
                 const std::string& conventions, const nlohmann::json& extra);

/// The camera poses of a run as trajectory.tum holds them (timestamps: docs/outputs.md).
std::vector<io::TumPose> trajectoryPoses(const TrackFilterResult& res, const ImageInfo& image);

/// summary.json's "figures": {"written": [names], "missing": [names], "why": "..." (only when
/// something is missing)} (docs/outputs.md, "Figures").
nlohmann::json figuresJson(const Figures& f);

/// The summary as JSON (also what summary.json holds).
nlohmann::json estimateSummary(const EstimateReport& r);

/// Writes every file into `files` (temporaries under `dir`; the caller commits) and returns the
/// summary it wrote. Throws std::runtime_error with a one-line message when a file cannot be
/// written; figures that cannot be made are left out and listed in the summary's "figures".
nlohmann::json writeEstimateReport(const EstimateReport& r, const std::filesystem::path& dir, io::AtomicFileSet* files,
                                   bool plots = true, Figures* figures = nullptr);

}  // namespace rsfm::report
