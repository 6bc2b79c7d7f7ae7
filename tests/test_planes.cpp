// Box scene geometry and the multi-plane experiment's plumbing (issue 3, in progress).
#include <gtest/gtest.h>

#include "rsfm/experiment/planes.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/sim/box_scene.hpp"

namespace rsfm {
namespace {

TEST(BoxScene, ThreeOrthogonalFacesWithVisiblePointsOnTheirPlanes) {
  BoxSceneOptions o;
  std::mt19937_64 rng(5);
  const BoxScene s = makeBoxScene(o, rng);
  ASSERT_EQ(s.faces(), 3);
  ASSERT_EQ(s.points.size(), 90u);
  for (int a = 0; a < 3; ++a)
    for (int b = a + 1; b < 3; ++b) EXPECT_NEAR(s.normals[a].dot(s.normals[b]), 0.0, 1e-12);
  for (int j = 0; j < 3; ++j) {
    EXPECT_LT(normalAngle(s.planes[j], s.normals[j]), 1e-12);
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
  EXPECT_TRUE(validatePlanesOptions(PlanesOptions{}).empty());
}

}  // namespace
}  // namespace rsfm
