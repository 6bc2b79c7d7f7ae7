#include "rsfm/vision/affine_lk.hpp"
#include "sampling.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>
#include <vector>

namespace rsfm::vision {

namespace {

/// Bicubic (Keys, a = -0.5) sample of a CV_32F image; false outside.
inline bool sampleCubic(const cv::Mat& img, double x, double y, float* v) {
  if (!(x >= 1.0 && y >= 1.0 && x < img.cols - 2 && y < img.rows - 2)) return false;
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const double fx = x - x0, fy = y - y0;
  auto w = [](double t, double* k) {
    const double t2 = t * t, t3 = t2 * t;
    k[0] = -0.5 * t3 + t2 - 0.5 * t;
    k[1] = 1.5 * t3 - 2.5 * t2 + 1.0;
    k[2] = -1.5 * t3 + 2.0 * t2 + 0.5 * t;
    k[3] = 0.5 * t3 - 0.5 * t2;
  };
  double kx[4], ky[4];
  w(fx, kx);
  w(fy, ky);
  double acc = 0.0;
  for (int i = 0; i < 4; ++i) {
    const float* r = img.ptr<float>(y0 - 1 + i) + x0 - 1;
    acc += ky[i] * (kx[0] * r[0] + kx[1] * r[1] + kx[2] * r[2] + kx[3] * r[3]);
  }
  *v = static_cast<float>(acc);
  return true;
}

inline bool sampleWith(bool cubic, const cv::Mat& img, double x, double y, float* v) {
  return cubic ? sampleCubic(img, x, y, v) : sampleBilinear<float>(img, x, y, v);
}

}  // namespace

bool AffineTemplate::init(const cv::Mat& img, const Eigen::Vector2d& c, const AffineLkOptions& o) {
  o_ = o;
  n_ = 0;
  const int r = o.radius, side = 2 * r + 1, n = side * side;
  const double sw = o.window_sigma > 0 ? o.window_sigma : r / 1.5;
  // Sample a (side + 2)^2 patch so that central-difference gradients exist on the template.
  const int big = side + 2;
  Eigen::MatrixXf P(big, big);
  for (int i = 0; i < big; ++i)
    for (int j = 0; j < big; ++j) {
      float v;
      if (!sampleWith(o.cubic, img, c.x() + j - r - 1, c.y() + i - r - 1, &v)) return false;
      P(i, j) = v;
    }
  x_.resize(n, 2);
  t_.resize(n);
  w_.resize(n);
  Eigen::Matrix<float, Eigen::Dynamic, 6> steep(n, 6);  // steepest-descent images
  Eigen::VectorXf gx(n), gy(n);
  for (int i = 0; i < side; ++i)
    for (int j = 0; j < side; ++j) {
      const int k = i * side + j;
      x_(k, 0) = static_cast<float>(j - r);
      x_(k, 1) = static_cast<float>(i - r);
      t_[k] = P(i + 1, j + 1);
      gx[k] = 0.5f * (P(i + 1, j + 2) - P(i + 1, j));
      gy[k] = 0.5f * (P(i + 2, j + 1) - P(i, j + 1));
      w_[k] = static_cast<float>(std::exp(-0.5 * (x_(k, 0) * x_(k, 0) + x_(k, 1) * x_(k, 1)) / (sw * sw)));
    }
  const float wsum = w_.sum();
  const float mean = w_.dot(t_) / wsum;
  const float var = w_.dot((t_.array() - mean).square().matrix()) / wsum;
  if (!(var > 1e-6f)) return false;
  const float sd = std::sqrt(var);
  t_ = (t_.array() - mean) / sd;
  gx /= sd;
  gy /= sd;
  // Parameters p = (a11 - 1, a21, a12, a22 - 1, b1, b2): dW/dp at p = 0.
  for (int k = 0; k < n; ++k) {
    const float X = x_(k, 0), Y = x_(k, 1);
    steep.row(k) << gx[k] * X, gy[k] * X, gx[k] * Y, gy[k] * Y, gx[k], gy[k];
  }
  sdw_ = w_.asDiagonal() * steep;
  const Eigen::Matrix<double, 6, 6> H = (sdw_.transpose() * steep).cast<double>();
  Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt(H);
  if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 1e-6 * ldlt.vectorD().maxCoeff())) return false;
  hinv_ = ldlt.solve(Eigen::Matrix<double, 6, 6>::Identity());
  n_ = n;
  return true;
}

bool AffineTemplate::align(const cv::Mat& img, Eigen::Matrix2d* A, Eigen::Vector2d* b, double* rms) const {
  if (n_ == 0) return false;
  Eigen::Matrix2d a = *A;
  Eigen::Vector2d t = *b;
  // The warped patch and its residual live in a per-thread buffer: no allocation per call once
  // warm (align runs for every live track in every frame).
  // Both start 16-byte aligned, as an Eigen::VectorXf would, so Eigen's reductions over them
  // take the same vectorized path (and sum in the same order).
  const size_t stride = (static_cast<size_t>(n_) + 15) & ~size_t{15};
  thread_local std::vector<float, Eigen::aligned_allocator<float>> scratch;
  if (scratch.size() < 2 * stride) scratch.resize(2 * stride);
  Eigen::Map<Eigen::VectorXf, Eigen::Aligned16> iw(scratch.data(), n_), e(scratch.data() + stride, n_);
  const double wsum = w_.sum();
  const int r_px = o_.radius;
  // Inner bound of the sampler's support: bilinear needs x in [0, cols - 1), bicubic [1, cols - 2).
  const double lo = o_.cubic ? 1.0 : 0.0, hi_x = img.cols - (o_.cubic ? 2.0 : 1.0), hi_y = img.rows - (o_.cubic ? 2.0 : 1.0);
  double r = 1e9;
  for (int it = 0; it < o_.max_iterations; ++it) {
    // The warp's image coordinates are a00 X + a01 Y + t (rounded products, summed); rounding is
    // monotone, so over the template's grid each coordinate is extreme at a corner: the patch is
    // inside the sampler's support exactly when its four corners are (the per-pixel test this
    // replaces gave the same answer).
    for (const int cy : {-r_px, r_px})
      for (const int cx : {-r_px, r_px}) {
        const double X = static_cast<float>(cx), Y = static_cast<float>(cy);
        const double x = a(0, 0) * X + a(0, 1) * Y + t.x(), y = a(1, 0) * X + a(1, 1) * Y + t.y();
        if (!(x >= lo && y >= lo && x < hi_x && y < hi_y)) return false;
      }
    for (int k = 0; k < n_; ++k) {
      const double X = x_(k, 0), Y = x_(k, 1);
      const double x = a(0, 0) * X + a(0, 1) * Y + t.x(), y = a(1, 0) * X + a(1, 1) * Y + t.y();
      if (o_.cubic)
        sampleCubic(img, x, y, &iw[k]);  // inside (the corners' test above)
      else
        iw[k] = bilinear<float>(img, x, y);
    }
    // Gain/bias: normalize the warped image like the template.
    const float mean = static_cast<float>(w_.dot(iw) / wsum);
    const float var = static_cast<float>(w_.dot((iw.array() - mean).square().matrix()) / wsum);
    if (!(var > 1e-6f)) return false;
    e = (iw.array() - mean) / std::sqrt(var) - t_.array();
    r = std::sqrt(w_.dot(e.cwiseAbs2()) / wsum);
    const Eigen::Matrix<double, 6, 1> dp = hinv_ * (sdw_.transpose() * e).cast<double>();
    // Inverse composition: W <- W o W(dp)^-1.
    Eigen::Matrix3d Wd = Eigen::Matrix3d::Identity();
    Wd(0, 0) += dp[0];
    Wd(1, 0) = dp[1];
    Wd(0, 1) = dp[2];
    Wd(1, 1) += dp[3];
    Wd(0, 2) = dp[4];
    Wd(1, 2) = dp[5];
    Eigen::Matrix3d W = Eigen::Matrix3d::Identity();
    W.topLeftCorner<2, 2>() = a;
    W.topRightCorner<2, 1>() = t;
    const Eigen::Matrix3d Wn = W * Wd.inverse();
    if (!Wn.allFinite()) return false;
    a = Wn.topLeftCorner<2, 2>();
    const Eigen::Vector2d t_new = Wn.topRightCorner<2, 1>();
    // Step size: how far the template's corners moved, or its centre.
    const double move = o_.converge_shape ? dp.head<4>().cwiseAbs().sum() * o_.radius + dp.tail<2>().norm()
                                          : (t_new - t).norm();
    t = t_new;
    if (move < o_.epsilon_px) break;
  }
  const double det = a.determinant();
  *rms = r;
  if (!(r <= o_.max_rms) || !(det >= o_.min_det && det <= o_.max_det)) return false;
  *A = a;
  *b = t;
  return true;
}

}  // namespace rsfm::vision
