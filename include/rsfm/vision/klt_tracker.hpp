#pragma once
// KLT tracking (docs/tracks.md): Shi-Tomasi corners refined to sub-pixel accuracy, pyramidal
// Lucas-Kanade frame to frame with a forward-backward check, re-detection to keep enough tracks,
// an optional region of interest in the first frame. Each track's position is predicted from its
// own last displacement (a new track: its nearest neighbour's), and the pyramid is made as deep
// as the last frame's prediction errors need, so slow and fast motion (0.1-10 deg per frame)
// track with the same options.
#include <opencv2/core.hpp>

#include <algorithm>
#include <cmath>
#include <map>
#include <vector>

#include "rsfm/track/tracks.hpp"
#include "rsfm/vision/affine_lk.hpp"
#include "rsfm/vision/frame_source.hpp"

namespace rsfm::vision {

/// The exposure change from grey frame a to grey frame b (same size, CV_8UC1): b ~ gain a +
/// offset. Every 4th pixel of every 4th row is binned by its mean grey level in a and b; each
/// bin's median difference b - a (a change of exposure moves every pixel alike; a small motion
/// changes pixels both ways, mostly at edges) and a line through those medians weighted by the
/// bins' counts (the darkest and brightest bins left out: clipping biases them; no gain when the
/// mean levels have a variance under 100). A large motion (most pixels changed) can read as a
/// change of a few levels (docs/tracks.md, "Exposure changes"). Unit gain, zero offset when the
/// sizes or types differ.
struct Photometric {
  double gain = 1.0, offset = 0.0;
  /// Moves some grey level in [16, 240] by a level or more: the 8-bit quantum (a smaller change
  /// is below what the frames can show, and applied it would only re-round them).
  bool changes() const { return std::max(std::abs((gain - 1.0) * 16.0 + offset), std::abs((gain - 1.0) * 240.0 + offset)) >= 1.0; }
};
Photometric photometricChange(const cv::Mat& a, const cv::Mat& b);

struct TrackerOptions {
  int max_tracks = 300;             ///< corners kept alive at most
  double quality = 0.01;            ///< Shi-Tomasi quality level (fraction of the best corner of a cell)
  int grid_cols = 8, grid_rows = 6; ///< detection grid: each cell gets max_tracks / cells corners at most
  double min_distance_px = 8.0;     ///< minimum distance between corners (px)
  int block_size = 7;               ///< Shi-Tomasi block (px)
  int window_px = 11;               ///< Lucas-Kanade window side (px)
  /// Pyramid levels above the image: at least pyramid_levels; more, up to max_pyramid_levels,
  /// when the motion left after the prediction needs them: the smallest L with
  /// (window_px / 2) 2^L >= 2 x the 95th percentile of the last frame's prediction errors; the
  /// first step (no motion seen yet) uses max_pyramid_levels.
  int pyramid_levels = 2;
  int max_pyramid_levels = 5;
  double fb_max_px = 0.5;           ///< forward-backward error above which a track ends (px)
  /// Forward-backward check (a track ends when tracking back misses its start by more than
  /// fb_max_px). Off only to save time on slow, clean sequences: without it a track that slips
  /// onto similar texture at a fast step carries on there.
  bool fb_check = true;
  double min_eig = 1e-4;            ///< LK minimum eigenvalue threshold (cv::OPTFLOW_LK_GET_MIN_EIGENVALS)
  double redetect_below = 0.7;      ///< re-detect when fewer than this fraction of max_tracks live
  /// ... or when fewer than redetect_below of the most tracks that had moved (more than
  /// moving_px from where they started) since the last detection still live, once at least
  /// min_moving had: a hand-held object before a still background loses its tracks at a jerk
  /// while the background keeps the count up, so the count alone never re-detects (issue 14).
  double moving_px = 2.0;
  int min_moving = 10;
  int border_px = 10;               ///< tracks closer than this to the border end
  /// Anchored tracking: after each frame-to-frame step every track is re-aligned to its own
  /// first appearance by inverse-compositional affine Lucas-Kanade (affine_lk.hpp), which removes
  /// the drift of chained frame-to-frame translations under perspective change. When the
  /// alignment fails (residual, degenerate warp) or lands more than anchor_max_px from the
  /// frame-to-frame position, the track is re-anchored on its current appearance (drift then
  /// only accumulates over re-anchorings).
  bool anchor = true;
  AffineLkOptions affine{.converge_shape = false};  ///< the anchoring's alignment (its position matters, not its shape)
  double anchor_max_px = 2.0;
  int anchor_every = 1;             ///< align to the first appearance every this many frames (2: 13 % faster tracking, focal errors 1.5x larger on the rendered orbits)
  /// Exposure changes (auto-exposure, flicker): before each step the last frame is brought to
  /// this frame's brightness (photometricChange: b ~ gain a + offset, applied when it moves a grey
  /// level by one or more), since Lucas-Kanade assumes constant brightness and its
  /// forward-backward check fails under a change of a few grey levels (box.mp4 brightened by
  /// 2.4 levels every second frame: 2216 tracks living a median 3 frames against 600 living 41.5;
  /// with this on, 618 living 34). Off by default: measured at the same pixels of the two frames,
  /// a large motion (10 deg per frame, hand-held jitter) reads as a change of 2-5 levels where
  /// there is none, and the regime suite's box-jitter then ended with a normal 2.5 deg off
  /// (docs/tracks.md, "Exposure changes").
  bool exposure_compensation = false;
  /// Region of interest: polygon in the first frame's pixels (empty: the whole image). Later
  /// re-detections stay inside the convex hull of the live tracks that started in it.
  std::vector<cv::Point2f> roi;
};

/// The re-detection rule of both trackers (KltTracker; PatchTracker with its own options): due
/// when fewer than `below` x `max_live` are alive, or fewer than `below` of the most moving ones
/// since the last detection (`*moving_peak`, raised here to `moving`) once at least `min_moving`
/// had. After detecting, the caller sets *moving_peak to the moving count it detected at.
bool redetectionDue(int live, int max_live, int moving, double below, int min_moving, int* moving_peak);

class KltTracker {
 public:
  explicit KltTracker(TrackerOptions o = {}) : o_(std::move(o)) {}
  /// Adds the next frame (8-bit gray or BGR).
  void process(const cv::Mat& frame);
  /// Tracks so far; image.cx, cy = image centre; first_frame = `first_frame`.
  Tracks tracks(int first_frame = 0) const;
  /// Live tracks in the last frame (id, position).
  const std::vector<TrackPoint>& live() const { return cur_; }
  /// Times a track was re-anchored because its first appearance no longer matched.
  long reanchored() const { return reanchored_; }

 private:
  void detect(const cv::Mat& gray, bool first);
  void anchor(std::vector<TrackPoint>* tracks);
  /// Each live track's predicted displacement into the next frame.
  std::vector<Eigen::Vector2d> predictedDisplacements() const;
  /// Pyramid levels for the next step (TrackerOptions::pyramid_levels).
  int levelsNeeded() const;
  TrackerOptions o_;
  std::vector<cv::Mat> prev_pyr_, next_pyr_;  // the last frame's pyramid; the buffers for the next
  cv::Mat gray_;                               // the frame in 8-bit grey (buffer reused)
  cv::Mat shifted_;                            // the last frame brought to this frame's brightness (buffer)
  std::vector<cv::Mat> shifted_pyr_;           // its pyramid (buffers)
  std::vector<TrackPoint> cur_;
  /// Per live track (cur_'s order): its last frame-to-frame displacement (NaN: none yet).
  std::vector<Eigen::Vector2d> vel_;
  double last_pred_err95_ = -1;    ///< 95th percentile of the last step's prediction errors (-1: none)
  struct Anchor {
    AffineTemplate tmpl;
    Eigen::Matrix2d A = Eigen::Matrix2d::Identity();
  };
  std::map<int, Anchor> anchors_;  // live tracks' templates (anchor = true)
  cv::Mat cur_float_;              // current frame as CV_32F
  long reanchored_ = 0;
  std::vector<std::vector<TrackPoint>> frames_;
  int next_id_ = 0;
  std::vector<Eigen::Vector2d> first_px_;  ///< per track id: where it started
  int moving_peak_ = 0;                    ///< most moving tracks alive since the last detection
  cv::Size size_;
};

}  // namespace rsfm::vision

#include <functional>
#include <string>

namespace rsfm::vision {


/// Tracks `input` (video, pattern or folder) over `range`. `progress(done, total)` is called per
/// frame (total = -1 when unknown). Leading frames without any track (a video that fades in from
/// black, featureless frames) are left out: the tracks' first_frame is the first frame with
/// corners (callers say so when it is after range.first). Throws io::InputError on bad input
/// (including a range that starts after the end, or fewer than 2 frames).
Tracks trackInput(const std::string& input, const TrackerOptions& options, FrameRange range = {},
                  const std::function<void(int, int)>& progress = {});

}  // namespace rsfm::vision
