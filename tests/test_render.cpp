// The rendered box sequence agrees with its written truth: corners tracked by pyramidal
// Lucas-Kanade in the decoded video move as the truth plane homographies (built from
// truth/trajectory.tum and truth/summary.json) predict; the video reads back frame for frame.
#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#include <opencv2/videoio.hpp>

#include "rsfm/io/summary.hpp"
#include "rsfm/io/tum.hpp"
#include "rsfm/render/scene_render.hpp"
#include "rsfm/render/truth_check.hpp"

namespace rsfm::render {
namespace {
namespace fs = std::filesystem;

RenderOptions smallOptions() {
  RenderOptions o;
  o.frames = 20;
  o.width = 320;
  o.height = 240;
  o.focal_px = 260;
  o.seed = 3;
  return o;
}

// Reference pixel -> frame-k pixel for the plane n.X = d (reference camera frame).
Eigen::Matrix3d planeHomography(const Eigen::Matrix3d& K, const io::TumPose& pose, const Eigen::Vector3d& n, double d) {
  const Eigen::Matrix3d Rt = pose.q.toRotationMatrix().transpose();
  return K * Rt * (Eigen::Matrix3d::Identity() - pose.p * n.transpose() / d) * K.inverse();
}

class RenderedBox : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("rsfm_test_render_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    result_ = writeSequence(smallOptions(), dir_);
  }
  static void TearDownTestSuite() { fs::remove_all(dir_); }
  static fs::path dir_;
  static RenderResult result_;
};
fs::path RenderedBox::dir_;
RenderResult RenderedBox::result_;

TEST_F(RenderedBox, FilesAndTruth) {
  EXPECT_TRUE(fs::exists(result_.video));
  const auto poses = io::readTum(dir_ / "truth" / "trajectory.tum");
  ASSERT_EQ(poses.size(), 20u);
  EXPECT_EQ(poses[0].p.norm(), 0.0);
  EXPECT_NEAR(poses[0].q.w(), 1.0, 1e-15);
  const io::Summary s = io::readSummary(dir_ / "truth" / "summary.json");
  // Timestamps in seconds at the video's frame rate (30 fps by default), stated in the summary.
  ASSERT_TRUE(s.fps.has_value());
  EXPECT_EQ(*s.fps, 30.0);
  EXPECT_DOUBLE_EQ(poses[19].t, 19.0 / 30.0);
  EXPECT_EQ(s.frames, 20);
  EXPECT_EQ(s.width, 320);
  EXPECT_EQ(*s.focal_px, 260.0);
  EXPECT_EQ(s.principal_point_px, Eigen::Vector2d(159.5, 119.5));
  ASSERT_GE(s.planes.size(), 4u);  // floor + front, right, top
  EXPECT_EQ(s.plane_names[0], "floor");
  for (std::size_t i = 0; i < s.planes.size(); ++i) {
    EXPECT_GT(s.plane_distances[i], 0);
    EXPECT_NEAR(s.planes[i].norm(), 1.0, 1e-12);
  }
  // The box faces are at right angles to each other and the floor is parallel to the top.
  auto idx = [&](const std::string& n) {
    return static_cast<int>(std::find(s.plane_names.begin(), s.plane_names.end(), n) - s.plane_names.begin());
  };
  EXPECT_NEAR(s.planes[idx("box_front")].dot(s.planes[idx("box_right")]), 0.0, 1e-12);
  EXPECT_NEAR(s.planes[idx("box_front")].dot(s.planes[idx("box_top")]), 0.0, 1e-12);
  // The floor and the top are parallel, both seen from above: same normal (pointing away from the
  // camera), and the floor is farther by the box height 0.7.
  EXPECT_NEAR(s.planes[idx("floor")].dot(s.planes[idx("box_top")]), 1.0, 1e-12);
  EXPECT_NEAR(s.plane_distances[idx("floor")] - s.plane_distances[idx("box_top")], 0.7, 1e-12);
}

TEST_F(RenderedBox, VideoReadsBack) {
  cv::VideoCapture cap(result_.video.string());
  ASSERT_TRUE(cap.isOpened());
  int n = 0;
  cv::Mat f;
  while (cap.read(f)) {
    EXPECT_EQ(f.cols, 320);
    EXPECT_EQ(f.rows, 240);
    ++n;
  }
  EXPECT_EQ(n, 20);
}

// Median distance between LK-tracked corners (frame 0 -> k, corners well inside each truth plane
// by `labels`) and their truth-homography prediction; also the number of tracks and of planes
// with >= 5 tracks.
struct TrackCheck {
  double median = 1e9;
  std::size_t tracks = 0;
  int planes = 0;
};
TrackCheck trackAgainstTruth(const cv::Mat& g0, const cv::Mat& gk, const cv::Mat& labels, const io::Summary& s,
                             const io::TumPose& pose) {
  Eigen::Matrix3d K;
  K << *s.focal_px, 0, s.principal_point_px.x(), 0, *s.focal_px, s.principal_point_px.y(), 0, 0, 1;
  std::vector<double> err;
  TrackCheck r;
  for (std::size_t p = 0; p < s.planes.size(); ++p) {
    cv::Mat mask = labels == static_cast<int>(p + 1);
    cv::erode(mask, mask, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(13, 13)));
    std::vector<cv::Point2f> c0, c1;
    cv::goodFeaturesToTrack(g0, c0, 60, 0.01, 5, mask);
    if (c0.empty()) continue;
    std::vector<uchar> st;
    std::vector<float> e;
    cv::calcOpticalFlowPyrLK(g0, gk, c0, c1, st, e, cv::Size(21, 21), 3,
                             cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-3));
    const Eigen::Matrix3d H = planeHomography(K, pose, s.planes[p], s.plane_distances[p]);
    int n = 0;
    for (std::size_t i = 0; i < c0.size(); ++i) {
      if (!st[i]) continue;
      const Eigen::Vector3d x = H * Eigen::Vector3d(c0[i].x, c0[i].y, 1);
      const double px = x.x() / x.z(), py = x.y() / x.z();
      if (px < 12 || py < 12 || px > g0.cols - 12 || py > g0.rows - 12) continue;
      err.push_back(std::hypot(px - c1[i].x, py - c1[i].y));
      ++n;
    }
    r.planes += n >= 5;
  }
  r.tracks = err.size();
  if (!err.empty()) {
    std::nth_element(err.begin(), err.begin() + err.size() / 2, err.end());
    r.median = err[err.size() / 2];
  }
  return r;
}

TEST(BoxRender, RenderedFramesEqualTheExactPlaneWarp) {
  // The geometry alone (no noise, no video coding): corners tracked from frame 0 into rendered
  // frame k and into frame 0 warped by the truth homography of their plane land at the same
  // place. (Tracking error of Lucas-Kanade's translation model on foreshortened planes is the
  // same in both and cancels; it is what the video test's 0.3 px tolerance is for.)
  RenderOptions o = smallOptions();
  o.noise_sigma = 0;
  Scene scene(o);
  const io::Summary s = scene.truth();
  Eigen::Matrix3d K;
  K << *s.focal_px, 0, s.principal_point_px.x(), 0, *s.focal_px, s.principal_point_px.y(), 0, 0, 1;
  cv::Mat labels, g0, gk;
  cv::cvtColor(scene.render(0, &labels), g0, cv::COLOR_BGR2GRAY);
  const cv::TermCriteria term(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-3);
  for (int k : {1, 2}) {
    cv::cvtColor(scene.render(k), gk, cv::COLOR_BGR2GRAY);
    std::vector<double> diff;
    for (std::size_t p = 0; p < s.planes.size(); ++p) {
      cv::Mat mask = labels == static_cast<int>(p + 1);
      cv::erode(mask, mask, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(13, 13)));
      std::vector<cv::Point2f> c0, c1, c2;
      cv::goodFeaturesToTrack(g0, c0, 60, 0.01, 5, mask);
      if (c0.empty()) continue;
      const Eigen::Matrix3d H = planeHomography(K, scene.pose(k), s.planes[p], s.plane_distances[p]);
      cv::Matx33d Hc;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) Hc(i, j) = H(i, j);
      cv::Mat warped;
      cv::warpPerspective(g0, warped, Hc, g0.size(), cv::INTER_CUBIC);
      std::vector<uchar> st1, st2;
      std::vector<float> e;
      cv::calcOpticalFlowPyrLK(g0, gk, c0, c1, st1, e, cv::Size(21, 21), 3, term);
      cv::calcOpticalFlowPyrLK(g0, warped, c0, c2, st2, e, cv::Size(21, 21), 3, term);
      for (std::size_t i = 0; i < c0.size(); ++i) {
        const cv::Point2f& q = c2[i];
        if (st1[i] && st2[i] && q.x > 12 && q.y > 12 && q.x < g0.cols - 12 && q.y < g0.rows - 12)
          diff.push_back(cv::norm(c1[i] - c2[i]));
      }
    }
    ASSERT_GE(diff.size(), 40u);
    std::nth_element(diff.begin(), diff.begin() + diff.size() / 2, diff.end());
    const double median = diff[diff.size() / 2];
    std::printf("frame 0 -> %d: %zu tracks, median |rendered - exact warp| %.3f px\n", k, diff.size(), median);
    EXPECT_LT(median, 0.05);
  }
}

TEST_F(RenderedBox, TrackedCornersFollowTheTruthPlaneHomographies) {
  // Frames decoded from the video; poses and planes read back from the truth files.
  const auto poses = io::readTum(dir_ / "truth" / "trajectory.tum");
  const io::Summary s = io::readSummary(dir_ / "truth" / "summary.json");
  std::vector<cv::Mat> grey;
  {
    cv::VideoCapture cap(result_.video.string());
    cv::Mat f, g;
    while (cap.read(f)) {
      cv::cvtColor(f, g, cv::COLOR_BGR2GRAY);
      grey.push_back(g.clone());
    }
  }
  ASSERT_EQ(grey.size(), 20u);
  // Plane labels from the scene itself (corners are taken well inside a plane). Frame pairs at the
  // start and in the middle (there the truth is re-expressed in frame a's camera frame).
  Scene scene(smallOptions());
  for (const auto& [a, b] : {std::pair{0, 1}, std::pair{10, 11}}) {
    cv::Mat labels;
    scene.render(a, &labels);
    const io::TumPose& pa = poses[a];
    io::TumPose rel;
    rel.q = pa.q.conjugate() * poses[b].q;
    rel.p = pa.q.conjugate() * (poses[b].p - pa.p);
    io::Summary sa = s;
    for (std::size_t i = 0; i < s.planes.size(); ++i) {
      sa.planes[i] = pa.q.conjugate() * s.planes[i];
      sa.plane_distances[i] = s.plane_distances[i] - s.planes[i].dot(pa.p);
    }
    const TrackCheck t = trackAgainstTruth(grey[a], grey[b], labels, sa, rel);
    std::printf("video frame %d -> %d: %zu tracks on %d planes, median error %.3f px\n", a, b, t.tracks, t.planes,
                t.median);
    EXPECT_GE(t.tracks, 40u);
    EXPECT_GE(t.planes, 3);
    EXPECT_LT(t.median, 0.3);
  }
}

TEST(BoxRender, SilhouetteEdgeLiesWhereTheTruthProjectsIt) {
  // Absolute pixel convention (principal point, pixel centres, supersampling offset): a uniform
  // box without floor over the row-constant background; on each row crossing the front face's
  // left edge, the face's coverage of a pixel window gives the edge's sub-pixel position, compared
  // with the projection of the truth edge by K. Half a pixel of convention error would show as a
  // mean offset of 0.25-0.5 px.
  const fs::path dir = fs::temp_directory_path() / ("rsfm_test_edge_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const fs::path tex = dir / "grey.png";
  cv::imwrite(tex.string(), cv::Mat(32, 32, CV_8UC3, cv::Scalar(40, 40, 40)));
  RenderOptions o = smallOptions();
  o.noise_sigma = 0;
  o.floor = false;
  o.texture = tex.string();
  Scene scene(o);
  fs::remove_all(dir);
  cv::Mat grey;
  cv::cvtColor(scene.render(0), grey, cv::COLOR_BGR2GRAY);
  const auto faces = scene.faces();
  const auto front = std::find_if(faces.begin(), faces.end(), [](const auto& f) { return f.name == "box_front"; });
  ASSERT_NE(front, faces.end());
  const cv::Matx33d K = scene.K();
  auto project = [&](const Eigen::Vector3d& X) {
    const cv::Vec3d x = K * cv::Vec3d(X.x(), X.y(), X.z());
    return cv::Point2d(x[0] / x[2], x[1] / x[2]);
  };
  const cv::Point2d top = project(front->corners[0]), bottom = project(front->corners[3]);
  std::vector<double> offsets;
  for (int y = static_cast<int>(std::ceil(top.y)) + 3; y < bottom.y - 3; ++y) {
    const double xl = top.x + (bottom.x - top.x) * (y - top.y) / (bottom.y - top.y);
    const int c = static_cast<int>(std::floor(xl));
    const int i0 = c - 4, i1 = c + 4;
    ASSERT_GE(i0 - 3, 0);
    const double B = grey.at<uchar>(y, i0 - 3), F = grey.at<uchar>(y, i1 + 3);
    ASSERT_GT(B - F, 50) << "row " << y;
    double coverage = 0;
    for (int i = i0; i <= i1; ++i) coverage += (grey.at<uchar>(y, i) - B) / (F - B);
    offsets.push_back((i1 + 0.5 - coverage) - xl);
  }
  ASSERT_GE(offsets.size(), 40u);
  double mean = 0, mean_abs = 0;
  for (double d : offsets) {
    mean += d;
    mean_abs += std::abs(d);
  }
  mean /= offsets.size();
  mean_abs /= offsets.size();
  std::printf("silhouette edge: %zu rows, mean offset %.3f px, mean |offset| %.3f px\n", offsets.size(), mean, mean_abs);
  EXPECT_LT(std::abs(mean), 0.1);
  EXPECT_LT(mean_abs, 0.25);
}

// tracksAgainstTruth: tracks made from the truth itself score zero; the same tracks pushed 0.1 px
// away from the image centre after their first frame score a median, 95th percentile and mean
// radial error of 0.1 px; tracks born on a surface boundary or the background are left out.
TEST(BoxRender, TracksAgainstTruthMeasuresAKnownOffset) {
  Scene scene(smallOptions());
  const cv::Mat l0 = scene.labels(0);
  Tracks exact, pushed;
  exact.image = pushed.image = ImageInfo::centred(320, 240);
  exact.frames.resize(20);
  pushed.frames.resize(20);
  const Eigen::Vector2d centre(159.5, 119.5);
  int id = 0;
  for (int v = 20; v < 220; v += 12)
    for (int u = 20; u < 300; u += 12, ++id) {
      const Eigen::Vector2d x0(u + 0.3, v + 0.6);
      exact.frames[0].push_back({id, x0});
      pushed.frames[0].push_back({id, x0});
      for (int k = 1; k < 20; ++k) {
        const auto t = scene.transfer(x0, 0, k, l0);
        if (!t) continue;
        exact.frames[k].push_back({id, *t});
        const Eigen::Vector2d r = *t - centre;
        pushed.frames[k].push_back({id, *t + 0.1 * r.normalized()});
      }
    }
  const TracksTruthError e0 = tracksAgainstTruth(scene, exact);
  const TracksTruthError e1 = tracksAgainstTruth(scene, pushed);
  std::printf("tracks against truth: %d tracks, %ld observations (of %d candidates); pushed: median %.4f, p95 %.4f, "
              "radial %+.4f px\n", e1.tracks, e1.observations, id, e1.median_px, e1.p95_px, e1.radial_mean_px);
  EXPECT_GT(e0.tracks, 50);
  EXPECT_LT(e0.tracks, id);  // the background and the boundaries are left out
  EXPECT_EQ(e0.tracks, e1.tracks);
  EXPECT_LT(e0.median_px, 1e-9);
  EXPECT_LT(e0.p95_px, 1e-9);
  EXPECT_NEAR(e1.median_px, 0.1, 1e-9);
  EXPECT_NEAR(e1.p95_px, 0.1, 1e-9);
  EXPECT_NEAR(e1.radial_mean_px, 0.1, 1e-9);
  EXPECT_NEAR(e1.radial_median_px, 0.1, 1e-9);
  // By age: 19 frames after the first give ages 1-2, 3-9 and 10-19 (the 10-29 bucket).
  ASSERT_EQ(e1.by_age.size(), 3u);
  long n = 0;
  for (const auto& b : e1.by_age) {
    EXPECT_NEAR(b.median_px, 0.1, 1e-9);
    EXPECT_NEAR(b.radial_median_px, 0.1, 1e-9);
    n += b.observations;
  }
  EXPECT_EQ(n, e1.observations);
  EXPECT_EQ(e1.by_age[0].first_age, 1);
  EXPECT_EQ(e1.by_age[0].last_age, 2);
  EXPECT_EQ(e1.by_age[2].first_age, 10);
  EXPECT_EQ(e1.by_age[2].last_age, 29);
  for (const auto& b : e0.by_age) EXPECT_LT(b.median_px, 1e-9);
}

TEST(BoxRender, ARollingShutterExposesEachRowAtItsOwnTime) {
  // Row y of frame k is exposed at k + readout (y - (H - 1)/2) / H frame intervals: a point of
  // the box is seen where the global shutter's frame puts it moved by that time times its image
  // velocity (to first order: the difference is the motion's second order), and the rendered
  // frames agree with that truth (tracked corners), not with the global shutter's.
  RenderOptions o = smallOptions();
  o.deg_per_frame = 5.0;
  o.noise_sigma = 0;
  RenderOptions og = o;
  o.readout = 0.8;
  const Scene rs(o), gs(og);
  const int k = 10;
  int compared = 0;
  double largest = 0;
  for (const Scene::FacePolygon& f : gs.faces()) {
    if (f.still_body || f.truth_index < 0) continue;
    for (double a : {0.25, 0.5, 0.75}) {
      const Eigen::Vector3d X = (1 - a) * (0.5 * (f.corners[0] + f.corners[1])) + a * (0.5 * (f.corners[2] + f.corners[3]));
      const auto xr = rs.project(X, k), xg = gs.project(X, k), xp = gs.project(X, k - 1), xn = gs.project(X, k + 1);
      if (!xr || !xg || !xp || !xn || xg->y() < 0 || xg->y() > o.height - 1) continue;
      const Eigen::Vector2d v = 0.5 * (*xn - *xp);
      const Eigen::Vector2d predicted = o.readout * (xr->y() - 0.5 * (o.height - 1)) / o.height * v;
      EXPECT_LT((*xr - *xg - predicted).norm(), 0.05) << f.name;
      largest = std::max(largest, (*xr - *xg).norm());
      ++compared;
    }
  }
  std::printf("rolling shutter 0.8: %d points, largest shift %.2f px\n", compared, largest);
  EXPECT_GE(compared, 6);
  EXPECT_GT(largest, 0.5);
  // A still start: frame 0's rows read over the still stretch are not sheared (nothing moves),
  // so it renders as the global shutter's frame 0.
  RenderOptions os = o, ogs = og;
  os.still_start = ogs.still_start = 5;
  EXPECT_EQ(cv::norm(Scene(os).render(0), Scene(ogs).render(0), cv::NORM_INF), 0.0);
  // The image: corners of the global shutter's frame k tracked into the rolling shutter's frame
  // k move by the readout's time offset of their row times their image velocity (the global
  // shutter's truth, by central differences over frames k - 1 and k + 1).
  cv::Mat lk, g, r;
  cv::cvtColor(gs.render(k, &lk), g, cv::COLOR_BGR2GRAY);
  cv::cvtColor(rs.render(k), r, cv::COLOR_BGR2GRAY);
  cv::Mat inner = (lk > 0) & (lk < Scene::kStillLabel);
  cv::erode(inner, inner, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(13, 13)));
  std::vector<cv::Point2f> c0, c1;
  cv::goodFeaturesToTrack(g, c0, 200, 0.01, 5, inner);
  std::vector<uchar> st;
  std::vector<float> err;
  cv::calcOpticalFlowPyrLK(g, r, c0, c1, st, err, cv::Size(21, 21), 3,
                           cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-3));
  std::vector<double> miss, seen;
  for (std::size_t i = 0; i < c0.size(); ++i) {
    const Eigen::Vector2d x(c0[i].x, c0[i].y);
    const auto xp = gs.transfer(x, k, k - 1, lk), xn = gs.transfer(x, k, k + 1, lk);
    if (!st[i] || !xp || !xn) continue;
    const Eigen::Vector2d d(c1[i].x - c0[i].x, c1[i].y - c0[i].y);
    const Eigen::Vector2d predicted = o.readout * (x.y() + d.y() - 0.5 * (o.height - 1)) / o.height * 0.5 * (*xn - *xp);
    miss.push_back((d - predicted).norm());
    seen.push_back(d.norm());
  }
  ASSERT_GE(miss.size(), 30u);
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  std::printf("frame %d, global -> rolling shutter: %zu corners, median shift %.3f px, median |shift - predicted| %.3f px\n",
              k, miss.size(), median(seen), median(miss));
  // The miss (0.07 px) is the first-order prediction's (the orbit's acceleration over up to 0.4
  // frame intervals) and Lucas-Kanade's on a sheared patch: the same with bands of an eighth
  // pixel. The geometry alone agrees to 0.05 px above and in RegimeSuite's warp check.
  EXPECT_GT(median(seen), 0.5);
  EXPECT_LT(median(miss), 0.1);
}

TEST(BoxRender, ValidateRejectsBadOptions) {
  RenderOptions o = smallOptions();
  EXPECT_TRUE(validate(o).empty());
  o.frames = 1;
  EXPECT_FALSE(validate(o).empty());
  o = smallOptions();
  o.width = 321;
  EXPECT_FALSE(validate(o).empty());
  o = smallOptions();
  o.focal_px = std::nan("");
  EXPECT_FALSE(validate(o).empty());
  o = smallOptions();
  o.texture = "/nonexistent/texture.png";
  EXPECT_FALSE(validate(o).empty());
}

}  // namespace
}  // namespace rsfm::render
