#pragma once
// Bilinear sampling of one-channel images, shared by the affine alignment (affine_lk.cpp, CV_32F)
// and the tracker's exposure measurement (klt_tracker.cpp, CV_8U) (internal header).
#include <opencv2/core.hpp>

namespace rsfm::vision {

/// Bilinear sample of a one-channel image of element type T at (x, y), in pixels, within
/// [0, cols - 1) x [0, rows - 1) (not checked).
template <typename T>
inline float bilinear(const cv::Mat& img, double x, double y) {
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const float ax = static_cast<float>(x - x0), ay = static_cast<float>(y - y0);
  const T* r0 = img.ptr<T>(y0) + x0;
  const T* r1 = img.ptr<T>(y0 + 1) + x0;
  return (1 - ay) * ((1 - ax) * r0[0] + ax * r0[1]) + ay * ((1 - ax) * r1[0] + ax * r1[1]);
}

/// bilinear<T>, false outside [0, cols - 1) x [0, rows - 1).
template <typename T>
inline bool sampleBilinear(const cv::Mat& img, double x, double y, float* v) {
  if (!(x >= 0.0 && y >= 0.0 && x < img.cols - 1 && y < img.rows - 1)) return false;
  *v = bilinear<T>(img, x, y);
  return true;
}

}  // namespace rsfm::vision
