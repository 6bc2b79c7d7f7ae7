#pragma once
// The options and the report step shared by `rsfm estimate` (apps/cmd_estimate.cpp) and `rsfm run`
// (apps/cmd_run.cpp). The overlay video is a callback, so that `rsfm estimate` does not link the
// video stack (issue 15: `rsfm` starts without OpenCV's video I/O; `rsfm run` lives in rsfm-video).
#include <CLI/CLI.hpp>

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "rsfm/pipeline/estimate.hpp"
#include "rsfm/pipeline/patch_pipeline.hpp"
#include "rsfm/report/estimate_report.hpp"
#include "rsfm/report/patch_report.hpp"
#include "rsfm/vision/overlay.hpp"

namespace rsfm::cli {

/// The command line of `rsfm estimate` / `rsfm run`: the library's option structs (filled by
/// CLI11 directly, each option in one place) and the few words that need parsing.
struct EstimateCli {
  EstimateOptions est;          ///< point | plane | planes (pipeline/estimate.hpp)
  PatchEstimateOptions pat;     ///< patches
  std::string model = toString(TrackModel::Planes);
  bool patches = false;         ///< --model patches: Calway's patch filter on affine patches
  std::string centres = "fused", measurement = "exact";
  std::string reference = std::string(toString(TrackFilterOptions::defaultFilter().reference));
  std::string plane_rois;       ///< "x,y,...;x,y,..."
  std::optional<double> beta_sd0;  ///< --beta-sd0: either pipeline's
  std::string refine = "final";    ///< --refine final | none
  std::string camera_file;         ///< --camera FILE
  std::vector<double> principal_point;  ///< --principal-point X,Y
  std::string readout_direction;        ///< --readout-direction down|up|right|left (empty: the tracks')
  bool plots = true;
  bool quiet = false;
  std::string out = "out/estimate";  ///< --out: the output directory, replaced whole (io::OutputDir)
  std::string shown_out;             ///< the directory named in messages (the staging one is written)
};

void addEstimateOptions(CLI::App* a, EstimateCli* e);
/// Checks and completes the options; a message when they are inconsistent.
std::string finishEstimateOptions(EstimateCli* e);
/// The progress of estimate() on stderr (none with --quiet): the plane models' filter runs over
/// the frames once per pass (TrackFilterOptions::passes), so the count is of frames over all
/// passes.
std::function<void(int, int)> estimateProgress(const EstimateCli& e);

/// The report of one estimate() run as `rsfm estimate` writes it: the result, the given camera,
/// summary.json's "start" and "plane_finding". The Python module builds its summary with it too
/// (python/rsfm_module.cpp), so both give the same numbers. Holds pointers into `tracks` and `r`.
struct EstimateRunReport {
  EstimateRunReport(const Tracks& tracks, const EstimateResult& r, const EstimateCli& e);
  EstimateRunReport(const EstimateRunReport&) = delete;
  EstimateRunReport& operator=(const EstimateRunReport&) = delete;
  report::EstimateReport rep;
  std::optional<report::GivenCamera> given;
};

/// The same for a patch run (estimatePatches): the result, the motion check, "start".
struct PatchRunReport {
  PatchRunReport(const PatchTracks& tracks, const PatchEstimateResult& pr);
  PatchRunReport(const PatchRunReport&) = delete;
  PatchRunReport& operator=(const PatchRunReport&) = delete;
  report::PatchReport rep;
};

/// Writes the overlay video of a result to a temporary file (committed with the other outputs);
/// returns its codec, a warning when it fell back from H.264, and a poster frame.
using TrackOverlay = std::function<vision::OverlayInfo(const EstimateResult&, const std::filesystem::path&)>;
using PatchOverlay = std::function<vision::OverlayInfo(const PatchRunResult&, const std::filesystem::path&)>;

/// The pipeline (pipeline/estimate.hpp) + report (+ the overlay when given). Returns the exit code.
/// What `rsfm run`'s tracking adds to summary.json: its seconds (`stage_seconds`) and its
/// `tracking` object (docs/outputs.md). vision::TrackingStats' counts, copied so that this
/// header, also built into `rsfm` (no video commands), does not include the tracker's.
struct RunTracking {
  double seconds = 0;
  long steps = 0;                       ///< frame-to-frame steps tracked
  long exposure_compensated_steps = 0;  ///< of them, tracked again for a change of exposure
  long dropped_frames = 0;              ///< frames the video dropped (vision::TrackingStats)
};
/// `tracking`: `rsfm run`'s tracking (null: the tracks came from a file).
int estimateAndReport(const Tracks& tracks, const EstimateCli& e, const TrackOverlay& overlay, double t_start,
                      bool write_tracks, const RunTracking* tracking = nullptr);
/// The patch pipeline + report (+ the overlay when given). Returns the exit code.
int patchEstimateAndReport(const PatchTracks& tracks, const EstimateCli& e, const PatchOverlay& overlay,
                           double t_start, bool write_patches);

}  // namespace rsfm::cli
