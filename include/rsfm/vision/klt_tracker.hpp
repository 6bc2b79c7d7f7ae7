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
#include <span>
#include <vector>

#include "rsfm/track/tracks.hpp"
#include "rsfm/vision/affine_lk.hpp"
#include "rsfm/vision/frame_source.hpp"

namespace rsfm::vision {

/// An exposure change b ~ gain a + offset between two 8-bit grey frames (docs/tracks.md,
/// "Exposure changes").
struct Photometric {
  double gain = 1.0, offset = 0.0;  ///< unit, zero: no change found
  double lo = 16, hi = 240;         ///< the grey levels the change was measured over
  /// The change (grey levels) that stays significant with any one of the bins of grey levels
  /// left out: over those fits, the smallest of each one's largest change at an end of its levels;
  /// 0 when one of them is not significant (a motion can change one surface's smoothed grey
  /// levels, and one surface can fill a bin).
  double robust_levels = 0;
  /// A robust change of a grey level or more, also with any one bin left out: the 8-bit quantum
  /// (a smaller change is below what the frames can show, and applied it would only re-round
  /// them).
  bool changes() const {
    return robust_levels >= 1.0 && std::max(std::abs((gain - 1.0) * lo + offset), std::abs((gain - 1.0) * hi + offset)) >= 1.0;
  }
};
/// One corresponding pair's grey levels: their mean and the difference b - a.
struct PhotometricSample {
  float level, diff;
};
/// The exposure change from frame a to frame b (CV_8UC1) measured at corresponding points:
/// pa[i] in a and pb[i] in b, in pixels of the frames' level 0, read bilinearly at `scale` x
/// those (a and b are then a pyramid level of the frames, 2^-L: a smoothed grey level that a
/// track's sub-pixel error hardly changes); pairs with ok[i] == 0 (ok empty: all used) or outside
/// either image are skipped. The pairs are binned by their mean level (16 bins of 16 levels);
/// each bin's median difference (a change of exposure moves every point alike; a wrong pair
/// is an outlier) with its standard error (from the bin's median absolute deviation), and a
/// line through those medians weighted by their inverse variances (the darkest and brightest
/// bins left out: clipping biases them; bins under max(5, 2 % of the pairs) left out; no gain
/// when the mean levels have a variance under 100). The change is reported (lo, hi: the bins'
/// levels) when, at either end of the levels covered, it is three standard errors of the line
/// (scaled up by the bins' scatter about it when that exceeds their errors: a motion that changes
/// some surfaces' smoothed grey levels), with robust_levels from the same fit with each bin left
/// out in turn. Unit gain, zero offset otherwise, with fewer than 20 pairs, or with mismatched
/// inputs. `work` (optional) is a buffer kept between calls.
Photometric photometricChangeAt(const cv::Mat& a, const cv::Mat& b, std::span<const cv::Point2f> pa,
                                std::span<const cv::Point2f> pb, std::span<const uchar> ok, double scale = 1.0,
                                std::vector<PhotometricSample>* work = nullptr);

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
  /// Exposure changes (auto-exposure, flicker): Lucas-Kanade assumes constant brightness and
  /// its forward-backward check fails under a change of a few grey levels (box.mp4 brightened by
  /// 2.4 levels every second frame: tracks lived a median 3 frames against 41.5). After each
  /// forward step the change is measured at the pairs it found (photometricChangeAt); when it
  /// moves a grey level by one or more, the last frame is brought to this frame's brightness and
  /// the step repeated (docs/tracks.md, "Exposure changes"). A sequence without such changes
  /// tracks exactly as with this off.
  bool exposure_compensation = true;
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
  /// Steps repeated with the last frame brought to the next one's brightness
  /// (TrackerOptions::exposure_compensation).
  long exposureChanges() const { return exposure_changes_; }

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
  std::vector<PhotometricSample> photometric_work_;  // photometricChangeAt's buffer
  long exposure_changes_ = 0;
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


/// What trackInput saw besides the tracks.
struct TrackingStats {
  long steps = 0;             ///< frame-to-frame steps tracked
  long exposure_changes = 0;  ///< of them, steps tracked again for a change of exposure (KltTracker::exposureChanges)
  /// Frames the video dropped within the range tracked, by its timestamps (SourceInfo::frame_offsets):
  /// the tracks number their frames by time, so these numbers are absent.
  long dropped_frames = 0;
};

/// Tracks `input` (video, pattern or folder) over `range`. `progress(done, total)` is called per
/// frame (total = -1 when unknown). Leading frames without any track (a video that fades in from
/// black, featureless frames) are left out: the tracks' first_frame is the first frame with
/// corners (callers say so when it is after range.first). Throws io::InputError on bad input
/// (including a range that starts after the end, or fewer than 2 frames). `stats`: optional.
Tracks trackInput(const std::string& input, const TrackerOptions& options, FrameRange range = {},
                  const std::function<void(int, int)>& progress = {}, TrackingStats* stats = nullptr);

}  // namespace rsfm::vision
