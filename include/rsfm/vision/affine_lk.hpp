#pragma once
// Inverse-compositional affine Lucas-Kanade (Baker & Matthews 2004) on one small patch, with a
// Gaussian window that warps with the patch and gain/bias normalization. The template is the
// patch around the feature in the frame it was first seen; each new frame is aligned to it, so a
// track does not drift the way chained frame-to-frame translations do under perspective change.
// Warp: x_image = A x + b for template coordinates x (pixels, centred on the feature); b is the
// feature's position in the image.
#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace rsfm::vision {

struct AffineLkOptions {
  int radius = 5;             ///< template half-size: (2r + 1)^2 pixels
  double window_sigma = 0.0;  ///< Gaussian window sd in template pixels (<= 0: radius / 1.5)
  int max_iterations = 5;
  /// Stop when a Gauss-Newton step moves the patch's corners (converge_shape) or its centre (the
  /// track's position) less than epsilon_px.
  double epsilon_px = 0.02;
  /// true: the affine shape must settle too (the patch tracker, whose normals come from it);
  /// false: the centre only (KLT anchoring, where the shape is just the next frame's start: a
  /// corner test kept iterating on the shape after the position had settled, 4.4 steps per
  /// alignment on box.mp4 with 39 % never meeting it, against 2.3 on the centre).
  bool converge_shape = true;
  double max_rms = 0.35;      ///< loss: normalized RMS residual above this (in units of the template's sd)
  double min_det = 0.25, max_det = 4.0;  ///< loss: area change of A outside these bounds
  /// Bicubic (Keys) instead of bilinear sampling of the template and the warped image: about 4x
  /// the cost, markedly less interpolation bias at the patch corners (tests/test_video.cpp).
  bool cubic = false;
};

class AffineTemplate {
 public:
  /// Builds the template around `c` in `img` (CV_32F, one channel). False when the patch leaves
  /// the image or is textureless (singular Hessian).
  bool init(const cv::Mat& img, const Eigen::Vector2d& c, const AffineLkOptions& o);
  /// Aligns the template to `img` (CV_32F) starting from (A, b); on success updates them and
  /// returns true. `rms` receives the final normalized RMS residual.
  bool align(const cv::Mat& img, Eigen::Matrix2d* A, Eigen::Vector2d* b, double* rms) const;
  bool valid() const { return n_ > 0; }

 private:
  AffineLkOptions o_;
  int n_ = 0;                        // pixels
  Eigen::Matrix<float, Eigen::Dynamic, 2> x_;    // template coordinates
  Eigen::VectorXf t_;                // normalized template (zero mean, unit sd)
  Eigen::VectorXf w_;                // window weights
  Eigen::Matrix<float, Eigen::Dynamic, 6> sdw_;  // steepest-descent images times the window
  Eigen::Matrix<double, 6, 6> hinv_;
};

}  // namespace rsfm::vision
