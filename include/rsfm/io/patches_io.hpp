#pragma once
// patches.csv, version 1 (docs/tracks.md): a versioned header of '#' lines, then
//   frame,patch,x0,y0,x,y,a11,a12,a21,a22,tx,ty,rms
// one row per patch per frame, frames ascending, patch ids ascending within a frame, pixels:
// (x0, y0) the patch centre in its first frame, (x, y) its centre in this frame, A = [a11 a12;
// a21 a22] the local affine map first frame -> this frame, (tx, ty) = (x, y) - A (x0, y0) the
// warp's translation (p = A q + t for a first-frame pixel q of the patch), rms the alignment
// residual (normalized intensity).
//   # rsfm-patches 1
//   # image_size 384 288
//   # principal_point 191.5 143.5
//   # frames 0 79
//   # radius 15
//   # source cube/image.%04d.pgm
#include <filesystem>
#include <iosfwd>
#include <string>

#include "rsfm/io/input_error.hpp"
#include "rsfm/track/patches.hpp"

namespace rsfm::io {

void writePatches(std::ostream& os, const PatchTracks& t);
std::string patchesToString(const PatchTracks& t);

/// Reads and validates a patches file. Throws InputError "FILE:LINE: problem" on: a missing or
/// unreadable file, a missing/unknown version, missing or invalid header keys, a wrong column
/// header, a row without exactly 13 fields, a non-numeric or non-finite value, a frame outside the
/// declared range or out of order, a repeated or out-of-order patch id, a map A with a
/// non-positive determinant, a first-frame centre that changes between rows of one patch, a
/// translation that disagrees with (x, y) - A (x0, y0) by more than 0.01 px, or no rows at all.
PatchTracks readPatches(const std::filesystem::path& file);
/// The same from a stream (`file` names it in messages). Limits (issue 17, docs/tracks.md): lines
/// of at most 8192 bytes, image sizes OpenCV can decode (2^20 px a side, 2^30 px), frame numbers
/// up to 2^31 - 1, a declared frame range no longer than the number of rows, ids below
/// max(2^20, 16 x rows).
PatchTracks readPatches(std::istream& in, const std::filesystem::path& file);

}  // namespace rsfm::io
