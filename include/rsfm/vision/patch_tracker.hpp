#pragma once
// Affine patch tracker (issue 5; docs/patches.md): each patch is a (2r+1)^2 template around a
// Shi-Tomasi corner in the frame where it is first seen. In every later frame the 6-parameter
// affine warp from that first appearance is estimated by inverse-compositional affine
// Lucas-Kanade with a Gaussian window that warps with the patch and gain/bias normalization
// (affine_lk.hpp), initialized from the previous frame's warp with the translation predicted by
// pyramidal LK of the centre. A patch is lost (and ends) when the alignment fails (residual above
// max_rms, area change outside [min_det, max_det], textureless, leaves the image) or lands more
// than max_jump_px from the LK prediction. New patches are detected when fewer than
// redetect_below * max_patches live, or fewer than redetect_below of the most patches that had
// moved since the last detection (the KLT tracker's rule, klt_tracker.hpp).
#include <opencv2/core.hpp>

#include <functional>
#include <map>
#include <string>
#include <vector>

#include "rsfm/track/patches.hpp"
#include "rsfm/vision/affine_lk.hpp"
#include "rsfm/vision/klt_tracker.hpp"

namespace rsfm::vision {

struct PatchTrackerOptions {
  int max_patches = 60;
  double quality = 0.01;          ///< Shi-Tomasi quality level (relative to the best corner)
  double min_distance_px = -1.0;  ///< minimum distance between patch centres (<= 0: 1.5 radius)
  int block_size = 7;
  int window_px = 21;             ///< LK window of the centre prediction (px)
  int pyramid_levels = 3;
  double max_jump_px = 3.0;       ///< loss: alignment this far from the LK prediction (px)
  double redetect_below = 0.7;
  /// ... or when fewer than redetect_below of the most patches that had moved (more than
  /// moving_px from where they started) since the last detection still live, once at least
  /// min_moving had: before a still background a moving object's lost patches are replaced
  /// (TrackerOptions::moving_px, min_moving: the same rule and values as the KLT tracker's).
  double moving_px = TrackerOptions{}.moving_px;
  int min_moving = TrackerOptions{}.min_moving;
  /// The alignment: radius 15 (31 x 31 templates), Gaussian window sigma 15, bicubic sampling,
  /// 20 iterations to 0.002 px. These reach 0.03-0.04 px at the corners of a known warp of a real
  /// image (tests/test_video.cpp); radius 10 with bilinear sampling gave up to 0.19 px.
  AffineLkOptions affine = [] {
    AffineLkOptions a;
    a.radius = 15;
    a.window_sigma = 15.0;
    a.cubic = true;
    a.max_iterations = 20;
    a.epsilon_px = 0.002;
    return a;
  }();
  std::vector<cv::Point2f> roi;   ///< first-frame polygon (px) where patches are detected (empty: all)
};

class PatchTracker {
 public:
  explicit PatchTracker(PatchTrackerOptions o = {}) : o_(std::move(o)) {}
  void process(const cv::Mat& frame);
  PatchTracks tracks(int first_frame = 0) const;
  /// Patches lost so far (alignment failure or jump).
  long lost() const { return lost_; }

 private:
  void detect(const cv::Mat& gray);
  struct Live {
    AffineTemplate tmpl;
    PatchObservation obs;
  };
  PatchTrackerOptions o_;
  std::vector<cv::Mat> prev_pyr_;
  cv::Mat cur_float_;
  std::map<int, Live> live_;
  std::vector<std::vector<PatchObservation>> frames_;
  int next_id_ = 0;
  long lost_ = 0;
  int moving_peak_ = 0;  // most moving patches alive since the last detection
  cv::Size size_;
};

/// Tracks patches through `input` (video, pattern or folder) over `range`; errors as trackInput.
PatchTracks trackPatchesInput(const std::string& input, const PatchTrackerOptions& options, FrameRange range = {},
                              const std::function<void(int, int)>& progress = {});

}  // namespace rsfm::vision
