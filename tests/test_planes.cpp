// Box scene geometry and the multi-plane experiment's plumbing (issue 3, in progress).
#include <gtest/gtest.h>

#include <string>

#include "rsfm/experiment/planes.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/rotation.hpp"
#include "rsfm/sim/box_scene.hpp"

namespace rsfm {
namespace {

/// Checks a box scene's faces (orthogonal, on their planes, away from the origin) and points
/// (on their face, inside the image margin in every frame) and the orbit about the box centre.
void checkBoxScene(const BoxSceneOptions& o, const BoxScene& s) {
  const int m = s.faces();
  ASSERT_EQ(s.points.size(), static_cast<size_t>(o.points_per_face * m));
  for (int a = 0; a < m; ++a)
    for (int b = a + 1; b < m; ++b) EXPECT_NEAR(s.normals[a].dot(s.normals[b]), 0.0, 1e-12);
  for (int j = 0; j < m; ++j) {
    EXPECT_LT(normalAngle(s.planes[j], s.normals[j]), 1e-7);  // acos resolution near 0: ~1.5e-8
    EXPECT_LT(1.0 / s.planes[j].norm(), 10.0);
    EXPECT_GT(1.0 / s.planes[j].norm(), 0.1);  // planes well away from the image-plane origin
  }
  const double lim = o.margin * (o.image_px / 2.0) / o.scale_px;
  for (size_t i = 0; i < s.points.size(); ++i) {
    EXPECT_NEAR(s.planes[s.labels[i]].dot(s.points[i]), 1.0, 1e-12);
    for (const auto& frame : s.uv) EXPECT_LE(frame[i].cwiseAbs().maxCoeff(), lim + 1e-12);
  }
  // Truth motion: an orbit about the box centre.
  EXPECT_LT((s.R.back() * o.centre + s.t.back() - o.centre).norm(), 1e-12);
}

TEST(BoxScene, DefaultTwoOrthogonalFacesThroughTheFiftyDegreeOrbit) {
  // Default: Table 1's -0.5 deg/frame orbit (50 deg); two faces stay visible throughout.
  BoxSceneOptions o;
  std::mt19937_64 rng(5);
  const BoxScene s = makeBoxScene(o, rng);
  ASSERT_EQ(s.faces(), 2);
  checkBoxScene(o, s);
  EXPECT_NEAR(rotationAngle(s.R.back(), Eigen::Matrix3d::Identity()) * 180.0 / M_PI, 50.0, 1e-9);
}

TEST(BoxScene, ThreeOrthogonalFacesWithVisiblePointsOnTheirPlanes) {
  // The earlier scene (pitch 25 deg, 0.3 deg/frame): three faces visible throughout.
  BoxSceneOptions o;
  o.pitch_deg = 25.0;
  o.deg_per_frame = 0.3;
  std::mt19937_64 rng(5);
  const BoxScene s = makeBoxScene(o, rng);
  ASSERT_EQ(s.faces(), 3);
  checkBoxScene(o, s);
}

TEST(BoxScene, FailsClearlyWhenFacesCannotStayVisible) {
  BoxSceneOptions o;
  o.deg_per_frame = 0.55;  // the orbit turns the faces away
  std::mt19937_64 rng(1);
  EXPECT_THROW(makeBoxScene(o, rng), std::runtime_error);
}

TEST(PlanesExperiment, RowsForEveryMethodAndBatchRatio) {
  PlanesOptions o;
  o.trials = 2;
  o.noise_px = {2.0};
  o.scene.frames = 20;
  o.scene.deg_per_frame = 1.0;  // 20 deg in 20 frames
  o.threads = 2;
  const PlanesResult r = runPlanes(o);
  ASSERT_EQ(r.rows.size(), 5u);
  EXPECT_EQ(r.faces, 3);
  std::vector<std::string> methods;
  for (const auto& row : r.rows) methods.push_back(row.method);
  EXPECT_EQ(methods, (std::vector<std::string>{"point", "plane-per-face", "planes-rigid", "planes-rigid-iekf", "batch"}));
  const PlanesRow& batch = r.rows.back();
  if (batch.failed < batch.trials) {
    EXPECT_NEAR(batch.ratio_to_batch, 1.0, 1e-12);
    EXPECT_GT(batch.crb_normal_deg, 0.0);
  }
  for (const auto& row : r.rows) {
    EXPECT_EQ(row.normal_err_by_frame.size(), 21u);
    if (row.failed < row.trials) {
      EXPECT_TRUE(std::isfinite(row.rms_t)) << row.method;
      EXPECT_TRUE(std::isfinite(row.face_angle_err_deg)) << row.method;
    }
  }
}

/// A quick run of the box experiment: `trials` trials at one noise level, no batch and no
/// iterated-filter row.
PlanesOptions quickPlanes(int trials, double noise_px) {
  PlanesOptions o;
  o.trials = trials;
  o.noise_px = {noise_px};
  o.batch = false;
  o.iekf_iterations = 0;
  o.threads = 2;
  return o;
}

/// The row of `method`; a test failure (and an empty row) when there is none.
PlanesRow methodRow(const PlanesResult& r, const std::string& method) {
  for (const auto& row : r.rows)
    if (row.method == method) return row;
  ADD_FAILURE() << "no row for " << method;
  return PlanesRow{};
}

TEST(PlanesExperiment, WarmupIterationsFixTheNoiseFreeStart) {
  // Noise-free tracks (filtered assuming 0.1 px), 8 trials, seed 1: with 90 accurate points the
  // first plain EKF updates collapse P around the poor linearization at beta0 = 0.5, and the
  // rigid filter keeps that error (measured: rms_t 0.0156, normal 0.155 deg, face angle 0.274
  // deg). Iterated updates in the first 5 frames (FilterOptions::warmup_frames) remove it
  // (rms_t 0.0016, normal 0.042 deg, face angle 0.058 deg). One pass, with the former process
  // noise (1e-3, 1e-4): a second pass from the first pass's planes hides the start problem.
  PlanesOptions o = quickPlanes(8, 0.0);
  o.passes = 1;
  o.q_translation = 1e-3;
  o.q_omega = 1e-4;
  const PlanesRow plain = methodRow(runPlanes(o), "planes-rigid");
  o.warmup_frames = 5;
  const PlanesRow warm = methodRow(runPlanes(o), "planes-rigid");
  ASSERT_EQ(plain.failed, 0);
  ASSERT_EQ(warm.failed, 0);
  EXPECT_LT(warm.rms_t, 0.004);
  EXPECT_LT(warm.normal_err_deg, 0.1);
  EXPECT_LT(warm.face_angle_err_deg, 0.12);
  EXPECT_GT(plain.rms_t, 0.01);  // without the warm-up
  EXPECT_GT(plain.face_angle_err_deg, 0.2);
}

TEST(PlanesExperiment, DelayedIterationKeepsTheIteratedUpdateFromFittingNoiseInBeta) {
  // Seed 3, 2 px, 14 trials: trial 13's iterated update, iterating from frame 1, moves beta from
  // 0.5 to 0.30 in frame 1 (the plain update leaves it: dh/dbeta = 0 at zero motion) and to the
  // bound 0.1 by frame 10, where the planes flip (measured: rms_t 0.321 against the plain
  // filter's 0.040, normal 6.0 deg). With the first 10 frames updated by the plain EKF
  // (FilterOptions::iterate_after_frames, the default iekf_after) no trial diverges (measured:
  // rms_t 0.036, normal 0.90 deg, face angle 0.68 deg, beta 3.4 %).
  PlanesOptions o = quickPlanes(14, 2.0);
  o.seed = 3;
  o.iekf_iterations = 5;
  ASSERT_EQ(o.iekf_after, 10);
  const PlanesResult delayed = runPlanes(o);
  const PlanesRow plain = methodRow(delayed, "planes-rigid"), iekf = methodRow(delayed, "planes-rigid-iekf");
  EXPECT_LT(iekf.rms_t, 1.1 * plain.rms_t);
  EXPECT_LT(iekf.normal_err_deg, 1.2);
  EXPECT_LT(iekf.face_angle_err_deg, 1.0);
  EXPECT_LT(iekf.beta_err_pct, 5.0);
  o.iekf_after = 0;
  const PlanesRow from_first = methodRow(runPlanes(o), "planes-rigid-iekf");
  EXPECT_GT(from_first.rms_t, 4.0 * plain.rms_t) << "the failure the delay prevents is gone: revisit the default";
}

TEST(PlanesExperiment, ReferencePositionsInTheStateSharpenTheFaces) {
  // ReferenceModel::State (the 2N reference coordinates in the state, as the batch estimates
  // them) against the default Refine, 6 trials, seed 1, 2 px, no batch: measured face angle error
  // 0.30 vs 0.76 deg, beta 1.8 vs 2.5 %, rms_t 0.033 vs 0.035.
  PlanesOptions o = quickPlanes(6, 2.0);
  const PlanesRow refine = methodRow(runPlanes(o), "planes-rigid");
  o.reference_model = "state";
  const PlanesRow state = methodRow(runPlanes(o), "planes-rigid");
  ASSERT_EQ(refine.failed, 0);
  ASSERT_EQ(state.failed, 0);
  EXPECT_LT(state.face_angle_err_deg, 0.45);
  EXPECT_LT(state.face_angle_err_deg, 0.6 * refine.face_angle_err_deg);
  EXPECT_LT(state.beta_err_pct, 3.0);
  EXPECT_LT(state.rms_t, refine.rms_t);
}

TEST(PlanesExperiment, DefaultSceneMeetsTheTwoPixelTargetsOnAFewTrials) {
  // The 2 px targets on the default box scene (Table 1's -0.5 deg/frame orbit), 6 trials,
  // seed 1, no batch, default options (2 passes, q 3e-2 / 1e-3): face angle within 1 deg of 90,
  // beta within 5 %, and planes-rigid's rms_t below plane-per-face's.
  const PlanesResult r = runPlanes(quickPlanes(6, 2.0));
  const PlanesRow rigid = methodRow(r, "planes-rigid"), per_face = methodRow(r, "plane-per-face");
  ASSERT_EQ(rigid.failed, 0);
  EXPECT_LT(rigid.face_angle_err_deg, 1.0);
  EXPECT_LT(rigid.beta_err_pct, 5.0);
  EXPECT_LT(rigid.rms_t, per_face.rms_t);
}

TEST(PlanesExperiment, RejectsBadOptions) {
  PlanesOptions o;
  o.trials = 0;
  EXPECT_FALSE(validatePlanesOptions(o).empty());
  o = PlanesOptions{};
  o.scene.points_per_face = 3;
  EXPECT_FALSE(validatePlanesOptions(o).empty());
  o = PlanesOptions{};
  o.reference_model = "magic";
  EXPECT_FALSE(validatePlanesOptions(o).empty());
  o = PlanesOptions{};
  o.beta_min = o.beta0;
  EXPECT_FALSE(validatePlanesOptions(o).empty());
  o = PlanesOptions{};
  o.warmup_frames = -1;
  EXPECT_FALSE(validatePlanesOptions(o).empty());
  EXPECT_TRUE(validatePlanesOptions(PlanesOptions{}).empty());
}

}  // namespace
}  // namespace rsfm
