// Evaluation maths: Umeyama Sim(3), ATE, RPE, plane matching (rsfm_eval, Eigen only).
#include <gtest/gtest.h>

#include <random>

#include "rsfm/eval/trajectory_metrics.hpp"
#include "rsfm/report/evaluation.hpp"

namespace rsfm::eval {
namespace {

Eigen::Matrix3d rot(double deg, const Eigen::Vector3d& axis) {
  return Eigen::AngleAxisd(deg * M_PI / 180.0, axis.normalized()).toRotationMatrix();
}

TEST(Umeyama, RecoversAKnownSim3) {
  std::mt19937 rng(7);
  std::normal_distribution<double> n(0, 1);
  Sim3 T;
  T.s = 2.5;
  T.R = rot(73, {0.3, -1, 0.4});
  T.t = {1.5, -0.2, 3.0};
  std::vector<Eigen::Vector3d> src, dst;
  for (int i = 0; i < 40; ++i) {
    src.emplace_back(n(rng), n(rng), n(rng));
    dst.push_back(T.apply(src.back()));
  }
  const UmeyamaResult r = umeyama(src, dst);
  ASSERT_TRUE(r.ok);
  EXPECT_NEAR(r.T.s, T.s, 1e-9);
  EXPECT_LT((r.T.R - T.R).norm(), 1e-9);
  EXPECT_LT((r.T.t - T.t).norm(), 1e-9);
  EXPECT_NEAR(r.T.R.determinant(), 1.0, 1e-12);
  // Without scale: s = 1 and the rotation is still found.
  const UmeyamaResult r1 = umeyama(src, dst, false);
  EXPECT_EQ(r1.T.s, 1.0);
  EXPECT_LT((r1.T.R - T.R).norm(), 1e-9);
}

TEST(Umeyama, ReflectionIsNotAllowed) {
  // dst is a mirror image of src: the best proper rotation, never det = -1.
  std::vector<Eigen::Vector3d> src{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}}, dst;
  for (const auto& p : src) dst.emplace_back(-p.x(), p.y(), p.z());
  const UmeyamaResult r = umeyama(src, dst);
  EXPECT_NEAR(r.T.R.determinant(), 1.0, 1e-12);
}

TEST(Umeyama, DegenerateInputIsReported) {
  std::vector<Eigen::Vector3d> same(5, Eigen::Vector3d(1, 2, 3));
  EXPECT_FALSE(umeyama(same, same).ok);
  EXPECT_FALSE(umeyama({Eigen::Vector3d::Zero()}, {Eigen::Vector3d::Zero()}).ok);
}

std::vector<Pose> orbit(int n) {
  std::vector<Pose> v;
  for (int k = 0; k < n; ++k) {
    Pose p;
    p.R = rot(2.0 * k, {0.1, 1, 0.2});
    p.p = Eigen::Vector3d(std::sin(0.1 * k), 0.05 * k, 1 - std::cos(0.1 * k));
    v.push_back(p);
  }
  return v;
}

TEST(Ate, ZeroOnIdenticalAndOnSimilarTrajectories) {
  const auto truth = orbit(30);
  const AteResult a = absoluteTrajectoryError(truth, truth);
  EXPECT_LT(a.stats.max, 1e-12);
  EXPECT_NEAR(a.alignment.T.s, 1.0, 1e-12);
  // The estimate is the truth in another similarity frame: still zero after alignment.
  Sim3 T;
  T.s = 0.3;
  T.R = rot(40, {1, 1, 0});
  T.t = {4, 5, 6};
  auto est = truth;
  for (auto& p : est) {
    p.p = T.apply(p.p);
    p.R = T.R * p.R;
  }
  const AteResult b = absoluteTrajectoryError(est, truth);
  EXPECT_LT(b.stats.max, 1e-9);
  EXPECT_NEAR(b.alignment.T.s, 1.0 / 0.3, 1e-9);
  const std::vector<long long> frames = [] {
    std::vector<long long> f;
    for (int k = 0; k < 30; ++k) f.push_back(k);
    return f;
  }();
  const RpeResult r = relativePoseError(est, truth, frames, 3, b.alignment.T.s);
  EXPECT_EQ(r.pairs, 27);
  EXPECT_LT(r.translation.max, 1e-9);
  EXPECT_LT(r.rotation_deg.max, 1e-6);
}

TEST(Ate, KnownValue) {
  // Two symmetric offsets that the alignment cannot remove: +-e along z on a square in the xy plane.
  std::vector<Pose> truth(4), est(4);
  const double e = 0.1;
  const Eigen::Vector3d c[4] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  for (int i = 0; i < 4; ++i) {
    truth[i].p = c[i];
    est[i].p = c[i] + Eigen::Vector3d(0, 0, (i % 2 ? e : -e));
  }
  const AteResult a = absoluteTrajectoryError(est, truth);
  // By symmetry the best SE(3) fit is the identity (zero centroid shift, zero cross-covariance
  // between the z offsets and x, y): residual e at every corner. Sim(3) can only do better.
  const AteResult a1 = absoluteTrajectoryError(est, truth, false);
  EXPECT_NEAR(a1.stats.rmse, e, 1e-12);
  EXPECT_LE(a.stats.rmse, a1.stats.rmse + 1e-15);
}

TEST(Rpe, KnownValues) {
  // Truth: unit steps along x, no rotation. Estimate: frame 2 displaced by 0.1 along y; frame 3
  // rotated by 2 degrees about z.
  std::vector<Pose> truth(5), est(5);
  for (int k = 0; k < 5; ++k) truth[k].p = est[k].p = Eigen::Vector3d(k, 0, 0);
  est[2].p.y() = 0.1;
  est[3].R = rot(2, {0, 0, 1});
  const std::vector<long long> frames{0, 1, 2, 3, 4};
  const RpeResult r = relativePoseError(est, truth, frames, 1, 1.0);
  ASSERT_EQ(r.pairs, 4);
  // Translation errors per pair: (0,1) 0; (1,2) 0.1; (2,3) 0.1 (frame 3's rotation does not move
  // its centre seen from frame 2); (3,4) |R_z(-2 deg) e_x - e_x| = 2 sin(1 deg).
  const double e34 = 2 * std::sin(M_PI / 180.0);
  EXPECT_NEAR(r.translation.max, 0.1, 1e-12);
  EXPECT_NEAR(r.translation.rmse, std::sqrt((0.01 + 0.01 + e34 * e34) / 4), 1e-12);
  EXPECT_NEAR(r.translation.median, 0.5 * (e34 + 0.1), 1e-12);
  // Rotation errors: 2 deg on pairs (2,3) and (3,4).
  EXPECT_NEAR(r.rotation_deg.max, 2.0, 1e-9);
  EXPECT_NEAR(r.rotation_deg.mean, 1.0, 1e-9);
  // A gap in the frame numbers: only pairs exactly delta apart count.
  const std::vector<long long> gappy{0, 1, 2, 4, 5};
  EXPECT_EQ(relativePoseError(est, truth, gappy, 1, 1.0).pairs, 3);
  EXPECT_EQ(relativePoseError(est, truth, gappy, 2, 1.0).pairs, 2);  // (0,2), (2,4)
  // Scale: an estimate at half size with scale 2 has no error.
  auto half = truth;
  for (auto& p : half) p.p *= 0.5;
  EXPECT_LT(relativePoseError(half, truth, frames, 2, 2.0).translation.max, 1e-12);
  EXPECT_NEAR(relativePoseError(half, truth, frames, 1, 1.0).translation.max, 0.5, 1e-12);
}

TEST(ErrorStats, MedianOddEven) {
  EXPECT_EQ(errorStats({3, 1, 2}).median, 2);
  EXPECT_EQ(errorStats({4, 1, 2, 3}).median, 2.5);
  EXPECT_EQ(errorStats({}).n, 0);
  EXPECT_NEAR(errorStats({3, 4}).rmse, std::sqrt(12.5), 1e-15);
}

Eigen::Vector3d dirDeg(double deg) { return {std::sin(deg * M_PI / 180), 0, std::cos(deg * M_PI / 180)}; }

TEST(PlaneMatching, OneToOneMinimumTotalAngle) {
  // Truth at 0 and 30 deg; estimates at 20 and 50 deg. Greedy (closest pair first: 30-20) gives
  // 10 + 50 = 60 deg; the best one-to-one matching gives 20 + 20 = 40 deg.
  const PlaneMatch m = matchPlanes({dirDeg(0), dirDeg(30)}, {dirDeg(20), dirDeg(50)});
  EXPECT_EQ(m.estimate_of_truth, (std::vector<int>{0, 1}));
  EXPECT_NEAR(m.angle_deg[0], 20, 1e-9);
  EXPECT_NEAR(m.angle_deg[1], 20, 1e-9);
}

TEST(PlaneMatching, PermutedEstimatesAndUnmatchedPlanes) {
  const std::vector<Eigen::Vector3d> truth{Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(), Eigen::Vector3d::UnitZ()};
  const Eigen::Matrix3d small = rot(1.5, {1, 2, 3});
  // Estimates: z, x, (a spurious one), y, each rotated by 1.5 deg.
  const std::vector<Eigen::Vector3d> est{small * truth[2], small * truth[0], Eigen::Vector3d(-1, -1, -1).normalized(),
                                         small * truth[1]};
  const PlaneMatch m = matchPlanes(truth, est);
  EXPECT_EQ(m.estimate_of_truth, (std::vector<int>{1, 3, 0}));
  EXPECT_EQ(m.truth_of_estimate, (std::vector<int>{2, 0, -1, 1}));
  for (double a : m.angle_deg) EXPECT_LE(a, 1.5 + 1e-9);
  // Fewer estimates than truth planes: the worst-fitting truth plane stays unmatched.
  const PlaneMatch f = matchPlanes(truth, {small * truth[1]});
  EXPECT_EQ(f.estimate_of_truth, (std::vector<int>{-1, 0, -1}));
  EXPECT_TRUE(std::isnan(f.angle_deg[0]));
  // Opposite normals are 180 deg apart (no sign flip).
  EXPECT_NEAR(angleDeg(Eigen::Vector3d::UnitZ(), -Eigen::Vector3d::UnitZ()), 180, 1e-12);
}

TEST(PlaneMatching, ParallelPlanesAreToldApartByScaledDistance) {
  // Floor (d = 1.1) and box top (d = 0.4) share a normal. The estimate is at half scale and lists
  // them in the other order with the normals slightly off in the misleading direction.
  const Eigen::Vector3d n = Eigen::Vector3d(0, 1, 0.4).normalized();
  const Eigen::Matrix3d tilt = rot(0.5, {1, 0, 0});
  const std::vector<Eigen::Vector3d> truth{n, n};
  const std::vector<double> truth_d{1.1, 0.4};
  const std::vector<Eigen::Vector3d> est{tilt * n, tilt.transpose() * n};
  const std::vector<double> est_d{0.2, 0.55};
  const PlaneMatch m = matchPlanes(truth, truth_d, est, est_d, 2.0);
  EXPECT_EQ(m.estimate_of_truth, (std::vector<int>{1, 0}));
  EXPECT_NEAR(m.angle_deg[0], 0.5, 1e-9);
  // The assignment itself: rows to columns with the least total cost.
  const auto a = minCostAssignment({{1.0, 2.0}, {2.0, 0.5}});
  EXPECT_EQ(a, (std::vector<int>{0, 1}));
}

}  // namespace
}  // namespace rsfm::eval

// Association by timestamp (issue 16; docs/evaluate.md): nearest pairs first, one to one.
TEST(AssociateByTime, NearestPairsFirstEachPoseOnce) {
  using P = std::vector<std::pair<std::size_t, std::size_t>>;
  // The same times: every pose paired with its twin.
  EXPECT_EQ(rsfm::report::associateByTime({0.0, 1.0, 2.0}, {0.0, 1.0, 2.0}, 0.01), (P{{0, 0}, {1, 1}, {2, 2}}));
  // Truth 0.01 is 0.001 from estimate 0.009, truth 0 is 0.009 from it: the nearer pair wins, and
  // truth 0 (nothing else within 0.01) stays unpaired. Walking in time order would pair truth 0.
  EXPECT_EQ(rsfm::report::associateByTime({0.0, 0.01, 0.02}, {0.009, 0.0195}, 0.01), (P{{1, 0}, {2, 1}}));
  // Nothing within max_diff: no pair; an estimate between two truths goes to the nearer one only.
  EXPECT_TRUE(rsfm::report::associateByTime({0.0, 1.0}, {0.5}, 0.01).empty());
  EXPECT_EQ(rsfm::report::associateByTime({0.0, 1.0}, {0.6}, 0.5), (P{{1, 0}}));
  // Frame numbers (t_max_diff 0.01 frames: exact matches only), with gaps on both sides.
  EXPECT_EQ(rsfm::report::associateByTime({0, 1, 2, 5, 6}, {1, 2, 3, 6}, 0.01), (P{{1, 0}, {2, 1}, {4, 3}}));
  EXPECT_TRUE(rsfm::report::associateByTime({0, 1}, {}, 0.01).empty());
}
