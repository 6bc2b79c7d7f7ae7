#include <fmt/format.h>

#include "rsfm/io/input_error.hpp"
#include "rsfm/vision/patch_tracker.hpp"

#include <algorithm>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>


namespace rsfm::vision {

void PatchTracker::detect(const cv::Mat& gray) {
  const int want = o_.max_patches - static_cast<int>(live_.size());
  if (want <= 0) return;
  const int r = o_.affine.radius;
  const double mind = o_.min_distance_px > 0 ? o_.min_distance_px : 1.5 * r;
  cv::Mat mask(gray.size(), CV_8U, cv::Scalar(0));
  const int b = r + 3;
  if (gray.cols <= 2 * b || gray.rows <= 2 * b) return;
  if (o_.roi.size() >= 3 && frames_.empty()) {
    std::vector<cv::Point> poly;
    for (const auto& p : o_.roi) poly.emplace_back(cvRound(p.x), cvRound(p.y));
    cv::fillPoly(mask, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(255));
    cv::Mat inner(gray.size(), CV_8U, cv::Scalar(0));
    inner(cv::Rect(b, b, gray.cols - 2 * b, gray.rows - 2 * b)).setTo(255);
    mask &= inner;
  } else if (o_.roi.size() >= 3) {
    // Later detections stay inside the convex hull of the live patches that started in the ROI.
    std::vector<cv::Point2f> pts;
    for (const auto& [id, l] : live_) pts.emplace_back(static_cast<float>(l.obs.px.x()), static_cast<float>(l.obs.px.y()));
    if (pts.size() < 3) return;
    std::vector<cv::Point2f> hull;
    cv::convexHull(pts, hull);
    std::vector<cv::Point> poly;
    for (const auto& p : hull) poly.emplace_back(cvRound(p.x), cvRound(p.y));
    cv::fillPoly(mask, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(255));
  } else {
    mask(cv::Rect(b, b, gray.cols - 2 * b, gray.rows - 2 * b)).setTo(255);
  }
  for (const auto& [id, l] : live_)
    cv::circle(mask, cv::Point(cvRound(l.obs.px.x()), cvRound(l.obs.px.y())), cvRound(mind), cv::Scalar(0), -1);
  std::vector<cv::Point2f> corners;
  cv::goodFeaturesToTrack(gray, corners, want, o_.quality, mind, mask, o_.block_size);
  if (corners.empty()) return;
  cv::cornerSubPix(gray, corners, cv::Size(5, 5), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 20, 0.01));
  for (const auto& c : corners) {
    Live l;
    const Eigen::Vector2d px(c.x, c.y);
    if (!l.tmpl.init(cur_float_, px, o_.affine)) continue;  // textureless or at the border
    l.obs.id = next_id_++;
    l.obs.px0 = px;
    l.obs.px = px;
    l.obs.A.setIdentity();
    l.obs.rms = 0.0;
    live_.emplace(l.obs.id, std::move(l));
  }
}

void PatchTracker::process(const cv::Mat& frame) {
  const cv::Mat gray = toGray8(frame);
  gray.convertTo(cur_float_, CV_32F);
  const cv::Size win(o_.window_px, o_.window_px);
  std::vector<cv::Mat> pyr;
  cv::buildOpticalFlowPyramid(gray, pyr, win, o_.pyramid_levels);
  if (frames_.empty()) {
    size_ = gray.size();
  } else if (!live_.empty()) {
    std::vector<cv::Point2f> p0, p1;
    std::vector<int> ids;
    for (const auto& [id, l] : live_) {
      p0.emplace_back(static_cast<float>(l.obs.px.x()), static_cast<float>(l.obs.px.y()));
      ids.push_back(id);
    }
    std::vector<uchar> st;
    std::vector<float> err;
    cv::calcOpticalFlowPyrLK(prev_pyr_, pyr, p0, p1, st, err, win, o_.pyramid_levels,
                             cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 30, 0.01));
    for (size_t i = 0; i < ids.size(); ++i) {
      Live& l = live_.at(ids[i]);
      // Prediction: LK's centre if it converged, else the previous centre; the previous A.
      const Eigen::Vector2d pred = st[i] ? Eigen::Vector2d(p1[i].x, p1[i].y) : l.obs.px;
      Eigen::Matrix2d A = l.obs.A;
      Eigen::Vector2d c = pred;
      double rms = 0.0;
      if (l.tmpl.align(cur_float_, &A, &c, &rms) && (c - pred).norm() <= o_.max_jump_px) {
        l.obs.A = A;
        l.obs.px = c;
        l.obs.rms = rms;
      } else {
        l.obs.id = -1;  // lost
      }
    }
    for (auto it = live_.begin(); it != live_.end();) {
      if (it->second.obs.id < 0) {
        ++lost_;
        it = live_.erase(it);
      } else {
        ++it;
      }
    }
  }
  int moving = 0;
  for (const auto& [id, l] : live_) moving += (l.obs.px - l.obs.px0).norm() > o_.moving_px;
  const bool due =
      redetectionDue(static_cast<int>(live_.size()), o_.max_patches, moving, o_.redetect_below, o_.min_moving, &moving_peak_);
  if (frames_.empty() || due) {
    detect(gray);
    moving_peak_ = moving;
  }
  std::vector<PatchObservation> f;
  f.reserve(live_.size());
  for (const auto& [id, l] : live_) f.push_back(l.obs);  // std::map: ascending ids
  frames_.push_back(std::move(f));
  prev_pyr_ = std::move(pyr);
}

PatchTracks PatchTracker::tracks(int first_frame) const {
  PatchTracks t;
  t.image = ImageInfo::centred(size_.width, size_.height);
  t.first_frame = first_frame;
  t.radius = o_.affine.radius;
  t.frames = frames_;
  return t;
}

PatchTracks trackPatchesInput(const std::string& input, const PatchTrackerOptions& options, FrameRange range,
                              const std::function<void(int, int)>& progress) {
  PatchTracker tracker(options);
  // The smallest frame the tracker works in: two patches and the prediction window side by side.
  const int need = 2 * (2 * options.affine.radius + 1) + options.window_px;
  const SourceInfo source = forEachFrame(
      input, range, [&](const cv::Mat& img) { tracker.process(img); }, progress,
      {need, fmt::format("patches of radius {} px with a {} px window need", options.affine.radius, options.window_px)});
  PatchTracks t = tracker.tracks(range.first);
  trimLeadingEmptyFrames(&t);  // a fade-in: the patches start at the first frame with one
  t.source = input;
  t.image.fps = source.stated_fps;  // the patch tracks keep the decoded numbering (docs/tracks.md)
  t.image.time_origin = source.time_origin_s;  // 0 without a rate (forEachFrame)
  t.image.readout_direction = readoutDirectionAfterRotation(source.rotation);
  return t;
}

}  // namespace rsfm::vision
