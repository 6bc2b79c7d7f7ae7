#include "rsfm/render/truth_check.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

namespace rsfm::render {
namespace {

constexpr double kBorder = 12;  // px: corners and their predictions this close to the border are skipped

// Corners of `grey` well inside each surface of `labels` (truth planes and the still body).
std::vector<std::pair<cv::Point2f, int>> corners(const cv::Mat& grey, const cv::Mat& labels) {
  std::vector<std::pair<cv::Point2f, int>> out;
  for (int l = 1; l <= Scene::kStillLabel; ++l) {
    cv::Mat mask = labels == l;
    if (cv::countNonZero(mask) == 0) continue;
    cv::erode(mask, mask, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(13, 13)));
    std::vector<cv::Point2f> c;
    cv::goodFeaturesToTrack(grey, c, 60, 0.01, 5, mask);
    for (const auto& p : c) out.emplace_back(p, l);
  }
  return out;
}

bool inside(const cv::Point2f& p, const cv::Mat& img) {
  return p.x > kBorder && p.y > kBorder && p.x < img.cols - kBorder && p.y < img.rows - kBorder;
}

/// The element at rank floor(q n) (at most n - 1) of a non-empty `v`, which it reorders.
double quantile(std::vector<double>& v, double q) {
  const auto i = std::min(v.size() - 1, static_cast<std::size_t>(q * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(i), v.end());
  return v[i];
}

TruthCheck summarize(int a, int b, std::vector<double> err, const std::map<int, int>& per_surface) {
  TruthCheck t;
  t.a = a;
  t.b = b;
  t.tracks = static_cast<int>(err.size());
  for (const auto& [l, n] : per_surface) t.surfaces += n >= 5;
  if (!err.empty()) {
    t.median_px = quantile(err, 0.5);
    t.p90_px = quantile(err, 0.9);
  }
  return t;
}

const cv::TermCriteria kTerm(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-3);

}  // namespace

TruthCheck trackAgainstTruth(const Scene& scene, const cv::Mat& grey_a, const cv::Mat& grey_b, int a, int b) {
  const cv::Mat la = scene.labels(a);
  const auto cs = corners(grey_a, la);
  std::vector<double> err;
  std::map<int, int> per;
  if (cs.empty()) return summarize(a, b, err, per);
  std::vector<cv::Point2f> p0, p1;
  for (const auto& c : cs) p0.push_back(c.first);
  std::vector<uchar> st;
  std::vector<float> e;
  cv::calcOpticalFlowPyrLK(grey_a, grey_b, p0, p1, st, e, cv::Size(21, 21), 3, kTerm);
  for (std::size_t i = 0; i < p0.size(); ++i) {
    if (!st[i]) continue;
    const auto truth = scene.transfer(Eigen::Vector2d(p0[i].x, p0[i].y), a, b, la);
    if (!truth) continue;
    const cv::Point2f q(static_cast<float>(truth->x()), static_cast<float>(truth->y()));
    if (!inside(q, grey_b)) continue;
    err.push_back(std::hypot(q.x - p1[i].x, q.y - p1[i].y));
    ++per[cs[i].second];
  }
  return summarize(a, b, err, per);
}

TracksTruthError tracksAgainstTruth(const Scene& scene, const Tracks& tracks) {
  TracksTruthError out;
  const auto spans = trackSpans(tracks);
  std::map<int, cv::Mat> labels;  // by scene frame: the frames where tracks are born
  // Age buckets: [kAgeEdges[b], kAgeEdges[b + 1] - 1].
  constexpr std::array<int, 7> kAgeEdges{1, 3, 10, 30, 60, 100, std::numeric_limits<int>::max()};
  constexpr int kBuckets = static_cast<int>(kAgeEdges.size()) - 1;
  std::array<std::vector<double>, kBuckets> err, rad;  // |track - truth| and its radial component, by age
  const Eigen::Vector2d centre((tracks.image.width - 1) / 2.0, (tracks.image.height - 1) / 2.0);
  for (int id = 0; id < static_cast<int>(spans.size()); ++id) {
    const TrackSpan s = spans[id];
    if (s.length() < 2) continue;
    const int a = tracks.frameNumber(s.first);
    auto it = labels.find(a);
    if (it == labels.end()) it = labels.emplace(a, scene.labels(a)).first;
    const cv::Mat& la = it->second;
    const Eigen::Vector2d x0 = tracks.find(s.first, id)->px;
    // Born well inside one surface: the 5 x 5 neighbourhood has one label, not the background.
    const int u = static_cast<int>(std::lround(x0.x())), v = static_cast<int>(std::lround(x0.y()));
    if (u < 2 || v < 2 || u >= la.cols - 2 || v >= la.rows - 2) continue;
    const uchar l0 = la.at<uchar>(v, u);
    bool one = l0 != 0 && l0 != 255;
    for (int dv = -2; dv <= 2 && one; ++dv)
      for (int du = -2; du <= 2 && one; ++du) one = la.at<uchar>(v + dv, u + du) == l0;
    if (!one) continue;
    bool used = false;
    for (int k = s.first + 1; k <= s.last; ++k) {
      const TrackPoint* p = tracks.find(k, id);
      if (!p) continue;
      const auto truth = scene.transfer(x0, a, tracks.frameNumber(k), la);
      if (!truth) continue;
      const Eigen::Vector2d d = p->px - *truth;
      const Eigen::Vector2d r = *truth - centre;
      const double dr = r.norm() > 1e-9 ? d.dot(r.normalized()) : 0.0;
      int b = 0;
      while (k - s.first >= kAgeEdges[b + 1]) ++b;
      err[b].push_back(d.norm());
      rad[b].push_back(dr);
      used = true;
    }
    out.tracks += used;
  }
  std::vector<double> all, all_rad;
  for (int b = 0; b < kBuckets; ++b) {
    if (err[b].empty()) continue;
    all.insert(all.end(), err[b].begin(), err[b].end());
    all_rad.insert(all_rad.end(), rad[b].begin(), rad[b].end());
    TracksTruthError::AgeBucket ab;
    ab.first_age = kAgeEdges[b];
    ab.last_age = kAgeEdges[b + 1] == std::numeric_limits<int>::max() ? -1 : kAgeEdges[b + 1] - 1;
    ab.observations = static_cast<long>(err[b].size());
    ab.median_px = quantile(err[b], 0.5);
    ab.p95_px = quantile(err[b], 0.95);
    ab.radial_median_px = quantile(rad[b], 0.5);
    out.by_age.push_back(ab);
  }
  out.observations = static_cast<long>(all.size());
  if (!all.empty()) {
    double radial = 0;
    for (double x : all_rad) radial += x;
    out.radial_mean_px = radial / static_cast<double>(all_rad.size());
    out.radial_median_px = quantile(all_rad, 0.5);
    out.median_px = quantile(all, 0.5);
    out.p95_px = quantile(all, 0.95);
  }
  return out;
}

cv::Mat warpThroughTruth(const Scene& scene, const cv::Mat& img_a, int a, int b) {
  const cv::Mat lb = scene.labels(b);
  cv::Mat mx(img_a.size(), CV_32F, cv::Scalar(-1e6)), my(img_a.size(), CV_32F, cv::Scalar(-1e6));
  for (int y = 0; y < img_a.rows; ++y)
    for (int x = 0; x < img_a.cols; ++x) {
      if (lb.at<uchar>(y, x) == 0) continue;
      const auto s = scene.transfer(Eigen::Vector2d(x, y), b, a, lb);
      if (!s) continue;
      mx.at<float>(y, x) = static_cast<float>(s->x());
      my.at<float>(y, x) = static_cast<float>(s->y());
    }
  cv::Mat out;
  cv::remap(img_a, out, mx, my, cv::INTER_CUBIC, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return out;
}

TruthCheck renderedAgainstWarp(const Scene& scene, int a, int b) {
  cv::Mat la, ga, gb;
  cv::cvtColor(scene.render(a, &la), ga, cv::COLOR_BGR2GRAY);
  cv::cvtColor(scene.render(b), gb, cv::COLOR_BGR2GRAY);
  const cv::Mat gw = warpThroughTruth(scene, ga, a, b);
  const auto cs = corners(ga, la);
  std::vector<double> diff;
  std::map<int, int> per;
  if (cs.empty()) return summarize(a, b, diff, per);
  std::vector<cv::Point2f> p0, p1, p2;
  for (const auto& c : cs) p0.push_back(c.first);
  std::vector<uchar> s1, s2;
  std::vector<float> e;
  cv::calcOpticalFlowPyrLK(ga, gb, p0, p1, s1, e, cv::Size(21, 21), 3, kTerm);
  cv::calcOpticalFlowPyrLK(ga, gw, p0, p2, s2, e, cv::Size(21, 21), 3, kTerm);
  for (std::size_t i = 0; i < p0.size(); ++i) {
    if (!s1[i] || !s2[i] || !inside(p2[i], gb)) continue;
    // The warp is valid only where b shows the same surface the corner lies on.
    const auto truth = scene.transfer(Eigen::Vector2d(p0[i].x, p0[i].y), a, b, la);
    if (!truth || std::hypot(truth->x() - p2[i].x, truth->y() - p2[i].y) > 3) continue;
    diff.push_back(std::hypot(p1[i].x - p2[i].x, p1[i].y - p2[i].y));
    ++per[cs[i].second];
  }
  return summarize(a, b, diff, per);
}

}  // namespace rsfm::render
