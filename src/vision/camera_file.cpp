#include "rsfm/vision/camera_file.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "rsfm/io/input_error.hpp"

namespace rsfm::vision {

bool CameraCalibration::distorted() const {
  return std::any_of(distortion.begin(), distortion.end(), [](double d) { return d != 0.0; });
}

namespace {

[[noreturn]] void bad(const std::filesystem::path& f, const std::string& m) { throw io::InputError(f.string() + ": " + m); }

cv::Mat matrixNode(const cv::FileStorage& fs, const char* name, const std::filesystem::path& f) {
  const cv::FileNode n = fs[name];
  if (n.empty()) bad(f, fmt::format("missing node \"{}\"", name));
  cv::Mat m;
  try {
    n >> m;
  } catch (const cv::Exception&) {
    bad(f, fmt::format("\"{}\" is not a matrix", name));
  }
  if (m.empty()) bad(f, fmt::format("\"{}\" is not a matrix", name));
  m.convertTo(m, CV_64F);
  return m;
}

int intNode(const cv::FileStorage& fs, const char* name, const std::filesystem::path& f) {
  const cv::FileNode n = fs[name];
  if (n.empty() || !(n.isInt() || n.isReal())) bad(f, fmt::format("missing or non-numeric node \"{}\"", name));
  const double v = static_cast<double>(n);
  if (!(v >= 1 && v <= 65536) || v != std::floor(v)) bad(f, fmt::format("\"{}\" must be a positive integer, got {}", name, v));
  return static_cast<int>(v);
}

}  // namespace

CameraCalibration readCameraFile(const std::filesystem::path& file) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec)) bad(file, "no such file");
  cv::FileStorage fs;
  try {
    if (!fs.open(file.string(), cv::FileStorage::READ)) bad(file, "not an OpenCV FileStorage YAML/XML file");
  } catch (const cv::Exception&) {
    bad(file, "not an OpenCV FileStorage YAML/XML file (parse error)");
  }
  CameraCalibration c;
  c.source = file.string();
  c.width = intNode(fs, "image_width", file);
  c.height = intNode(fs, "image_height", file);
  const cv::Mat K = matrixNode(fs, "camera_matrix", file);
  if (K.rows != 3 || K.cols != 3) bad(file, fmt::format("\"camera_matrix\" must be 3x3, got {}x{}", K.rows, K.cols));
  for (int i = 0; i < 9; ++i)
    if (!std::isfinite(K.at<double>(i / 3, i % 3))) bad(file, "\"camera_matrix\" has a non-finite entry");
  c.fx = K.at<double>(0, 0);
  c.fy = K.at<double>(1, 1);
  c.cx = K.at<double>(0, 2);
  c.cy = K.at<double>(1, 2);
  if (!(c.fx > 0) || !(c.fy > 0)) bad(file, fmt::format("focal lengths must be positive, got fx {}, fy {}", c.fx, c.fy));
  if (std::abs(c.fx - c.fy) > 0.01 * c.focal())
    bad(file, fmt::format("fx {} and fy {} differ by more than 1 %: rsfm models square pixels", c.fx, c.fy));
  if (std::abs(K.at<double>(0, 1)) > 1e-6 * c.fx || K.at<double>(1, 0) != 0 || K.at<double>(2, 0) != 0 ||
      K.at<double>(2, 1) != 0 || K.at<double>(2, 2) != 1)
    bad(file, "\"camera_matrix\" must be [fx 0 cx; 0 fy cy; 0 0 1] (no skew)");
  if (!(c.cx >= 0 && c.cx <= c.width - 1 && c.cy >= 0 && c.cy <= c.height - 1))
    bad(file, fmt::format("principal point ({}, {}) outside the {}x{} image", c.cx, c.cy, c.width, c.height));
  if (!fs["distortion_coefficients"].empty()) {
    const cv::Mat D = matrixNode(fs, "distortion_coefficients", file);
    const int n = static_cast<int>(D.total());
    if (!(D.rows == 1 || D.cols == 1) || (n != 4 && n != 5 && n != 8 && n != 12 && n != 14))
      bad(file, fmt::format("\"distortion_coefficients\" must have 4, 5, 8, 12 or 14 entries, got {}x{}", D.rows, D.cols));
    for (int i = 0; i < n; ++i) {
      const double v = D.at<double>(i);
      if (!std::isfinite(v)) bad(file, "\"distortion_coefficients\" has a non-finite entry");
      c.distortion.push_back(v);
    }
  }
  return c;
}

Tracks undistortTracks(const Tracks& tracks, const CameraCalibration& cal) {
  if (tracks.image.width != cal.width || tracks.image.height != cal.height)
    throw io::InputError(fmt::format("{}: the calibration is for {}x{} images, the tracks are {}x{}", cal.source, cal.width,
                                     cal.height, tracks.image.width, tracks.image.height));
  Tracks out = tracks;
  out.image.cx = cal.cx;
  out.image.cy = cal.cy;
  if (!cal.distorted()) return out;
  const cv::Matx33d K(cal.fx, 0, cal.cx, 0, cal.fy, cal.cy, 0, 0, 1);
  const cv::Matx33d P(cal.focal(), 0, cal.cx, 0, cal.focal(), cal.cy, 0, 0, 1);
  for (auto& frame : out.frames) {
    if (frame.empty()) continue;
    std::vector<cv::Point2d> in, und;
    for (const auto& p : frame) in.emplace_back(p.px.x(), p.px.y());
    cv::undistortPoints(in, und, K, cal.distortion, cv::noArray(), P,
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-10));
    for (std::size_t i = 0; i < frame.size(); ++i) frame[i].px = Eigen::Vector2d(und[i].x, und[i].y);
  }
  return out;
}

}  // namespace rsfm::vision
