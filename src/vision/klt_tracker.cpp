#include <fmt/format.h>

#include "rsfm/io/input_error.hpp"
#include "rsfm/vision/klt_tracker.hpp"
#include "sampling.hpp"

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

// Documented in klt_tracker.hpp.
Photometric photometricChangeAt(const cv::Mat& a, const cv::Mat& b, std::span<const cv::Point2f> pa,
                                std::span<const cv::Point2f> pb, std::span<const uchar> ok, double scale,
                                std::vector<PhotometricSample>* work) {
  Photometric out;
  if (a.empty() || b.empty() || a.type() != CV_8UC1 || b.type() != CV_8UC1 || pa.size() != pb.size() ||
      (!ok.empty() && ok.size() != pa.size())) {
    return out;
  }
  std::vector<PhotometricSample> local;
  std::vector<PhotometricSample>& s = work ? *work : local;
  s.clear();
  // Each pair's grey levels in a and b, binned by their mean (16 bins of 16 levels): binned by a
  // alone, a point's noise would bias the medians (a sample bright in a by chance is on average
  // darker in b: regression to the mean, a false gain below 1); a and b enter the mean alike.
  constexpr int kBins = 16;
  std::array<int, kBins> count{};
  const float f = static_cast<float>(scale);
  for (std::size_t i = 0; i < pa.size(); ++i) {
    if (!ok.empty() && !ok[i]) continue;
    float va = 0, vb = 0;
    if (!sampleBilinear<uchar>(a, f * pa[i].x, f * pa[i].y, &va) || !sampleBilinear<uchar>(b, f * pb[i].x, f * pb[i].y, &vb)) continue;
    const float m = 0.5f * (va + vb);
    s.push_back({m, vb - va});
    ++count[static_cast<std::size_t>(std::clamp(static_cast<int>(m) >> 4, 0, kBins - 1))];
  }
  const int n = static_cast<int>(s.size());
  if (n < 20) return out;  // too few pairs to tell an exposure change from a few bad tracks
  // Grouped by bin (a counting sort into the buffer's second half), each bin's median difference
  // (bins with at least max(5, 2 % of the pairs)), then the line diff = (gain - 1) level + offset
  // through them, weighted by their counts.
  std::array<int, kBins + 1> start{};
  for (int k = 0; k < kBins; ++k) start[static_cast<std::size_t>(k + 1)] = start[static_cast<std::size_t>(k)] + count[static_cast<std::size_t>(k)];
  s.resize(2 * static_cast<std::size_t>(n));
  std::array<int, kBins> fill = {};
  for (int i = 0; i < n; ++i) {
    const int k = std::clamp(static_cast<int>(s[static_cast<std::size_t>(i)].level) >> 4, 0, kBins - 1);
    s[static_cast<std::size_t>(n + start[static_cast<std::size_t>(k)] + fill[static_cast<std::size_t>(k)]++)] = s[static_cast<std::size_t>(i)];
  }
  struct Bin {
    double x, y, w;  // mean level, median difference, 1 / its variance
  };
  std::array<Bin, kBins> bins{};
  int used = 0;
  for (int k = 1; k + 1 < kBins; ++k) {  // the end bins left out: clipping at 0 and 255 biases their medians
    const int c = count[static_cast<std::size_t>(k)];
    if (c < std::max(5, n / 50)) continue;
    const auto first = s.begin() + n + start[static_cast<std::size_t>(k)];
    const auto mid = first + c / 2;
    std::nth_element(first, mid, first + c, [](const PhotometricSample& p, const PhotometricSample& q) { return p.diff < q.diff; });
    double level = 0;
    for (auto it = first; it != first + c; ++it) level += it->level;
    // The median's standard error from the bin's median absolute deviation (1.4826 MAD: the sd
    // of a normal sample; the median's is sqrt(pi / 2) sd / sqrt(c)), at least 0.1 level.
    const float med = mid->diff;
    for (int i = 0; i < c; ++i) s[static_cast<std::size_t>(i)].diff = std::abs(first[i].diff - med);
    std::nth_element(s.begin(), s.begin() + c / 2, s.begin() + c,
                     [](const PhotometricSample& p, const PhotometricSample& q) { return p.diff < q.diff; });
    const double se = std::max(0.1, 1.4826 * 1.2533 * s[static_cast<std::size_t>(c / 2)].diff / std::sqrt(c));
    bins[static_cast<std::size_t>(used++)] = {level / c, med, 1.0 / (se * se)};
  }
  if (used == 0) return out;
  // The weighted line diff = slope level + intercept through the bins' medians but bin `skip`
  // (none: -1); no slope when their levels spread less than 10 levels sd. Its covariance is scaled
  // up by the bins' scatter about it when that exceeds their standard errors. Significant: three
  // standard errors at either end of the levels the bins cover (the size, `most`, is judged by
  // the caller: Photometric::changes).
  struct Line {
    double mx = 0, my = 0, slope = 0, lo = 255, hi = 0;
    bool significant = false;
    double most = 0;  // the largest |change| at an end of [lo, hi]
  };
  const auto fit = [&](int skip) {
    Line l;
    double sw = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
    int m = 0;
    for (int k = 0; k < used; ++k) {
      if (k == skip) continue;
      const Bin& q = bins[static_cast<std::size_t>(k)];
      sw += q.w;
      sx += q.w * q.x;
      sy += q.w * q.y;
      sxx += q.w * q.x * q.x;
      sxy += q.w * q.x * q.y;
      l.lo = std::min(l.lo, q.x);
      l.hi = std::max(l.hi, q.x);
      ++m;
    }
    if (m == 0) return l;
    l.mx = sx / sw;
    l.my = sy / sw;
    const double vx = sxx / sw - l.mx * l.mx;
    const bool fit_slope = vx > 100.0;
    l.slope = fit_slope ? (sxy / sw - l.mx * l.my) / vx : 0.0;
    double chi2 = 0;
    for (int k = 0; k < used; ++k) {
      if (k == skip) continue;
      const Bin& q = bins[static_cast<std::size_t>(k)];
      chi2 += q.w * std::pow(q.y - (l.my + l.slope * (q.x - l.mx)), 2);
    }
    const int dof = m - (fit_slope ? 2 : 1);
    const double inflate = dof > 0 ? std::max(1.0, chi2 / dof) : 1.0;
    for (const double x : {l.lo, l.hi}) {
      const double d = l.my + l.slope * (x - l.mx);
      const double var = inflate * (1.0 / sw + (fit_slope ? (x - l.mx) * (x - l.mx) / (sw * vx) : 0.0));
      l.significant = l.significant || std::abs(d) >= 3.0 * std::sqrt(var);
      l.most = std::max(l.most, std::abs(d));
    }
    return l;
  };
  const Line line = fit(-1);
  double robust = line.significant ? line.most : 0.0;
  for (int k = 0; robust > 0 && used >= 3 && k < used; ++k) {
    const Line l = fit(k);
    robust = l.significant ? std::min(robust, l.most) : 0.0;
  }
  // b = g a + o against the mean level m = (a + b) / 2: b - a = s m + c with s = 2 (g - 1) / (1 + g)
  // and c = 2 o / (1 + g).
  if (!line.significant || !(std::abs(line.slope) < 1.0)) return out;  // a gain beyond 3 or under 1/3: not an exposure change
  out.gain = (2.0 + line.slope) / (2.0 - line.slope);
  out.offset = (line.my - line.slope * line.mx) * (1.0 + out.gain) / 2.0;
  out.lo = line.lo;
  out.hi = line.hi;
  out.robust_levels = robust;
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
    // Track i's predicted position in this frame: where each Lucas-Kanade step starts.
    const auto predicted = [&](size_t i) {
      const Eigen::Vector2d x = cur_[i].px + pred[i];
      return cv::Point2f(static_cast<float>(x.x()), static_cast<float>(x.y()));
    };
    p0.reserve(cur_.size());
    p1.reserve(cur_.size());
    for (size_t i = 0; i < cur_.size(); ++i) {
      p0.emplace_back(static_cast<float>(cur_[i].px.x()), static_cast<float>(cur_[i].px.y()));
      p1.push_back(predicted(i));
    }
    std::vector<uchar> st, stb;
    std::vector<float> err, errb;
    const cv::TermCriteria term(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 20, 0.03);
    // The last frame's pyramid: images at even indices (buildOpticalFlowPyramid with derivatives).
    const std::vector<cv::Mat>* prev = &prev_pyr_;
    cv::calcOpticalFlowPyrLK(*prev, pyr, p0, p1, st, err, win, levels, term, cv::OPTFLOW_USE_INITIAL_FLOW, o_.min_eig);
    if (o_.exposure_compensation) {
      // A change of exposure between the frames (auto-exposure, flicker) breaks Lucas-Kanade's
      // brightness constancy, and its forward-backward check then ends the tracks. Measured at the
      // pairs the forward step found (photometricChangeAt, on pyramid level 2: a smoothed grey
      // level, little changed by a track's sub-pixel error), a motion does not read as a change.
      // When a robust change of a grey level or more is found, the last frame is brought to this
      // frame's brightness and the step repeated from the prediction; the change left is measured
      // again at the new pairs (the first step's are pulled towards the old brightness, so its
      // change reads about half the true one) and, while it is robust (any size), composed and the
      // step repeated: four steps at most (docs/tracks.md, "Exposure changes").
      const int L = std::min(2, built);
      const auto level = [L](const std::vector<cv::Mat>& p) -> const cv::Mat& { return p[static_cast<std::size_t>(2 * L)]; };
      // The total change applied (b ~ gain a + offset).
      Photometric total;
      for (int round = 0; round < 4; ++round) {
        const Photometric change = photometricChangeAt(level(*prev), level(pyr), p0, p1, st, std::ldexp(1.0, -L), &photometric_work_);
        if (round == 0 ? !change.changes() : !(change.robust_levels > 0)) break;
        exposure_changes_ += round == 0;
        total.offset = change.gain * total.offset + change.offset;
        total.gain *= change.gain;
        prev_pyr_[0].convertTo(shifted_, CV_8U, total.gain, total.offset);
        cv::buildOpticalFlowPyramid(shifted_, shifted_pyr_, win, built);
        prev = &shifted_pyr_;
        for (size_t i = 0; i < cur_.size(); ++i) p1[i] = predicted(i);
        cv::calcOpticalFlowPyrLK(*prev, pyr, p0, p1, st, err, win, levels, term, cv::OPTFLOW_USE_INITIAL_FLOW, o_.min_eig);
      }
    }
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
                  const std::function<void(int, int)>& progress, TrackingStats* stats) {
  KltTracker tracker(options);
  // The smallest frame the tracker works in: a window and the anchoring template inside the
  // border on both sides.
  const int need = 2 * (options.border_px + std::max(options.window_px, 2 * options.affine.radius + 1));
  const SourceInfo source = forEachFrame(
      input, range, [&](const cv::Mat& img) { tracker.process(img); }, progress,
      {need, fmt::format("tracking with a {} px window, {} px template radius and {} px border needs", options.window_px,
                         options.affine.radius, options.border_px)});
  Tracks t = tracker.tracks(range.first);
  const std::vector<int>& numbers = source.frame_offsets;
  if (stats)
    *stats = {std::max(0L, static_cast<long>(t.numFrames()) - 1), tracker.exposureChanges(),
              numbers.empty() ? 0L : static_cast<long>(numbers.back()) - numbers.front() + 1 - t.numFrames()};
  // A video that dropped frames: each frame keeps the number its timestamp gives (the dropped
  // ones are absent: tracks.csv's '# dropped_frames', docs/tracks.md).
  if (!numbers.empty()) t.frame_numbers = numbers;
  // Frames before the first corner carry nothing to estimate from (the tracker detects again in
  // every frame until corners appear): the tracks start at the first frame that has some.
  const int trimmed = trimLeadingEmptyFrames(&t);
  // Numbered by time, the tracks' first_frame stays frames[0]'s decoded index (the overlay reads
  // the video by it; Tracks::frame_numbers).
  if (!numbers.empty()) t.first_frame = range.first + trimmed;
  t.source = input;
  t.image.fps = source.fps;
  t.image.time_origin = source.time_origin_s;  // 0 without a rate (forEachFrame)
  t.image.readout_direction = readoutDirectionAfterRotation(source.rotation);
  return t;
}

}  // namespace rsfm::vision
