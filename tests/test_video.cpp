// The video front end and the filters on tracks (issue 4): tracks.csv, frame sources, KLT,
// plane finding, transfer of new tracks, and the whole estimate on synthetic pixel tracks.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <random>

#include "rsfm/camera.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/io/patches_io.hpp"
#include "rsfm/io/tracks_io.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/pipeline/estimate.hpp"
#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/rotation.hpp"
#include "rsfm/sim/box_scene.hpp"
#include "rsfm/sim/table1_scene.hpp"
#include "rsfm/vision/affine_lk.hpp"
#include "rsfm/vision/patch_tracker.hpp"
#include "rsfm/vision/frame_source.hpp"
#include "rsfm/vision/klt_tracker.hpp"
#include "rsfm/vision/overlay.hpp"
#include "rsfm/vision/plane_finder.hpp"
#include "rsfm/vision/plane_init.hpp"

namespace fs = std::filesystem;
using namespace rsfm;

namespace {

fs::path tempDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("rsfm_test_video_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

/// A 400 x 300 texture: uniform noise on a 40 x 30 grid, bicubically enlarged (seed 7).
cv::Mat smoothTexture() {
  cv::Mat tex(300, 400, CV_8U);
  cv::RNG rng(7);
  cv::Mat noise(30, 40, CV_8U);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 255);
  cv::resize(noise, tex, tex.size(), 0, 0, cv::INTER_CUBIC);
  return tex;
}

/// A still textured top half (smoothTexture) over a belt carrying another texture to the right at
/// 6 px per frame (bottom half of 400 x 300): the belt's tracks leave at the right border and new
/// texture enters at the left, while the top half keeps its tracks (the moving re-detection's
/// tests). frame(k), k = 0..kFrames-1.
struct BeltScene {
  static constexpr int kFrames = 25, kSpeed = 6;
  cv::Mat top = smoothTexture();
  cv::Mat wide = [] {
    cv::Mat w(150, 1200, CV_8U);
    cv::RNG rng(11);
    cv::Mat noise(15, 120, CV_8U);
    rng.fill(noise, cv::RNG::UNIFORM, 0, 255);
    cv::resize(noise, w, w.size(), 0, 0, cv::INTER_CUBIC);
    return w;
  }();
  cv::Mat frame(int k) const {
    cv::Mat f = top.clone();
    wide(cv::Rect(600 - kSpeed * k, 0, 400, 150)).copyTo(f(cv::Rect(0, 150, 400, 150)));
    return f;
  }
};

void writeText(const fs::path& p, const std::string& s) {
  std::ofstream o(p);
  o << s;
}

std::string readError(const fs::path& p) {
  try {
    io::readTracks(p);
  } catch (const io::InputError& e) {
    return e.what();
  }
  return "";
}

/// Box-scene tracks in pixels (s = 256, 512 x 512, c = 255.5) with Gaussian noise, plus optional
/// static background tracks and random-walk outliers; labels of the true faces.
struct SyntheticTracks {
  Tracks tracks;
  BoxScene scene;
  std::vector<int> face;  ///< per track id: face, -1 static background, -2 outlier
};

SyntheticTracks boxTracks(double noise_px, int background, int outliers, unsigned seed, int frames = 100,
                          double deg_per_frame = -0.5) {
  SyntheticTracks st;
  std::mt19937_64 rng(seed);
  BoxSceneOptions bo;
  bo.frames = frames;
  bo.deg_per_frame = deg_per_frame;
  st.scene = makeBoxScene(bo, rng);
  const double s = bo.scale_px, c = (bo.image_px - 1) / 2.0;
  Tracks& t = st.tracks;
  t.image = {static_cast<int>(bo.image_px), static_cast<int>(bo.image_px), c, c};
  t.frames.resize(bo.frames + 1);
  std::normal_distribution<double> g(0.0, noise_px);
  std::uniform_real_distribution<double> u(40.0, bo.image_px - 40.0);
  const int n = static_cast<int>(st.scene.points.size());
  std::vector<Eigen::Vector2d> bg(background), walk(outliers);
  for (auto& b : bg) b = {u(rng), u(rng)};
  for (auto& w : walk) w = {u(rng), u(rng)};
  for (int k = 0; k <= bo.frames; ++k) {
    int id = 0;
    for (int i = 0; i < n; ++i, ++id)
      t.frames[k].push_back({id, st.scene.uv[k][i] * s + Eigen::Vector2d(c, c) + Eigen::Vector2d(g(rng), g(rng))});
    for (int i = 0; i < background; ++i, ++id) t.frames[k].push_back({id, bg[i] + Eigen::Vector2d(g(rng), g(rng))});
    for (int i = 0; i < outliers; ++i, ++id) {
      walk[i] += Eigen::Vector2d(3.0 * g(rng) / std::max(noise_px, 1e-9), 3.0 * g(rng) / std::max(noise_px, 1e-9));
      t.frames[k].push_back({id, walk[i]});
    }
  }
  for (int i = 0; i < n; ++i) st.face.push_back(st.scene.labels[i]);
  for (int i = 0; i < background; ++i) st.face.push_back(-1);
  for (int i = 0; i < outliers; ++i) st.face.push_back(-2);
  return st;
}

}  // namespace

TEST(TracksIo, RoundTripKeepsEverything) {
  SyntheticTracks st = boxTracks(0.5, 0, 0, 3, 5);
  st.tracks.source = "synthetic box";
  st.tracks.first_frame = 10;
  const fs::path d = tempDir("rt");
  writeText(d / "tracks.csv", io::tracksToString(st.tracks));
  const Tracks r = io::readTracks(d / "tracks.csv");
  EXPECT_EQ(r.image.width, 512);
  EXPECT_EQ(r.image.readout_direction, ReadoutDirection::Down);
  EXPECT_EQ(io::tracksToString(st.tracks).find("readout_direction"), std::string::npos);  // down: not written
  EXPECT_EQ(r.first_frame, 10);
  EXPECT_EQ(r.source, "synthetic box");
  ASSERT_EQ(r.numFrames(), st.tracks.numFrames());
  for (int k = 0; k < r.numFrames(); ++k) {
    ASSERT_EQ(r.frames[k].size(), st.tracks.frames[k].size());
    for (size_t i = 0; i < r.frames[k].size(); ++i) {
      EXPECT_EQ(r.frames[k][i].id, st.tracks.frames[k][i].id);
      EXPECT_NEAR((r.frames[k][i].px - st.tracks.frames[k][i].px).norm(), 0.0, 1e-4);
    }
  }
  // A readout along the columns (a video turned by its rotation metadata) is kept, and so is the
  // principal point's default without a principal_point line.
  st.tracks.image.readout_direction = ReadoutDirection::Left;
  std::string text = io::tracksToString(st.tracks);
  EXPECT_NE(text.find("# readout_direction left\n"), std::string::npos);
  text.erase(text.find("# principal_point"), text.find('\n', text.find("# principal_point")) - text.find("# principal_point") + 1);
  writeText(d / "left.csv", text);
  const Tracks l = io::readTracks(d / "left.csv");
  EXPECT_EQ(l.image.readout_direction, ReadoutDirection::Left);
  EXPECT_EQ(l.image.cx, (l.image.width - 1) / 2.0);
  // Frames a video dropped (frame_numbers skipping 12-13 and 15): written as stretches, read back
  // absent (not as empty frames), and every row where it was.
  Tracks g = st.tracks;
  g.frame_numbers.clear();
  for (int k = 0; k < g.numFrames(); ++k) g.frame_numbers.push_back(10 + k + (k >= 2 ? 2 : 0) + (k >= 3 ? 1 : 0));
  text = io::tracksToString(g);
  EXPECT_NE(text.find("# frames 10 " + std::to_string(g.frame_numbers.back()) + "\n"), std::string::npos) << text.substr(0, 200);
  EXPECT_NE(text.find("# dropped_frames 12-13 15\n"), std::string::npos) << text.substr(0, 200);
  writeText(d / "dropped.csv", text);
  const Tracks dr = io::readTracks(d / "dropped.csv");
  EXPECT_EQ(dr.frame_numbers, g.frame_numbers);
  ASSERT_EQ(dr.numFrames(), g.numFrames());
  for (int k = 0; k < dr.numFrames(); ++k) {
    ASSERT_EQ(dr.frames[k].size(), g.frames[k].size());
    for (size_t i = 0; i < dr.frames[k].size(); ++i) EXPECT_EQ(dr.frames[k][i].px, g.frames[k][i].px);
  }
  EXPECT_EQ(io::tracksToString(dr), text);
  // A time origin (images named by their timestamps) is kept with its rate, and gives the
  // trajectory's timestamps: seconds from it.
  Tracks o = st.tracks;
  o.image.fps = 30.000267;
  o.image.time_origin = 1305031102.175304;
  text = io::tracksToString(o);
  EXPECT_NE(text.find("# time_origin 1305031102.175304\n"), std::string::npos) << text.substr(0, 200);
  writeText(d / "origin.csv", text);
  const Tracks ro = io::readTracks(d / "origin.csv");
  EXPECT_EQ(ro.image.time_origin, o.image.time_origin);
  EXPECT_EQ(ro.image.timestamp(3), 1305031102.175304 + 3 / 30.000267);
  fs::remove_all(d);
}

TEST(FrameSource, DroppedFramesAreFoundFromTheTimestamps) {
  double interval = 0;
  // 30 frames/s with millisecond timestamps (as a container rounds them), frames 3 and 6-7 gone.
  std::vector<double> t;
  for (int k : {0, 1, 2, 4, 5, 8, 9}) t.push_back(std::round(k * 1000.0 / 30.0) / 1000.0);
  EXPECT_EQ(vision::droppedFrameOffsets(t, &interval), (std::vector<int>{0, 1, 2, 4, 5, 8, 9}));
  EXPECT_NEAR(1.0 / interval, 30.0, 0.05);
  // 400 frames/s in milliseconds: gaps of 2 and 3 ms (the median 2 ms made each 3 ms gap a
  // dropped frame); nothing dropped, then frames 17 and 30-31 gone.
  for (const bool drop : {false, true}) {
    std::vector<double> h;
    std::vector<int> kept;
    for (int k = 0; k < 60; ++k)
      if (!drop || (k != 17 && k != 30 && k != 31)) {
        kept.push_back(k);
        h.push_back(std::floor(k * 1000.0 / 400.0) / 1000.0);
      }
    const std::vector<int> off = vision::droppedFrameOffsets(h, &interval);
    if (drop) EXPECT_EQ(off, kept);
    else EXPECT_TRUE(off.empty()) << off.size();
    EXPECT_NEAR(1.0 / interval, 400.0, 2.0);  // the floor of 1000 k / 400 ms: 401.4 frames/s over 59 intervals
  }
  // Nothing dropped, including a variable rate within half an interval: no offsets.
  std::vector<double> v{0.0, 0.030, 0.071, 0.100, 0.128, 0.170};
  EXPECT_TRUE(vision::droppedFrameOffsets(v, &interval).empty());
  EXPECT_NEAR(interval, 0.170 / 5, 1e-12);
  // Timestamps that cannot be gone by (missing, repeated, going back): no offsets.
  EXPECT_TRUE(vision::droppedFrameOffsets({0.0, std::nan(""), 0.1}).empty());
  EXPECT_TRUE(vision::droppedFrameOffsets({0.0, 0.033, 0.033, 0.1}).empty());
  EXPECT_TRUE(vision::droppedFrameOffsets({0.0, 0.1, 0.05}).empty());
  EXPECT_TRUE(vision::droppedFrameOffsets({0.5}).empty());
}

TEST(FrameSource, AFolderIsReadInTheOrderOfItsNamesNumbersWhichGiveTheTimes) {
  const fs::path d = tempDir("named");
  // Each image's grey level says which it is; `names` are written in a scrambled order.
  const auto folder = [&](const std::string& sub, const std::vector<std::string>& names) {
    fs::create_directories(d / sub);
    for (std::size_t i = 0; i < names.size(); ++i)
      cv::imwrite((d / sub / names[i]).string(), cv::Mat(24, 24, CV_8U, cv::Scalar(static_cast<double>(10 * i))));
    return (d / sub).string();
  };
  // The grey levels read, in order, and what forEachFrame learnt.
  const auto readAll = [](const std::string& in, vision::SourceInfo* info) {
    std::vector<int> levels;
    *info = vision::forEachFrame(in, {}, [&](const cv::Mat& m) { levels.push_back(m.at<uchar>(0, 0) / 10); });
    return levels;
  };
  vision::SourceInfo info;
  // Unpadded frame numbers (ffmpeg's img%d.png): 2 before 10, not after 1 (a plain sort of the
  // names put 10 second). The numbers count frames: no rate; 7 is missing, a dropped frame.
  const std::string plain =
      folder("plain", {"img10.png", "img2.png", "img1.png", "img8.png", "img3.png", "img4.png", "img5.png", "img6.png", "img9.png"});
  EXPECT_EQ(readAll(plain, &info), (std::vector<int>{2, 1, 4, 5, 6, 7, 3, 8, 0}));
  EXPECT_EQ(info.fps, 0.0);
  EXPECT_EQ(info.time_origin_s, 0.0);
  EXPECT_EQ(info.frame_offsets, (std::vector<int>{0, 1, 2, 3, 4, 5, 7, 8, 9}));
  // TUM's names: seconds since 1970 with microseconds, ~30 frames/s with the interval's jitter,
  // the frame after the third missing. The rate from the names, the first name the time origin.
  const std::vector<std::string> tum = {"1305031102.175304.png", "1305031102.211242.png", "1305031102.243139.png",
                                        "1305031102.311158.png", "1305031102.343213.png", "1305031102.375071.png"};
  const std::string tum_dir = folder("tum", {tum[3], tum[0], tum[5], tum[1], tum[4], tum[2]});
  EXPECT_EQ(readAll(tum_dir, &info), (std::vector<int>{1, 3, 5, 0, 4, 2}));
  EXPECT_EQ(info.frame_offsets, (std::vector<int>{0, 1, 2, 4, 5, 6}));
  EXPECT_NEAR(info.fps, 6.0 / (0.375071 - 0.175304), 1e-5);
  EXPECT_NEAR(info.time_origin_s, 1305031102.175304, 1e-6);
  EXPECT_NEAR(info.stated_fps, 5.0 / (0.375071 - 0.175304), 1e-5);  // the average, as a container states it
  {
    const vision::FrameSource src(tum_dir);  // the overlay's rate: the average, not a stated one
    EXPECT_NEAR(src.fps(), 5.0 / (0.375071 - 0.175304), 1e-6);
    EXPECT_FALSE(src.fpsKnown());
    EXPECT_EQ(src.timeKind(), vision::TimeKind::Seconds);
  }
  // EuRoC's (and ROS's): nanoseconds since 1970, 20 frames/s, nothing dropped: the rate and
  // origin all the same, no offsets.
  std::vector<std::string> euroc;
  for (long long k = 0; k < 4; ++k) euroc.push_back(std::to_string(1403636579763555584LL + 50000000LL * k) + ".png");
  EXPECT_EQ(readAll(folder("euroc", {euroc[2], euroc[0], euroc[3], euroc[1]}), &info), (std::vector<int>{1, 3, 0, 2}));
  EXPECT_TRUE(info.frame_offsets.empty());
  EXPECT_NEAR(info.fps, 20.0, 1e-9);
  EXPECT_NEAR(info.time_origin_s, 1403636579.763555584, 1e-6);
  // Epochs in milliseconds (13 digits: a phone app's, Android's System.currentTimeMillis) and
  // microseconds (16): 25 frames/s, the frame after the second missing: the rate and origin, the
  // dropped frame found as in a video.
  for (const auto& [digits, per_s] : {std::pair<int, long long>{13, 1000}, {16, 1000000}}) {
    std::vector<std::string> names;
    for (long long k : {0, 1, 3, 4, 5}) names.push_back("cam_" + std::to_string(1403636579763LL * (per_s / 1000) + k * per_s / 25) + ".png");
    ASSERT_EQ(names[0].size(), 4 + digits + 4);
    EXPECT_EQ(readAll(folder("epoch" + std::to_string(digits), {names[4], names[2], names[0], names[3], names[1]}), &info),
              (std::vector<int>{2, 4, 1, 3, 0}))
        << digits;
    EXPECT_EQ(info.frame_offsets, (std::vector<int>{0, 1, 3, 4, 5})) << digits;
    EXPECT_NEAR(info.fps, 25.0, 1e-6) << digits;
    EXPECT_NEAR(info.time_origin_s, 1403636579.763, 1e-6) << digits;
  }
  // A date written as digits with no fraction (14 digits), one image a second across a minute:
  // the number orders the frames; its steps (a second's 1, the minute's 41) are no frame gaps,
  // and no rate is read.
  EXPECT_EQ(readAll(folder("date14", {"20230615123501.png", "20230615123459.png", "20230615123500.png", "20230615123458.png"}), &info),
            (std::vector<int>{3, 1, 2, 0}));
  EXPECT_EQ(info.fps, 0.0);
  EXPECT_EQ(info.time_origin_s, 0.0);
  EXPECT_TRUE(info.frame_offsets.empty());
  // Epochs of two units in one folder (a stray name): no time read, the order only.
  EXPECT_EQ(readAll(folder("mixedunits", {"1403636579763.png", "1403636579763000.png", "1403636579803.png"}), &info),
            (std::vector<int>{0, 2, 1}));
  EXPECT_EQ(info.fps, 0.0);
  EXPECT_TRUE(info.frame_offsets.empty());
  // Names with no one number (two numbers, prefixes that differ): natural order, no times.
  EXPECT_EQ(readAll(folder("mixed", {"b2_x.png", "a10.png", "a9.png", "b10_x.png"}), &info), (std::vector<int>{2, 1, 0, 3}));
  EXPECT_TRUE(info.frame_offsets.empty());
  EXPECT_EQ(info.fps, 0.0);
  // Seconds no timestamp can be (a date written as digits): ordered by the number, no time.
  EXPECT_EQ(readAll(folder("dates", {"20230615123457.5.png", "20230615123456.25.png"}), &info), (std::vector<int>{1, 0}));
  EXPECT_EQ(info.fps, 0.0);
  EXPECT_EQ(info.time_origin_s, 0.0);
  EXPECT_TRUE(info.frame_offsets.empty());
  // Two names with one number: which comes first is not the reader's to guess.
  folder("twice", {"1.png", "01.png", "2.png"});
  try {
    vision::FrameSource s((d / "twice").string());
    ADD_FAILURE() << "two images with one number were taken";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("two images with one number"), std::string::npos) << e.what();
  }
  fs::remove_all(d);
}

TEST(TracksIo, MalformedFilesNameFileAndLine) {
  const fs::path d = tempDir("bad");
  const std::string head = "# rsfm-tracks 1\n# image_size 640 480\n# frames 0 3\nframe,track,x,y\n";
  struct Case {
    std::string text, expect;
  };
  const std::vector<Case> cases = {
      {"", "empty file"},
      {"frame,track,x,y\n0,1,2,3\n", ":1: not an rsfm tracks file"},
      {"# rsfm-tracks 2\n", ":1: unsupported tracks format version 2"},
      {"# rsfm-tracks 1\nframe,track,x,y\n", ":2: missing '# image_size"},
      {head, "no track rows"},
      {head + "0,1,2\n", ":5: expected 4 fields"},
      {head + "0,a,2,3\n", ":5: track id is not an integer"},
      {head + "0,1,nan,3\n", ":5: x or y is not finite"},
      {head + "0,1,2,3\n7,1,2,3\n", ":6: frame 7 outside the declared range"},
      {head + "1,1,2,3\n0,1,2,3\n", ":6: frame 0 after frame 1"},
      {head + "0,1,2,3\n0,1,4,5\n", ":6: track 1 repeated"},
      {head + "0,-1,2,3\n", ":5: track id -1 out of range"},
      {head + "0,1,5000,3\n", ":5: position (5000, 3) far outside"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# frames 0 3\nframe;track;x;y\n", ":4: expected the column header"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# readout_direction sideways\n", ":3: readout_direction needs one of down"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# readout_direction left up\n", ":3: readout_direction needs one of down"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# frames 0 3\n# dropped_frames 2-x\nframe,track,x,y\n0,1,2,3\n", ":4: dropped_frames needs frame numbers"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# frames 0 3\n# dropped_frames\nframe,track,x,y\n0,1,2,3\n", ":4: dropped_frames needs frame numbers"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# frames 0 3\n# dropped_frames 2-1\nframe,track,x,y\n0,1,2,3\n", ":4: dropped_frames needs frame numbers"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# frames 0 3\n# dropped_frames 3\nframe,track,x,y\n0,1,2,3\n0,2,2,3\n1,1,2,3\n2,1,2,3\n", ":4: dropped frames 3-3 are not inside"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# frames 0 3\n# dropped_frames 1-2\nframe,track,x,y\n0,1,2,3\n0,2,2,3\n2,1,2,3\n3,1,2,3\n", ":8: frame 2 is listed in dropped_frames"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# time_origin 1305031102.175304\n# frames 0 3\nframe,track,x,y\n0,1,2,3\n", ":3: time_origin needs '# fps'"},
      {"# rsfm-tracks 1\n# image_size 640 480\n# fps 30\n# time_origin -4\n# frames 0 3\nframe,track,x,y\n0,1,2,3\n", ":4: time_origin needs one number"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const fs::path p = d / ("case" + std::to_string(i) + ".csv");
    writeText(p, cases[i].text);
    const std::string msg = readError(p);
    EXPECT_NE(msg.find(p.string()), std::string::npos) << "case " << i << ": " << msg;
    EXPECT_NE(msg.find(cases[i].expect), std::string::npos) << "case " << i << ": " << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "one line";
  }
  EXPECT_NE(readError(d / "missing.csv").find("no such file"), std::string::npos);
  fs::remove_all(d);
}

TEST(PlaneTransfer, RecoversTheReferencePositionOfAPlanePoint) {
  // A point of plane N seen first in frame k is carried back to its reference position.
  const Eigen::Vector3d N(0.2, -0.1, 0.4);
  const double beta = 0.8;
  const Eigen::Matrix3d R = incrementalRotation(Eigen::Vector3d(0.05, -0.2, 0.03));
  const Eigen::Vector3d t(0.3, -0.1, 0.2);
  for (const Eigen::Vector2d& uv0 : {Eigen::Vector2d(0.1, 0.2), Eigen::Vector2d(-0.4, 0.3), Eigen::Vector2d(0, 0)}) {
    Eigen::Vector3d X;
    ASSERT_EQ(PlaneModel::point(N, beta, uv0, &X, nullptr, nullptr), MeasureStatus::Ok);
    const Eigen::Vector3d Xc = t + R * X;
    const Eigen::Vector2d uvk = Xc.head<2>() / (1.0 + beta * Xc.z());
    Eigen::Vector2d back;
    ASSERT_EQ(PlaneModel::transferToReference(N, beta, R, t, uvk, &back), MeasureStatus::Ok);
    EXPECT_NEAR((back - uv0).norm(), 0.0, 1e-12);
  }
  // A ray (nearly) parallel to the plane is reported, not divided through.
  Eigen::Vector2d out;
  EXPECT_EQ(PlaneModel::transferToReference(Eigen::Vector3d(0, 0, 1), 1.0, Eigen::Matrix3d::Identity(),
                                            Eigen::Vector3d::Zero(), Eigen::Vector2d(1e9, 0), &out),
            MeasureStatus::HorizonSingular);
  // A point behind the camera is reported.
  EXPECT_EQ(PlaneModel::transferToReference(Eigen::Vector3d(0, 0, -1), 1.0, Eigen::Matrix3d::Identity(),
                                            Eigen::Vector3d::Zero(), Eigen::Vector2d(0.1, 0.1), &out),
            MeasureStatus::BehindCamera);
}

TEST(PlaneTransfer, TwoViewsPlaceAPointAndRefuseTooLittleParallax) {
  // A plane point seen by two cameras (motions from the reference frame) is triangulated back
  // (the start of a plane that joins mid-run, PlaneModel::twoViewPoint).
  const Eigen::Vector3d N(0.2, -0.1, 0.4);
  const double beta = 0.8;
  const Eigen::Matrix3d Ra = incrementalRotation(Eigen::Vector3d(0.05, -0.2, 0.03));
  const Eigen::Vector3d ta(0.3, -0.1, 0.2);
  const Eigen::Matrix3d Rb = incrementalRotation(Eigen::Vector3d(-0.1, 0.15, 0.0));
  const Eigen::Vector3d tb(-0.4, 0.2, 0.5);
  auto see = [&](const Eigen::Matrix3d& R, const Eigen::Vector3d& t, const Eigen::Vector3d& X) {
    const Eigen::Vector3d Xc = t + R * X;
    return Eigen::Vector2d(Xc.head<2>() / (1.0 + beta * Xc.z()));
  };
  for (const Eigen::Vector2d& uv0 : {Eigen::Vector2d(0.1, 0.2), Eigen::Vector2d(-0.4, 0.3), Eigen::Vector2d(0, 0)}) {
    Eigen::Vector3d X, back;
    ASSERT_EQ(PlaneModel::point(N, beta, uv0, &X, nullptr, nullptr), MeasureStatus::Ok);
    double parallax = 0;
    ASSERT_EQ(PlaneModel::twoViewPoint(beta, Ra, ta, see(Ra, ta, X), Rb, tb, see(Rb, tb, X), 1e-3, &back, &parallax), MeasureStatus::Ok);
    EXPECT_NEAR((back - X).norm(), 0.0, 1e-10);
    EXPECT_GT(parallax, 1e-3);
    // The same camera twice: no parallax, no point.
    EXPECT_EQ(PlaneModel::twoViewPoint(beta, Ra, ta, see(Ra, ta, X), Ra, ta, see(Ra, ta, X), 1e-3, &back), MeasureStatus::HorizonSingular);
  }
  // Rays that meet behind the cameras are refused.
  Eigen::Vector3d back;
  EXPECT_EQ(PlaneModel::twoViewPoint(1.0, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero(), Eigen::Vector2d(0.1, 0.0),
                                     Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.1, 0, 0), Eigen::Vector2d(0.0, 0.0), 1e-3, &back),
            MeasureStatus::BehindCamera);
}

TEST(FrameSource, ReportsMissingCorruptAndGappedInput) {
  const fs::path d = tempDir("src");
  auto msgOf = [](const std::string& in) -> std::string {
    try {
      vision::FrameSource s(in);
      cv::Mat m;
      while (s.read(&m)) {
      }
    } catch (const io::InputError& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_NE(msgOf((d / "nope.mp4").string()).find("no such file"), std::string::npos);
  fs::create_directories(d / "empty");
  EXPECT_NE(msgOf((d / "empty").string()).find("no images"), std::string::npos);
  writeText(d / "notavideo.mp4", "this is not a video\n");
  EXPECT_NE(msgOf((d / "notavideo.mp4").string()).find("cannot be opened as a video"), std::string::npos);
  cv::Mat img(32, 48, CV_8U, cv::Scalar(100));
  for (int i : {0, 1, 2, 4}) cv::imwrite((d / cv::format("f%03d.png", i)).string(), img);
  EXPECT_NE(msgOf((d / "f%03d.png").string()).find("missing frame"), std::string::npos);
  fs::remove(d / "f004.png");
  writeText(d / "f003.png", "garbage");
  EXPECT_NE(msgOf((d / "f%03d.png").string()).find("frame 3 cannot be decoded"), std::string::npos);
  {
    // A range that ends before the corrupt frame never reads it (opencv-doc's tree.avi breaks at
    // frame 68: --last 67 runs).
    int frames = 0;
    EXPECT_NO_THROW(vision::forEachFrame((d / "f%03d.png").string(), {0, 2}, [&](const cv::Mat&) { ++frames; }, {}, {}));
    EXPECT_EQ(frames, 3);
  }
  cv::imwrite((d / "f003.png").string(), cv::Mat(16, 16, CV_8U, cv::Scalar(0)));
  EXPECT_NE(msgOf((d / "f%03d.png").string()).find("frame 3 is 16x16"), std::string::npos);
  EXPECT_NE(msgOf((d / "bad%s.png").string()).find("exactly one integer field"), std::string::npos);
  fs::remove_all(d);
}

TEST(KltTracker, FollowsAKnownSubpixelMotion) {
  // A textured image translated by a known sub-pixel shift per frame: tracks follow it.
  cv::Mat tex = smoothTexture();
  cv::GaussianBlur(tex, tex, cv::Size(3, 3), 0.8);
  vision::TrackerOptions o;
  o.max_tracks = 150;
  vision::KltTracker tr(o);
  const double dx = 1.37, dy = -0.61;
  const int F = 12;
  for (int k = 0; k < F; ++k) {
    cv::Mat m = (cv::Mat_<double>(2, 3) << 1, 0, dx * k, 0, 1, dy * k);
    cv::Mat f;
    cv::warpAffine(tex, f, m, tex.size(), cv::INTER_CUBIC, cv::BORDER_REFLECT);
    tr.process(f);
  }
  const Tracks t = tr.tracks();
  ASSERT_EQ(t.numFrames(), F);
  ASSERT_GT(t.frames[0].size(), 100u);
  std::vector<double> err;
  for (const auto& p : t.frames[F - 1]) {
    const TrackPoint* p0 = t.find(0, p.id);
    if (!p0) continue;
    err.push_back((p.px - p0->px - Eigen::Vector2d(dx, dy) * (F - 1)).norm());
  }
  ASSERT_GT(err.size(), 80u);
  std::sort(err.begin(), err.end());
  EXPECT_LT(err[err.size() / 2], 0.05) << "median error after 11 frames (px)";
  EXPECT_LT(err[err.size() * 9 / 10], 0.15) << "90th percentile (px)";
}

TEST(KltTracker, LostMovingTracksAreReplacedWhileAStillBackgroundKeepsTheCount) {
  // Issue 14: the tracker re-detected only when fewer than 70 % of max_tracks lived, so before a
  // still background (webcam-object: 215 of its tracks) the moving object's tracks, once lost,
  // were never replaced. It now also re-detects when fewer than 70 % of the most tracks that had
  // moved since the last detection live (TrackerOptions::moving_px, min_moving). Scene: the top
  // half of a 400 x 300 image is a still texture; the bottom half a belt carrying another
  // texture to the right at 6 px per frame, so its tracks leave at the right border and new
  // texture enters at the left. After 25 frames: tracks on the left of the belt (started after
  // frame 0) with the default, none with the moving trigger off (the count alone never fell
  // below 70 %).
  const BeltScene belt;
  auto leftBeltTracks = [&](int min_moving) {
    vision::TrackerOptions o;
    o.min_moving = min_moving;
    vision::KltTracker tr(o);
    for (int k = 0; k < BeltScene::kFrames; ++k) tr.process(belt.frame(k));
    const Tracks t = tr.tracks();
    int n = 0, total = 0;
    for (const auto& p : t.frames.back()) {
      ++total;
      if (p.px.y() > 160 && p.px.x() < 120 && !t.find(0, p.id)) ++n;
    }
    EXPECT_GT(total, 150) << "the still half keeps its tracks";
    std::cout << "[ note ] min_moving " << min_moving << ": " << n << " new tracks on the belt's left, " << total << " live\n";
    return n;
  };
  EXPECT_GE(leftBeltTracks(vision::TrackerOptions{}.min_moving), 10) << "new texture on the belt is tracked";
  EXPECT_EQ(leftBeltTracks(std::numeric_limits<int>::max()), 0) << "the count alone re-detected: the scene does not test the trigger";
}

TEST(KltTracker, DetectsNoCornerItsLucasKanadeWouldRefuse) {
  // Detection is bucketed with a quality level relative to each cell's best corner, so a bare
  // cell still offers corners; before, those whose window fails Lucas-Kanade's own
  // minimum-eigenvalue test (TrackerOptions::min_eig) became tracks that ended in the next
  // frame, and the re-detection they triggered refilled the bare cells with more (the ViSP
  // cube on its white table: 3867 of 5407 tracks lived one or two frames). Scene: the left half
  // textured, the right half a bare shaded wall (a smooth ramp with +-1 grey level of enlarged
  // noise); the image then moves by a sub-pixel shift.
  const cv::Mat tex = smoothTexture();
  cv::Mat img = tex.clone();
  {
    cv::RNG rng(5);
    cv::Mat faint(6, 4, CV_32F), big;
    rng.fill(faint, cv::RNG::UNIFORM, -1.0, 1.0);
    cv::resize(faint, big, cv::Size(200, 300), 0, 0, cv::INTER_CUBIC);
    for (int y = 0; y < 300; ++y)
      for (int x = 0; x < 200; ++x)
        img.at<uchar>(y, 200 + x) = cv::saturate_cast<uchar>(120.0 + 0.05 * x + big.at<float>(y, x));
  }
  // The scene's premise: the relative quality level finds corners on the bare half.
  std::vector<cv::Point2f> offered;
  const vision::TrackerOptions o;
  cv::goodFeaturesToTrack(img(cv::Rect(200 + o.border_px, o.border_px, 200 - 2 * o.border_px, 300 - 2 * o.border_px)), offered, 50,
                          o.quality, o.min_distance_px, cv::noArray(), o.block_size);
  ASSERT_GE(offered.size(), 5u) << "the bare half offers no corner: the scene does not test the check";
  vision::KltTracker tr(o);
  tr.process(img);
  cv::Mat moved;
  const cv::Mat m = (cv::Mat_<double>(2, 3) << 1, 0, 0.4, 0, 1, -0.3);
  cv::warpAffine(img, moved, m, img.size(), cv::INTER_CUBIC, cv::BORDER_REFLECT);
  tr.process(moved);
  const Tracks t = tr.tracks();
  int bare = 0, ended = 0;
  for (const auto& p : t.frames[0]) {
    bare += p.px.x() > 205;
    ended += t.find(1, p.id) == nullptr;
  }
  std::cout << "[ note ] " << offered.size() << " corners offered on the bare half; " << t.frames[0].size() << " tracks, "
            << bare << " on the bare half, " << ended << " ended in frame 1\n";
  EXPECT_GT(t.frames[0].size(), 100u) << "the textured half is tracked";
  EXPECT_EQ(bare, 0) << "tracks on the bare half";
  // Without the check: 111 tracks on the bare half, 116 ended at the first step; with it a few on
  // the texture's edge still do (5 of 185).
  EXPECT_LE(ended, static_cast<int>(t.frames[0].size()) / 20) << "tracks that ended at the first step";
}

TEST(PatchTracker, LostMovingPatchesAreReplacedWhileAStillBackgroundKeepsTheCount) {
  // The KLT tracker's rule (LostMovingTracksAreReplacedWhileAStillBackgroundKeepsTheCount) in the
  // patch tracker: before, it re-detected only when fewer than 70 % of max_patches lived, so a
  // moving object's patches, once lost, were not replaced while a still background kept the
  // count. The same scene: a still textured top half, a belt carrying texture to the right at
  // 6 px per frame below it. After 25 frames: patches on the belt's entering side (started after
  // frame 0) with the default, none with the moving trigger off.
  const BeltScene belt;
  auto leftBeltPatches = [&](int min_moving) {
    vision::PatchTrackerOptions o;
    o.min_moving = min_moving;
    vision::PatchTracker tr(o);
    for (int k = 0; k < BeltScene::kFrames; ++k) tr.process(belt.frame(k));
    const PatchTracks t = tr.tracks();
    int n = 0, total = 0;
    for (const auto& p : t.frames.back()) {
      ++total;
      if (p.px.y() > 165 && p.px.x() < 150 &&
          std::none_of(t.frames[0].begin(), t.frames[0].end(), [&](const PatchObservation& q) { return q.id == p.id; }))
        ++n;
    }
    EXPECT_GE(total, static_cast<int>(0.7 * o.max_patches)) << "the still half keeps the count up";
    std::cout << "[ note ] min_moving " << min_moving << ": " << n << " new patches on the belt's left, " << total << " live\n";
    return n;
  };
  EXPECT_GE(leftBeltPatches(vision::PatchTrackerOptions{}.min_moving), 3) << "new texture on the belt is tracked";
  EXPECT_EQ(leftBeltPatches(std::numeric_limits<int>::max()), 0) << "the count alone re-detected: the scene does not test the trigger";
}

TEST(KltTracker, AVideoThatFadesInFromBlackIsTrackedFromItsFirstCorners) {
  // Three black frames, then a textured image moving by a known shift. The tracker finds no
  // corner in the first frame and must look again in every frame until corners appear (before,
  // it never did: no track at all, as on opencv-doc's Megamind.avi); the tracks then start at
  // the first textured frame, the frames before it left out.
  const cv::Mat tex = smoothTexture();
  const fs::path d = tempDir("fade_in");
  const int black = 3, F = 12;
  const double dx = 0.8, dy = 0.3;
  for (int k = 0; k < F; ++k) {
    cv::Mat f(tex.size(), CV_8U, cv::Scalar(0));
    if (k >= black) {
      const cv::Mat m = (cv::Mat_<double>(2, 3) << 1, 0, dx * (k - black), 0, 1, dy * (k - black));
      cv::warpAffine(tex, f, m, tex.size(), cv::INTER_CUBIC, cv::BORDER_REFLECT);
    }
    cv::imwrite((d / cv::format("f%03d.png", k)).string(), f);
  }
  const Tracks t = vision::trackInput((d / "f%03d.png").string(), vision::TrackerOptions{}, {});
  EXPECT_EQ(t.first_frame, black);
  ASSERT_EQ(t.numFrames(), F - black);
  EXPECT_GT(t.frames[0].size(), 100u);
  int followed = 0;
  for (const auto& p : t.frames.back()) {
    const TrackPoint* p0 = t.find(0, p.id);
    if (p0 && (p.px - p0->px - Eigen::Vector2d(dx, dy) * (F - 1 - black)).norm() < 0.1) ++followed;
  }
  EXPECT_GT(followed, 100);
  fs::remove_all(d);
}

TEST(Overlay, StartsAtTheFirstFrameWithTracks) {
  // Three black frames, then six textured ones: the tracks (and a result) start at frame 3, and
  // so must the overlay video (it started at the range's first frame, one black frame per
  // frame left out, everything drawn on the wrong frame).
  const cv::Mat tex = smoothTexture();
  const fs::path d = tempDir("overlay_fade_in");
  const int black = 3, F = 9;
  for (int k = 0; k < F; ++k)
    cv::imwrite((d / cv::format("f%03d.png", k)).string(), k < black ? cv::Mat(tex.size(), CV_8U, cv::Scalar(0)) : tex);
  const std::string input = (d / "f%03d.png").string();
  const Tracks t = vision::trackInput(input, vision::TrackerOptions{}, {});
  ASSERT_EQ(t.first_frame, black);
  TrackFilterResult res;
  res.scale_px = 200;
  for (int k = black; k < F; ++k) {
    TrackFrame f;
    f.frame = k;
    f.beta = 1.0;
    res.frames.push_back(f);
  }
  const fs::path video = d / "overlay.mp4";
  vision::writeOverlay(input, {}, t, std::vector<int>(static_cast<size_t>(t.idBound()), -1), res, video);
  cv::VideoCapture cap(video.string());
  ASSERT_TRUE(cap.isOpened());
  cv::Mat first, grey;
  ASSERT_TRUE(cap.read(first));
  cv::cvtColor(first, grey, cv::COLOR_BGR2GRAY);
  EXPECT_GT(cv::mean(grey)[0], 0.5 * cv::mean(tex)[0]) << "the overlay's first frame is a black one";
  int frames = 1;
  while (cap.read(first)) ++frames;
  EXPECT_EQ(frames, F - black);
  fs::remove_all(d);
}

TEST(Tracks, LeadingFramesWithoutTracksAreLeftOutAndTheEstimateSaysWhy) {
  Tracks t;
  t.image = ImageInfo::centred(64, 48);
  t.first_frame = 10;
  t.frames.resize(5);
  t.frames[2] = {{0, Eigen::Vector2d(5, 5)}};
  t.frames[4] = {{0, Eigen::Vector2d(6, 5)}};
  // estimate() refuses a first frame without tracks, naming where they start.
  try {
    estimate(t, EstimateOptions{});
    FAIL() << "estimated from a first frame without tracks";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("frame 10, the first, has no tracks"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("they start at frame 12"), std::string::npos) << e.what();
  }
  Tracks u = t;
  EXPECT_EQ(trimLeadingEmptyFrames(&u), 2);
  EXPECT_EQ(u.first_frame, 12);
  EXPECT_EQ(u.numFrames(), 3);
  EXPECT_EQ(u.frameNumber(2), 14);
  EXPECT_EQ(trimLeadingEmptyFrames(&u), 0);
  // With explicit frame numbers (frames left out) the numbers follow.
  Tracks v = t;
  v.frame_numbers = {10, 11, 13, 14, 20};
  EXPECT_EQ(trimLeadingEmptyFrames(&v), 2);
  EXPECT_EQ(v.frameNumber(0), 13);
  EXPECT_EQ(v.frameNumber(2), 20);
  // No track anywhere: left as is.
  Tracks w;
  w.frames.resize(3);
  EXPECT_EQ(trimLeadingEmptyFrames(&w), 0);
  EXPECT_EQ(w.numFrames(), 3);
}

TEST(PlaneFinder, FindsTheFacesAndRejectsStaticAndRandomTracks) {
  const SyntheticTracks st = boxTracks(0.5, 25, 20, 5);
  const vision::PlaneFinding pf = vision::findPlanes(st.tracks);
  const int faces = st.scene.faces();
  ASSERT_EQ(pf.numPlanes(), faces);
  // Each found plane is one face: no face track joins the wrong plane; a few near the edge the
  // faces share (where both homographies carry them) may be left out as ambiguous.
  int swapped = 0, missed = 0, on_faces = 0;
  std::vector<int> face_of_plane(faces, -9);
  for (size_t id = 0; id < st.face.size(); ++id) {
    const int l = pf.labels[id], f = st.face[id];
    if (f >= 0) {
      ++on_faces;
      if (l < 0) {
        ++missed;
        continue;
      }
      if (face_of_plane[l] == -9) face_of_plane[l] = f;
      swapped += face_of_plane[l] != f;
    } else {
      EXPECT_EQ(l, -1) << "background/outlier track " << id << " must be an outlier";
    }
  }
  EXPECT_EQ(swapped, 0) << "face tracks on the wrong plane";
  EXPECT_LE(missed, on_faces / 10) << "face tracks left out";
  bool saw_static = false;
  for (const auto& c : pf.candidates) saw_static |= c.verdict == vision::PlaneVerdict::Static;
  EXPECT_TRUE(saw_static) << "the static background is found and rejected as static";
}

TEST(PlaneFinder, AStillTrackDoesNotJoinAMovingPlane) {
  // Issue 14 item 2: a track born later joins a plane only when its own motion tests it. The box
  // turns slowly (0.1 deg per frame), and two tracks are born at frame 50 on the face point that
  // moves most: one follows the point to the end (joins the face's plane), one stays where the
  // point was for as many frames as the plane needs to move it ~1.5 px (within the 3 px join
  // tolerance: without the motion test it joins, checked). It never moves 3 px from where it started, so
  // "still" explains it as well as the plane: it stays out.
  SyntheticTracks st = boxTracks(0.3, 0, 0, 5, 100, -0.1);
  Tracks& t = st.tracks;
  // One plane (the plane model's search): the still track cannot be left out for fitting two.
  vision::PlaneFinderOptions fo;
  fo.max_planes = 1;
  const std::vector<int> labels0 = vision::findPlanes(t, fo).labels;
  // The point of that plane that moves most between frames 50 and 100.
  int source = -1;
  double most = 0.0;
  for (const TrackPoint& p : t.frames[50])
    if (const TrackPoint* q = t.find(100, p.id); labels0[p.id] == 0 && q && (q->px - p.px).norm() > most)
      most = (q->px - p.px).norm(), source = p.id;
  ASSERT_GE(source, 0);
  ASSERT_GT(most, 6.0) << "the moving track must move more than the join tolerance";
  // The still track lives as long as the plane needs to move its point ~1.5 px (at least 3 frames).
  const int still_frames = std::clamp(static_cast<int>(50 * 1.5 / most), 3, 10);
  const int moving_id = t.idBound(), still_id = moving_id + 1;
  const Eigen::Vector2d start = t.find(50, source)->px;
  for (int k = 50; k <= 100; ++k) {
    const TrackPoint* p = t.find(k, source);
    ASSERT_NE(p, nullptr);
    t.frames[k].push_back({moving_id, p->px + Eigen::Vector2d(0.05, -0.05)});
    if (k < 50 + still_frames) t.frames[k].push_back({still_id, start});
  }
  const vision::PlaneFinding pf = vision::findPlanes(t, fo);
  ASSERT_EQ(pf.numPlanes(), 1);
  ASSERT_GE(pf.labels[source], 0) << "the source point is on a plane";
  EXPECT_EQ(pf.labels[moving_id], pf.labels[source]) << "a moving track born later joins its plane";
  EXPECT_LT(pf.labels[still_id], 0) << "a still track stays off the moving plane";
}

TEST(PlaneFinder, AStillReferenceTrackDoesNotJoinAMovingPlane) {
  // Issue 14 item 2, for reference tracks (box.mp4@18: two still tracks on the background at the
  // image's edge were members of the box's front face, whose homographies barely move that part
  // of the image). A plane's homographies leave points near the image of its rotation axis almost
  // in place, so a still point there fits the plane in every frame within the tolerances; its own
  // motion never reaches the 3 px verification tolerance, so it does not test the plane and is
  // no member. The still track is put where the main plane's homographies move the image least.
  SyntheticTracks st = boxTracks(0.3, 0, 0, 5, 100, -0.5);
  Tracks& t = st.tracks;
  vision::PlaneFinderOptions fo;
  fo.max_planes = 1;
  const vision::PlaneFinding pf0 = vision::findPlanes(t, fo);
  ASSERT_EQ(pf0.numPlanes(), 1);
  const vision::FoundPlane* main_plane = nullptr;
  for (const auto& c : pf0.candidates)
    if (c.label == 0) main_plane = &c;
  ASSERT_NE(main_plane, nullptr);
  Eigen::Vector2d still(0, 0);
  double least = 1e9;
  for (double x = 0; x < t.image.width; x += 4)
    for (double y = 0; y < t.image.height; y += 4) {
      double worst = 0;
      for (const cv::Matx33d& H : main_plane->H) {
        const cv::Vec3d q = H * cv::Vec3d(x, y, 1.0);
        worst = std::max(worst, std::hypot(q[0] / q[2] - x, q[1] / q[2] - y));
      }
      if (worst < least) least = worst, still = {x, y};
    }
  ASSERT_LT(least, 1.5) << "the plane's homographies leave a point within 1.5 px of where it is";
  const int still_id = t.idBound();
  std::mt19937_64 rng(17);
  std::normal_distribution<double> g(0.0, 0.3);
  for (auto& f : t.frames) f.push_back({still_id, still + Eigen::Vector2d(g(rng), g(rng))});
  const vision::PlaneFinding pf = vision::findPlanes(t, fo);
  ASSERT_EQ(pf.numPlanes(), 1);
  EXPECT_LT(pf.labels[still_id], 0) << "the still track at (" << still.x() << ", " << still.y() << ") stays off the plane";
  int members = 0;
  for (size_t id = 0; id + 1 < pf.labels.size(); ++id) members += pf.labels[id] == 0;
  EXPECT_GE(members, static_cast<int>(main_plane->members.size()) - 2) << "the plane keeps its moving members";
}

TEST(PlaneFinder, EightTracksMakeAPlane) {
  // Issue 14 item 2: a plane needs the tracks that let its homography test its members
  // (vision::kHomographyTestTracks = 8: 4 fix it, 8 residual degrees of freedom), not a fixed 12.
  // The box's second face keeps 9 of its tracks (the rest are dropped): it is found.
  SyntheticTracks st = boxTracks(0.3, 0, 0, 5, 100, -0.5);
  int kept = 0;
  std::vector<char> drop(st.face.size(), 0);
  for (size_t id = 0; id < st.face.size(); ++id)
    if (st.face[id] == 1 && ++kept > 9) drop[id] = 1;
  ASSERT_GT(kept, 9) << "the scene's second face has more than 9 tracks";
  for (auto& f : st.tracks.frames)
    f.erase(std::remove_if(f.begin(), f.end(), [&](const TrackPoint& p) { return drop[p.id]; }), f.end());
  const vision::PlaneFinding pf = vision::findPlanes(st.tracks);
  EXPECT_EQ(vision::PlaneFinderOptions{}.min_plane_tracks, vision::kHomographyTestTracks);
  EXPECT_EQ(pf.numPlanes(), st.scene.faces()) << "every face, the 9-track one too";
  int on_second = 0;
  for (size_t id = 0; id < st.face.size(); ++id)
    if (st.face[id] == 1 && !drop[id] && pf.labels[id] >= 0) ++on_second;
  EXPECT_GE(on_second, 8) << "the 9-track face's tracks are on a plane";
}

TEST(PlaneFinder, ASmallGroupThatBarelyMovesFailsTheSecondPlanesEpipole) {
  // Plane + parallax ([IA96]) against the main plane's homography: a second plane moving rigidly
  // with it has its parallax along lines through one epipole. A small group that barely moves
  // (an arm beside a turning box: opencv-doc box.mp4 at 320 x 240) has nearly parallel parallax
  // vectors (minus the main plane's flow), which a far epipole of its own fits: it passes its own
  // test (vision::sameMotionFraction). Held to an epipole the second plane accepts
  // (vision::epipoleAgreement) it fails, and a third rigid plane agrees. f = 500 px, 640 x 480;
  // the camera turns 10 deg about x (the main plane's flow is mostly vertical) and moves (0.3,
  // 0.1, 0.2) of the main plane's distance (the epipole at (1070, 490) px); 0.2 px noise.
  const cv::Matx33d K(500, 0, 320, 0, 500, 240, 0, 0, 1);
  const double a = 10.0 * M_PI / 180.0;
  const cv::Matx33d R(1, 0, 0, 0, std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a));
  const cv::Vec3d t(0.3, 0.1, 0.2);
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0.0, 0.2);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto project = [&](const cv::Vec3d& X) {
    const cv::Vec3d x = K * X;
    return cv::Point2d(x[0] / x[2] + g(rng), x[1] / x[2] + g(rng));
  };
  auto moved = [&](const cv::Vec3d& X) { return cv::Vec3d(R * X + t); };
  // The main plane Z = 5 (n = (0, 0, 1), d = 5): H1 = K (R + t n^T / d) K^-1.
  const cv::Matx33d H1 = K * (R + cv::Matx33d(0, 0, t[0] / 5, 0, 0, t[1] / 5, 0, 0, t[2] / 5)) * K.inv();
  using Pts = std::vector<cv::Point2d>;
  auto plane = [&](int n, auto point) {
    Pts x, xp;
    for (int i = 0; i < n; ++i) {
      const cv::Vec3d X = point();
      x.push_back(project(X));
      xp.push_back(project(moved(X)));
    }
    return std::make_pair(x, xp);
  };
  const auto [x2, xp2] = plane(20, [&] { return cv::Vec3d(1.2, 0.8 * u(rng), 4.5 + 1.5 * u(rng)); });  // X = 1.2
  const auto [x3, xp3] = plane(15, [&] { return cv::Vec3d(0.8 * u(rng), 1.0, 4.5 + 1.5 * u(rng)); });  // Y = 1
  const auto [x0, xp0] = plane(15, [&] { return cv::Vec3d(0.8 * u(rng), 0.6 * u(rng), 5.0); });  // on the main plane
  // 12 points in a 40 px patch near (100, 400) that move (4, 3) px together.
  Pts xj, xpj;
  for (int i = 0; i < 12; ++i) {
    const cv::Point2d p(100 + 20 * u(rng), 400 + 20 * u(rng));
    xj.push_back(p);
    xpj.push_back(p + cv::Point2d(4 + g(rng), 3 + g(rng)));
  }
  const double tol = 2.0, pass = vision::PlaneFinderOptions{}.same_motion_fraction;
  const double own2 = vision::sameMotionFraction(H1, x2, xp2, tol, 7), own3 = vision::sameMotionFraction(H1, x3, xp3, tol, 7),
               ownj = vision::sameMotionFraction(H1, xj, xpj, tol, 7);
  const double j_at_2 = vision::epipoleAgreement(H1, x2, xp2, xj, xpj, tol, pass, 7),
               three_at_2 = vision::epipoleAgreement(H1, x2, xp2, x3, xp3, tol, pass, 7);
  std::printf("own tests: second plane %.2f, third %.2f, small group %.2f; with the second plane's epipoles: third %.2f, "
              "small group %.2f\n", own2, own3, ownj, three_at_2, j_at_2);
  EXPECT_GE(own2, 0.9);
  EXPECT_GE(own3, 0.9);
  EXPECT_GE(ownj, pass) << "the small group passes its own test (the weakness)";
  EXPECT_GE(three_at_2, 0.9) << "a rigid third plane agrees with the second's epipole";
  EXPECT_LT(j_at_2, pass) << "the small group does not";
  // Untested (-1): points without parallax (on the main plane), on either side.
  EXPECT_EQ(vision::epipoleAgreement(H1, x2, xp2, x0, xp0, tol, pass, 7), -1.0);
  EXPECT_EQ(vision::epipoleAgreement(H1, x0, xp0, x3, xp3, tol, pass, 7), -1.0);
  // The limit: the larger plane decides. Had the small group been the larger, the real plane
  // would be judged by the far epipoles it accepts.
  EXPECT_LT(vision::epipoleAgreement(H1, xj, xpj, x2, xp2, tol, pass, 7), pass);
}

TEST(PlaneStart, AStillStartDoesNotHideTheFocalLength) {
  // The box tracks after 120 still frames (frame 0 again, fresh 0.5 px noise), as hand-held videos
  // often begin (the ViSP cube: 17 still frames). The start decomposes the homographies at the
  // pair frame and at the frame where the motion reaches half of the pair frame's; taking half the
  // pair frame's index instead put that frame among the still ones, where the decompositions fit
  // noise (on the cube the agreement was then best at the grid's end, 1152 px).
  const SyntheticTracks st = boxTracks(0.5, 25, 20, 9);
  Tracks t = st.tracks;
  std::mt19937_64 rng(5);
  std::normal_distribution<double> g(0.0, 0.5);
  std::vector<std::vector<TrackPoint>> still(120, st.tracks.frames[0]);
  for (auto& f : still)
    for (auto& p : f) p.px += Eigen::Vector2d(g(rng), g(rng));
  t.frames.insert(t.frames.begin() + 1, still.begin(), still.end());
  const vision::PlaneFinding pf = vision::findPlanes(t);
  ASSERT_GE(pf.numPlanes(), 1);
  const vision::PlaneStart start = vision::planeStart(t, pf);
  ASSERT_TRUE(start.ok) << start.note;
  EXPECT_FALSE(start.used().at_grid_end);
  EXPECT_NEAR(start.used().focal_px, 256.0, 0.1 * 256.0) << "pair frame " << pf.pair_frame;
  // Hypotheses, not one answer: the lowest disagreement first (the fields above), the frontal
  // start last, every decomposition with unit normals.
  ASSERT_GE(start.hypotheses.size(), 2u);
  EXPECT_EQ(start.chosen, 0);
  for (size_t i = 1; i + 1 < start.hypotheses.size(); ++i)
    EXPECT_LE(start.hypotheses[i - 1].disagreement_deg, start.hypotheses[i].disagreement_deg);
  EXPECT_TRUE(start.hypotheses.back().frontal);
  for (const auto& h : start.hypotheses)
    for (const auto& n : h.normals) EXPECT_NEAR(n.norm(), 1.0, 1e-9);
}

/// The planar two-fold ambiguity ([AS99] §3.1) made hard: a plane tilted 30 deg (normal `n`), the
/// camera (f = 512 px on 512 x 512) orbiting its centre 0.3 deg per frame while moving `forward`
/// of the plane's distance per frame towards it, so that the second decomposition is in front of
/// the camera too; 60 points, 0.5 px, 61 frames.
constexpr double kAmbiguousFocalPx = 512.0;
Tracks ambiguousPlaneTracks(double forward, Eigen::Vector3d* n) {
  const double f = kAmbiguousFocalPx, c = 255.5;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-0.35, 0.35);
  std::normal_distribution<double> g(0.0, 0.5);
  *n = Eigen::AngleAxisd(30.0 * M_PI / 180.0, Eigen::Vector3d::UnitX()) * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d centre(0, 0, 3.0);
  std::vector<Eigen::Vector3d> X;  // on n . X = 3, seen in the reference camera
  while (X.size() < 60) {
    const Eigen::Vector3d ray(u(rng), u(rng), 1.0);
    X.push_back(ray * (3.0 / n->dot(ray)));
  }
  Tracks tracks;
  tracks.image = {512, 512, c, c};
  for (int k = 0; k <= 60; ++k) {
    const Eigen::Matrix3d R = Eigen::AngleAxisd(0.3 * k * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
    const Eigen::Vector3d C = centre - R.transpose() * centre + forward * k * (R.transpose() * Eigen::Vector3d::UnitZ());
    std::vector<TrackPoint> pts;
    for (size_t i = 0; i < X.size(); ++i) {
      const Eigen::Vector3d Y = R * (X[i] - C);
      pts.push_back({static_cast<int>(i), Eigen::Vector2d(f * Y.x() / Y.z() + c + g(rng), f * Y.y() / Y.z() + c + g(rng))});
    }
    tracks.frames.push_back(std::move(pts));
  }
  return tracks;
}

/// The one-plane pipeline with default options on those tracks: the result, its final normal's
/// angle to the truth (deg) and its focal length (px).
struct AmbiguousRun {
  EstimateResult r;
  double normal_err_deg = 0, focal_px = 0;
};
AmbiguousRun runAmbiguous(double forward) {
  Eigen::Vector3d n;
  const Tracks tracks = ambiguousPlaneTracks(forward, &n);
  EstimateOptions eo;
  eo.filter.model = TrackModel::Plane;
  AmbiguousRun a;
  a.r = estimate(tracks, eo);
  if (a.r.refined.ok) {
    const TrackFrame& last = a.r.main().frames.back();
    a.normal_err_deg = std::acos(std::min(1.0, std::abs(last.N[0].normalized().dot(n)))) * 180.0 / M_PI;
    a.focal_px = a.r.main().scale_px / last.beta;
  }
  return a;
}

// Issue 14 item 3. A disabled reproducer until 2026-12-04, when it was found passing: since the
// still start and the process noise from the data (issue 14 items 1 and 4) the scoring filters
// rank the right start first (docs/regimes.md, "A start chosen by a refinement per hypothesis").
TEST(PlaneStart, TheBranchAndTheFocalMinimumAreChosenRight) {
  // Both branches are among the hypotheses, at two focal minima. The scoring filters used to
  // rank the second focal minimum (50 deg off) first by a hair: 1.935 against 1.936 (forward
  // 0.02) and 1.929 against 1.946 (0.03), and the pipeline ended there: focal 1153 and 1318 px,
  // the normal 49 and 42 deg off (reported not determined since 2026-12-03: see
  // AnAmbiguousStartIsNotReportedAsKnown). Measured 2026-12-04: the right start scores 1.9124
  // against 1.9222 and 1.9148 against 1.9160 and is chosen; normal 0.49 and 1.09 deg off, focal
  // 504.9 and 499.8 px. The second margin is 0.06 %: this test is the alarm if it flips.
  for (const double forward : {0.02, 0.03}) {
    SCOPED_TRACE(forward);
    const AmbiguousRun a = runAmbiguous(forward);
    const EstimateResult& r = a.r;
    ASSERT_TRUE(r.refined.ok) << r.refined.message;
    int branches = 0;
    for (const auto& h : r.start.hypotheses) branches = std::max(branches, h.branch + 1);
    EXPECT_EQ(branches, 2) << "both decompositions in front: the ambiguity is there to resolve";
    EXPECT_LT(a.normal_err_deg, 2.5) << "the estimated normal";
    EXPECT_NEAR(a.focal_px, kAmbiguousFocalPx, 0.03 * kAmbiguousFocalPx) << "the estimated focal length";
  }
}

TEST(PlaneStart, AnAmbiguousStartIsNotReportedAsKnown) {
  // The same tracks. Whichever start wins, the result must not be confidently wrong: either the
  // focal length and the normal are right, or the focal length is reported not determined with
  // the truth inside its interval and the plane - whose normal turns with the focal length along
  // the profile - not determined either. Before the profile's spread entered the normal's sd, the
  // plane was reported determined 49 and 42 deg off.
  for (const double forward : {0.02, 0.03}) {
    SCOPED_TRACE(forward);
    const AmbiguousRun a = runAmbiguous(forward);
    const EstimateResult& r = a.r;
    const double f = kAmbiguousFocalPx;
    ASSERT_TRUE(r.refined.ok) << r.refined.message;
    if (a.normal_err_deg < 2.5 && std::abs(a.focal_px - f) < 0.03 * f) continue;  // right
    EXPECT_FALSE(r.refined.focal_determined) << "focal " << a.focal_px << " px reported as known";
    ASSERT_TRUE(r.refined.focal_interval_px.has_value());
    EXPECT_LE((*r.refined.focal_interval_px)[0], f);
    EXPECT_GE((*r.refined.focal_interval_px)[1], f);
    ASSERT_EQ(r.refined.plane_determined.size(), 1u);
    EXPECT_FALSE(r.refined.plane_determined[0]) << "a normal " << a.normal_err_deg << " deg off reported as known; " << r.refined.why;
  }
}

TEST(PlaneStart, TheDataChooseTheStartNotTheOrder) {
  // Issue 14 item 3: the starts are hypotheses - each local minimum of the focal search and each
  // decomposition with the plane in front (the planar two-fold ambiguity, [AS99] §3.1), beside
  // the frontal start - and a bank of filters scores them (rsfm::scoreStartHypotheses). Put in
  // reverse order (the frontal and the worst first), the chosen start is still a right one and
  // every wrong one scores worse: the choice is the data's, not the order's. Scene: Table 1's
  // plane ([AS99] §4; 30 deg off-axis, 50 deg of orbit) with 60 points and 0.5 px noise, and the
  // box scene's dominant face. "Right": within 5 deg of the true normal (a start on a 49-step
  // focal grid from two homographies). Measured: the wrong hypothesis is the second focal
  // minimum (1536 px, 42 and 36 deg off; scores 7.6 and 3.6 against 1.9 for the right start and
  // 2.0 for the frontal one); the second decomposition is behind the camera for some points in
  // both scenes (90 deg field of view), so only one branch is in front.
  for (int scene = 0; scene < 2; ++scene) {
    SCOPED_TRACE(scene == 0 ? "Table 1 plane" : "box face");
    Tracks tracks;
    Eigen::Vector3d truth;
    std::vector<int> labels;
    vision::PlaneFinding pf;
    if (scene != 1) {
      std::mt19937_64 rng(21);
      Table1SceneOptions so;
      so.points = 60;
      const Table1Scene sc = makeTable1Scene(so, rng);
      const double s = so.scale_px, c = (so.image_px - 1) / 2.0;
      tracks.image = {static_cast<int>(so.image_px), static_cast<int>(so.image_px), c, c};
      std::normal_distribution<double> g(0.0, 0.5);
      for (const auto& f : sc.uv) {
        std::vector<TrackPoint> pts;
        for (size_t i = 0; i < f.size(); ++i)
          pts.push_back({static_cast<int>(i), f[i] * s + Eigen::Vector2d(c + g(rng), c + g(rng))});
        tracks.frames.push_back(std::move(pts));
      }
      truth = sc.unitNormal();
    } else {
      const SyntheticTracks st = boxTracks(0.5, 0, 0, 9);
      tracks = st.tracks;
      vision::PlaneFinderOptions fo;
      fo.max_planes = 1;
      pf = vision::findPlanes(tracks, fo);
      std::vector<int> votes(st.scene.faces(), 0);
      for (size_t id = 0; id < pf.labels.size(); ++id)
        if (pf.labels[id] == 0 && st.face[id] >= 0) ++votes[st.face[id]];
      truth = st.scene.planes[std::max_element(votes.begin(), votes.end()) - votes.begin()].normalized();
    }
    if (scene != 1) {
      vision::PlaneFinderOptions fo;
      fo.max_planes = 1;
      pf = vision::findPlanes(tracks, fo);
    }
    ASSERT_EQ(pf.numPlanes(), 1);
    auto angle = [&](const Eigen::Vector3d& n) { return std::acos(std::min(1.0, std::abs(n.dot(truth)))) * 180.0 / M_PI; };
    vision::PlaneStart start = vision::planeStart(tracks, pf);
    ASSERT_TRUE(start.ok) << start.note;
    std::reverse(start.hypotheses.begin(), start.hypotheses.end());
    TrackFilterOptions o;
    o.model = TrackModel::Plane;
    o.sigma_px = 0.5;
    scoreStartHypotheses(tracks, pf.labels, o, 1, &start);
    const vision::StartHypothesis& c = start.hypotheses[start.chosen];
    ASSERT_TRUE(std::isfinite(c.score)) << c.stopped;
    int wrong = 0;
    for (const auto& h : start.hypotheses)
      if (!h.frontal && angle(h.normals[0]) > 5.0) {
        ++wrong;
        EXPECT_GT(h.score, c.score) << "a wrong start (" << angle(h.normals[0]) << " deg off) explains the tracks better";
      }
    EXPECT_GE(wrong, 1) << "a wrong hypothesis to choose against";
    EXPECT_TRUE(c.frontal || angle(c.normals[0]) < 5.0) << "chosen normal " << angle(c.normals[0]) << " deg off";
    EXPECT_GE(start.scored_from, 1);
    EXPECT_EQ(start.scored_to, tracks.first_frame + tracks.numFrames() - 1);
  }
}

TEST(PlaneStart, AFocalLengthAtTheGridsEndKeepsTheGuesssWidth) {
  // A decomposition's focal length at an end of the focal grid (no minimum of the homographies'
  // disagreement) is not determined by them: rsfm::startOptions keeps beta's prior sd at the
  // guess's width (kGuessBetaSd0) instead of a start's 0.1, while its normals and relative
  // distances still start the planes; a width the user gives is kept either way. Measured on
  // box.mp4@4 (docs/regimes.md): from a 1920 px start (3.3x the focal length) with sd 0.1 the
  // filter held 1660-2440 px and the refinement ended not determined; with 0.3, 578 px.
  vision::StartHypothesis h;
  h.focal_px = 1920.0;
  h.normals = {Eigen::Vector3d(0.0, 0.6, 0.8), Eigen::Vector3d(0.6, -0.8, 0.0)};
  h.distance_ratios = {1.0, 0.5};
  TrackFilterOptions base;
  for (bool end : {false, true}) {
    h.at_grid_end = end;
    const TrackFilterOptions o = startOptions(base, h, 2);
    ASSERT_TRUE(o.beta_sd0.has_value());
    EXPECT_DOUBLE_EQ(*o.beta_sd0, end ? TrackFilterOptions::kGuessBetaSd0 : 0.1);
    ASSERT_TRUE(o.normal_sd0.has_value());
    EXPECT_DOUBLE_EQ(*o.normal_sd0, 0.1) << "the normals are the decomposition's either way";
    EXPECT_DOUBLE_EQ(o.focal0_px, 1920.0);
    ASSERT_EQ(o.initial_normals.size(), 2u);
  }
  base.beta_sd0 = 0.05;
  EXPECT_DOUBLE_EQ(*startOptions(base, h, 2).beta_sd0, 0.05) << "a given width is the user's";
}

TEST(TrackFilter, RecoversFocalAndFaceAnglesFromPixelTracks) {
  // The whole estimate on pixel tracks of the box scene (orthogonal faces, 0.5 px noise, focal
  // 256 px), with labels from the plane finder and the homography start. Tolerances: the start's
  // focal within 10 %, the filter's within 8 % (5.6 % observed: this scene constrains the focal
  // length weakly, see docs/planes.md), every face angle within 1.5 deg of 90.
  const SyntheticTracks st = boxTracks(0.5, 25, 20, 9);
  const vision::PlaneFinding pf = vision::findPlanes(st.tracks);
  ASSERT_EQ(pf.numPlanes(), st.scene.faces());
  // The start from the homographies (what `rsfm estimate` does) is already close ...
  const vision::PlaneStart start = vision::planeStart(st.tracks, pf);
  ASSERT_TRUE(start.ok) << start.note;
  const vision::StartHypothesis& used = start.used();
  EXPECT_NEAR(used.focal_px, 256.0, 0.1 * 256.0);
  EXPECT_FALSE(used.at_grid_end) << "an interior minimum of the focal grid";
  TrackFilterOptions o;
  o.sigma_px = 0.5;
  o.focal0_px = used.focal_px;
  o.initial_normals = used.normals;
  o.initial_distance_ratios = used.distance_ratios;
  o.normal_sd0 = 0.1;
  o.beta_sd0 = 0.1;
  const TrackFilterResult r = runTrackFilter(st.tracks, pf.labels, o);
  ASSERT_TRUE(r.ok()) << r.stopped;
  ASSERT_EQ(r.frames.size(), st.tracks.frames.size());
  const TrackFrame& f = r.frames.back();
  EXPECT_NEAR(r.scale_px / f.beta, 256.0, 0.08 * 256.0);
  for (int a = 0; a < pf.numPlanes(); ++a)
    for (int b = a + 1; b < pf.numPlanes(); ++b)
      EXPECT_NEAR(normalAngle(f.N[a], f.N[b]) * 180.0 / M_PI, 90.0, 1.5) << "planes " << a << ", " << b;
  for (double rms : r.plane_rms_px) EXPECT_LT(rms, 1.0);
}

TEST(TrackFilter, LaterTracksJoinThroughTheEstimate) {
  // Tracks that start at frame 40 join their plane by transfer; their transferred reference
  // positions land within 1.5 px of the truth (the estimate's own error at that frame).
  SyntheticTracks st = boxTracks(0.3, 0, 0, 13);
  const int n = static_cast<int>(st.scene.points.size());
  // Give every third point a new id from frame 40 on (a track that ends and one that starts).
  const int base = n + 1000;
  for (int k = 40; k < st.tracks.numFrames(); ++k)
    for (auto& p : st.tracks.frames[k])
      if (p.id % 3 == 0) p.id += base;
  for (auto& fr : st.tracks.frames)
    std::sort(fr.begin(), fr.end(), [](const TrackPoint& a, const TrackPoint& b) { return a.id < b.id; });
  std::vector<int> labels(st.tracks.idBound(), -2);
  for (int i = 0; i < n; ++i) {
    labels[i] = st.face[i];
    if (i % 3 == 0) labels[i + base] = st.face[i];
  }
  TrackFilterOptions o;
  o.sigma_px = 0.3;
  const TrackFilterResult r = runTrackFilter(st.tracks, labels, o);
  ASSERT_TRUE(r.ok()) << r.stopped;
  int joined = 0;
  for (int j : r.plane_new_tracks) joined += j;
  EXPECT_EQ(joined, (n + 2) / 3);
  for (double rms : r.plane_rms_px) EXPECT_LT(rms, 0.6);
}

namespace {

/// A real photograph (visp-images-data's Klimt, or a procedural texture when it is absent) warped
/// by a known affine map about a point; three 21 x 21 patches aligned from a start 1 px off with
/// no shape guess. Returns, per patch, the centre error and the largest corner error (px).
/// f0 warped by x' = A x + t, sampled exactly (double-precision bicubic, Keys a = -0.5):
/// cv::warpAffine quantizes sub-pixel positions to 1/32 px, an error of the test image itself.
cv::Mat warpExactly(const cv::Mat& f0, const Eigen::Matrix2d& A, const Eigen::Vector2d& t) {
  cv::Mat f1(f0.size(), CV_32F, cv::Scalar(0));
  const Eigen::Matrix2d Ai = A.inverse();
  auto keys = [](double u) {
    u = std::abs(u);
    return u < 1 ? 1.5 * u * u * u - 2.5 * u * u + 1 : u < 2 ? -0.5 * u * u * u + 2.5 * u * u - 4 * u + 2 : 0.0;
  };
  for (int y = 0; y < f1.rows; ++y)
    for (int x = 0; x < f1.cols; ++x) {
      const Eigen::Vector2d src = Ai * (Eigen::Vector2d(x, y) - t);
      const int x0 = static_cast<int>(std::floor(src.x())), y0 = static_cast<int>(std::floor(src.y()));
      if (x0 < 1 || y0 < 1 || x0 + 2 >= f0.cols || y0 + 2 >= f0.rows) continue;
      double acc = 0;
      for (int j = -1; j <= 2; ++j)
        for (int i = -1; i <= 2; ++i)
          acc += keys(src.x() - (x0 + i)) * keys(src.y() - (y0 + j)) * f0.at<float>(y0 + j, x0 + i);
      f1.at<float>(y, x) = static_cast<float>(acc);
    }
  return f1;
}

/// The Klimt photograph (visp-images-data), blurred by sigma 1, as CV_32F; a smoothed noise
/// image when the package is not installed.
cv::Mat texturedImage() {
  cv::Mat img = cv::imread("/usr/share/visp-images-data/ViSP-images/Klimt/Klimt.pgm", cv::IMREAD_GRAYSCALE);
  if (img.empty()) {
    cv::Mat noise(40, 50, CV_8U);
    cv::RNG(3).fill(noise, cv::RNG::UNIFORM, 0, 255);
    cv::resize(noise, img, cv::Size(500, 400), 0, 0, cv::INTER_CUBIC);
  }
  cv::Mat f0;
  img.convertTo(f0, CV_32F);
  cv::GaussianBlur(f0, f0, cv::Size(0, 0), 1.0);
  return f0;
}

std::vector<std::pair<double, double>> affineWarpErrors(const vision::AffineLkOptions& o) {
  const cv::Mat f0 = texturedImage();
  // Known warp about a centre c: x' = A (x - c) + c + d.
  const Eigen::Vector2d c(f0.cols * 0.45, f0.rows * 0.5);
  Eigen::Matrix2d A;
  A << 1.06, 0.05, -0.04, 0.95;
  const Eigen::Vector2d d(2.3, -1.7);
  const Eigen::Vector2d t = c + d - A * c;
  const cv::Mat f1 = warpExactly(f0, A, t);
  std::vector<std::pair<double, double>> out;
  const std::vector<Eigen::Vector2d> centres = {c, c + Eigen::Vector2d(40, 25), c + Eigen::Vector2d(-60, 30)};
  for (const Eigen::Vector2d& p : centres) {
    vision::AffineTemplate tmpl;
    if (!tmpl.init(f0, p, o)) continue;
    Eigen::Matrix2d a = Eigen::Matrix2d::Identity();
    Eigen::Vector2d b = p + d + Eigen::Vector2d(0.8, -0.6);
    double rms = 0;
    if (!tmpl.align(f1, &a, &b, &rms)) {
      out.emplace_back(1e9, 1e9);
      continue;
    }
    const Eigen::Vector2d truth_b = A * p + t;
    double corner = 0.0;
    for (int sx : {-1, 1})
      for (int sy : {-1, 1}) {
        const Eigen::Vector2d k(sx * o.radius, sy * o.radius);
        corner = std::max(corner, (a * k + b - (A * k + truth_b)).norm());
      }
    out.emplace_back((b - truth_b).norm(), corner);
  }
  return out;
}

}  // namespace

TEST(AffineLk, SmallBilinearTemplates) {
  // 21 x 21 templates (radius 10, window sigma 10) with bilinear sampling: centre within 0.05 px,
  // corners only within 0.25 px (0.05-0.19 px observed): the interpolation error of the warped
  // image, amplified by how weakly a small window fixes A.
  vision::AffineLkOptions o;
  o.radius = 10;
  o.window_sigma = 10;
  o.epsilon_px = 1e-3;
  o.max_iterations = 50;
  const auto e = affineWarpErrors(o);
  ASSERT_GE(e.size(), 2u);
  for (const auto& [centre, corner] : e) {
    EXPECT_LT(centre, 0.05);
    EXPECT_LT(corner, 0.25);
  }
}

TEST(AffineLk, PatchTrackerRecoversAKnownWarpToFiveHundredthsOfAPixelAtTheCorners) {
  // The patch tracker's alignment (PatchTrackerOptions: radius 15, window sigma 15, bicubic,
  // 20 iterations to 0.002 px): a known affine warp of a real image (Klimt) is recovered within
  // 0.05 px at the centre and at the 31 x 31 patch's corners (issue 5).
  const auto e = affineWarpErrors(vision::PatchTrackerOptions{}.affine);
  ASSERT_EQ(e.size(), 3u);
  double worst = 0;
  for (const auto& [centre, corner] : e) {
    EXPECT_LT(centre, 0.05);
    EXPECT_LT(corner, 0.05);
    worst = std::max(worst, corner);
  }
  std::printf("patch corners: worst %.4f px\n", worst);
}

TEST(PatchTracker, FollowsAKnownAffineSequence) {
  // 12 frames of a real image under a growing affine warp about the image centre; every patch's
  // warp from its first appearance must match the truth within 0.05 px at its corners.
  const cv::Mat f0 = texturedImage();
  const Eigen::Vector2d c(f0.cols / 2.0, f0.rows / 2.0);
  vision::PatchTrackerOptions o;
  o.max_patches = 12;
  vision::PatchTracker tracker(o);
  std::vector<Eigen::Matrix2d> As;
  std::vector<Eigen::Vector2d> ts;
  for (int k = 0; k < 12; ++k) {
    Eigen::Matrix2d A;
    A << 1.0 + 0.006 * k, 0.004 * k, -0.003 * k, 1.0 - 0.004 * k;
    const Eigen::Vector2d t = c + Eigen::Vector2d(0.9 * k, -0.6 * k) - A * c;
    As.push_back(A);
    ts.push_back(t);
    cv::Mat f8;
    warpExactly(f0, A, t).convertTo(f8, CV_8U);
    tracker.process(f8);
  }
  const PatchTracks pt = tracker.tracks();
  ASSERT_EQ(pt.numFrames(), 12);
  ASSERT_GE(pt.frames[0].size(), 6u);
  double worst = 0;
  int checked = 0;
  for (const auto& p : pt.frames[11]) {
    // Truth: first frame k0 where the patch appeared (all appear in frame 0 here).
    ASSERT_NE(pt.find(0, p.id), nullptr);
    const Eigen::Matrix2d A = As[11] * As[0].inverse();
    const Eigen::Vector2d truth_c = As[11] * (As[0].inverse() * (p.px0 - ts[0])) + ts[11];
    for (int sx : {-1, 1})
      for (int sy : {-1, 1}) {
        const Eigen::Vector2d k(sx * pt.radius, sy * pt.radius);
        worst = std::max(worst, (p.A * k + p.px - (A * k + truth_c)).norm());
      }
    ++checked;
  }
  EXPECT_GE(checked, 6);
  // 8-bit frames add quantization noise that the exact-warp test above does not have.
  EXPECT_LT(worst, 0.1);
  std::printf("patch tracker, 8-bit sequence: %d patches, worst corner %.4f px\n", checked, worst);
}

TEST(PatchesIo, RoundTripAndErrors) {
  PatchTracks t;
  t.image = {384, 288, 191.5, 143.5};
  t.radius = 15;
  t.first_frame = 3;
  t.source = "unit test";
  PatchObservation a;
  a.id = 2;
  a.px0 = {100.25, 80.5};
  a.px = a.px0;
  PatchObservation b = a;
  b.px = {103.125, 79.75};
  b.A << 1.01, 0.02, -0.015, 0.99;
  b.rms = 0.12;
  t.frames = {{a}, {b}};
  const auto dir = std::filesystem::temp_directory_path() / "rsfm_patches_io";
  std::filesystem::create_directories(dir);
  const auto good = dir / "patches.csv";
  {
    std::ofstream f(good);
    f << io::patchesToString(t);
  }
  const PatchTracks r = io::readPatches(good);
  ASSERT_EQ(r.numFrames(), 2);
  EXPECT_EQ(r.first_frame, 3);
  EXPECT_EQ(r.radius, 15);
  ASSERT_NE(r.find(1, 2), nullptr);
  EXPECT_LT((r.find(1, 2)->A - b.A).norm(), 1e-6);
  EXPECT_LT((r.find(1, 2)->px - b.px).norm(), 1e-4);
  // Each broken line is named with its file and line number.
  const std::string text = io::patchesToString(t);
  auto expectError = [&](const std::string& bad, const std::string& what) {
    const auto f = dir / "bad.csv";
    {
      std::ofstream o(f);
      o << bad;
    }
    try {
      io::readPatches(f);
      ADD_FAILURE() << "no error for: " << what;
    } catch (const io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("bad.csv:"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  auto replace = [&](std::string s, const std::string& from, const std::string& to) {
    s.replace(s.find(from), from.size(), to);
    return s;
  };
  expectError(replace(text, "# rsfm-patches 1", "# rsfm-tracks 1"), "not an rsfm patches file");
  expectError(replace(text, "# radius 15\n", ""), "missing '# radius R'");
  expectError(replace(text, "1.0100000", "abc"), "a11 is not a number");
  expectError(replace(text, "1.0100000", "nan"), "a11 is not");
  expectError(replace(text, "0.9900000", "-0.9900000"), "non-positive determinant");
  expectError(replace(text, "103.1250", "104.1250"), "disagree");
  expectError(text + "9,1,1,1,1,1,1,0,0,1,0,0,0\n", "outside the declared range");
  expectError(replace(text, "4,2,100.2500", "4,2,101.2500"), "first-frame centre changed");
  expectError(text.substr(0, text.find("frame,patch")) + "frame,patch\n", "expected the column header");
  std::filesystem::remove_all(dir);
}

