#include "rsfm/vision/still_start.hpp"

#include <fmt/format.h>
#include <opencv2/calib3d.hpp>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace rsfm::vision {

namespace {
double medianOf(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

/// The median of a 2-D Gaussian error's norm, per axis sd 1: sqrt(2 ln 2) (Rayleigh).
const double kRayleighMedian = std::sqrt(2.0 * std::log(2.0));

cv::Point2d apply(const cv::Matx33d& h, const cv::Point2d& p) {
  const cv::Vec3d x = h * cv::Vec3d(p.x, p.y, 1.0);
  if (std::abs(x[2]) < 1e-12) return {1e9, 1e9};
  return {x[0] / x[2], x[1] / x[2]};
}
}  // namespace

std::vector<std::array<int, 2>> heldStretches(const StillStart& s) { return consecutiveStretches(s.held); }

StillStart findStillStart(const Tracks& tracks, double still_px, int min_tracks) {
  if (std::isnan(still_px)) throw std::invalid_argument("still_px must be a number (<= 0: no still start)");
  if (min_tracks < 1) throw std::invalid_argument(fmt::format("min_tracks must be >= 1, got {}", min_tracks));
  StillStart s;
  if (still_px <= 0.0) {
    s.moves = true;
    return s;
  }
  const int F = tracks.numFrames();
  if (F < 2) return s;
  std::vector<cv::Point2d> a, b;
  std::vector<double> r;
  // A still run: its first frame's tracks and their mean positions over the run so far. Against
  // its first frame alone, a track whose position there is off by its noise would stay near the
  // threshold and get a new chance to pass it in every frame.
  struct Run {
    std::vector<TrackPoint> at;  // the run's first frame (sorted by id)
    std::vector<Eigen::Vector2d> sum;
    std::vector<int> count;
    void reset(const std::vector<TrackPoint>& f) {
      at = f;
      sum.resize(f.size());
      count.assign(f.size(), 1);
      for (size_t i = 0; i < f.size(); ++i) sum[i] = f[i].px;
    }
  } run;
  std::vector<int> index;  // into run.at, per pair
  // The tracks of frame k alive in the run: their mean positions over the run into `a`, frame
  // k's into `b`, their index in the run into `index` (both frames are sorted by id).
  auto match = [&](int k) {
    a.clear();
    b.clear();
    index.clear();
    size_t i = 0;
    for (const TrackPoint& q : tracks.frames[k]) {
      while (i < run.at.size() && run.at[i].id < q.id) ++i;
      if (i == run.at.size()) break;
      if (run.at[i].id != q.id) continue;
      const Eigen::Vector2d m = run.sum[i] / run.count[i];
      a.emplace_back(m.x(), m.y());
      b.emplace_back(q.px.x(), q.px.y());
      index.push_back(static_cast<int>(i));
    }
  };
  // The noise: the frame 0 -> 1 displacements around their least-median-of-squares homography.
  run.reset(tracks.frames[0]);
  match(1);
  // The median of the residuals a least-median fit minimized is biased low (0.62 for 0.71 px on
  // the test's 200 tracks): its inliers (within 3 of those sds) are fitted again by least
  // squares, and the sd is their RMS per axis with the fit's 8 degrees of freedom taken out.
  if (a.size() >= 16) {
    const cv::Mat H = cv::findHomography(a, b, cv::LMEDS);
    if (!H.empty()) {
      r.clear();
      for (size_t i = 0; i < a.size(); ++i) r.push_back(cv::norm(apply(cv::Matx33d(H), a[i]) - b[i]));
      const double cut = 3.0 * medianOf(r) / kRayleighMedian;
      std::vector<cv::Point2d> ai, bi;
      for (size_t i = 0; i < a.size(); ++i)
        if (r[i] <= cut) {
          ai.push_back(a[i]);
          bi.push_back(b[i]);
        }
      const cv::Mat L = ai.size() >= 16 ? cv::findHomography(ai, bi, 0) : cv::Mat();
      if (!L.empty()) {
        double ss = 0.0;
        for (size_t i = 0; i < ai.size(); ++i) ss += std::pow(cv::norm(apply(cv::Matx33d(L), ai[i]) - bi[i]), 2);
        s.noise_px = std::sqrt(ss / (2.0 * static_cast<double>(ai.size()) - 8.0));
      }
    }
  }
  s.threshold_px = std::max(still_px, 4.0 * s.noise_px);
  // Whether frame k moved from the run; adds it to the run when not. n < 8: cannot tell (-1).
  // `moving` nullptr: only whether it moved is asked, and (b) below answers that without the
  // homography when enough tracks moved on their own.
  auto test = [&](int k, int* moving) {
    match(k);
    const int n = static_cast<int>(a.size());
    if (n < 8) return -1;
    int moved = 0;
    for (int j = 0; j < n; ++j) moved += cv::norm(b[j] - a[j]) > s.threshold_px;
    if (!moving && moved >= min_tracks) return 1;
    // The dominant motion: a homography, robust to the tracks of a smaller moving object.
    const cv::Mat H = cv::findHomography(a, b, cv::RANSAC, std::max(1.0, 3.0 * s.noise_px), cv::noArray(), 2000, 0.999);
    const cv::Matx33d h = H.empty() ? cv::Matx33d::eye() : cv::Matx33d(H);
    r.clear();
    for (int j = 0; j < n; ++j) r.push_back(cv::norm(apply(h, a[j]) - a[j]));
    // (a) The dominant surface moved (a camera, or an object filling most of the view): its
    // homography's median displacement above still_px and above its own fit's noise, per axis
    // noise_px sqrt(8 / n) for the 8 parameters.
    const double fit_px = std::max(still_px, 4.0 * kRayleighMedian * s.noise_px * std::sqrt(8.0 / n));
    const bool dominant = medianOf(r) > fit_px;
    // (b) Tracks that moved on their own (an object before a still background): min_tracks of
    // them more than threshold_px from their still positions. While (a) finds the dominant
    // motion within its noise, the identity is that motion; the homography itself is not the
    // reference: it bends towards a corner's moving tracks while they are its inliers.
    if (dominant || moved >= min_tracks) {
      if (moving) *moving = dominant ? n : moved;
      return 1;
    }
    for (int j = 0; j < n; ++j) {
      run.sum[index[j]] += Eigen::Vector2d(b[j].x, b[j].y);
      ++run.count[index[j]];
    }
    return 0;
  };
  int k = 1, moving = 0, last_still = 0;
  for (; k < F; ++k) {
    const int moved = test(k, &moving);
    if (moved == 1) break;
    if (moved == 0) last_still = k;  // a frame that cannot be tested (-1) is not known to be still
  }
  if (k == F) return s;  // nothing moves
  s.moves = true;
  s.moving_tracks = moving;
  s.still_frames = last_still;
  // Later still stretches: runs of at least kMinHeldFrames frames that did not move from the
  // frame before them.
  run.reset(tracks.frames[k]);
  std::vector<int> stretch;
  auto close = [&] {
    if (static_cast<int>(stretch.size()) >= kMinHeldFrames) s.held.insert(s.held.end(), stretch.begin(), stretch.end());
    stretch.clear();
  };
  for (++k; k < F; ++k) {
    const int moved = test(k, nullptr);
    if (moved == 0) {
      stretch.push_back(k);
      continue;
    }
    close();
    run.reset(tracks.frames[k]);
  }
  close();
  return s;
}

}  // namespace rsfm::vision
