#pragma once
// Camera calibration files (docs/estimate.md, "A known camera"; docs/outputs.md, camera.yaml):
// OpenCV FileStorage YAML or XML as cv::calibrateCamera tools write them, with `camera_matrix`
// (3x3), `distortion_coefficients` (1x4, 1x5, 1x8, 1x12 or 1x14: k1, k2, p1, p2[, k3, ...]) and
// `image_width`, `image_height`. rsfm's model has square pixels: fx and fy must agree within 1 %
// (their mean is used). Tracks from a calibrated camera are undistorted with the whole model
// (cv::undistortPoints) onto the ideal pinhole with that focal length and principal point.
#include <Eigen/Core>

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "rsfm/io/camera_yaml.hpp"
#include "rsfm/track/tracks.hpp"

namespace rsfm::vision {

struct CameraCalibration {
  int width = 0, height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  std::vector<double> distortion;  ///< OpenCV's order: k1, k2, p1, p2[, k3, k4, k5, k6, ...]; may be empty
  /// A rolling shutter's known readout, frame intervals (node `rolling_shutter_readout`: rsfm's
  /// camera.yaml writes it when its refinement determined it, docs/outputs.md; calibration tools
  /// do not). Absent: not known (the refinement estimates it). At most kMaxRollingShutterReadout.
  std::optional<double> rolling_shutter_readout;
  std::string source;              ///< the file it came from
  double focal() const { return 0.5 * (fx + fy); }
  bool distorted() const;
};

/// Reads and checks a calibration file. Throws io::InputError "FILE: problem" (unreadable, not
/// OpenCV FileStorage, a missing or malformed node, non-positive or non-square focal lengths, a
/// principal point outside the image).
CameraCalibration readCameraFile(const std::filesystem::path& file);
/// The same from the file's text (YAML, XML or JSON FileStorage; `file` names it in messages).
CameraCalibration readCameraText(const std::string& text, const std::filesystem::path& file);
/// The largest camera file read: a calibration is a few hundred bytes.
inline constexpr std::size_t kMaxCameraFileBytes = 1u << 20;

/// The tracks undistorted onto the ideal pinhole (focal(), cx, cy) of `cal`; throws
/// io::InputError naming the file when the tracks' image size differs from the calibration's.
Tracks undistortTracks(const Tracks& tracks, const CameraCalibration& cal);

/// `cal` for the same camera's frames turned clockwise by `degrees` (90, 180, 270), as OpenCV's
/// reader turns a video with rotation metadata: the size, focal lengths and principal point
/// follow the pixels ((x, y) -> (h - 1 - y, x) for 90), the radial terms stay, the tangential
/// ones turn with the image ((p1, p2) -> (p2, -p1) for 90). Throws io::InputError naming the file
/// for thin-prism or tilt terms (OpenCV's coefficients 9-14), which are not turned here.
CameraCalibration rotateCalibration(const CameraCalibration& cal, int degrees);
/// The calibration that applies to tracks of `image`: `cal` when the sizes agree; turned by
/// rotateCalibration when the tracks' frames are its frames on their side and the tracks say
/// which way (readout_direction left: 90 degrees, right: 270; a phone video calibrated held
/// level and filmed upright). Otherwise io::InputError naming the file and both sizes.
CameraCalibration calibrationForTracks(const CameraCalibration& cal, const ImageInfo& image);


}  // namespace rsfm::vision
