#pragma once
// camera.yaml: a pinhole camera with OpenCV's radial distortion in the OpenCV FileStorage YAML of
// cv::calibrateCamera tools (camera_matrix, distortion_coefficients [k1, k2, 0, 0, 0],
// image_width, image_height), readable by cv::FileStorage and by `--camera` (vision/camera_file.hpp).
// Text only (no OpenCV): the renderer writes its truth's, the estimator its result's.
#include <string>
#include <vector>

namespace rsfm::io {

/// The YAML text, with `extra` lines (already formatted `key: value`) appended.
std::string cameraYaml(int width, int height, double focal, double cx, double cy, double k1, double k2,
                       const std::vector<std::string>& extra = {});

}  // namespace rsfm::io
