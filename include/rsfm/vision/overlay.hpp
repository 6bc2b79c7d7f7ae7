#pragma once
// overlay.mp4 (docs/outputs.md): the input frames with the tracks coloured by plane (outliers as
// red crosses, tracks too short to judge in grey) and each estimated plane drawn as a grid
// projected with the estimated motion and focal length of that frame.
#include <filesystem>
#include <string>
#include <vector>

#include "rsfm/pipeline/patch_pipeline.hpp"
#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/track/patches.hpp"
#include "rsfm/track/tracks.hpp"
#include "rsfm/vision/klt_tracker.hpp"

namespace rsfm::vision {

/// What an overlay video was written with.
struct OverlayInfo {
  std::string codec;                    ///< "h264" (browser-playable) or "mpeg4" (the fallback)
  std::string warning;                  ///< one line when the fallback was used
  std::vector<unsigned char> poster_png;  ///< the middle frame as PNG (at most 960 px wide)
};

/// Writes the overlay video of frames result.frames (input re-read over `range`) to `path`: H.264
/// (FFmpeg's libx264), else MPEG-4 Part 2 with a warning; the container follows the extension.
/// Throws io::InputError / std::runtime_error.
OverlayInfo writeOverlay(const std::string& input, FrameRange range, const Tracks& tracks, const std::vector<int>& labels,
                  const TrackFilterResult& result, const std::filesystem::path& path);

/// Patch overlay: each live patch drawn as its warped square (the tracker's A) and its estimated
/// normal as an arrow from the centre towards the camera (a 3-D segment of 1/20 of the patch's
/// distance from the centre of projection, projected with that frame's focal length, at most 2.5
/// patch radii long in the image), green within 5 degrees of the median normal of the frame's
/// patches, orange beyond.
OverlayInfo writePatchOverlay(const std::string& input, FrameRange range, const PatchTracks& tracks, const PatchRunResult& result,
                       const std::filesystem::path& path);

}  // namespace rsfm::vision
