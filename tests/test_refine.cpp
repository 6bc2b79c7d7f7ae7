// The final refinement (pipeline/refine.hpp) on synthetic tracks of the cube scene
// (sim/box_scene.hpp, three faces): it recovers a distorted camera with an off-centre principal
// point; a known camera gives the undistorted run's figures; its focal-length interval holds the
// truth at the stated rate; pure rotation and pure translation are reported not determined.
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <opencv2/core.hpp>
#include <random>

#include "rsfm/geometry.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/models/radial_camera.hpp"
#include "rsfm/residual_correlation.hpp"
#include "rsfm/units.hpp"
#include "rsfm/pipeline/estimate.hpp"
#include "rsfm/render/regime_suite.hpp"
#include "rsfm/render/scene_render.hpp"
#include "rsfm/sim/box_scene.hpp"
#include "regime_tracks.hpp"

namespace rsfm {
namespace {

using test::RegimeTracks;
using test::regimeTracks;


struct Synthetic {
  BoxScene scene;
  Tracks tracks;
  double focal = 0;
};

/// The cube scene's tracks in pixels through a camera with principal point c = image centre +
/// `pp_offset`, radial distortion (k1, k2) and Gaussian noise of sd `noise_px`, independent
/// (`ar_rho` 0) or drifting along each track as an AR(1) process e_k = rho e_{k-1} + sqrt(1 -
/// rho^2) g_k (a tracker's error).
Synthetic makeTracks(unsigned seed, double noise_px, const Eigen::Vector2d& pp_offset, double k1, double k2,
                     int frames = 80, double deg_per_frame = 0.3, double ar_rho = 0.0) {
  Synthetic s;
  BoxSceneOptions bo;
  bo.frames = frames;
  bo.pitch_deg = 25.0;
  bo.deg_per_frame = deg_per_frame;
  bo.scale_px = 512.0;  // f = 512 px on a 512 px image (53 deg)
  std::mt19937_64 rng(seed);
  s.scene = makeBoxScene(bo, rng);
  s.focal = bo.scale_px / bo.beta;
  const double c0 = (bo.image_px - 1) / 2.0;
  const Eigen::Vector2d c = Eigen::Vector2d(c0, c0) + pp_offset;
  s.tracks.image = ImageInfo::centred(static_cast<int>(bo.image_px), static_cast<int>(bo.image_px));
  s.tracks.frames.resize(bo.frames + 1);
  std::normal_distribution<double> g(0.0, noise_px);
  const Eigen::Vector4d cam(0, 0, k1, k2);
  std::vector<Eigen::Vector2d> e(s.scene.points.size());
  for (auto& x : e) x = Eigen::Vector2d(g(rng), g(rng));
  const double innov = std::sqrt(1 - ar_rho * ar_rho);
  for (int k = 0; k <= bo.frames; ++k)
    for (int i = 0; i < static_cast<int>(s.scene.points.size()); ++i) {
      // A&P h in units of s; pixels f D(beta h) + c = s RadialCamera(h) + c (dc = 0).
      const Eigen::Vector2d u = RadialCamera::apply(cam, bo.beta, s.scene.uv[k][i]);
      if (k > 0) e[i] = ar_rho * e[i] + innov * Eigen::Vector2d(g(rng), g(rng));
      s.tracks.frames[k].push_back({i, u * bo.scale_px + c + e[i]});
    }
  return s;
}

double worstNormalDeg(const io::Summary& truth, const TrackFilterResult& r) {
  double worst = 0;
  for (const auto& N : r.frames.back().N) {
    double best = 180;
    for (const auto& n : truth.planes) best = std::min(best, std::acos(std::min(1.0, std::abs(n.dot(N.normalized())))) * kRadToDeg);
    worst = std::max(worst, best);
  }
  return worst;
}

TEST(Refine, RecoversADistortedCameraWithAnOffCentrePrincipalPoint) {
  // The geometry of the regime box-k1-neg (k1 = -0.25, f = 700 px, principal point (20, 12) px
  // off the centre), 60 frames, 0.3 px tracks.
  render::RenderOptions ro = render::RenderOptions{};
  ro.frames = 60;
  ro.focal_px = 700;
  ro.k1 = -0.25;
  ro.principal_offset_px = Eigen::Vector2d(20, 12);
  ro.seed = 15;
  const RegimeTracks s = regimeTracks(ro, 0.3, 5);
  const Eigen::Vector2d pp = s.truth.principal_point_px;
  const EstimateResult r = estimate(s.tracks, EstimateOptions{});
  ASSERT_TRUE(r.refined.ok) << r.refined.message;
  const RefineResult& f = r.refined;
  const double focal = f.state.scale_px / f.state.frames.back().beta;
  std::printf("refined: focal %.2f (truth 700), pp (%.2f, %.2f) (truth (%.1f, %.1f)), k1 %.4f, k2 %.4f; online focal %.2f; %s\n",
              focal, f.principal_point_px.x(), f.principal_point_px.y(), pp.x(), pp.y(), f.camera[2], f.camera[3],
              r.online.scale_px / r.online.frames.back().beta, f.why.c_str());
  EXPECT_TRUE(f.focal_determined);
  EXPECT_NEAR(focal / 700.0, 1.0, 0.01);
  EXPECT_NEAR(f.principal_point_px.x(), pp.x(), 2.0);
  EXPECT_NEAR(f.principal_point_px.y(), pp.y(), 2.0);
  EXPECT_NEAR(f.camera[2], -0.25, 0.02);
  const double n_free = worstNormalDeg(s.truth, f.state);
  EXPECT_LT(n_free, 0.5);
  // The filter alone, without a camera model, is off on the same tracks.
  EXPECT_GT(std::abs(r.online.scale_px / r.online.frames.back().beta / 700.0 - 1.0), 0.01);

  // Given the true camera, the tracks give the figures of an undistorted camera's tracks.
  EstimateOptions known;
  vision::CameraCalibration cal;
  cal.width = ro.width;
  cal.height = ro.height;
  cal.fx = cal.fy = 700;
  cal.cx = pp.x();
  cal.cy = pp.y();
  cal.distortion = {-0.25, 0.0, 0.0, 0.0, 0.0};
  cal.source = "truth";
  known.camera = cal;
  const EstimateResult rk = estimate(s.tracks, known);
  ASSERT_TRUE(rk.refined.ok) << rk.refined.message;
  render::RenderOptions plain_o = ro;
  plain_o.k1 = 0;
  const RegimeTracks plain = regimeTracks(plain_o, 0.3, 5);
  EstimateOptions pk;
  pk.filter.focal_px = 700;
  pk.principal_point = pp;
  pk.refine.estimate_distortion = false;
  const EstimateResult ru = estimate(plain.tracks, pk);
  ASSERT_TRUE(ru.refined.ok) << ru.refined.message;
  const double nk = worstNormalDeg(s.truth, rk.refined.state), nu = worstNormalDeg(plain.truth, ru.refined.state);
  std::printf("normals: estimated camera %.3f deg; known camera on the distorted tracks %.3f deg, undistorted tracks %.3f deg\n",
              n_free, nk, nu);
  EXPECT_LT(nk, 0.5);
  EXPECT_NEAR(nk, nu, 0.1);
}

struct Coverage {
  int inside = 0, trials = 0;
  double mean_z2 = 0;
  double mean_inflation = 0;  ///< RefineResult::correlation_inflation
  int angle_pairs = 0, angles_inside = 0;  ///< determined angles between planes; truth inside their 95 % interval
  double cross_effect = 0;  ///< summed |sd without the planes' cross-covariances / sd - 1| (countAngles)
};

/// The true angle between the truth's faces nearest to record f's planes a and b (deg, between
/// lines); -1 when both are nearest the same face.
double trueAngleDeg(const std::vector<Eigen::Vector3d>& truth, const TrackFrame& f, int a, int b) {
  auto nearest = [&](const Eigen::Vector3d& N) {
    int best = 0;
    for (int i = 1; i < static_cast<int>(truth.size()); ++i)
      if (normalAngle(truth[static_cast<std::size_t>(i)], N) < normalAngle(truth[static_cast<std::size_t>(best)], N)) best = i;
    return best;
  };
  const int ta = nearest(f.N[static_cast<std::size_t>(a)]), tb = nearest(f.N[static_cast<std::size_t>(b)]);
  return ta == tb ? -1.0 : normalAngle(truth[static_cast<std::size_t>(ta)], truth[static_cast<std::size_t>(tb)]) * kRadToDeg;
}

/// Counts record f's angles between planes (those with `determined` set, all when null) whose
/// reported 95 % interval (planeAngle) holds the truth's angle.
/// `cross_effect` (optional) accumulates |sd without the cross-covariances / sd - 1|: what the
/// planes' joint covariance (TrackFrame::cov_N_pair) changes.
void countAngles(const std::vector<Eigen::Vector3d>& truth, const TrackFrame& f, const std::vector<bool>* determined, int* pairs,
                 int* inside, double* cross_effect = nullptr) {
  TrackFrame no_cross = f;
  for (auto& C : no_cross.cov_N_pair) C.setZero();
  const int m = static_cast<int>(f.N.size());
  for (int a = 0; a < m; ++a)
    for (int b = a + 1; b < m; ++b) {
      if (determined && !((*determined)[static_cast<std::size_t>(a)] && (*determined)[static_cast<std::size_t>(b)])) continue;
      const double at = trueAngleDeg(truth, f, a, b);
      if (at < 0) continue;
      const PlaneAngle pa = planeAngle(f, a, b);
      EXPECT_TRUE(pa.has_sd) << "planes " << a << ", " << b;
      ++*pairs;
      *inside += pa.has_sd && pa.lo_deg <= at && at <= pa.hi_deg;
      if (cross_effect && pa.sd_deg > 0) *cross_effect += std::abs(planeAngle(no_cross, a, b).sd_deg / pa.sd_deg - 1.0);
    }
}
/// The refined focal length's z = (f - truth) / sd over `trials` seeds.
Coverage focalCoverage(double ar_rho, int trials = 20) {
  Coverage c;
  c.trials = trials;
  for (int t = 0; t < trials; ++t) {
    const Synthetic s = makeTracks(100 + t, 0.5, Eigen::Vector2d::Zero(), 0.0, 0.0, 50, 0.3, ar_rho);
    EstimateOptions o;
    o.refine.estimate_principal_point = false;
    o.refine.estimate_distortion = false;
    // The refinement's intervals are what is tested: the filter starts from a focal length 20 %
    // off (the homography start on this 53-deg scene is poor: issue 14).
    o.homography_start = false;
    o.filter.focal0_px = 0.8 * s.focal;
    const EstimateResult r = estimate(s.tracks, o);
    EXPECT_TRUE(r.refined.ok) << "trial " << t << ": " << r.refined.message;
    if (!r.refined.ok) continue;
    const TrackFrame& last = r.refined.state.frames.back();
    const double f = r.refined.state.scale_px / last.beta;
    const double sd = r.refined.state.scale_px * std::sqrt(last.var_beta) / (last.beta * last.beta);
    const double z = (f - s.focal) / sd;
    c.mean_z2 += z * z / trials;
    c.mean_inflation += r.refined.correlation_inflation / trials;
    c.inside += std::abs(z) <= 1.96;
    countAngles(s.scene.normals, last, &r.refined.plane_determined, &c.angle_pairs, &c.angles_inside, &c.cross_effect);
  }
  std::printf("focal (AR rho %.2f): %d of %d inside the 95 %% interval; mean z^2 %.2f; correlation inflation %.1f; angles "
              "between planes %d of %d inside (their sds without the planes' cross-covariances off by %.0f %% on average)\n",
              ar_rho, c.inside, c.trials, c.mean_z2, c.mean_inflation, c.angles_inside, c.angle_pairs,
              c.angle_pairs ? 100 * c.cross_effect / c.angle_pairs : 0.0);
  return c;
}

TEST(Refine, FocalIntervalHoldsTheTruth) {
  // Gaussian noise, independent: the 95 % interval f +- 1.96 sd must hold the truth in most trials
  // (binomial: >= 16 of 20 at a 95 % rate fails by chance with probability < 2 %).
  const Coverage c = focalCoverage(0.0);
  EXPECT_GE(c.inside, 16);
  EXPECT_LT(c.mean_z2, 2.5);  // z^2 averages 1 when the sd is right
  // The angles between the cube's faces (planeAngle: the planes' joint covariance, cov_N_pair)
  // at about the stated rate as well.
  EXPECT_GE(c.angle_pairs, 20);
  EXPECT_GE(c.angles_inside, c.angle_pairs * 85 / 100);
  EXPECT_GT(c.cross_effect / c.angle_pairs, 0.1);  // the joint covariance is used, and it matters
}

TEST(Refine, FocalIntervalHoldsTheTruthWhenTrackErrorsDrift) {
  // Tracker-like errors: each track's error drifts (AR(1), rho 0.97: about 30 frames of memory,
  // so 50 frames hold few independent errors). The residuals' correlation along tracks
  // (correlation_inflation, the variance factor) must widen the interval enough.
  const Coverage c = focalCoverage(0.97);
  EXPECT_GE(c.inside, 16);
  EXPECT_LT(c.mean_z2, 2.5);
  EXPECT_GE(c.angle_pairs, 20);
  EXPECT_GE(c.angles_inside, c.angle_pairs * 85 / 100);
  EXPECT_GT(c.mean_inflation, 5.0);  // the correlation was seen (independent errors: about 1)
}

/// The track-clustered check's variance ratio for the focal length (clustered / inflated bound,
/// before max(1, .)) and the reported focal sd, averaged over `trials` seeds of the box-orbit
/// regime's geometry with `frames` frames and tracks whose errors follow AR(1) with `rho`.
struct ClusteredCheck {
  double mean_ratio = 0, mean_factor = 0, mean_inflation = 0;
};
ClusteredCheck clusteredCheck(int frames, double rho, int trials) {
  const render::Regime* rg = render::builtinRegimeSuite().find("box-orbit");
  EXPECT_NE(rg, nullptr);
  ClusteredCheck c;
  if (!rg) return c;
  render::RenderOptions ro = rg->options;
  ro.frames = frames;
  for (int t = 0; t < trials; ++t) {
    const RegimeTracks s = regimeTracks(ro, 0.3, 40 + t, rho);
    const EstimateResult r = estimate(s.tracks, EstimateOptions{});
    EXPECT_TRUE(r.refined.ok) << r.refined.message;
    c.mean_ratio += r.refined.clustered_focal_ratio / trials;
    c.mean_factor += r.refined.clustered_focal_factor / trials;
    c.mean_inflation += r.refined.correlation_inflation / trials;
  }
  std::printf("%d frames, AR rho %.2f: clustered / inflated focal variance %.2f, sd factor %.2f, correlation inflation %.1f\n",
              frames, rho, c.mean_ratio, c.mean_factor, c.mean_inflation);
  return c;
}

/// The recursive filter's own (online) focal length against the truth over `trials` seeds of
/// the cube scene (50 frames, 0.5 px noise; AR(1) errors along tracks with `ar_rho`): z with the
/// sd reported - the filter's covariance calibrated by its residuals
/// (TrackFilterResult::SdCalibration) without a refinement, the error against the refinement
/// (OnlineAccuracy) with one - and with the covariance the filter computed.
struct OnlineCoverage {
  int trials = 0, inside = 0, inside_raw = 0, normals = 0, normals_inside = 0;
  int angle_pairs = 0, angles_inside = 0;  ///< the filter alone: its angles between planes (all pairs)
  double mean_z2 = 0, mean_factor = 0;
};
OnlineCoverage onlineFocalCoverage(double ar_rho, int trials, bool refine) {
  OnlineCoverage c;
  c.trials = trials;
  for (int t = 0; t < trials; ++t) {
    const Synthetic s = makeTracks(300 + t, 0.5, Eigen::Vector2d::Zero(), 0.0, 0.0, 50, 0.3, ar_rho);
    EstimateOptions o;
    o.refine.enabled = refine;
    const EstimateResult r = estimate(s.tracks, o);
    EXPECT_TRUE(r.online.ok()) << r.online.stopped;
    if (!r.online.ok()) continue;
    const TrackFrame& last = r.online.frames.back();
    const double f = r.online.scale_px / last.beta;
    const double own_sd = r.online.scale_px * std::sqrt(last.var_beta) / (last.beta * last.beta);
    const double factor = r.online.sd_calibration.variance_factor;
    double sd = own_sd;
    if (refine) {
      EXPECT_TRUE(r.refined.ok && r.refined.online_accuracy.checked && r.refined.online_accuracy.focal_determined)
          << r.refined.message;
      if (!r.refined.online_accuracy.focal_determined) continue;
      sd = r.refined.online_accuracy.focal_sd_px;
      // Normals: each plane's angle to the truth's nearest face against its reported sd.
      for (std::size_t j = 0; j < last.N.size(); ++j) {
        if (!r.refined.online_accuracy.plane_determined[j]) continue;
        const Eigen::Vector3d n = last.N[j].normalized();
        double best = 180;
        for (const auto& tn : s.scene.normals) best = std::min(best, std::acos(std::min(1.0, std::abs(n.dot(tn.normalized())))) * kRadToDeg);
        ++c.normals;
        // sd = sqrt(trace) of the tangent covariance: the 95 % radius of a 2-D error is sqrt(5.99 / 2) sd.
        c.normals_inside += best <= 1.7308 * r.refined.online_accuracy.normal_sd_deg[j];
      }
    }
    if (!refine) countAngles(s.scene.normals, last, nullptr, &c.angle_pairs, &c.angles_inside);
    const double z = (f - s.focal) / sd;
    c.mean_z2 += z * z / trials;
    c.mean_factor += factor / trials;
    c.inside += std::abs(z) <= 1.96;
    c.inside_raw += std::abs(f - s.focal) <= 1.96 * own_sd / std::sqrt(factor);
  }
  std::printf("online focal (AR rho %.2f, %s): %d of %d inside the reported 95 %% interval (%d with the filter's own "
              "covariance); mean z^2 %.2f; variance factor %.1f; normals %d of %d inside; angles between planes %d of %d inside\n",
              ar_rho, refine ? "against the refinement" : "filter alone", c.inside, c.trials, c.inside_raw, c.mean_z2,
              c.mean_factor, c.normals_inside, c.normals, c.angles_inside, c.angle_pairs);
  return c;
}

TEST(FilterSds, TheOnlineFocalIntervalHoldsTheTruthWhenTrackErrorsDrift) {
  // Errors drifting along each track (AR(1), rho 0.97), no refinement: the filter's covariance,
  // which assumes independent errors, under-covers; widened by its residuals' along-track
  // correlation it must hold the truth at about the stated rate (>= 16 of 20 fails by chance
  // with probability < 2 % at a 95 % rate). Measured: 18 of 20 (7 with its own covariance).
  const OnlineCoverage c = onlineFocalCoverage(0.97, 20, false);
  EXPECT_GE(c.inside, 16);
  // The filter's angles between planes, from its calibrated joint covariance (cov_N_pair).
  EXPECT_GE(c.angle_pairs, 20);
  EXPECT_GE(c.angles_inside, c.angle_pairs * 85 / 100);
  EXPECT_LT(c.inside_raw, c.inside - 4);  // the calibration is what holds it
  EXPECT_GT(c.mean_factor, 5.0);
}

TEST(FilterSds, TheOnlineFiguresAgainstTheRefinementHoldTheTruth) {
  // Independent errors on a scene whose start is poor (a 53-deg view, 15 deg of turn): the
  // filter stops 10-100 px from the truth with a covariance of ~8 px (1 of 10 inside: the
  // residuals are white, so their calibration leaves it). Against the refinement the online
  // figures' sds must hold the truth.
  const OnlineCoverage c = onlineFocalCoverage(0.0, 10, true);
  EXPECT_GE(c.inside, 9);
  EXPECT_LE(c.inside_raw, 3);  // the case needs the check
  EXPECT_LT(c.mean_factor, 2.0);  // white residuals: the calibration alone leaves the covariance
  EXPECT_GE(c.normals_inside, c.normals * 9 / 10);
}

TEST(FilterSds, WithoutARefinementTheFilterSaysWhatItsSdsDoNotDetermine) {
  // No refinement: the filter's own verdict (FilterDeterminacy) on clean tracks (0.2 px, white),
  // where its sds alone would call everything determined (box-translate: 201.5 +- 2.8 px against
  // 520; poster-rotate's plane: a normal sd under 5 deg). A camera that only translates
  // determines neither the focal length nor the tilts; one that only turns determines the focal
  // length and no plane; the orbit determines both.
  struct Case {
    const char* name;
    bool focal, planes, translates;
  };
  for (const Case& c : {Case{"box-translate", false, false, true}, Case{"box-orbit", true, true, true},
                        Case{"box-rotate", true, false, false}, Case{"poster-rotate", true, false, false}}) {
    const render::Regime* rg = render::builtinRegimeSuite().find(c.name);
    ASSERT_NE(rg, nullptr) << c.name;
    const RegimeTracks s = regimeTracks(rg->options, 0.2, 5);
    EstimateOptions o;
    o.refine.enabled = false;
    const EstimateResult r = estimate(s.tracks, o);
    ASSERT_TRUE(r.online.ok()) << c.name << ": " << r.online.stopped;
    const FilterDeterminacy d = filterDeterminacy(r.online, false);
    const TrackFrame& last = r.online.frames.back();
    const double f = r.online.scale_px / last.beta, sd = r.online.scale_px * std::sqrt(last.var_beta) / (last.beta * last.beta);
    std::printf("%s: filter focal %.1f +- %.1f px (truth %.1f), Wald rotation %.1f, translation %.1f: %s\n", c.name, f, sd,
                *s.truth.focal_px, d.wald_rotation_chi2, d.wald_translation_chi2, d.why.empty() ? "determined" : d.why.c_str());
    EXPECT_EQ(d.focal_determined, c.focal) << c.name;
    ASSERT_FALSE(d.plane_determined.empty());
    for (bool b : d.plane_determined) EXPECT_EQ(b, c.planes) << c.name;
    EXPECT_EQ(d.rotates, c.focal) << c.name;
    EXPECT_EQ(d.translates, c.translates) << c.name;
    EXPECT_TRUE(filterDeterminacy(r.online, true).focal_determined);  // a given focal length is known
  }
}

TEST(PointModel, IsRefinedAsThePlanesModelAndItsOnlineSdsHoldTheTruth) {
  // The point filter (A&P, 7 + N), even started on the homography start's planes, is far from
  // the truth on the box orbit's geometry with drifting track errors (100 frames, 8 x 8 tracks a
  // face, AR(1) rho 0.9: 815-1092 px for 520; white errors: ~405 px, 12 of its sds), with a
  // calibrated sd that does not hold it. Its tracks are on the finder's planes, so its run is
  // refined from the planes model's filter: the result must be the planes model's, and the point
  // filter's own figure, now in the online section, must carry an sd that holds the truth.
  const render::Regime* rg = render::builtinRegimeSuite().find("box-orbit");
  ASSERT_NE(rg, nullptr);
  int own_inside = 0, online_inside = 0, trials = 0;
  render::RenderOptions ro = rg->options;
  ro.frames = 100;
  for (unsigned seed : {61u, 62u, 63u}) {
    const RegimeTracks s = regimeTracks(ro, 0.3, seed, 0.9, 8);
    const double truth = *s.truth.focal_px;
    EstimateOptions o;
    o.filter.model = TrackModel::Point;
    const EstimateResult point = estimate(s.tracks, o);
    const EstimateResult planes = estimate(s.tracks, EstimateOptions{});
    ASSERT_TRUE(point.online.ok()) << point.online.stopped;
    ASSERT_TRUE(point.refined.ok) << point.refined.message;
    ASSERT_TRUE(planes.refined.ok) << planes.refined.message;
    ASSERT_EQ(point.main().planes, planes.main().planes);
    const auto focal = [](const TrackFilterResult& r) { return r.scale_px / r.frames.back().beta; };
    const auto focal_sd = [](const TrackFilterResult& r) {
      const TrackFrame& l = r.frames.back();
      return r.scale_px * std::sqrt(l.var_beta) / (l.beta * l.beta);
    };
    const double f_point = focal(point.online), f_refined = focal(point.main()), f_planes = focal(planes.main());
    // The point filter starts from the plane models' homography start (its focal length; the
    // depths on the chosen hypothesis's planes).
    ASSERT_TRUE(point.start_tried && point.start.ok && !point.start.used().frontal);
    EXPECT_NEAR(point.online.scale_px / point.online.frames.front().beta, point.start.used().focal_px, 1e-9 * truth);
    const OnlineAccuracy& a = point.refined.online_accuracy;
    ASSERT_TRUE(a.checked && a.focal_determined);
    std::printf("seed %u: point filter %.1f +- %.1f px (own, calibrated), +- %.1f px (against the refinement); refined %.2f +- "
                "%.2f px; planes model refined %.2f px; truth %.1f\n",
                seed, f_point, focal_sd(point.online), a.focal_sd_px, f_refined, focal_sd(point.main()), f_planes, truth);
    // The refinement starts from the planes model's filter: the planes model's result exactly.
    EXPECT_EQ(f_refined, f_planes);
    EXPECT_EQ(point.refined.labels, planes.refined.labels);
    EXPECT_NEAR(f_refined, truth, 0.01 * truth);
    EXPECT_TRUE(point.refined.plane_determined.size() == static_cast<std::size_t>(planes.main().planes));
    EXPECT_TRUE(a.plane_determined.empty());  // the point filter has no planes of its own
    ++trials;
    own_inside += std::abs(f_point - truth) <= 1.96 * focal_sd(point.online);
    online_inside += std::abs(f_point - truth) <= 1.96 * a.focal_sd_px;
  }
  std::printf("point filter's focal length inside its 95 %% interval: %d of %d with its own sd, %d against the refinement\n",
              own_inside, trials, online_inside);
  EXPECT_EQ(online_inside, trials);
  EXPECT_LT(own_inside, trials);  // the case needs the check
}

TEST(FilterSds, TheCorrelationInflationOfAnAr1SeriesIsItsIntegratedAutocorrelationTime) {
  // AR(1) with rho: sum over all lags of rho^|lag| = (1 + rho) / (1 - rho).
  for (const double rho : {0.0, 0.5, 0.9}) {
    std::mt19937_64 rng(7);
    std::normal_distribution<double> g(0.0, 1.0);
    std::vector<std::vector<double>> per(200);
    for (auto& v : per) {
      Eigen::Vector2d e(g(rng), g(rng));
      for (int k = 0; k < 400; ++k) {
        if (k > 0) e = rho * e + std::sqrt(1 - rho * rho) * Eigen::Vector2d(g(rng), g(rng));
        v.push_back(e.x());
        v.push_back(e.y());
      }
    }
    const double expected = (1 + rho) / (1 - rho);
    EXPECT_NEAR(alongTrackCorrelationInflation(per), expected, 0.1 * expected + 0.05) << "rho " << rho;
  }
  EXPECT_EQ(alongTrackCorrelationInflation({}), 1.0);
}

TEST(Refine, TheTrackClusteredCheckAgreesWithTheBoundOnIndependentNoise) {
  // Independent Gaussian noise is what the bound assumes: the tracks' scores must say the same
  // (a wrong motion elimination in the scores gives ratios far from 1), a little below 1 for the
  // parameters' leverage. Measured: 0.81-1.04 per seed.
  const ClusteredCheck c = clusteredCheck(60, 0.0, 3);
  EXPECT_GT(c.mean_ratio, 0.75);
  EXPECT_LT(c.mean_ratio, 1.15);
  EXPECT_LT(c.mean_factor, 1.1);
}

TEST(Refine, TheTrackClusteredCheckWidensWhatThePooledInflationMisses) {
  // Errors drifting along each track (AR(1), rho 0.95: a variance factor (1 + rho) / (1 - rho) =
  // 39 for a track seen throughout) on tracks that come and go as the box turns: the pooled
  // autocorrelation, from pairs within each track's shorter life, gives ~20. The scores of each
  // track see the whole correlation (measured 1.17-1.53 per seed) and widen the focal sd.
  const ClusteredCheck c = clusteredCheck(150, 0.95, 3);
  EXPECT_GT(c.mean_ratio, 1.1);
  EXPECT_GT(c.mean_factor, 1.04);
}

/// The focal length's z = (f - truth) / sd and its sd factor on box-orbit's geometry (100 frames)
/// whose tracks carry, besides 0.2 px of independent noise, an error shared by the tracks of each
/// region of the image (a 4 x 4 grid over the first observation): per region, AR(1) in time with
/// rho 0.98 and sd `shared_px` (a tracker's pull that neighbouring tracks feel alike). Each trial's
/// tracks (10 x 10 a face) are made once and estimated with every grid of `spatial_grids`.
struct RegionCheck {
  double mean_z2 = 0, mean_factor = 0;
  int inside = 0;
};
std::vector<RegionCheck> regionCheck(double shared_px, const std::vector<int>& spatial_grids, int trials) {
  const render::Regime* rg = render::builtinRegimeSuite().find("box-orbit");
  EXPECT_NE(rg, nullptr);
  std::vector<RegionCheck> c(spatial_grids.size());
  if (!rg) return c;
  render::RenderOptions ro = rg->options;
  ro.frames = 100;
  for (int t = 0; t < trials; ++t) {
    RegimeTracks s = regimeTracks(ro, 0.2, 60 + t, 0.0, 10);
    std::mt19937_64 rng(90 + t);
    std::normal_distribution<double> g(0.0, 1.0);
    const double rho = 0.98;
    std::vector<Eigen::Vector2d> e(16, Eigen::Vector2d::Zero());
    for (auto& v : e) v = shared_px * Eigen::Vector2d(g(rng), g(rng));
    std::vector<int> region(static_cast<size_t>(s.tracks.idBound()), -1);
    for (int k = 0; k < s.tracks.numFrames(); ++k) {
      if (k > 0)
        for (auto& v : e) v = rho * v + std::sqrt(1 - rho * rho) * shared_px * Eigen::Vector2d(g(rng), g(rng));
      for (TrackPoint& p : s.tracks.frames[k]) {
        int& r = region[static_cast<size_t>(p.id)];
        if (r < 0)
          r = std::clamp(static_cast<int>(4 * p.px.x() / ro.width), 0, 3) + 4 * std::clamp(static_cast<int>(4 * p.px.y() / ro.height), 0, 3);
        p.px += e[static_cast<size_t>(r)];
      }
    }
    for (size_t i = 0; i < spatial_grids.size(); ++i) {
      EstimateOptions o;
      o.refine.spatial_grid = spatial_grids[i];
      const EstimateResult r = estimate(s.tracks, o);
      EXPECT_TRUE(r.refined.ok) << r.refined.message;
      if (!r.refined.ok) continue;
      const TrackFrame& last = r.refined.state.frames.back();
      const double f = r.refined.state.scale_px / last.beta;
      const double sd = r.refined.state.scale_px * std::sqrt(last.var_beta) / (last.beta * last.beta);
      const double z = (f - *s.truth.focal_px) / sd;
      c[i].mean_z2 += z * z / trials;
      c[i].inside += std::abs(z) <= 1.96;
      c[i].mean_factor += r.refined.clustered_focal_factor / trials;
    }
  }
  for (size_t i = 0; i < spatial_grids.size(); ++i)
    std::printf("shared %.2f px, regions %d: focal inside its 95 %% interval %d of %d, mean z^2 %.2f, sd factor %.2f\n",
                shared_px, spatial_grids[i], c[i].inside, trials, c[i].mean_z2, c[i].mean_factor);
  return c;
}

TEST(Refine, TheRegionsCheckWidensForErrorsSharedByNeighbouringTracks) {
  // Errors shared by a region's tracks are independent between regions, not between tracks: the
  // bound and the tracks' sandwich take each track as independent evidence and are too narrow;
  // the regions' sandwich (RefineOptions::spatial_grid) sees it. Measured (5 trials, 10 x 10
  // tracks a face): tracks only 0/5 inside, mean z^2 16.0, sd factor 1.25; with the regions 3/5,
  // 4.6, 2.46 (12 x 12 a face: 0/5, 26.8, 1.23 and 2/5, 7.1, 2.73, at 3x the cost). Not all of it:
  // 16 shared errors drifting over 100 frames are few independent draws, and a sandwich over a
  // grid that does not follow the error's regions sees part of them (docs/estimate.md section 4).
  const std::vector<RegionCheck> c = regionCheck(0.15, {0, 3}, 5);
  const RegionCheck& tracks_only = c[0];
  const RegionCheck& regions = c[1];
  EXPECT_GT(regions.mean_factor, 1.5 * tracks_only.mean_factor);
  EXPECT_LT(regions.mean_z2, 0.5 * tracks_only.mean_z2);
  EXPECT_GE(regions.inside, tracks_only.inside);
}

TEST(Refine, APrincipalPointTheDataDoNotDetermineIsHeldAtTheCentre) {
  // The cube scene turned 15 deg about a vertical axis (50 frames of 0.3 deg), 0.5 px noise, the
  // principal point at the image centre: its y is not placed within 1 % of the image (sd 15 px,
  // x 3.7 px). Held, it sits exactly at the nominal centre, still with a variance in the bound
  // (its prior's, narrowed by what the data say), so the focal length's sd is no smaller than
  // with the principal point given; not held, it stays where the solver stopped.
  const Synthetic s = makeTracks(100, 0.5, Eigen::Vector2d::Zero(), 0.0, 0.0, 50, 0.3);
  EstimateOptions o;
  o.refine.estimate_distortion = false;
  o.homography_start = false;
  o.filter.focal0_px = 0.8 * s.focal;
  auto focalSd = [](const EstimateResult& r) {
    const TrackFrame& last = r.refined.state.frames.back();
    return r.refined.state.scale_px * std::sqrt(last.var_beta) / (last.beta * last.beta);
  };
  const double sc = 256.0;  // s = max(width, height) / 2
  const EstimateResult held = estimate(s.tracks, o);
  ASSERT_TRUE(held.refined.ok) << held.refined.message;
  const Eigen::Vector2d centre(s.tracks.image.cx, s.tracks.image.cy);
  EXPECT_FALSE(held.refined.camera_free[0] || held.refined.camera_free[1]);
  EXPECT_EQ(held.refined.principal_point_px, centre);
  EXPECT_NE(held.refined.why.find("held at"), std::string::npos) << held.refined.why;
  const double sd_y = sc * std::sqrt(held.refined.cov_camera(1, 1));
  EXPECT_GT(sd_y, 0.01 * 512);                   // not determined ...
  EXPECT_LE(sd_y, 0.03 * 512 * (1 + 1e-9));      // ... and no wider than its prior
  // The bound's own ordering (the sandwiches' widening, estimated from the data on different
  // parameter sets, is left out: with it the two came out 18.16 and 18.30 px).
  EstimateOptions bound_only = o;
  bound_only.refine.track_clustered_sd = false;
  const EstimateResult held_bound = estimate(s.tracks, bound_only);
  EstimateOptions given = bound_only;
  given.principal_point = centre;
  const EstimateResult known = estimate(s.tracks, given);
  ASSERT_TRUE(known.refined.ok) << known.refined.message;
  ASSERT_TRUE(held_bound.refined.ok) << held_bound.refined.message;
  std::printf("focal sd (bound): principal point held %.3f px, given %.3f px; held y sd %.1f px\n", focalSd(held_bound),
              focalSd(known), sd_y);
  EXPECT_GE(focalSd(held_bound), focalSd(known));
  EstimateOptions free = o;
  free.refine.hold_undetermined_principal_point = false;
  const EstimateResult moved = estimate(s.tracks, free);
  ASSERT_TRUE(moved.refined.ok) << moved.refined.message;
  EXPECT_TRUE(moved.refined.camera_free[0]);
  EXPECT_FALSE(moved.refined.camera_determined[0] && moved.refined.camera_determined[1]);
  EXPECT_GT((moved.refined.principal_point_px - centre).norm(), 0.1);
  // With the distortion estimated too (the default), the point is judged after the distortion's
  // own solve (stage 2 of docs/estimate.md section 4 is then that solve, and its bound the final
  // one) and held the same way, at the same focal sd as without the distortion to within its
  // own contribution.
  EstimateOptions with_k = o;
  with_k.refine.estimate_distortion = true;
  const EstimateResult hk = estimate(s.tracks, with_k);
  ASSERT_TRUE(hk.refined.ok) << hk.refined.message;
  std::printf("with the distortion estimated: k1 %.4f, focal %.2f px (truth %.1f), sd %.3f px; %s\n", hk.refined.camera[2],
              hk.refined.state.scale_px / hk.refined.state.frames.back().beta, s.focal, focalSd(hk), hk.refined.why.c_str());
  EXPECT_FALSE(hk.refined.camera_free[0] || hk.refined.camera_free[1]);
  EXPECT_TRUE(hk.refined.camera_free[2]);
  EXPECT_EQ(hk.refined.principal_point_px, centre);
  EXPECT_NE(hk.refined.why.find("held at"), std::string::npos) << hk.refined.why;
  EXPECT_GE(focalSd(hk), focalSd(held) * (1 - 1e-6));
}

TEST(Refine, PureRotationDeterminesNoPlane) {
  // The cube's tracks turned about the centre of projection: every frame is a homography K R K^-1
  // of the first (the scene's rotations, no translation).
  Synthetic s = makeTracks(7, 0.0, Eigen::Vector2d::Zero(), 0.0, 0.0, 60);
  const double c0 = 255.5;
  const std::vector<TrackPoint> first = s.tracks.frames[0];
  std::mt19937_64 rng(70);
  std::normal_distribution<double> g(0.0, 0.3);
  for (int k = 0; k < static_cast<int>(s.tracks.frames.size()); ++k)
    for (auto& p : s.tracks.frames[k]) {
      const Eigen::Vector2d x0 = (first[p.id].px - Eigen::Vector2d(c0, c0)) / s.focal;
      const Eigen::Vector3d w = s.scene.R[k] * Eigen::Vector3d(x0.x(), x0.y(), 1.0);
      p.px = Eigen::Vector2d(w.x() / w.z(), w.y() / w.z()) * s.focal + Eigen::Vector2d(c0, c0) + Eigen::Vector2d(g(rng), g(rng));
    }
  EstimateOptions o;
  o.finder.reject_static = false;
  const EstimateResult r = estimate(s.tracks, o);
  ASSERT_TRUE(r.refined.ok) << r.refined.message;
  EXPECT_FALSE(r.refined.translation_significant) << r.refined.why;
  for (bool d : r.refined.plane_determined) EXPECT_FALSE(d);
  EXPECT_NE(r.refined.why.find("only turns"), std::string::npos) << r.refined.why;
}

TEST(Refine, PureTranslationDeterminesNeitherFocalLengthNorTilt) {
  Synthetic s = makeTracks(9, 0.0, Eigen::Vector2d::Zero(), 0.0, 0.0, 60);
  // Every frame translated sideways and forward, no rotation: project the scene's 3-D points.
  const double c0 = 255.5;
  std::mt19937_64 rng(90);
  std::normal_distribution<double> g(0.0, 0.3);
  for (int k = 0; k < static_cast<int>(s.tracks.frames.size()); ++k)
    for (auto& p : s.tracks.frames[k]) {
      const Eigen::Vector3d X = s.scene.points[p.id] + Eigen::Vector3d(0, 0, 1.0);  // COP-centred (beta = 1)
      const Eigen::Vector3d Y = X - Eigen::Vector3d(0.02 * k, 0.005 * k, -0.01 * k);
      p.px = Eigen::Vector2d(Y.x() / Y.z(), Y.y() / Y.z()) * s.focal + Eigen::Vector2d(c0, c0) + Eigen::Vector2d(g(rng), g(rng));
    }
  const EstimateResult r = estimate(s.tracks, EstimateOptions{});
  ASSERT_TRUE(r.refined.ok) << r.refined.message;
  EXPECT_FALSE(r.refined.focal_determined);
  ASSERT_TRUE(r.refined.focal_interval_px.has_value());
  EXPECT_LE((*r.refined.focal_interval_px)[0], s.focal);
  EXPECT_GE((*r.refined.focal_interval_px)[1], s.focal);
  // Nothing rotates: no focal length is excluded, not even beyond the 0.3-3 x range the profile
  // searches (tele-translate: 2500 px on a 640 px image).
  EXPECT_EQ((*r.refined.focal_interval_px)[0], 0.0);
  EXPECT_TRUE(std::isinf((*r.refined.focal_interval_px)[1]));
  for (bool d : r.refined.plane_determined) EXPECT_FALSE(d);
  EXPECT_NE(r.refined.why.find("only translates"), std::string::npos) << r.refined.why;
  // The focal length's valley is flat: the last solve stops at its iteration limit, and says so.
  EXPECT_TRUE(r.refined.at_iteration_limit);
  EXPECT_NE(r.refined.why.find("stopped at its iteration limit"), std::string::npos) << r.refined.why;
}

TEST(Refine, AnUndeterminedFocalLengthGetsItsProfileInterval) {
  // A short, slow turn (20 frames, 0.1 deg per frame, 1 px noise): the focal length's sd is far
  // beyond the 5 % limit, and the optimum the refinement reaches can be a local one (seed 32:
  // 152 px, truth 512 px; its linear interval 154-429 px excluded the truth). The reported
  // interval (docs/estimate.md, section 4: widened by the focal length's profile, the whole
  // range when the profile finds a better fit) holds the truth on every seed. Seed 31's optimum
  // (with the filter's measurement sd at the measured 1.01 px) is at beta -0.042, a focal length
  // of -6052 px: not determined, whatever its relative sd reads (it read "determined" before
  // the refinement checked beta's sign).
  int local = 0;
  for (unsigned seed : {31u, 32u, 33u, 35u}) {
    Synthetic s = makeTracks(seed, 1.0, Eigen::Vector2d::Zero(), 0.0, 0.0, 20, 0.1);
    const EstimateResult r = estimate(s.tracks, EstimateOptions{});
    ASSERT_TRUE(r.refined.ok) << r.refined.message;
    EXPECT_FALSE(r.refined.focal_determined) << "seed " << seed;
    ASSERT_TRUE(r.refined.focal_interval_px.has_value()) << "seed " << seed;
    EXPECT_LE((*r.refined.focal_interval_px)[0], s.focal) << "seed " << seed << ": " << r.refined.why;
    EXPECT_GE((*r.refined.focal_interval_px)[1], s.focal) << "seed " << seed << ": " << r.refined.why;
    local += r.refined.why.find("local optimum") != std::string::npos;
  }
  // Seed 32's optimum was the local one until the plane finder's cuts (2026-12-07: its tracks
  // changed by a few); seed 35's is now (seed 36 finds no moving plane at all).
  EXPECT_GE(local, 1) << "the profile finds a local optimum (seed 35)";
}

}  // namespace
}  // namespace rsfm

namespace rsfm {
namespace {

/// The pipeline up to the filter (no refinement), for a refine() call of the test's own.
EstimateResult filterOnly(const Synthetic& s) {
  EstimateOptions o;
  o.refine.enabled = false;
  return estimate(s.tracks, o);
}

// A long refinement says what it is solving (RefineOptions::progress_seconds; the 1200-frame
// orbit's took 15-30 s in silence): every solve's iterations, the profile's too; the result does
// not depend on whether anyone listens.
TEST(Refine, SaysWhatItSolvesAsItGoes) {
  const Synthetic s = makeTracks(31, 1.0, Eigen::Vector2d::Zero(), 0.0, 0.0, 20, 0.1);  // a slow turn: the profile runs
  const EstimateResult r = filterOnly(s);
  ASSERT_TRUE(r.online.ok());
  RefineOptions ro;
  ro.progress_seconds = 0;
  std::vector<std::string> lines;
  const RefineResult heard = refine(s.tracks, r.planes.labels, r.online, r.filter_used, ro,
                                    [&](const std::string& m) { lines.push_back(m); });
  const RefineResult silent = refine(s.tracks, r.planes.labels, r.online, r.filter_used, ro);
  ASSERT_TRUE(heard.ok) << heard.message;
  ASSERT_FALSE(lines.empty());
  EXPECT_NE(lines.front().find("the camera held: iteration"), std::string::npos) << lines.front();
  bool profile = false;
  for (const std::string& l : lines) {
    EXPECT_EQ(l.rfind("refine: ", 0), 0u) << l;
    EXPECT_NE(l.find(" s so far; "), std::string::npos) << l;
    profile = profile || l.find("the focal length's profile at ") != std::string::npos;
  }
  EXPECT_TRUE(profile) << "the profile's solves are reported too";
  EXPECT_GE(static_cast<int>(lines.size()), heard.iterations);  // every iteration, iteration 0 included
  EXPECT_EQ(heard.iterations, silent.iterations);
  EXPECT_EQ(heard.state.frames.back().beta, silent.state.frames.back().beta);
  EXPECT_EQ(heard.why, silent.why);
}

TEST(Refine, AFailedRefinementKeepsTheOnlineEstimateAndSaysWhy) {
  const Synthetic s = makeTracks(11, 0.3, Eigen::Vector2d::Zero(), 0.0, 0.0, 30);
  EstimateResult r = filterOnly(s);
  ASSERT_TRUE(r.online.ok());
  // An online estimate that predicts nothing (non-finite focal length): no start to refine from.
  TrackFilterResult broken = r.online;
  for (auto& f : broken.frames) f.beta = std::nan("");
  const RefineResult f = refine(s.tracks, r.planes.labels, broken, r.filter_used);
  EXPECT_FALSE(f.ok);
  EXPECT_NE(f.message.find("cannot predict"), std::string::npos) << f.message;
  // Through the pipeline, a refinement that does not succeed leaves the filter's result as the main one.
  r.refined = f;
  EXPECT_EQ(&r.main(), &r.online);
  EXPECT_EQ(&r.labels(), &r.planes.labels);
}

TEST(Refine, APlaneLeftWithThreeTracksIsNotDetermined) {
  // The cube scene's three faces; the last face keeps three of its tracks (the others marked
  // outliers, as the finder's or the refinement's relabelling can leave a plane). Each of the
  // three alone decides one direction of that plane (the planes' jackknife: a leverage of 1), so
  // nothing tests it: it is reported not determined, and why, whatever its bound's sd; the other
  // faces stay determined. With two tracks left the reason says so (it was "in the null space
  // (e.g. pure rotation)").
  const Synthetic s = makeTracks(11, 0.3, Eigen::Vector2d::Zero(), 0.0, 0.0, 60);
  const EstimateResult r = filterOnly(s);
  ASSERT_TRUE(r.online.ok());
  ASSERT_EQ(r.online.planes, 3);
  const int L = *std::max_element(r.planes.labels.begin(), r.planes.labels.end());
  ASSERT_GE(L, 0);
  const int j = r.online.plane_of_label[L];
  ASSERT_NE(j, 0);  // not the gauge plane (its two free components)
  // The finder's labels with plane L cut to its first n tracks (the rest outliers); its tracks before.
  auto cutTo = [&](int n, int* had) {
    std::vector<int> labels = r.planes.labels;
    *had = 0;
    for (int& l : labels)
      if (l == L && ++*had > n) l = -1;
    return labels;
  };
  int had = 0;
  const RefineResult f = refine(s.tracks, cutTo(3, &had), r.online, r.filter_used);
  ASSERT_GT(had, 3);
  ASSERT_TRUE(f.ok) << f.message;
  ASSERT_EQ(f.plane_determined.size(), 3u);
  ASSERT_EQ(f.jackknife_plane_factor.size(), 3u);
  std::printf("three tracks left on plane %d: %s\n", j, f.why.c_str());
  EXPECT_FALSE(f.plane_determined[j]);
  EXPECT_TRUE(std::isinf(f.jackknife_plane_factor[j]));
  EXPECT_NE(f.why.find(fmt::format("plane {}: one of its tracks alone decides its normal", j)), std::string::npos) << f.why;
  for (int i = 0; i < 3; ++i)
    if (i != j) {
      EXPECT_TRUE(f.plane_determined[i]) << i;
      EXPECT_TRUE(std::isfinite(f.jackknife_plane_factor[i])) << i;
    }
  // Two tracks: the plane is in the bound's null space, and the reason names the tracks left.
  const RefineResult f2 = refine(s.tracks, cutTo(2, &had), r.online, r.filter_used);
  ASSERT_TRUE(f2.ok) << f2.message;
  std::printf("two tracks left on plane %d: %s\n", j, f2.why.c_str());
  EXPECT_FALSE(f2.plane_determined[j]);
  EXPECT_NE(f2.why.find(fmt::format("plane {}: 2 of its tracks left (too few to place it)", j)), std::string::npos) << f2.why;
}

// PlaneModel::horizonDistance, the refinement's test for a reference at its plane's horizon
// (pipeline/refine.cpp; docs/estimate.md section 4, "Planes seen edge-on from the reference
// frame"): the distance to the line where the reference rays run parallel to the plane. At the
// foot of the perpendicular the ray is singular; along the normal to the line the distance grows
// linearly and the point's depth as 1 / the distance; a plane parallel to the image has none.
TEST(Refine, TheHorizonDistanceIsTheDistanceToTheLineWhereRaysRunParallelToThePlane) {
  const double beta = 0.8;
  const Eigen::Vector3d N(0.9, -0.4, 0.35);
  const Eigen::Vector2d uv(0.21, 0.13);
  const double d = PlaneModel::horizonDistance(N, beta, uv);
  ASSERT_GT(d, 0.05);
  // The foot of the perpendicular on the line beta N_xy . uv + N_z = 0.
  const Eigen::Vector2d dir = N.head<2>().normalized();
  const double side = beta * N.head<2>().dot(uv) + N.z() > 0 ? 1.0 : -1.0;
  const Eigen::Vector2d foot = uv - side * d * dir;
  EXPECT_NEAR(beta * N.head<2>().dot(foot) + N.z(), 0.0, 1e-12);
  EXPECT_EQ(PlaneModel::checkRay(N, beta, foot), MeasureStatus::HorizonSingular);
  // Moving along the line leaves the distance; across it, it changes linearly.
  const Eigen::Vector2d along(-dir.y(), dir.x());
  EXPECT_NEAR(PlaneModel::horizonDistance(N, beta, uv + 0.3 * along), d, 1e-12);
  EXPECT_NEAR(PlaneModel::horizonDistance(N, beta, foot + side * 0.25 * d * dir), 0.25 * d, 1e-12);
  // Depth from the centre of projection along the ray grows as 1 / the distance.
  auto depth = [&](double e) {
    Eigen::Vector3d p;
    const Eigen::Vector2d at = foot + side * e * dir;
    EXPECT_EQ(PlaneModel::point(N, beta, at, &p, nullptr, nullptr), MeasureStatus::Ok);
    return 1.0 + beta * p.z();
  };
  EXPECT_NEAR(depth(1e-2) / depth(2e-2), 2.0, 0.05);
  EXPECT_NEAR(depth(2e-2) / depth(4e-2), 2.0, 0.1);  // (below a grazing sine of 1e-3 the ray is singular)
  EXPECT_TRUE(std::isinf(PlaneModel::horizonDistance(Eigen::Vector3d(0, 0, 0.5), beta, uv)));
}

}  // namespace
}  // namespace rsfm
