// Issue 15 item 4: the front end's cost per frame, side by side with the plain OpenCV recipe a
// user would write, on the same frames, with each one's tracking error against the truth.
// The frames: the regime suite's default rendered sequence (box, orbit, 640 x 480, f = 520 px,
// render/scene_render.hpp), its first kFrames frames rendered once into memory (not timed: the
// decoding a video would add is left out, as it is the same for both).
//   rsfm:   vision::KltTracker (klt_tracker.hpp) over the frames, a fresh tracker per pass;
//           argument 0 = the defaults (anchoring to each track's first appearance every frame,
//           forward-backward check), 1 = without the anchoring, 2 = without the
//           forward-backward check.
//   OpenCV: cv::goodFeaturesToTrack (300 corners, quality 0.01, 8 px apart) in the first frame
//           and again whenever fewer than 70 % live, cv::calcOpticalFlowPyrLK frame to frame with
//           OpenCV's default 21 px window and 3 pyramid levels, status-checked.
// Counters: per_frame (seconds), track_err_median_px / track_err_p95_px (render::tracksAgainstTruth:
// every observation against where the truth carries the track's first observation), tracks.
//   OPENCV_FOR_THREADS_NUM=1 taskset -c 0 build/rsfm_bench --benchmark_filter=Track --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "rsfm/render/scene_render.hpp"
#include "rsfm/render/truth_check.hpp"
#include "rsfm/vision/klt_tracker.hpp"

namespace {

using namespace rsfm;

constexpr int kFrames = 60;

struct Sequence {
  std::unique_ptr<render::Scene> scene;
  std::vector<cv::Mat> grey;
};

const Sequence& sequence() {
  static const Sequence s = [] {
    Sequence q;
    render::RenderOptions o;  // the suite's box-orbit
    q.scene = std::make_unique<render::Scene>(o);
    for (int k = 0; k < kFrames; ++k) {
      cv::Mat g;
      cv::cvtColor(q.scene->render(k), g, cv::COLOR_BGR2GRAY);
      q.grey.push_back(g);
    }
    return q;
  }();
  return s;
}

void report(benchmark::State& state, const Tracks& t) {
  const render::TracksTruthError e = render::tracksAgainstTruth(*sequence().scene, t);
  state.counters["per_frame"] = benchmark::Counter(static_cast<double>(kFrames), benchmark::Counter::kIsIterationInvariantRate |
                                                                                   benchmark::Counter::kInvert);
  state.counters["tracks"] = e.tracks;
  state.counters["track_err_median_px"] = e.median_px;
  state.counters["track_err_p95_px"] = e.p95_px;
}

void BM_Track_rsfm(benchmark::State& state) {
  const Sequence& s = sequence();
  vision::TrackerOptions o;
  if (state.range(0) == 1) o.anchor = false;
  if (state.range(0) == 2) o.fb_check = false;
  Tracks t;
  for (auto _ : state) {
    vision::KltTracker tracker(o);
    for (const cv::Mat& g : s.grey) tracker.process(g);
    t = tracker.tracks(0);
    benchmark::DoNotOptimize(t);
  }
  report(state, t);
}

void BM_Track_cvKLT(benchmark::State& state) {
  const Sequence& s = sequence();
  Tracks t;
  for (auto _ : state) {
    t = Tracks{};
    t.image = ImageInfo::centred(s.grey[0].cols, s.grey[0].rows);
    std::vector<cv::Point2f> pts, next;
    std::vector<int> ids;
    int next_id = 0;
    auto detect = [&](const cv::Mat& g) {
      cv::Mat mask(g.size(), CV_8U, cv::Scalar(255));
      for (const auto& p : pts) cv::circle(mask, p, 8, cv::Scalar(0), -1);
      std::vector<cv::Point2f> c;
      cv::goodFeaturesToTrack(g, c, 300 - static_cast<int>(pts.size()), 0.01, 8, mask);
      for (const auto& p : c) {
        pts.push_back(p);
        ids.push_back(next_id++);
      }
    };
    detect(s.grey[0]);
    for (size_t k = 0; k < s.grey.size(); ++k) {
      if (k > 0) {
        std::vector<uchar> st;
        std::vector<float> err;
        cv::calcOpticalFlowPyrLK(s.grey[k - 1], s.grey[k], pts, next, st, err);
        std::vector<cv::Point2f> kept;
        std::vector<int> kept_ids;
        for (size_t i = 0; i < pts.size(); ++i)
          if (st[i] && next[i].x >= 0 && next[i].y >= 0 && next[i].x < s.grey[k].cols && next[i].y < s.grey[k].rows) {
            kept.push_back(next[i]);
            kept_ids.push_back(ids[i]);
          }
        pts.swap(kept);
        ids.swap(kept_ids);
        if (pts.size() < 210) detect(s.grey[k]);
      }
      std::vector<TrackPoint> f;
      for (size_t i = 0; i < pts.size(); ++i) f.push_back({ids[i], Eigen::Vector2d(pts[i].x, pts[i].y)});
      t.frames.push_back(std::move(f));
    }
    benchmark::DoNotOptimize(t);
  }
  report(state, t);
}

}  // namespace

BENCHMARK(BM_Track_rsfm)->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Track_cvKLT)->Unit(benchmark::kMillisecond);
