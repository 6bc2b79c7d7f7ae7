#pragma once
// Outputs of `rsfm estimate --patches` / `rsfm run --model patches` (docs/outputs.md,
// docs/patches.md): trajectory.tum, patch_normals.csv, summary.json and the plot patch_run
// (.png, .svg): focal length and each patch normal's angle to the median normal against frame.
#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>

#include "rsfm/io/atomic_file.hpp"
#include "rsfm/io/tum.hpp"
#include "rsfm/report/report.hpp"
#include "rsfm/pipeline/motion_check.hpp"
#include "rsfm/pipeline/patch_pipeline.hpp"
#include "rsfm/track/patches.hpp"

namespace rsfm::report {

struct PatchReport {
  const PatchTracks* tracks = nullptr;
  const PatchRunResult* result = nullptr;
  const PatchMotionCheck* motion = nullptr;  ///< the motion check (may be null: not run)
  std::string command;
  double seconds = 0.0;
  nlohmann::json extra = nlohmann::json::object();
};


nlohmann::json patchSummary(const PatchReport& r);
/// The camera poses of a patch run as trajectory.tum holds them (timestamps: docs/outputs.md).
std::vector<io::TumPose> patchTrajectory(const PatchRunResult& res, const ImageInfo& image);
/// Writes every file into `files` (the caller commits); returns the summary.
nlohmann::json writePatchReport(const PatchReport& r, const std::filesystem::path& dir, io::AtomicFileSet* files,
                                bool plots = true, Figures* figures = nullptr);

}  // namespace rsfm::report
