// Calway's affine-patch model ([Cal00]; docs/patches.md): both measurement functions and the
// Murray-Shapiro transition against geometry and against central differences (the shared checker),
// including near-singular cases; the exact and instantaneous forms agree to first order in the
// motion.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <memory>
#include <random>

#include "jacobian_checker.hpp"
#include "rsfm/models/patch_model.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {
namespace {

using test::expectJacobian;
using Motion = Eigen::Matrix<double, 7, 1>;

Motion motion(double tx, double ty, double tzb, double wx, double wy, double wz, double beta) {
  return (Motion() << tx, ty, tzb, wx, wy, wz, beta).finished();
}

/// Image point (A&P: u = X / (1 + beta Z)) of a 3-D point.
Eigen::Vector2d project(const Eigen::Vector3d& X, double beta) { return X.head<2>() / (1.0 + beta * X.z()); }

/// The 3-D point of plane s (current frame) seen at image point c: Z = g / (1 - beta g).
Eigen::Vector3d backProject(const Eigen::Vector3d& s, double beta, const Eigen::Vector2d& c) {
  const double Z = PatchModel::depthAt(s, beta, c);
  return {c.x() * (1.0 + beta * Z), c.y() * (1.0 + beta * Z), Z};
}

/// Image map previous -> current of plane s under motion m, through 3-D points.
Eigen::Vector2d mapThroughPoints(const Motion& m, const Eigen::Vector3d& s, const Eigen::Vector2d& c) {
  const double beta = m[6];
  const Eigen::Vector3d t(m[0], m[1], m[2] / beta);
  const Eigen::Matrix3d R = incrementalRotation(m.segment<3>(3));
  return project(t + R * backProject(s, beta, c), beta);
}

void checkMeasurementJacobians(const Motion& m, const Eigen::Vector3d& s, const Eigen::Vector2d& c,
                               const std::string& what, double tol = 1e-6) {
  for (AffineMeasurement kind : {AffineMeasurement::Exact, AffineMeasurement::Instantaneous}) {
    Vector6d z;
    PatchJacobian<6> J;
    ASSERT_EQ(PatchModel::measure(kind, m, s, c, &z, &J), MeasureStatus::Ok) << what;
    Eigen::VectorXd x(10);
    x << m, s;
    auto f = [&](const Eigen::VectorXd& xx, Eigen::VectorXd* out) {
      Vector6d zz;
      if (PatchModel::measure(kind, xx.head<7>(), xx.tail<3>(), c, &zz, nullptr) != MeasureStatus::Ok) return false;
      *out = zz;
      return true;
    };
    expectJacobian(f, x, J, tol, what + (kind == AffineMeasurement::Exact ? " (exact)" : " (instantaneous)"));
  }
  // The cumulative map carried by the exact inter-frame map (PatchCentres::State): with respect
  // to (m, s) and to the previous map w = (c, A) (which includes the exact form's dz/dc).
  Vector6d w;
  w << c, 1.05, 0.02, -0.03, 0.97;
  Vector6d w1;
  PatchJacobian<6> J;
  Eigen::Matrix<double, 6, 6> Jw;
  ASSERT_EQ(PatchModel::composeMap(m, s, w, &w1, &J, &Jw), MeasureStatus::Ok) << what;
  Eigen::VectorXd x(10);
  x << m, s;
  auto fm = [&](const Eigen::VectorXd& xx, Eigen::VectorXd* out) {
    Vector6d o;
    if (PatchModel::composeMap(xx.head<7>(), xx.tail<3>(), w, &o, nullptr, nullptr) != MeasureStatus::Ok) return false;
    *out = o;
    return true;
  };
  expectJacobian(fm, x, J, tol, what + " (map, d/d(m, s))");
  auto fw = [&](const Eigen::VectorXd& ww, Eigen::VectorXd* out) {
    Vector6d o;
    if (PatchModel::composeMap(m, s, ww, &o, nullptr, nullptr) != MeasureStatus::Ok) return false;
    *out = o;
    return true;
  };
  expectJacobian(fw, Eigen::VectorXd(w), Jw, tol, what + " (map, d/dw)");
  Vector6d z;
  ASSERT_EQ(PatchModel::exact(m, s, c, &z, nullptr), MeasureStatus::Ok);
  EXPECT_NEAR((w1.head<2>() - z.head<2>()).norm(), 0.0, 1e-15) << what;
}

void checkPropagateJacobian(const Motion& m, const Eigen::Vector3d& s, const std::string& what,
                            double tol = 1e-6) {
  Eigen::Vector3d s1;
  PatchJacobian<3> J;
  ASSERT_EQ(PatchModel::propagate(m, s, &s1, &J), MeasureStatus::Ok) << what;
  Eigen::VectorXd x(10);
  x << m, s;
  auto f = [&](const Eigen::VectorXd& xx, Eigen::VectorXd* out) {
    Eigen::Vector3d o;
    if (PatchModel::propagate(xx.head<7>(), xx.tail<3>(), &o, nullptr) != MeasureStatus::Ok) return false;
    *out = o;
    return true;
  };
  expectJacobian(f, x, J, tol, what + " (transition)");
}

const Motion kGeneric = motion(0.02, -0.015, 0.03, 0.01, -0.02, 0.015, 0.9);
const Eigen::Vector3d kS{0.3, -0.2, 0.6};
const Eigen::Vector2d kC{0.12, -0.08};

TEST(PatchModelJacobian, Generic) {
  checkMeasurementJacobians(kGeneric, kS, kC, "generic");
  checkPropagateJacobian(kGeneric, kS, "generic");
}

TEST(PatchModelJacobian, OmegaZero) {
  const Motion m = motion(0.02, -0.015, 0.03, 0.0, 0.0, 0.0, 0.9);
  checkMeasurementJacobians(m, kS, kC, "omega = 0");
  checkPropagateJacobian(m, kS, "omega = 0");
  checkMeasurementJacobians(motion(0, 0, 0, 0, 0, 0, 1.0), kS, kC, "no motion");
  checkPropagateJacobian(motion(0, 0, 0, 0, 0, 0, 1.0), kS, "no motion");
}

TEST(PatchModelJacobian, LargeOmega) {
  const Motion m = motion(0.1, 0.05, -0.08, 0.5, -0.4, 0.3, 1.2);
  checkMeasurementJacobians(m, kS, kC, "large omega");
  checkPropagateJacobian(m, kS, "large omega");
}

TEST(PatchModelJacobian, SmallBeta) {
  // beta = 0.02: a 50-unit focal length (narrow field of view); t_Z = (t_Z beta) / beta is large.
  const Motion m = motion(0.02, -0.015, 0.001, 0.01, -0.02, 0.015, 0.02);
  checkMeasurementJacobians(m, {0.3, -0.2, 5.0}, kC, "small beta");
  checkPropagateJacobian(m, {0.3, -0.2, 5.0}, "small beta");
}

TEST(PatchModelJacobian, NearHorizonAndFarAway) {
  // 1 - beta g = 0.01: the patch centre is ~100 focal lengths away (g close to 1/beta).
  const double beta = 1.0;
  const Eigen::Vector2d c(0.1, 0.05);
  const Eigen::Vector3d s(0.2, 0.1, 0.99 + 0.2 * 0.1 + 0.1 * 0.05);
  ASSERT_NEAR(1.0 - beta * (s[2] - s[0] * c.x() - s[1] * c.y()), 0.01, 1e-12);
  const Motion m = motion(0.002, -0.001, 0.001, 0.001, -0.002, 0.001, beta);
  checkMeasurementJacobians(m, s, c, "far patch", 1e-5);
  checkPropagateJacobian(m, s, "far patch", 1e-5);
  // A plane seen nearly edge-on: large p1 (sigma = n_3 + beta d small relative to n_1).
  const Eigen::Vector3d grazing(20.0, 0.0, 2.1);
  checkMeasurementJacobians(m, grazing, c, "grazing plane", 1e-5);
  checkPropagateJacobian(m, grazing, "grazing plane", 1e-5);
}

TEST(PatchModelJacobian, PlaneNearlyThroughOrigin) {
  // d ~ 0: the plane passes (nearly) through the image-plane origin, p4 ~ 0. The normalized
  // parameters have no singularity there (unlike N . X = 1 of the plane model).
  const Eigen::Vector3d s(0.4, -0.3, 1e-9);
  checkMeasurementJacobians(kGeneric, s, kC, "plane through origin");
  checkPropagateJacobian(kGeneric, s, "plane through origin");
}

TEST(PatchModel, ExactMeasurementMatchesPointGeometry) {
  // h is where the centre's 3-D point goes; A is the derivative of the point map (central
  // differences through 3-D points, independent of the homography algebra).
  for (const Motion& m : {kGeneric, motion(0.1, 0.05, -0.08, 0.5, -0.4, 0.3, 1.2)}) {
    Vector6d z;
    ASSERT_EQ(PatchModel::exact(m, kS, kC, &z, nullptr), MeasureStatus::Ok);
    const Eigen::Vector2d h = mapThroughPoints(m, kS, kC);
    EXPECT_NEAR((z.head<2>() - h).norm(), 0.0, 1e-12);
    const double e = 1e-6;
    for (int j = 0; j < 2; ++j) {
      const Eigen::Vector2d d = Eigen::Vector2d::Unit(j) * e;
      const Eigen::Vector2d col = (mapThroughPoints(m, kS, kC + d) - mapThroughPoints(m, kS, kC - d)) / (2 * e);
      EXPECT_NEAR(z[2 + j], col.x(), 1e-8);
      EXPECT_NEAR(z[4 + j], col.y(), 1e-8);
    }
  }
}

TEST(PatchModel, ExactAndInstantaneousAgreeToFirstOrder) {
  // Motion scaled by eps: the flows (z - (c, I)) agree to O(eps^2), so their difference shrinks
  // four times when eps halves, and relative to the flow it vanishes with eps.
  const Motion unit = motion(0.4, -0.3, 0.5, 0.2, -0.3, 0.25, 0.9);
  const Vector6d base = (Vector6d() << kC, 1, 0, 0, 1).finished();
  double prev = -1.0;
  for (double eps : {1e-2, 5e-3, 2.5e-3, 1.25e-3}) {
    Motion m = unit;
    m.head<6>() *= eps;
    Vector6d ze, zi;
    ASSERT_EQ(PatchModel::exact(m, kS, kC, &ze, nullptr), MeasureStatus::Ok);
    ASSERT_EQ(PatchModel::instantaneous(m, kS, kC, &zi, nullptr), MeasureStatus::Ok);
    const double diff = (ze - zi).norm(), flow = (ze - base).norm();
    EXPECT_LT(diff, 0.02 * flow * (eps / 1e-2)) << "eps " << eps;
    if (prev > 0) {
      EXPECT_NEAR(prev / diff, 4.0, 0.3) << "eps " << eps;
    }
    prev = diff;
  }
  // And their Jacobians coincide at zero motion.
  PatchJacobian<6> Je, Ji;
  const Motion still = motion(0, 0, 0, 0, 0, 0, 0.9);
  ASSERT_EQ(PatchModel::exact(still, kS, kC, nullptr, &Je), MeasureStatus::Ok);
  ASSERT_EQ(PatchModel::instantaneous(still, kS, kC, nullptr, &Ji), MeasureStatus::Ok);
  EXPECT_LT((Je - Ji).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(PatchModel, TransitionCarriesThePlaneWithTheCamera) {
  // Points of the patch plane, moved by the motion, lie on the propagated plane.
  const Motion m = motion(0.1, 0.05, -0.08, 0.2, -0.15, 0.1, 1.1);
  Eigen::Vector3d s1;
  ASSERT_EQ(PatchModel::propagate(m, kS, &s1, nullptr), MeasureStatus::Ok);
  const double beta = m[6];
  const Eigen::Vector3d t(m[0], m[1], m[2] / beta);
  const Eigen::Matrix3d R = incrementalRotation(m.segment<3>(3));
  for (const Eigen::Vector2d& c : {Eigen::Vector2d(0.1, 0.2), Eigen::Vector2d(-0.3, 0.05), Eigen::Vector2d(0, 0)}) {
    const Eigen::Vector3d X1 = t + R * backProject(kS, beta, c);
    const Eigen::Vector2d c1 = project(X1, beta);
    EXPECT_NEAR(PatchModel::depthAt(s1, beta, c1), X1.z(), 1e-12);
  }
  // Normal: n' = R n.
  EXPECT_LT((PatchModel::normal(s1, beta) - R * PatchModel::normal(kS, beta)).norm(), 1e-12);
}

Eigen::VectorXd threePatchState() {
  Eigen::VectorXd x(16);
  x << kGeneric, kS, 0.1, 0.05, 0.8, -0.2, 0.3, 0.4;
  return x;
}

TEST(PatchModel, RegaugeLeavesEveryMeasurementUnchanged) {
  // Rescaling the scene about the centre of projection (with the translation) changes no image.
  const Eigen::VectorXd x = threePatchState();
  Eigen::VectorXd y;
  const double lambda = PatchModel::regauge(x, 1, 0.65, &y, nullptr);
  ASSERT_GT(lambda, 0.0);
  EXPECT_NE(lambda, 1.0);
  EXPECT_DOUBLE_EQ(y[PatchModel::p4Index(1)], 0.65);
  const std::vector<Eigen::Vector2d> cs{kC, {-0.2, 0.1}, {0.05, 0.3}};
  // (The instantaneous form is first order in a translation taken about the image-plane origin,
  // so it is invariant only to first order; the exact form is invariant.)
  for (int k = 0; k < 3; ++k) {
    Vector6d z0, z1;
    ASSERT_EQ(PatchModel::exact(x.head<7>(), x.segment<3>(7 + 3 * k), cs[k], &z0, nullptr), MeasureStatus::Ok);
    ASSERT_EQ(PatchModel::exact(y.head<7>(), y.segment<3>(7 + 3 * k), cs[k], &z1, nullptr), MeasureStatus::Ok);
    EXPECT_LT((z0 - z1).norm(), 1e-12) << "patch " << k;
  }
  // Normals do not change; depths scale about the centre of projection: Z + 1/beta -> (Z + 1/beta) / lambda.
  for (int k = 0; k < 3; ++k) {
    EXPECT_LT((PatchModel::normal(x.segment<3>(7 + 3 * k), x[6]) - PatchModel::normal(y.segment<3>(7 + 3 * k), y[6])).norm(), 1e-12);
    const double z0 = PatchModel::depthAt(x.segment<3>(7 + 3 * k), x[6], cs[k]) + 1.0 / x[6];
    const double z1 = PatchModel::depthAt(y.segment<3>(7 + 3 * k), y[6], cs[k]) + 1.0 / y[6];
    EXPECT_NEAR(z1, z0 / lambda, 1e-12);
  }
}

TEST(PatchModelJacobian, RegaugeAndWholeTransition) {
  const Eigen::VectorXd x = threePatchState();
  for (double c : {0.65, x[PatchModel::p4Index(1)]}) {
    Eigen::VectorXd y;
    Eigen::MatrixXd G;
    ASSERT_GT(PatchModel::regauge(x, 1, c, &y, &G), 0.0);
    auto f = [&](const Eigen::VectorXd& xx, Eigen::VectorXd* out) {
      return PatchModel::regauge(xx, 1, c, out, nullptr) > 0.0;
    };
    expectJacobian(f, x, G, 1e-6, "regauge");
    EXPECT_EQ(G.row(PatchModel::p4Index(1)).norm(), 0.0);
  }
  const PatchModel model({kC, {-0.2, 0.1}, {0.05, 0.3}});
  const double c = x[PatchModel::p4Index(0)];
  Eigen::VectorXd y;
  Eigen::MatrixXd F;
  double lambda = 0;
  ASSERT_EQ(model.transition(x, 0, c, &y, &F, &lambda), MeasureStatus::Ok);
  EXPECT_NEAR(y[PatchModel::p4Index(0)], c, 1e-15);
  auto f = [&](const Eigen::VectorXd& xx, Eigen::VectorXd* out) {
    return model.transition(xx, 0, c, out, nullptr, nullptr) == MeasureStatus::Ok;
  };
  expectJacobian(f, x, F, 1e-6, "whole transition");
  Eigen::VectorXd x0 = x;
  x0.segment<3>(3).setZero();
  ASSERT_EQ(model.transition(x0, 0, c, &y, &F, &lambda), MeasureStatus::Ok);
  auto f0 = [&](const Eigen::VectorXd& xx, Eigen::VectorXd* out) {
    return model.transition(xx, 0, c, out, nullptr, nullptr) == MeasureStatus::Ok;
  };
  expectJacobian(f0, x0, F, 1e-6, "whole transition, omega = 0");
}

TEST(PatchModel, ReportsInvisiblePlanesAndBadState) {
  Vector6d z;
  // 1 - beta g <= 0: the centre is at or behind the centre of projection.
  EXPECT_EQ(PatchModel::exact(kGeneric, {0, 0, 1.0 / 0.9 + 0.1}, kC, &z, nullptr), MeasureStatus::BehindCamera);
  EXPECT_EQ(PatchModel::instantaneous(kGeneric, {0, 0, 1.0 / 0.9 + 0.1}, kC, &z, nullptr),
            MeasureStatus::BehindCamera);
  EXPECT_EQ(PatchModel::exact(motion(0, 0, 0, 0, 0, 0, -1), kS, kC, &z, nullptr), MeasureStatus::BehindCamera);
  EXPECT_EQ(PatchModel::exact(motion(0, 0, 0, 2, 0, 0, 1), kS, kC, &z, nullptr), MeasureStatus::InvalidRotation);
  EXPECT_EQ(PatchModel::exact(motion(NAN, 0, 0, 0, 0, 0, 1), kS, kC, &z, nullptr), MeasureStatus::NonFinite);
  Eigen::Vector3d s1;
  // A plane that the motion puts behind the new camera.
  EXPECT_EQ(PatchModel::propagate(motion(0, 0, -5.0, 0, 0, 0, 1.0), {0, 0, 0.5}, &s1, nullptr),
            MeasureStatus::BehindCamera);
}

}  // namespace
}  // namespace rsfm

// ---- The patch filter ----
#include "rsfm/experiment/patches.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/filters/patch_filter.hpp"

namespace rsfm {
namespace {

/// Patch filter on a sphere scene with noise rho, started at the true motion, beta and structure
/// (consistency) or at the experiment's prior (convergence).
struct SphereRun {
  double beta = 0, beta_sd = 0, nis_per_dof = 0, worst_normal_deg = 0;
};

SphereRun runSphere(std::uint64_t seed, double rho, bool from_truth, PatchFilter** keep = nullptr) {
  std::mt19937_64 rng(seed);
  const PatchScene s = makeSphereScene(SphereSceneOptions{}, rng);
  const int K = s.patches(), n = 7 + 3 * K;
  const Vector6d sd = relativeNoiseSd(s, rho);
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
  if (from_truth) x0.head<7>() = s.motion[1];
  x0[6] = from_truth ? s.beta : 0.5;
  for (int j = 0; j < 6; ++j) P0(j, j) = 1e-4;
  P0(6, 6) = 0.1;
  for (int p = 0; p < K; ++p) {
    const int i = PatchModel::structureIndex(p);
    if (from_truth) x0.segment<3>(i) = s.structure[0][p];
    else x0.segment<3>(i) << 0.0, 0.0, s.structure[0][0][2];
    P0(i, i) = P0(i + 1, i + 1) = from_truth ? 0.01 : 1.0;
    P0(i + 2, i + 2) = from_truth ? 0.001 : 0.25 * std::pow(s.structure[0][0][2], 2);
  }
  PatchFilterOptions fo;
  fo.measurement_sd = sd;
  fo.centre_sd = 0.5 * (sd[0] + sd[1]);
  fo.q_motion << 3e-7, 3e-7, 3e-7, 3e-7, 3e-7, 3e-7, 0.0;
  if (!from_truth) fo.anneal_frames = 50, fo.anneal_factor = 300;
  std::vector<Eigen::Vector2d> c0 = s.centre[0];
  std::normal_distribution<double> g(0.0, 1.0);
  for (auto& c : c0) c += Eigen::Vector2d(g(rng) * sd[0], g(rng) * sd[1]);
  auto* f = new PatchFilter(PatchModel(c0), Ekf(x0, P0, std::vector<bool>(n, false)), 0, fo);
  SphereRun r;
  double nis = 0;
  int dof = 0;
  for (int k = 1; k <= s.frames(); ++k) {
    std::vector<AffineObservation> obs(K);
    for (int p = 0; p < K; ++p) {
      obs[p].id = p;
      obs[p].z = s.affine[k][p];
      for (int j = 0; j < 6; ++j) obs[p].z[j] += g(rng) * sd[j];
    }
    const PatchFrameStats fs = f->step(obs);
    EXPECT_TRUE(fs.ok()) << "frame " << k;
    if (k > s.frames() / 2) nis += fs.update.nis, dof += fs.update.nis_dof;
  }
  r.beta = f->beta();
  r.beta_sd = std::sqrt(f->ekf().P()(6, 6));
  r.nis_per_dof = nis / std::max(1, dof);
  for (int p = 0; p < K; ++p)
    r.worst_normal_deg = std::max(r.worst_normal_deg, normalAngle(f->normal(p), s.normal[s.frames()][p]) * 57.29577951308232);
  if (keep) *keep = f;
  else delete f;
  return r;
}

TEST(PatchFilter, ConsistentFromTheTruthOnTheSphere) {
  // Started at the truth, 10 % noise (Calway's): over 10 seeds the beta NEES (beta - 1)^2 / P_beta
  // averages near its 1 dof, and NIS per dof over the second half near 1.
  double nees = 0, nis = 0;
  const int trials = 10;
  for (int t = 0; t < trials; ++t) {
    const SphereRun r = runSphere(100 + t, 0.1, true);
    nees += std::pow((r.beta - 1.0) / r.beta_sd, 2) / trials;
    nis += r.nis_per_dof / trials;
  }
  EXPECT_GT(nis, 0.8);
  EXPECT_LT(nis, 1.2);
  // 95 % band of the mean of 10 chi2(1) is [0.33, 1.9]; allow the EKF some optimism.
  EXPECT_LT(nees, 3.0);
  EXPECT_GT(nees, 0.1);
}

TEST(PatchesExperiment, SphereConvergesFromAFrontoParallelStart) {
  // Calway's test ([Cal00]) at 10 % noise from beta0 = 0.5 and fronto-parallel patches, the
  // experiment's protocol over 10 trials (seed 1), at frame 200. Issue 5: beta within 5 % and
  // every patch normal within 5 deg. Observed (exact): beta 2.2 % (trial mean; 8 of 10 trials
  // within 5 %, the worst 6.1 %: the data fix beta to about 4 % per trial), patch normals 1.2 deg
  // on average, the worst patch of any trial 2.7 deg. Seeds 1-10 all hold the trial-mean check
  // (docs/patches.md).
  PatchesOptions o;
  o.trials = 10;
  o.plane_noise.clear();
  const PatchesResult r = runPatches(o);
  ASSERT_EQ(r.rows.size(), 3u);
  for (int m = 0; m < 2; ++m) {
    const PatchesRow& row = r.rows[m];
    EXPECT_EQ(row.failed, 0) << row.measurement;
    EXPECT_LT(row.beta_err_pct, 5.0) << row.measurement;
    EXPECT_GE(row.trials_beta_within, 7) << row.measurement;
    EXPECT_LT(row.normal_err_deg, 2.0) << row.measurement;
    EXPECT_LT(row.worst_normal_err_deg, 5.0) << row.measurement;
  }
}

TEST(PatchFilter, RemovingTheGaugePatchMovesTheGauge) {
  PatchFilter* f = nullptr;
  runSphere(7, 0.1, true, &f);
  std::unique_ptr<PatchFilter> own(f);
  const int K = f->numPatches();
  const Eigen::VectorXd x = f->ekf().x();
  ASSERT_EQ(f->gauge(), 0);
  ASSERT_TRUE(f->removePatch(0));
  EXPECT_EQ(f->numPatches(), K - 1);
  const int g = f->gauge();
  ASSERT_GE(g, 0);
  // Values unchanged (lambda = 1), the new gauge's p4 is fixed with zero variance.
  EXPECT_LT((f->ekf().x().head<7>() - x.head<7>()).norm(), 1e-12);
  EXPECT_LT((f->ekf().x().tail(3 * (K - 1)) - x.tail(3 * (K - 1))).norm(), 1e-12);
  const int ig = PatchModel::p4Index(g);
  EXPECT_TRUE(f->ekf().fixed()[ig]);
  EXPECT_EQ(f->ekf().P().row(ig).norm(), 0.0);
  for (int k = 0; k < f->numPatches(); ++k)
    if (k != g) {
      EXPECT_GT(f->ekf().P()(PatchModel::p4Index(k), PatchModel::p4Index(k)), 0.0);
    }
  // New patch joins with a vague prior.
  const int slot = f->addPatch({0.05, 0.02}, {0.0, 0.0, 0.5}, Eigen::Matrix3d::Identity());
  EXPECT_EQ(slot, K - 1);
  EXPECT_EQ(f->ekf().size(), 7 + 3 * K);
}

TEST(PatchesExperiment, PlaneSceneNormalsNoWorseThanThePointFilter) {
  // Table 1 plane through 20 patches, 5 trials: the normal of the plane fitted to the patch
  // filter's 3-D centres at frame 100 is no worse than the point filter's on the same centres.
  PatchesOptions o;
  o.trials = 5;
  o.sphere_noise.clear();
  o.plane_noise = {0.05, 0.2};
  const PatchesResult r = runPatches(o);
  ASSERT_EQ(r.rows.size(), 6u);
  for (int l = 0; l < 2; ++l) {
    const PatchesRow& exact = r.rows[3 * l];
    const PatchesRow& point = r.rows[3 * l + 2];
    ASSERT_EQ(exact.measurement, "exact");
    ASSERT_EQ(point.measurement, "point-centres");
    EXPECT_EQ(exact.failed, 0);
    EXPECT_LE(exact.normal_err_frame100, point.normal_err_frame100) << "rho " << exact.noise;
  }
}

}  // namespace
}  // namespace rsfm

// ---- The pipeline on patch tracks (pixels, cumulative maps) ----
#include "rsfm/pipeline/patch_pipeline.hpp"

namespace rsfm {
namespace {

/// Patch tracks in pixels from a sphere scene: centres and cumulative maps (first frame -> k),
/// as the tracker reports them; patch 1 ends at frame 60 and a copy of patch 2 (new id) starts
/// at frame 40, to exercise leaving and joining.
PatchTracks tracksFromScene(const PatchScene& s, double s_px, double noise_px, std::uint64_t seed) {
  PatchTracks t;
  t.image = {640, 480, 319.5, 239.5};
  t.radius = 15;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  const Eigen::Vector2d c(t.image.cx, t.image.cy);
  std::vector<Eigen::Matrix2d> cum(s.patches(), Eigen::Matrix2d::Identity());
  Eigen::Matrix2d cum_late = Eigen::Matrix2d::Identity();
  for (int k = 0; k <= s.frames(); ++k) {
    std::vector<PatchObservation> f;
    for (int p = 0; p < s.patches(); ++p) {
      if (k > 0) {
        Eigen::Matrix2d A;
        A << s.affine[k][p][2], s.affine[k][p][3], s.affine[k][p][4], s.affine[k][p][5];
        cum[p] = A * cum[p];
        if (p == 2 && k > 40) cum_late = A * cum_late;
      }
      if (p == 1 && k > 60) continue;
      PatchObservation o;
      o.id = p;
      o.px0 = s.centre[0][p] * s_px + c;
      o.px = s.centre[k][p] * s_px + c + Eigen::Vector2d(g(rng), g(rng)) * noise_px;
      o.A = cum[p];
      if (k == 0) o.px = o.px0;
      f.push_back(o);
    }
    if (k >= 40 && s.patches() > 2) {  // a late patch (a copy of patch 2) joins at frame 40
      PatchObservation o;
      o.id = s.patches();
      o.px0 = s.centre[40][2] * s_px + c;
      o.px = k == 40 ? o.px0 : Eigen::Vector2d(s.centre[k][2] * s_px + c);
      o.A = cum_late;
      f.push_back(o);
    }
    t.frames.push_back(f);
  }
  return t;
}

/// The sphere (seed 5) as pixel tracks (tracksFromScene: noise-free maps, 0.05 px on the
/// centres, s = 320, the focal length known), run through the patch pipeline with `centres`.
struct SphereTracksRun {
  PatchScene scene;
  PatchTracks tracks;
  PatchPipelineOptions options;
  PatchRunResult result;
  double worst_normal_deg = NAN;  ///< largest patch normal error at the last frame
};

/// `still` > 0: that many still frames (frame 0 again, centres jittered by 0.01 px) come first.
SphereTracksRun runSphereTracks(PatchCentres centres, bool fused_maps = false, int still = 0) {
  SphereTracksRun run;
  std::mt19937_64 rng(5);
  run.scene = makeSphereScene(SphereSceneOptions{}, rng);
  const PatchScene& s = run.scene;
  const double s_px = 320.0;
  run.tracks = tracksFromScene(s, s_px, 0.05, 9);
  std::normal_distribution<double> jitter(0.0, 0.01);
  for (int k = 0; k < still; ++k) {
    std::vector<PatchObservation> f = run.tracks.frames[0];
    for (auto& o : f) o.px += Eigen::Vector2d(jitter(rng), jitter(rng));
    run.tracks.frames.insert(run.tracks.frames.begin() + 1, f);
  }
  PatchPipelineOptions& o = run.options;
  o.scale_px = s_px;
  o.focal_px = s_px / s.beta;
  o.sigma_affine = 0.002;
  o.centres = centres;
  o.fused_maps = fused_maps;
  run.result = runPatchTracks(run.tracks, o);
  if (!run.result.ok() || run.result.frames.empty()) return run;
  run.worst_normal_deg = 0.0;
  for (const PatchEstimate& e : run.result.frames.back().patches) {
    const int truth_patch = e.id == s.patches() ? 2 : e.id;  // the late patch re-tracks patch 2
    run.worst_normal_deg =
        std::max(run.worst_normal_deg, normalAngle(e.normal, s.normal[s.frames()][truth_patch]) * 57.29577951308232);
  }
  return run;
}

TEST(PatchPipeline, RecoversTheSphereFromPixelTracks) {
  // Every patch normal within 3 degrees of the truth at the last frame; the patch that ends
  // leaves the state and the late one joins.
  const SphereTracksRun run = runSphereTracks(PatchCentres::Fused);
  const PatchScene& s = run.scene;
  const PatchRunResult& r = run.result;
  ASSERT_TRUE(r.ok()) << r.stopped;
  EXPECT_EQ(r.left, 1);
  EXPECT_EQ(r.joined, 1);
  const PatchRunFrame& last = r.frames.back();
  ASSERT_EQ(static_cast<int>(last.patches.size()), s.patches());
  EXPECT_LT(run.worst_normal_deg, 3.0);
  // The camera pose is dead-reckoned from inter-frame motions: after 200 frames its rotation is
  // 4.8 deg off here (0.7 deg even with exact centres: the sphere's curvature within a cluster is
  // model error for the tangent-plane measurement). Bound it loosely.
  const Eigen::Matrix3d Rtrue = s.R[s.frames()];
  EXPECT_LT(rotationAngle(last.R, Rtrue) * 57.29577951308232, 6.0);
  // Agreement statistic of the report.
  const NormalAgreement a = normalAgreement(last);
  EXPECT_EQ(static_cast<int>(a.angle_deg.size()), s.patches());
}

TEST(PatchPipeline, AStillStartIsNotStepped) {
  // 12 still frames before the sphere's motion (as the ViSP cube's 17): they are taken as still
  // (PatchPipelineOptions::still_px), keep the identity pose, and the run ends as without them
  // (every normal within 3 deg).
  const SphereTracksRun run = runSphereTracks(PatchCentres::Fused, false, 12);
  const PatchRunResult& r = run.result;
  ASSERT_TRUE(r.ok()) << r.stopped;
  EXPECT_EQ(r.still_frames, 12);
  ASSERT_GT(r.frames.size(), 13u);
  for (int k = 1; k <= 12; ++k) EXPECT_TRUE(r.frames[k].R.isIdentity(0.0)) << "frame " << k;
  EXPECT_FALSE(r.frames[13].R.isIdentity(1e-9));
  EXPECT_LT(run.worst_normal_deg, 3.0);
  EXPECT_EQ(runSphereTracks(PatchCentres::Fused).result.still_frames, 0);
}

TEST(PatchPipeline, FusedMapsRecoverTheSphereToo) {
  // --fused-maps: each patch's cumulative map estimated beside the filter; the same bound on the
  // normals as without it (docs/patches.md: no gain on real sequences).
  const SphereTracksRun run = runSphereTracks(PatchCentres::Fused, true);
  ASSERT_TRUE(run.result.ok()) << run.result.stopped;
  EXPECT_LT(run.worst_normal_deg, 3.0);
}

TEST(PatchPipeline, RejectsTooFewPatches) {
  std::mt19937_64 rng(5);
  SphereSceneOptions so;
  so.patches = 2;
  const PatchScene s = makeSphereScene(so, rng);
  const PatchTracks t = tracksFromScene(s, 320.0, 0.0, 1);
  EXPECT_THROW(runPatchTracks(t, PatchPipelineOptions{}), std::invalid_argument);
}

TEST(PatchPipeline, MapsInTheStateRecoverTheSphere) {
  // As RecoversTheSphereFromPixelTracks with PatchCentres::State: the tracker's cumulative maps
  // are measured directly (state 7 + 9K). Measured: every normal within 1.4 deg (fused centres:
  // 3 deg bound), the rotation 1.4 deg off at frame 200 (fused: 4.8 deg): the maps'
  // long-baseline information is kept.
  SphereTracksRun run = runSphereTracks(PatchCentres::State);
  const PatchScene& s = run.scene;
  const PatchRunResult& r = run.result;
  ASSERT_TRUE(r.ok()) << r.stopped;
  EXPECT_EQ(r.left, 1);
  EXPECT_EQ(r.joined, 1);
  ASSERT_EQ(static_cast<int>(r.frames.back().patches.size()), s.patches());
  EXPECT_LT(run.worst_normal_deg, 2.0);
  EXPECT_LT(rotationAngle(r.frames.back().R, s.R[s.frames()]) * 57.29577951308232, 2.5);
  // The instantaneous measurement and fused maps are refused with maps in the state.
  PatchPipelineOptions o = run.options;
  o.measurement = AffineMeasurement::Instantaneous;
  EXPECT_THROW(runPatchTracks(run.tracks, o), std::invalid_argument);
  o.measurement = AffineMeasurement::Exact;
  o.fused_maps = true;
  EXPECT_THROW(runPatchTracks(run.tracks, o), std::invalid_argument);
}

}  // namespace
}  // namespace rsfm
