#pragma once
// TUM trajectory files (`t tx ty tz qx qy qz qw`, one pose per line).
//
// rsfm convention (docs/render.md, docs/evaluate.md):
//  - t is the frame index (0, 1, 2, ...: frame numbers, not seconds);
//  - p = (tx, ty, tz) is the camera centre in the reference (first) camera's COP-centred frame
//    (x right, y down, z forward);
//  - q = (qx, qy, qz, qw) is the Hamilton rotation camera -> reference (a point's camera-k
//    coordinates X_k map to reference coordinates q X_k + p); written normalized with qw >= 0.
//  - The reference frame (frame 0) has the identity pose.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <filesystem>
#include <iosfwd>
#include <vector>

#include "rsfm/io/input_error.hpp"

namespace rsfm::io {

struct TumPose {
  double t = 0;
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
};

/// Reads `t tx ty tz qx qy qz qw` lines ('#' comments and blank lines allowed). Throws
/// rsfm::io::InputError (derived from std::runtime_error) whose what() is "FILE:LINE: problem" on
/// any malformed line, non-finite value, non-unit quaternion (|1-|q|| > 1e-3), non-increasing
/// timestamps, or an empty file (then LINE is the file's last line, or 1). A file that cannot be
/// opened gives "FILE: cannot open ...". Quaternions are returned normalized.
std::vector<TumPose> readTum(const std::filesystem::path& file);
/// The same from a stream (`file` names it in messages); lines of at most 8192 bytes.
std::vector<TumPose> readTum(std::istream& in, const std::filesystem::path& file);

/// Writes one line per pose with full double precision (shortest round-trip form), q normalized
/// with w >= 0, after a '#' header line stating the convention above.
void writeTum(std::ostream& os, const std::vector<TumPose>& poses);

}  // namespace rsfm::io
