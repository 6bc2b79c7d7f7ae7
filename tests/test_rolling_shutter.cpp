// A rolling shutter: its known readout (EstimateOptions::rolling_shutter_readout,
// correctRollingShutter) and its estimate in the refinement (RefineOptions::estimate_readout);
// docs/estimate.md section 6, "A rolling shutter".
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <random>
#include <tuple>

#include "regime_tracks.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/pipeline/estimate.hpp"
#include "rsfm/render/regime_suite.hpp"
#include "rsfm/track/tracks.hpp"
#include "rsfm/units.hpp"

namespace rsfm {
namespace {

/// Where a w x h image's readout reaches the point p, from -1/2 to 1/2, written out per direction
/// (ImageInfo::readoutOffset is what is tested).
double offsetOf(ReadoutDirection d, const Eigen::Vector2d& p, double w, double h) {
  switch (d) {
    case ReadoutDirection::Down: return (p.y() - (h - 1.0) / 2.0) / h;
    case ReadoutDirection::Up: return ((h - 1.0 - p.y()) - (h - 1.0) / 2.0) / h;
    case ReadoutDirection::Right: return (p.x() - (w - 1.0) / 2.0) / w;
    case ReadoutDirection::Left: return ((w - 1.0 - p.x()) - (w - 1.0) / 2.0) / w;
  }
  return 0.0;
}

/// The sensor line through p, read over `tau` frame intervals, is exposed at k + tau s, s its
/// offset along the readout `d` (offsetOf): the time at which a point on the path `at` is seen in
/// frame k (fixed point: its line depends on that time).
template <class Path>
Eigen::Vector2d seenAt(const Path& at, int k, double tau, double w, double h, ReadoutDirection d = ReadoutDirection::Down) {
  double t = k;
  for (int i = 0; i < 30; ++i) t = k + tau * offsetOf(d, at(t), w, h);
  return at(t);
}

/// Quadratic interpolation of a track's positions at time k + d (|d| <= 1) from frames k-1, k,
/// k+1 (a path for seenAt on a track that only has whole frames).
Eigen::Vector2d interpolate(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c, double d) {
  return b + d * 0.5 * (c - a) + 0.5 * d * d * (c - 2.0 * b + a);
}

TEST(RollingShutter, MovesObservationsBackToTheGlobalShuttersPositions) {
  // Points turning about (300, 250) at 0.02 rad/frame (up to 4 px/frame): each frame sees them
  // where the sensor lines' exposure times put them; the correction with the track's own
  // velocity takes them back to the frame's time to second order in the motion. For each of the
  // four readout directions (a video turned by its rotation metadata reads along its columns),
  // and the wrong one (down) assumed for a readout along the columns leaves the error.
  const double tau = 1.0, w = 0.02;
  const Eigen::Vector2d c(300, 250);
  for (const ReadoutDirection d : {ReadoutDirection::Down, ReadoutDirection::Up, ReadoutDirection::Right, ReadoutDirection::Left}) {
    Tracks t;
    t.image = ImageInfo::centred(640, 480);
    t.image.readout_direction = d;
    const int frames = 20;
    t.frames.resize(frames);
    std::vector<std::vector<Eigen::Vector2d>> truth(frames);
    int id = 0;
    for (double r : {40.0, 120.0, 200.0})
      for (double phi = 0.0; phi < 6.2; phi += 0.7) {
        auto at = [&](double time) {
          const double a = phi + w * time;
          return Eigen::Vector2d(c + r * Eigen::Vector2d(std::cos(a), std::sin(a)));
        };
        // Tracks of different lives: every third one seen in frames 3-12 only (its ends one-sided).
        const int first = id % 3 == 0 ? 3 : 0, last = id % 3 == 0 ? 12 : frames - 1;
        for (int k = first; k <= last; ++k) {
          t.frames[k].push_back({id, seenAt(at, k, tau, 640, 480, d)});
          truth[k].push_back(at(k));
        }
        ++id;
      }
    t.frames[7].push_back({id, {100.0, 400.0}});  // a track of one frame: no velocity, left alone
    truth[7].push_back({100.0, 400.0});
    auto largest = [&](const Tracks& fixed, double* inner, double* ends) {
      *inner = *ends = 0.0;
      for (int k = 0; k < frames; ++k)
        for (std::size_t i = 0; i < t.frames[k].size(); ++i) {
          ASSERT_EQ(fixed.frames[k][i].id, t.frames[k][i].id);
          const double e = (fixed.frames[k][i].px - truth[k][i]).norm();
          const int tid = t.frames[k][i].id;
          const bool end = !t.find(k - 1, tid) || !t.find(k + 1, tid);  // one-sided velocity there
          double& m = end ? *ends : *inner;
          m = std::max(m, e);
        }
    };
    double before = 0, before_ends = 0, after = 0, after_ends = 0;
    largest(t, &before, &before_ends);
    largest(correctRollingShutter(t, tau), &after, &after_ends);
    std::printf("rolling shutter 1 frame %s, up to 4 px/frame: largest error %.3f px seen, %.4f px corrected (%.4f px "
                "at a track's ends)\n",
                readoutDirectionName(d), std::max(before, before_ends), after, after_ends);
    EXPECT_GT(before, 1.0) << readoutDirectionName(d);      // the shutter moves points by pixels
    EXPECT_LT(after, 0.02) << readoutDirectionName(d);      // central differences: second order
    EXPECT_LT(after_ends, 0.1) << readoutDirectionName(d);  // one-sided differences at a track's ends: first order
    if (d == ReadoutDirection::Left) {
      Tracks wrong = t;
      wrong.image.readout_direction = ReadoutDirection::Down;
      double wrong_inner = 0, wrong_ends = 0;
      largest(correctRollingShutter(wrong, tau), &wrong_inner, &wrong_ends);
      EXPECT_GT(wrong_inner, 1.0) << "the rows' correction of a readout along the columns";
    }
    // A global shutter (readout 0) leaves the tracks as they are, bit for bit.
    const Tracks same = correctRollingShutter(t, 0.0);
    for (int k = 0; k < frames; ++k)
      for (std::size_t i = 0; i < t.frames[k].size(); ++i) EXPECT_EQ(same.frames[k][i].px, t.frames[k][i].px);
  }
  // The names and a video's rotation (OpenCV turns a 90-degree one clockwise: row 0 to the right).
  for (const ReadoutDirection d : {ReadoutDirection::Down, ReadoutDirection::Up, ReadoutDirection::Right, ReadoutDirection::Left}) {
    ReadoutDirection back = ReadoutDirection::Down;
    EXPECT_TRUE(parseReadoutDirection(readoutDirectionName(d), &back));
    EXPECT_EQ(back, d);
  }
  ReadoutDirection none;
  EXPECT_FALSE(parseReadoutDirection("sideways", &none));
  EXPECT_EQ(readoutDirectionAfterRotation(0), ReadoutDirection::Down);
  EXPECT_EQ(readoutDirectionAfterRotation(90), ReadoutDirection::Left);
  EXPECT_EQ(readoutDirectionAfterRotation(180), ReadoutDirection::Up);
  EXPECT_EQ(readoutDirectionAfterRotation(270), ReadoutDirection::Right);
  EXPECT_EQ(readoutDirectionAfterRotation(-90), ReadoutDirection::Right);
  EXPECT_EQ(readoutDirectionAfterRotation(45), ReadoutDirection::Down);
}

TEST(RollingShutter, TheReadoutKnownOrEstimatedTakesTheShuttersErrorOutOfTheEstimate) {
  // box-1deg's orbit (1 deg a frame about the box: 3-7 px/frame) seen by a rolling shutter that
  // reads its rows over 0.8 frame intervals (the tracks' positions at each row's time from their
  // frames by quadratic interpolation, then 0.2 px of noise). A global shutter assumed, the faces
  // and the focal length take the shutter's shear; with the readout given, or estimated by the
  // refinement (the default), they come back. The same orbit through a global shutter estimates
  // a readout consistent with 0.
  const render::Regime* reg = render::builtinRegimeSuite().find("box-1deg");
  ASSERT_NE(reg, nullptr);
  const test::RegimeTracks clean = test::regimeTracks(reg->options, 1e-9, 5);
  const double tau = 0.8, w = clean.tracks.image.width, h = clean.tracks.image.height;
  Tracks seen = clean.tracks;
  std::mt19937_64 rng(11);
  std::normal_distribution<double> g(0.0, 0.2);
  for (int k = 0; k < seen.numFrames(); ++k)
    for (TrackPoint& p : seen.frames[k]) {
      const TrackPoint* a = clean.tracks.find(k - 1, p.id);
      const TrackPoint* c = clean.tracks.find(k + 1, p.id);
      const Eigen::Vector2d b = clean.tracks.find(k, p.id)->px;
      if (a && c)
        p.px = seenAt([&](double time) { return interpolate(a->px, b, c->px, time - k); }, k, tau, w, h);
      else if (a || c)  // a track's first or last frame: along the line through its neighbour
        p.px = seenAt([&](double time) { return Eigen::Vector2d(b + (time - k) * (c ? c->px - b : b - a->px)); }, k, tau, w, h);
    }
  // Then the noise on every point (the same noise on the global shutter's tracks).
  Tracks global = clean.tracks;
  for (std::size_t k = 0; k < seen.frames.size(); ++k)
    for (std::size_t i = 0; i < seen.frames[k].size(); ++i) {
      const Eigen::Vector2d n(g(rng), g(rng));
      seen.frames[k][i].px += n;
      global.frames[k][i].px += n;
    }
  // Runs with the readout given (none: estimated), returning (planes, |focal error| %, largest
  // angle error deg, residual sd px, the refinement's readout and its sd).
  auto run = [&](std::optional<double> readout, const Tracks& tracks = {}) {
    EstimateOptions o;
    o.rolling_shutter_readout = readout;
    const EstimateResult e = estimate(tracks.frames.empty() ? seen : tracks, o);
    EXPECT_TRUE(e.refined.ok) << e.refined.message;
    const TrackFrame& last = e.main().frames.back();
    const double focal_err = 100.0 * (e.main().scale_px / last.beta / *clean.truth.focal_px - 1.0);
    double angle_err = 0.0;  // the box's faces and the floor are perpendicular to each other
    for (std::size_t a = 0; a < last.N.size(); ++a)
      for (std::size_t b = a + 1; b < last.N.size(); ++b)
        angle_err = std::max(angle_err, std::abs(90.0 - normalAngle(last.N[a], last.N[b]) * kRadToDeg));
    std::printf("readout %s: %zu planes, focal error %+.2f %%, largest angle error %.2f deg, residual sd %.3f px; refined "
                "readout %.3f +- %.3f (%s)\n",
                readout ? fmt::format("{:.1f} given", *readout).c_str() : "estimated", last.N.size(), focal_err, angle_err,
                e.refined.sigma_px, e.refined.readout, e.refined.readout_sd,
                e.refined.readout_free ? (e.refined.readout_determined ? "determined" : "not determined") : "not a parameter");
    EXPECT_EQ(e.refined.readout_free, !readout.has_value());
    // The edge-on third plane's weak direction (below) does not take the rest with it.
    EXPECT_TRUE(e.refined.focal_determined);
    EXPECT_TRUE(e.refined.camera_determined[0] && e.refined.camera_determined[1]);
    if (!readout) {
      EXPECT_TRUE(e.refined.readout_determined);
    }
    return std::make_tuple(static_cast<int>(last.N.size()), std::abs(focal_err), angle_err, e.refined.sigma_px,
                           e.refined.readout, e.refined.readout_sd);
  };
  const auto [planes0, focal0, angle0, sigma0, r0, r0_sd] = run(0.0);
  const auto [planes1, focal1, angle1, sigma1, r1, r1_sd] = run(tau);
  const auto [planes2, focal2, angle2, sigma2, r2, r2_sd] = run(std::nullopt);
  const auto [planes3, focal3, angle3, sigma3, r3, r3_sd] = run(std::nullopt, global);
  ASSERT_GE(planes1, 2);
  // The shutter's shear is a misfit of the global-shutter model (0.23 px against the tracks'
  // 0.2 px of noise); corrected, the residuals are the noise.
  EXPECT_LT(sigma1, 0.92 * sigma0);
  EXPECT_LT(sigma1, 0.21);
  EXPECT_LT(angle1, 0.2);
  EXPECT_LT(focal1, 0.4);
  EXPECT_GT(std::max(angle0 - angle1, focal0 - focal1), 0.3) << "the shutter does not bias this estimate: the test shows nothing";
  // Estimated: the readout near the truth, the estimate as good as with the readout given. (Not
  // within 3 of its sds, 0.008: the third plane this scene's tracks give is seen nearly edge-on
  // (|N| ~ 20-70), its valley stops the last solve at its iteration limit at 0.776. Its weak
  // direction in the bound, an eigenvalue of ~1e-12 of the largest, used to count as null and
  // left the focal length, the principal point and the readout "not determined" (the checks in
  // `run`); docs/estimate.md section 6 and "Null, weak and seen directions".)
  ASSERT_GE(planes2, 2);
  EXPECT_LT(std::abs(r2 - tau), 0.1);
  EXPECT_LT(r2_sd, 0.1);
  EXPECT_LT(angle2, 0.2);
  EXPECT_LT(focal2, 0.4);
  EXPECT_LT(sigma2, 0.21);
  // A global shutter: a readout within 3 sds of 0, and no worse an estimate.
  ASSERT_GE(planes3, 2);
  EXPECT_LT(std::abs(r3), 3.0 * r3_sd);
  EXPECT_LT(r3_sd, 0.1);
  EXPECT_LT(angle3, 0.2);
  EXPECT_LT(focal3, 0.4);
  // The same frames decoded turned by a phone video's 90-degree rotation metadata: (x, y) ->
  // (h - 1 - y, x), a 480 x 640 image whose readout goes left (ImageInfo::readout_direction, as
  // the tracker sets it). The estimate is the same one; with the readout assumed down it is not.
  Tracks turned = seen;
  turned.image = ImageInfo::centred(seen.image.height, seen.image.width);
  turned.image.readout_direction = ReadoutDirection::Left;
  for (auto& f : turned.frames)
    for (TrackPoint& p : f) p.px = Eigen::Vector2d(h - 1.0 - p.px.y(), p.px.x());
  const auto [planes4, focal4, angle4, sigma4, r4, r4_sd] = run(std::nullopt, turned);
  ASSERT_GE(planes4, 2);
  EXPECT_NEAR(r4, r2, 0.02);
  EXPECT_LT(angle4, 0.2);
  EXPECT_LT(focal4, 0.4);
  EstimateOptions down;
  down.readout_direction = ReadoutDirection::Down;
  const EstimateResult e5 = estimate(turned, down);
  ASSERT_TRUE(e5.refined.ok) << e5.refined.message;
  std::printf("turned, the readout assumed down: refined readout %.3f +- %.3f, residual sd %.3f px\n", e5.refined.readout,
              e5.refined.readout_sd, e5.refined.sigma_px);
  EXPECT_GT(e5.refined.sigma_px, sigma4 + 0.01);
  EXPECT_GT(std::abs(e5.refined.readout - tau), 0.3);
  // Outside its range the readout is refused with the range.
  EstimateOptions bad;
  bad.rolling_shutter_readout = 3.0;
  EXPECT_THROW(estimate(seen, bad), std::invalid_argument);
}

}  // namespace
}  // namespace rsfm
