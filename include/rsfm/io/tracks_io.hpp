#pragma once
// tracks.csv, version 1 (docs/tracks.md): a versioned header of '#' lines, then
//   frame,track,x,y
// one row per track per frame, frames ascending, track ids ascending within a frame, pixels.
//   # rsfm-tracks 1
//   # image_size 640 480
//   # principal_point 319.5 239.5
//   # frames 0 149
//   # source box.mp4
#include <filesystem>
#include <iosfwd>
#include <string>

#include "rsfm/io/input_error.hpp"
#include "rsfm/track/tracks.hpp"

namespace rsfm::io {

/// Writes `t` in the format above (positions to 1e-4 px).
void writeTracks(std::ostream& os, const Tracks& t);
std::string tracksToString(const Tracks& t);
/// The header's '# dropped_frames' lines for `stretches` ([first, last] frame numbers; "N" or
/// "A-B"), a bounded number per line (the reader's lines are at most 8192 bytes); empty for none.
std::string droppedFramesLines(const std::vector<std::array<int, 2>>& stretches);

/// Reads and validates a tracks file. Throws InputError "FILE:LINE: problem" on: a missing or
/// unreadable file, a missing/unknown version, missing or invalid header keys, a wrong column
/// header, a row without exactly 4 fields, a non-numeric or non-finite value, a frame outside the
/// declared range or out of order, a negative or repeated track id within a frame, a position
/// more than one image outside the image, or no rows at all.
Tracks readTracks(const std::filesystem::path& file);
/// The same from a stream (`file` names it in messages). Limits (issue 17, docs/tracks.md): lines
/// of at most 8192 bytes, image sizes OpenCV can decode (2^20 px a side, 2^30 px), frame numbers
/// up to 2^31 - 1, a declared frame range no longer than the number of rows, ids below
/// max(2^20, 16 x rows).
Tracks readTracks(std::istream& in, const std::filesystem::path& file);

}  // namespace rsfm::io
