#pragma once
// The image side of the camera for the final refinement (docs/estimate.md §4): the
// principal point and OpenCV's radial distortion, applied to the A&P projection.
//
// The A&P models predict h = (X_C, Y_C) / (1 + beta Z_C) ([AS99] eq. 7) in normalized units of s
// pixels about the nominal principal point c0. With the pinhole coordinates x = beta h (= X/Z in
// the centre-of-projection frame), OpenCV's radial model D(x) = x (1 + k1 r^2 + k2 r^4), r = |x|,
// and the principal point c = c0 + s dc, the observed normalized position is
//   u = D(beta h) / beta + dc,   i.e. pixels  s u + c0 = f D(x) + c,  f = s / beta.
// Parameters (dc_x, dc_y, k1, k2); (0, 0, 0, 0) is the plain A&P projection (then u = h exactly).
#include <Eigen/Core>

namespace rsfm {

struct RadialCamera {
  /// u for h and beta, with the Jacobians with respect to h (2x2), beta (2x1) and the parameters
  /// (2x4); any output may be null.
  static Eigen::Vector2d apply(const Eigen::Vector4d& camera, double beta, const Eigen::Vector2d& h,
                               Eigen::Matrix2d* J_h = nullptr, Eigen::Vector2d* J_beta = nullptr,
                               Eigen::Matrix<double, 2, 4>* J_camera = nullptr);
  /// The inverse for h (undistortion by Newton's method on the radius; the map must be monotonic
  /// there). Returns false when it does not converge.
  static bool invert(const Eigen::Vector4d& camera, double beta, const Eigen::Vector2d& u, Eigen::Vector2d* h);
  /// Largest distorted radius (pinhole units) up to which x -> x (1 + k1 r^2 + k2 r^4) is monotonic
  /// (infinity when it always is): the image must lie within it to be a camera's.
  static double monotonicRadius(double k1, double k2);
};

}  // namespace rsfm
