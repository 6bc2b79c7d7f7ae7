#pragma once
// overlay.mp4 (docs/outputs.md): the input frames with the tracks coloured by plane (outliers as
// red crosses, tracks too short to judge in grey) and each estimated plane drawn as a grid
// projected with the estimated motion and focal length of that frame.
#include <filesystem>
#include <string>
#include <vector>

#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/track/tracks.hpp"
#include "rsfm/vision/klt_tracker.hpp"

namespace rsfm::vision {

/// Writes the overlay video of frames result.frames (input re-read over `range`) to `path`
/// (codec mp4v; the container follows the extension). Throws io::InputError / std::runtime_error.
void writeOverlay(const std::string& input, FrameRange range, const Tracks& tracks, const std::vector<int>& labels,
                  const TrackFilterResult& result, const std::filesystem::path& path);

}  // namespace rsfm::vision
