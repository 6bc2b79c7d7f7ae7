// Tracker options shared by `rsfm track` and `rsfm run`.
#pragma once

#include <CLI/CLI.hpp>

#include <string>
#include <vector>

#include "rsfm/vision/klt_tracker.hpp"
#include "rsfm/vision/patch_tracker.hpp"

namespace rsfm::cli {

struct TrackCli {
  vision::TrackerOptions tracker;
  vision::FrameRange range;
  std::string roi;  ///< "x,y,x,y,..." (first-frame pixels)
  vision::PatchTrackerOptions patches;  ///< --patches (shares range and roi)
};

void addTrackerOptions(CLI::App* app, TrackCli* t);
/// The affine-patch tracker's options (--patch-radius, --max-patches, ...).
void addPatchTrackerOptions(CLI::App* app, TrackCli* t);
/// Parses "x,y,x,y,x,y[,...]" (at least 3 vertices) into `out`; returns an error message or "".
std::string parsePolygon(const std::string& s, std::vector<cv::Point2f>* out);
/// Checks the tracker options and range; returns an error message or "".
std::string finishTrackerOptions(TrackCli* t);

}  // namespace rsfm::cli
