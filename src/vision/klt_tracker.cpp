#include <fmt/format.h>

#include "rsfm/io/input_error.hpp"
#include "rsfm/vision/klt_tracker.hpp"

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

namespace rsfm::vision {

// Documented in klt_tracker.hpp.
bool redetectionDue(int live, int max_live, int moving, double below, int min_moving, int* moving_peak) {
  *moving_peak = std::max(*moving_peak, moving);
  const bool few = static_cast<double>(live) < below * max_live;
  const bool few_moving = *moving_peak >= min_moving && static_cast<double>(moving) < below * *moving_peak;
  return few || few_moving;
}

void KltTracker::detect(const cv::Mat& gray, bool first) {
  const int want = o_.max_tracks - static_cast<int>(cur_.size());
  if (want <= 0) return;
  cv::Mat mask(gray.size(), CV_8U, cv::Scalar(0));
  const int b = o_.border_px;
  if (o_.roi.size() >= 3) {
    std::vector<cv::Point> poly;
    if (first) {
      for (const auto& p : o_.roi) poly.emplace_back(cvRound(p.x), cvRound(p.y));
    } else if (cur_.size() >= 3) {
      std::vector<cv::Point2f> pts;
      for (const auto& t : cur_) pts.emplace_back(static_cast<float>(t.px.x()), static_cast<float>(t.px.y()));
      std::vector<cv::Point2f> hull;
      cv::convexHull(pts, hull);
      for (const auto& p : hull) poly.emplace_back(cvRound(p.x), cvRound(p.y));
    }
    if (poly.size() >= 3) cv::fillPoly(mask, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(255));
  } else {
    mask(cv::Rect(b, b, std::max(1, gray.cols - 2 * b), std::max(1, gray.rows - 2 * b))).setTo(255);
  }
  for (const auto& t : cur_)
    cv::circle(mask, cv::Point(cvRound(t.px.x()), cvRound(t.px.y())), cvRound(o_.min_distance_px), cv::Scalar(0), -1);
  // Bucketed detection: the quality level is relative to the best corner of each grid cell, so
  // weakly textured regions (a face in shadow, a low-contrast print) still get corners, and each
  // cell gets at most its share of the budget.
  std::vector<cv::Point2f> corners;
  const int gx = std::max(1, o_.grid_cols), gy = std::max(1, o_.grid_rows);
  const int per_cell = std::max(1, (o_.max_tracks + gx * gy - 1) / (gx * gy));
  std::vector<int> live(gx * gy, 0);
  auto cellOf = [&](double x, double y) {
    const int cx = std::clamp(static_cast<int>(x * gx / gray.cols), 0, gx - 1);
    const int cy = std::clamp(static_cast<int>(y * gy / gray.rows), 0, gy - 1);
    return cy * gx + cx;
  };
  for (const auto& t : cur_) ++live[cellOf(t.px.x(), t.px.y())];
  for (int cy = 0; cy < gy; ++cy)
    for (int cx = 0; cx < gx; ++cx) {
      const int room = per_cell - live[cy * gx + cx];
      if (room <= 0) continue;
      const cv::Rect r(cx * gray.cols / gx, cy * gray.rows / gy, (cx + 1) * gray.cols / gx - cx * gray.cols / gx,
                       (cy + 1) * gray.rows / gy - cy * gray.rows / gy);
      if (cv::countNonZero(mask(r)) == 0) continue;
      std::vector<cv::Point2f> c;
      cv::goodFeaturesToTrack(gray(r), c, room, o_.quality, o_.min_distance_px, mask(r), o_.block_size);
      for (auto& p : c) corners.emplace_back(p.x + r.x, p.y + r.y);
    }
  if (corners.empty()) return;
  cv::cornerSubPix(gray, corners, cv::Size(5, 5), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 20, 0.01));
  // A corner the tracker would refuse at once is no corner: Lucas-Kanade ends a track whose
  // window's gradient matrix has its smaller eigenvalue (per pixel) under min_eig, and a cell of
  // bare table or wall offers corners that pass the cell's relative quality level but not that
  // (the ViSP cube on its white table: 3867 of 5407 tracks lived one or two frames). The test is
  // OpenCV's own, on this frame's pyramid, at the sub-pixel position the track starts from.
  {
    std::vector<cv::Point2f> same = corners;
    std::vector<uchar> st;
    std::vector<float> eig;
    cv::calcOpticalFlowPyrLK(next_pyr_, next_pyr_, corners, same, st, eig, cv::Size(o_.window_px, o_.window_px), 0,
                             cv::TermCriteria(cv::TermCriteria::COUNT, 1, 0.03),
                             cv::OPTFLOW_USE_INITIAL_FLOW | cv::OPTFLOW_LK_GET_MIN_EIGENVALS, o_.min_eig);
    size_t k = 0;
    for (size_t i = 0; i < corners.size(); ++i)
      if (st[i] && eig[i] >= o_.min_eig) corners[k++] = corners[i];
    corners.resize(k);
  }
  for (const auto& c : corners) {
    const Eigen::Vector2d px(c.x, c.y);
    if (o_.anchor) {
      Anchor a;
      if (!a.tmpl.init(cur_float_, px, o_.affine)) continue;  // textureless or at the border
      anchors_[next_id_] = std::move(a);
    }
    first_px_.push_back(px);  // ids ascend from 0: first_px_[id]
    cur_.push_back({next_id_++, px});
    vel_.push_back(Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN()));
  }
}

void KltTracker::anchor(std::vector<TrackPoint>* tracks) {
  std::vector<TrackPoint> out;
  out.reserve(tracks->size());
  for (auto& t : *tracks) {
    auto it = anchors_.find(t.id);
    if (it == anchors_.end()) continue;
    Eigen::Matrix2d A = it->second.A;
    Eigen::Vector2d b = t.px;
    double rms = 0.0;
    if (it->second.tmpl.align(cur_float_, &A, &b, &rms) && (b - t.px).norm() <= o_.anchor_max_px) {
      it->second.A = A;
      t.px = b;
      out.push_back(t);
      continue;
    }
    // The first appearance no longer matches (lighting, occlusion edge, strong deformation):
    // re-anchor the track on its frame-to-frame position in this frame - unless that position is
    // itself doubtful (the alignment moved it far: an occlusion or a slip), or the patch has no
    // texture; then the track ends.
    if ((b - t.px).norm() > o_.anchor_max_px && b.allFinite()) continue;
    Anchor fresh;
    if (!fresh.tmpl.init(cur_float_, t.px, o_.affine)) continue;
    it->second = std::move(fresh);
    ++reanchored_;
    out.push_back(t);
  }
  tracks->swap(out);
}

std::vector<Eigen::Vector2d> KltTracker::predictedDisplacements() const {
  // A track's own last displacement; a track without one takes its nearest neighbour's (the
  // same surface most likely), none at all: zero.
  std::vector<Eigen::Vector2d> d(cur_.size(), Eigen::Vector2d::Zero());
  std::vector<int> known;
  for (size_t i = 0; i < cur_.size(); ++i)
    if (vel_[i].allFinite()) known.push_back(static_cast<int>(i));
  for (size_t i = 0; i < cur_.size(); ++i) {
    if (vel_[i].allFinite()) {
      d[i] = vel_[i];
      continue;
    }
    double best = INFINITY;
    for (int j : known) {
      const double dist = (cur_[j].px - cur_[i].px).squaredNorm();
      if (dist < best) {
        best = dist;
        d[i] = vel_[j];
      }
    }
  }
  return d;
}

int KltTracker::levelsNeeded() const {
  const bool any_velocity = std::any_of(vel_.begin(), vel_.end(), [](const Eigen::Vector2d& v) { return v.allFinite(); });
  const int lo = std::max(0, o_.pyramid_levels), hi = std::max(lo, o_.max_pyramid_levels);
  if (!any_velocity || last_pred_err95_ < 0) return hi;  // no motion seen yet: the deepest pyramid
  int L = lo;
  while (L < hi && 0.5 * o_.window_px * std::pow(2.0, L) < 2.0 * last_pred_err95_) ++L;
  return L;
}

Photometric photometricChange(const cv::Mat& a, const cv::Mat& b) {
  Photometric out;
  if (a.empty() || a.size() != b.size() || a.type() != CV_8UC1 || b.type() != CV_8UC1) return out;
  // Every 4th pixel of every 4th row, binned by its mean grey level in a and b (16 bins of 16
  // levels): a histogram of the 511 possible differences b - a per bin. Binned by a alone, the
  // motion would bias the medians (a pixel bright in a meets, after the motion, an average one
  // in b: regression to the mean, a false gain below 1); a and b enter the mean alike.
  constexpr int kBins = 16;
  std::array<std::array<int, 511>, kBins> hist{};  // 32 kB on the stack: no allocation per frame
  std::array<int, kBins> count{};
  std::array<double, kBins> level{};
  int n = 0;
  for (int y = 0; y < a.rows; y += 4) {
    const uchar* pa = a.ptr<uchar>(y);
    const uchar* pb = b.ptr<uchar>(y);
    for (int x = 0; x < a.cols; x += 4, ++n) {
      const int k = (pa[x] + pb[x]) >> 5;
      ++hist[static_cast<std::size_t>(k)][static_cast<std::size_t>(255 + pb[x] - pa[x])];
      ++count[static_cast<std::size_t>(k)];
      level[static_cast<std::size_t>(k)] += 0.5 * (pa[x] + pb[x]);
    }
  }
  // Each bin's median difference (bins with at least 2 % of the samples), then the line
  // diff = (gain - 1) level + offset through them, weighted by their counts.
  double sw = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (int k = 1; k + 1 < kBins; ++k) {  // the end bins left out: clipping at 0 and 255 biases their medians
    const int c = count[static_cast<std::size_t>(k)];
    if (c < std::max(20, n / 50)) continue;
    int cum = 0, med = 0;
    for (int d = 0; d < 511; ++d) {
      cum += hist[static_cast<std::size_t>(k)][static_cast<std::size_t>(d)];
      if (2 * cum > c) {
        med = d - 255;
        break;
      }
    }
    const double x = level[static_cast<std::size_t>(k)] / c, w = c;
    sw += w;
    sx += w * x;
    sy += w * med;
    sxx += w * x * x;
    sxy += w * x * med;
  }
  if (!(sw > 0)) return out;
  const double mx = sx / sw, my = sy / sw, vx = sxx / sw - mx * mx;
  const double slope = vx > 100.0 ? (sxy / sw - mx * my) / vx : 0.0;  // a spread of grey levels to fit a gain on
  // b = g a + o against the mean level m = (a + b) / 2: b - a = s m + c with s = 2 (g - 1) / (1 + g)
  // and c = 2 o / (1 + g).
  if (!(std::abs(slope) < 1.0)) return out;  // a gain beyond 3 or under 1/3: not an exposure change
  out.gain = (2.0 + slope) / (2.0 - slope);
  out.offset = (my - slope * mx) * (1.0 + out.gain) / 2.0;
  return out;
}

void KltTracker::process(const cv::Mat& frame) {
  const cv::Mat gray = toGray8(frame, &gray_);
  const cv::Size win(o_.window_px, o_.window_px);
  if (o_.anchor) gray.convertTo(cur_float_, CV_32F);
  const int built = std::max(o_.pyramid_levels, o_.max_pyramid_levels);
  // Built into the buffers of the pyramid before last (same size every frame): no fresh
  // allocation, hence no page faults, per frame.
  std::vector<cv::Mat>& pyr = next_pyr_;
  cv::buildOpticalFlowPyramid(gray, pyr, win, built);
  if (frames_.empty()) {
    size_ = gray.size();
    detect(gray, true);
  } else if (cur_.empty()) {
    // No live track: a video that starts black or featureless (a fade-in), or every track lost.
    // Detect again in every frame until corners appear; before the first track ever, a region
    // of interest is still the first frame's polygon.
    detect(gray, next_id_ == 0);
  } else {
    const int levels = levelsNeeded();
    const std::vector<Eigen::Vector2d> pred = predictedDisplacements();
    std::vector<cv::Point2f> p0, p1, pb;
    p0.reserve(cur_.size());
    p1.reserve(cur_.size());
    for (size_t i = 0; i < cur_.size(); ++i) {
      const Eigen::Vector2d& x = cur_[i].px;
      p0.emplace_back(static_cast<float>(x.x()), static_cast<float>(x.y()));
      p1.emplace_back(static_cast<float>(x.x() + pred[i].x()), static_cast<float>(x.y() + pred[i].y()));
    }
    std::vector<uchar> st, stb;
    std::vector<float> err, errb;
    const cv::TermCriteria term(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 20, 0.03);
    // A change of exposure between the frames (auto-exposure, flicker) breaks Lucas-Kanade's
    // brightness constancy: with TrackerOptions::exposure_compensation the last frame is brought
    // to this one's brightness, a gain and an offset from the two frames' median differences at
    // the same pixels (photometricChange).
    // The last frame is its pyramid's level 0 (buildOpticalFlowPyramid with derivatives:
    // images at even indices).
    const cv::Mat& last = prev_pyr_[0];
    const Photometric change = o_.exposure_compensation ? photometricChange(last, gray) : Photometric{};
    const std::vector<cv::Mat>* prev = &prev_pyr_;
    if (change.changes()) {
      last.convertTo(shifted_, CV_8U, change.gain, change.offset);
      cv::buildOpticalFlowPyramid(shifted_, shifted_pyr_, win, built);
      prev = &shifted_pyr_;
    }
    cv::calcOpticalFlowPyrLK(*prev, pyr, p0, p1, st, err, win, levels, term, cv::OPTFLOW_USE_INITIAL_FLOW,
                             o_.min_eig);
    pb = p0;
    if (o_.fb_check) {
      cv::calcOpticalFlowPyrLK(pyr, *prev, p1, pb, stb, errb, win, levels, term, cv::OPTFLOW_USE_INITIAL_FLOW,
                               o_.min_eig);
    } else {
      stb = st;
    }
    std::vector<TrackPoint> next;
    next.reserve(cur_.size());
    const double b = o_.border_px;
    for (size_t i = 0; i < cur_.size(); ++i) {
      if (!st[i] || !stb[i]) continue;
      const double fb = std::hypot(pb[i].x - p0[i].x, pb[i].y - p0[i].y);
      if (!(fb <= o_.fb_max_px)) continue;
      if (p1[i].x < b || p1[i].y < b || p1[i].x > gray.cols - 1 - b || p1[i].y > gray.rows - 1 - b) continue;
      next.push_back({cur_[i].id, Eigen::Vector2d(p1[i].x, p1[i].y)});
    }
    if (o_.anchor && !next.empty() && frames_.size() % std::max(1, o_.anchor_every) == 0) anchor(&next);
    // The survivors' displacements (their velocity for the next prediction) and how far the
    // prediction missed (the next step's pyramid depth).
    std::vector<Eigen::Vector2d> next_vel;
    std::vector<double> miss;
    next_vel.reserve(next.size());
    miss.reserve(next.size());
    for (const TrackPoint& t : next) {
      const auto it = std::lower_bound(cur_.begin(), cur_.end(), t.id, [](const TrackPoint& a, int id) { return a.id < id; });
      const size_t i = static_cast<size_t>(it - cur_.begin());
      next_vel.push_back(t.px - cur_[i].px);
      miss.push_back((t.px - (cur_[i].px + pred[i])).norm());
    }
    if (!miss.empty()) {
      const size_t q = std::min(miss.size() - 1, static_cast<size_t>(0.95 * static_cast<double>(miss.size())));
      std::nth_element(miss.begin(), miss.begin() + static_cast<long>(q), miss.end());
      last_pred_err95_ = miss[q];
    }
    cur_.swap(next);
    vel_.swap(next_vel);
    int moving = 0;
    for (const auto& t : cur_) moving += (t.px - first_px_[static_cast<size_t>(t.id)]).norm() > o_.moving_px;
    if (redetectionDue(static_cast<int>(cur_.size()), o_.max_tracks, moving, o_.redetect_below, o_.min_moving, &moving_peak_)) {
      detect(gray, false);
      moving_peak_ = moving;
    }
  }
  // Ids ascend: survivors keep their order and detect() appends fresh, larger ids (the lookups
  // above and Tracks rely on it).
  assert(std::is_sorted(cur_.begin(), cur_.end(), [](const TrackPoint& a, const TrackPoint& c) { return a.id < c.id; }));
  frames_.push_back(cur_);
  if (o_.anchor) {  // forget the templates of tracks that ended
    for (auto it = anchors_.begin(); it != anchors_.end();) {
      it = findById(cur_, it->first) ? std::next(it) : anchors_.erase(it);
    }
  }
  std::swap(prev_pyr_, next_pyr_);
}

Tracks KltTracker::tracks(int first_frame) const {
  Tracks t;
  t.image = ImageInfo::centred(size_.width, size_.height);
  t.first_frame = first_frame;
  t.frames = frames_;
  return t;
}

Tracks trackInput(const std::string& input, const TrackerOptions& options, FrameRange range,
                  const std::function<void(int, int)>& progress) {
  KltTracker tracker(options);
  // The smallest frame the tracker works in: a window and the anchoring template inside the
  // border on both sides.
  const int need = 2 * (options.border_px + std::max(options.window_px, 2 * options.affine.radius + 1));
  const double fps = forEachFrame(
      input, range, [&](const cv::Mat& img) { tracker.process(img); }, progress,
      {need, fmt::format("tracking with a {} px window, {} px template radius and {} px border needs", options.window_px,
                         options.affine.radius, options.border_px)});
  Tracks t = tracker.tracks(range.first);
  // Frames before the first corner carry nothing to estimate from (the tracker detects again in
  // every frame until corners appear): the tracks start at the first frame that has some.
  trimLeadingEmptyFrames(&t);
  t.source = input;
  t.image.fps = fps;
  return t;
}

}  // namespace rsfm::vision
