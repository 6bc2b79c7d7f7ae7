#pragma once
// Tracked affine patches in pixels: what the patch tracker produces and the patch filter consumes
// (docs/tracks.md, "patches.csv"). Pixel convention as tracks.hpp (x right, y down, (0, 0) the
// centre of the top-left pixel). No I/O here: the file format lives in rsfm/io/patches_io.hpp.
//
// Patch `id` was first seen centred at px0 in frame first (its template). In a later frame its
// warp maps template pixels to image pixels: p = A (q - px0) + px for a point q of the template
// (first-frame pixels), i.e. p = A q + t with the translation t = px - A px0.
#include <Eigen/Core>

#include <string>
#include <vector>

#include "rsfm/track/tracks.hpp"

namespace rsfm {

struct PatchObservation {
  int id = 0;                                     ///< patch id, >= 0, unique within a frame
  Eigen::Vector2d px0 = Eigen::Vector2d::Zero();  ///< centre in the patch's first frame (pixels)
  Eigen::Vector2d px = Eigen::Vector2d::Zero();   ///< centre in this frame (pixels)
  Eigen::Matrix2d A = Eigen::Matrix2d::Identity();  ///< local affine map first frame -> this frame
  double rms = 0.0;  ///< alignment residual (normalized intensity RMS; 0 in the first frame)
  Eigen::Vector2d translation() const { return px - A * px0; }
};

/// Patch tracks of one sequence. frames[k] holds the patches seen in frame first_frame + k, sorted by id.
struct PatchTracks {
  ImageInfo image;
  int first_frame = 0;
  int radius = 0;  ///< template half-size (pixels)
  std::vector<std::vector<PatchObservation>> frames;
  std::string source;
  int numFrames() const { return static_cast<int>(frames.size()); }
  /// The patch with id `id` in frame index k, or nullptr.
  const PatchObservation* find(int k, int id) const;
};

/// As trimLeadingEmptyFrames(Tracks*) (track/tracks.hpp): leaves out the frames before the first
/// one with a patch and returns how many; first_frame follows. Without any patch: left as is.
int trimLeadingEmptyFrames(PatchTracks* t);

}  // namespace rsfm
