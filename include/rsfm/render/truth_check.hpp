#pragma once
// Checks of a rendered sequence against its truth (docs/render.md, "Checks"; docs/regimes.md).
//
//  - trackAgainstTruth: corners of frame a tracked into frame b by pyramidal Lucas-Kanade (the
//    frames as decoded from the video, with every image effect) against where the truth puts
//    them (Scene::transfer): the truth seen through a real tracker, tracker errors included.
//  - renderedAgainstWarp: the renderer's geometry alone: corners of frame a tracked into rendered
//    frame b and into frame a warped to b's view through the truth (warpThroughTruth) land at the
//    same place; the tracker's own errors (its translation model on foreshortened faces) are the
//    same in both and cancel.
//  - tracksAgainstTruth: a tracker's whole output (rsfm's tracks.csv) against the truth, each
//    track carried from its first observation (where it was detected) by Scene::transfer: its
//    drift and error over its whole life (issue 15: the tracker's speed-ups must not change it).
// Corners are taken well inside one surface (labels eroded by 13 x 13 px), 12 px from the border.
#include <opencv2/core.hpp>
#include <vector>

#include "rsfm/render/scene_render.hpp"
#include "rsfm/track/tracks.hpp"

namespace rsfm::render {

struct TruthCheck {
  int a = 0, b = 0;
  int tracks = 0;           ///< corners compared
  int surfaces = 0;         ///< surfaces (truth planes, the still body) with >= 5 of them
  double median_px = 0;     ///< median distance (valid when tracks > 0)
  double p90_px = 0;        ///< 90th percentile
};

TruthCheck trackAgainstTruth(const Scene& scene, const cv::Mat& grey_a, const cv::Mat& grey_b, int a, int b);

/// Frame a's image seen from frame b: each pixel of b takes the colour of the point of a it
/// shows (Scene::transfer through b's labels), bicubic; 0 where b shows the background.
cv::Mat warpThroughTruth(const Scene& scene, const cv::Mat& img_a, int a, int b);

TruthCheck renderedAgainstWarp(const Scene& scene, int a, int b);

/// |track - truth| over every observation after a track's first, the truth being where the scene
/// point seen at the track's first observation appears (Scene::transfer). Tracks born within 2 px
/// of a surface boundary or on the background are left out. Pixels; tracks.first_frame is the
/// scene's frame of tracks.frames[0].
struct TracksTruthError {
  int tracks = 0;              ///< tracks compared
  long observations = 0;       ///< observations compared
  double median_px = 0, p95_px = 0;  ///< of |track - truth| (valid when observations > 0)
  /// Mean component of (track - truth) along the direction from the image centre to the truth:
  /// > 0 the tracks sit outside the truth (a radial bias looks like distortion or a focal change).
  double radial_mean_px = 0;
  /// Median of that radial component: the bulk's bias, which the mean mixes with the tails
  /// (slips of a pixel or more drag the mean where the median stays near 0).
  double radial_median_px = 0;
  /// The same by track age (frames since the track's first observation), ages [first_age,
  /// last_age]: the anchored tracker's error grows as the template ages (docs/regimes.md).
  struct AgeBucket {
    int first_age = 0, last_age = 0;  ///< last_age -1: no upper limit
    long observations = 0;
    double median_px = 0, p95_px = 0, radial_median_px = 0;
  };
  std::vector<AgeBucket> by_age;  ///< ages 1-2, 3-9, 10-29, 30-59, 60-99, 100+ (buckets with observations)
};
TracksTruthError tracksAgainstTruth(const Scene& scene, const Tracks& tracks);

}  // namespace rsfm::render
