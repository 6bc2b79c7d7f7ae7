// The regime suite (bench/regimes.json, docs/regimes.md): its definitions parse and cover every
// axis of issue 12; every sequence renders and its frames agree with its truth (the renderer's
// geometry against the truth's warp, within 0.1 px); the truth's determinacy answers the known
// cases (still, pure rotation, pure translation, a general orbit). Accuracy of the estimator is
// not asserted here: that is the scoreboard's job (rsfm bench regimes).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <set>

#include "rsfm/batch/plane_batch.hpp"
#include "rsfm/render/determinacy.hpp"
#include "rsfm/render/regime_suite.hpp"
#include "rsfm/render/truth_check.hpp"

namespace rsfm::render {
namespace {

TEST(RegimeSuite, BuiltInSuiteParsesAndCoversEveryAxis) {
  const RegimeSuite& s = builtinRegimeSuite();
  ASSERT_GE(s.sequences.size(), 24u);
  // Coverage from the options themselves (not from the declared axis tags).
  std::set<std::string> have;
  for (const Regime& r : s.sequences) {
    const RenderOptions& o = r.options;
    have.insert("scene:" + std::string(toString(o.scene)));
    have.insert("motion:" + std::string(toString(o.motion)));
    const double speed = o.sweepDeg() / std::max(1, o.movingFrames() - 1);
    if (o.motion == MotionKind::Orbit && speed <= 0.1 + 1e-12) have.insert("speed<=0.1");
    if (o.motion == MotionKind::Orbit && speed >= 5 - 1e-12) have.insert("speed>=5");
    if (o.frames <= 12 && speed >= 8) have.insert("short-fast");
    if (o.still_start >= 30) have.insert("still-start");
    if (o.still_middle >= 30) have.insert("still-middle");
    if (o.jitter_deg > 0) have.insert("jitter");
    if (o.focal_px <= 300) have.insert("focal<=300");
    if (o.focal_px >= 4000) have.insert("focal>=4000");
    if (o.principal_offset_px.cwiseAbs().maxCoeff() >= 0.03 * o.width) have.insert("principal-point");
    if (o.k1 <= -0.25) have.insert("k1<=-0.25");
    if (o.k1 >= 0.1) have.insert("k1>=0.1");
    if (o.k2 != 0) have.insert("k2");
    if (o.width == 384 && o.height == 288) have.insert("384x288");
    if (o.width == 1280 && o.height == 720) have.insert("1280x720");
    if (o.noise_sigma >= 5) have.insert("noise");
    if (o.blur > 0) have.insert("blur");
    if (o.readout > 0) have.insert("rolling-shutter");
    if (o.jpeg_quality > 0 && o.jpeg_quality <= 20) have.insert("compression");
    if (o.jitter_deg > 0 && o.blur > 0 && o.jpeg_quality > 0) have.insert("combination");
    EXPECT_FALSE(r.why.empty()) << r.name;
    EXPECT_FALSE(r.axes.empty()) << r.name;
  }
  for (const char* axis :
       {"scene:box", "scene:corner", "scene:poster", "scene:object", "scene:lowtex", "motion:orbit", "motion:translate",
        "motion:rotate", "motion:forward", "motion:none", "speed<=0.1", "speed>=5", "short-fast", "still-start",
        "still-middle", "jitter", "focal<=300", "focal>=4000", "principal-point", "k1<=-0.25", "k1>=0.1", "k2",
        "384x288", "1280x720", "noise", "blur", "rolling-shutter", "compression", "combination"})
    EXPECT_TRUE(have.count(axis)) << "no sequence covers " << axis;
}

TEST(RegimeSuite, RejectsMalformedSuites) {
  auto parses = [](const std::string& text) {
    try {
      parseRegimeSuite(text, "t.json");
      return std::string();
    } catch (const std::exception& e) {
      return std::string(e.what());
    }
  };
  const std::string head = R"({"format":"rsfm-regimes","version":1,"sequences":[)";
  EXPECT_EQ(parses(head + R"({"name":"a","options":{"seed":1}}]})"), "");
  EXPECT_NE(parses(head + R"({"name":"a","options":{"seed":1}},{"name":"a","options":{"seed":2}}]})").find("twice"),
            std::string::npos);
  EXPECT_NE(parses(head + R"({"name":"A b","options":{"seed":1}}]})").find("a-z"), std::string::npos);
  EXPECT_NE(parses(head + R"({"name":"a","options":{"seed":1,"still_start":200}}]})").find("moving frames"),
            std::string::npos);
  EXPECT_NE(parses(head + R"({"name":"a","options":{"seed":1,"scene":"cave"}}]})").find("scene"), std::string::npos);
  EXPECT_NE(parses(head + R"({"name":"a","options":{"seed":1,"focal_px":"long"}}]})").find("number"), std::string::npos);
  EXPECT_NE(parses(R"({"format":"rsfm-regimes","version":2,"sequences":[]})").find("version"), std::string::npos);
  // Options round-trip through their JSON form.
  for (const Regime& r : builtinRegimeSuite().sequences) EXPECT_EQ(optionsToJson(optionsFromJson(r.options_json)), r.options_json);
}

TEST(RegimeSuite, DistortionMustStayMonotonicToTheCorner) {
  EXPECT_EQ(monotonicDistortedRadius(0.1, 0.05), std::numeric_limits<double>::infinity());
  // k1 < 0, k2 = 0: the map r (1 + k1 r^2) peaks at r = 1/sqrt(-3 k1) with value 2/3 of it.
  EXPECT_NEAR(monotonicDistortedRadius(-0.25, 0), 2.0 / 3.0 / std::sqrt(0.75), 1e-12);
  RenderOptions o;
  o.k1 = -0.25;  // 640 x 480 at 520 px: the corner is at 0.769, the fold at 0.770
  EXPECT_NE(validate(o).find("fold"), std::string::npos);
  o.focal_px = 700;  // corner at 0.571
  EXPECT_EQ(validate(o), "");
}

// Every sequence of the suite renders, and its frames agree with its truth: the geometry (image
// effects off) against the truth's warp, at the first moving frame pair and half-way.
class EverySequence : public ::testing::TestWithParam<std::string> {};

TEST_P(EverySequence, RendersAndAgreesWithItsTruth) {
  const Regime* r = builtinRegimeSuite().find(GetParam());
  ASSERT_NE(r, nullptr);
  RenderOptions o = r->options;
  o.noise_sigma = 0;
  o.jpeg_quality = 0;
  o.blur = 0;
  Scene scene(o);
  const io::Summary t = scene.truth();
  ASSERT_FALSE(t.planes.empty()) << r->name;
  for (std::size_t i = 0; i < t.planes.size(); ++i) {
    EXPECT_NEAR(t.planes[i].norm(), 1.0, 1e-12);
    EXPECT_GT(t.plane_distances[i], 0);
  }
  const int a0 = o.still_start;  // the first moving pair
  const int mid = o.frames / 2;
  for (const auto& [a, b] : {std::pair{a0, a0 + 1}, std::pair{mid, std::min(mid + 1, o.frames - 1)}}) {
    const TruthCheck c = renderedAgainstWarp(scene, a, b);
    std::printf("%-18s frames %3d -> %3d: %3d corners on %d surfaces, median %.3f px, p90 %.3f px\n", r->name.c_str(), a,
                b, c.tracks, c.surfaces, c.median_px, c.p90_px);
    ASSERT_GE(c.tracks, 20) << r->name;
    EXPECT_LT(c.median_px, 0.1) << r->name << " frames " << a << " -> " << b;
  }
}

std::vector<std::string> suiteNames() {
  std::vector<std::string> n;
  for (const Regime& r : builtinRegimeSuite().sequences) n.push_back(r.name);
  return n;
}

INSTANTIATE_TEST_SUITE_P(RegimeSuite, EverySequence, ::testing::ValuesIn(suiteNames()),
                         [](const auto& info) {
                           std::string s = info.param;
                           std::replace(s.begin(), s.end(), '-', '_');
                           return s;
                         });

// The truth's determinacy on the known cases (the bound's null space, rsfm::planeBatchBound).
TEST(RegimeSuite, DeterminacyOfTheKnownCases) {
  auto analyse = [](const std::string& name, int frames) {
    RenderOptions o = builtinRegimeSuite().find(name)->options;
    o.frames = frames;
    o.still_start = std::min(o.still_start, frames / 3);
    return analyseDeterminacy(Scene(o));
  };
  const Determinacy orbit = analyse("box-orbit", 40);
  EXPECT_TRUE(orbit.summary.focal);
  EXPECT_TRUE(orbit.summary.structure);
  EXPECT_EQ(orbit.null_dim, 0);
  const Determinacy rot = analyse("box-rotate", 30);
  EXPECT_TRUE(rot.summary.focal);      // a rotating camera determines its focal length
  EXPECT_FALSE(rot.summary.structure);  // but nothing of the scene's depth
  EXPECT_GE(rot.null_dim, 1);
  const Determinacy tr = analyse("box-translate", 30);
  EXPECT_FALSE(tr.summary.focal);  // pure translation: the affine ambiguity mixes f and the tilt
  EXPECT_FALSE(tr.summary.structure);
  EXPECT_EQ(tr.null_dim, 1);
  const Determinacy still = analyse("still", 10);
  EXPECT_FALSE(still.moves);
  EXPECT_FALSE(still.summary.focal);
  EXPECT_FALSE(still.summary.structure);
}

}  // namespace
}  // namespace rsfm::render
