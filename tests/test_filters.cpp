// Whole filters on seeded synthetic scenes: convergence to ground truth with stated tolerances,
// the gauge, NEES/NIS consistency, reproducibility, and reporting of numerical trouble.
#include <gtest/gtest.h>

#include <random>

#include "rsfm/chi2.hpp"
#include "rsfm/units.hpp"
#include "rsfm/experiment/table1.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/models/point_model.hpp"
#include "rsfm/filters/recursive_filter.hpp"

namespace rsfm {
namespace {


// ---------------------------------------------------------------------------------------------
// Noise-free Table 1 scene: both readings converge to the truth.
struct NoiselessResult {
  double normal_err_deg, beta_err, t_err, rot_err_deg;
  double nz_final;
};

/// The plane filter on a Table 1 scene from the paper's start: beta0 = 0.5, N0 = (1.5, 0.5, 2)
/// with N_Z the gauge, variances 0.1.
RecursiveFilter<PlaneModel> table1PlaneFilter(const Table1Scene& scene, const FilterOptions& fo) {
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(10);
  x0[idx::kBeta] = 0.5;
  x0.tail<3>() << 1.5, 0.5, 2.0;
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(10, 10);
  P0(6, 6) = 0.1;
  P0(7, 7) = P0(8, 8) = 0.1;
  std::vector<bool> fixed(10, false);
  fixed[9] = true;
  const int Np = static_cast<int>(scene.points.size());
  return RecursiveFilter<PlaneModel>(PlaneModel(scene.uv[0], std::vector<int>(Np, 0)), Ekf(x0, P0, fixed), fo);
}

NoiselessResult runNoiselessPlane(RotationReading reading, int iterations = 1) {
  Table1SceneOptions so;
  std::mt19937_64 rng(42);
  const Table1Scene scene = makeTable1Scene(so, rng);
  const int Np = static_cast<int>(scene.points.size());
  FilterOptions fo;
  fo.reading = reading;
  fo.sigma_uv = 0.1 / so.scale_px;  // the filter assumes 0.1 px; the data are exact
  fo.q_motion << 3e-4, 3e-4, 3e-4, 1e-4, 1e-4, 1e-4, 0.0;
  fo.iterations = iterations;
  RecursiveFilter<PlaneModel> f = table1PlaneFilter(scene, fo);
  for (int k = 1; k <= so.frames; ++k) {
    std::vector<Observation> obs;
    for (int i = 0; i < Np; ++i) obs.push_back({i, scene.uv[k][i]});
    const FrameStats& fs = f.step(obs);
    EXPECT_EQ(fs.health, kHealthy) << "frame " << k;
  }
  NoiselessResult r;
  r.normal_err_deg = normalAngle(f.ekf().x().tail<3>(), so.plane) / kDegToRad;
  r.beta_err = std::abs(f.beta() - so.beta);
  r.t_err = (f.translation() - scene.t.back()).norm();
  r.rot_err_deg = rotationAngle(f.rotation(), scene.R.back()) / kDegToRad;
  r.nz_final = f.ekf().x()[9];
  return r;
}

TEST(PlaneFilter, IterationScheduleWarmUpThenPlainThenIterated) {
  // FilterOptions::warmup_frames iterate the first frames, iterate_after_frames then holds the
  // plain update until its frame count, and later frames use `iterations`.
  Table1SceneOptions so;
  std::mt19937_64 rng(42);
  const Table1Scene scene = makeTable1Scene(so, rng);
  const int Np = static_cast<int>(scene.points.size());
  FilterOptions fo;
  fo.sigma_uv = 0.1 / so.scale_px;
  fo.iterations = 4;
  fo.warmup_frames = 2;
  fo.iterate_after_frames = 6;
  RecursiveFilter<PlaneModel> f = table1PlaneFilter(scene, fo);
  for (int k = 1; k <= 10; ++k) {
    std::vector<Observation> obs;
    for (int i = 0; i < Np; ++i) obs.push_back({i, scene.uv[k][i]});
    const FrameStats& fs = f.step(obs);
    ASSERT_EQ(fs.health, kHealthy) << "frame " << k;
    if (k <= 2 || k > 6)
      EXPECT_GT(fs.iterations, 1) << "frame " << k;
    else
      EXPECT_EQ(fs.iterations, 1) << "frame " << k;
  }
}

TEST(PlaneFilter, BetaBoundProjectsTheEstimateOntoTheBound) {
  // FilterOptions::beta_min: a bound above the truth (beta = 1) that the noise-free data pull
  // the estimate through (beta0 = 2.5). Without it beta goes below 2; with it beta never does,
  // it sits exactly on the bound whenever it was projected.
  Table1SceneOptions so;
  std::mt19937_64 rng(42);
  const Table1Scene scene = makeTable1Scene(so, rng);
  const int Np = static_cast<int>(scene.points.size());
  auto run = [&](double beta_min, int* projected, double* min_beta) {
    FilterOptions fo;
    fo.sigma_uv = 1.0 / so.scale_px;
    fo.beta_min = beta_min;
    Eigen::VectorXd x0 = Eigen::VectorXd::Zero(10);
    x0[idx::kBeta] = 2.5;
    x0.tail<3>() = so.plane;
    Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(10, 10);
    P0(6, 6) = 1.0;
    P0(7, 7) = P0(8, 8) = 0.1;
    std::vector<bool> fixed(10, false);
    fixed[9] = true;
    RecursiveFilter<PlaneModel> f(PlaneModel(scene.uv[0], std::vector<int>(Np, 0)), Ekf(x0, P0, fixed), fo);
    *projected = 0;
    *min_beta = HUGE_VAL;
    for (int k = 1; k <= 30; ++k) {
      std::vector<Observation> obs;
      for (int i = 0; i < Np; ++i) obs.push_back({i, scene.uv[k][i]});
      const FrameStats& fs = f.step(obs);
      EXPECT_EQ(fs.health, kHealthy) << "frame " << k;
      *min_beta = std::min(*min_beta, f.beta());
      if (fs.beta_projected) {
        ++*projected;
        EXPECT_NEAR(f.beta(), beta_min, 1e-12) << "frame " << k;
      }
    }
  };
  int projected = 0;
  double min_beta = 0;
  run(0.0, &projected, &min_beta);
  EXPECT_EQ(projected, 0);
  EXPECT_LT(min_beta, 1.9);  // without the bound
  run(2.0, &projected, &min_beta);
  EXPECT_GT(projected, 0);
  EXPECT_GE(min_beta, 2.0 - 1e-12);
}

// ---------------------------------------------------------------------------------------------
// ReferenceModel::Conditional (issue 15 item 2): the references conditional on the state.

/// The Table 1 scene with `points` points and `noise_px` uniform noise on every frame (the
/// reference frame included), seeded.
struct NoisyTable1 {
  Table1SceneOptions so;
  Table1Scene scene;
  std::vector<std::vector<Eigen::Vector2d>> uv;
};
NoisyTable1 noisyTable1(int points, double noise_px, std::uint64_t seed, int frames = 100) {
  NoisyTable1 t;
  t.so.points = points;
  t.so.frames = frames;
  std::mt19937_64 rng(seed);
  t.scene = makeTable1Scene(t.so, rng);
  t.uv = addUniformNoise(t.scene.uv, noise_px, t.so.scale_px, rng);
  return t;
}
std::vector<Observation> frameObservations(const NoisyTable1& t, int k) {
  std::vector<Observation> obs;
  for (int i = 0; i < static_cast<int>(t.uv[k].size()); ++i) obs.push_back({i, t.uv[k][i]});
  return obs;
}

TEST(ConditionalReferences, AreTheStateFiltersEstimateWithoutProcessNoise) {
  // Without process noise the references are conditionally independent given the state, so the
  // O(N) conditional form is the references-in-the-state filter (state 10 + 2N) exactly: same
  // linearization points, same linear-Gaussian update. 12 frames of 20 points at 1 px, the gate
  // off (with Q = 0 the orbit does not fit: this is about the algebra, not the fit).
  const NoisyTable1 t = noisyTable1(20, 1.0, 11, 12);
  FilterOptions fo;
  fo.sigma_uv = 1.0 / t.so.scale_px;
  fo.q_motion.setZero();
  fo.update.gate_probability = 0.0;
  fo.reference = ReferenceModel::State;
  RecursiveFilter<PlaneModel> state = table1PlaneFilter(t.scene, fo);
  fo.reference = ReferenceModel::Conditional;
  RecursiveFilter<PlaneModel> cond = table1PlaneFilter(t.scene, fo);
  // The initial motion must be free to move for the frames to inform anything.
  for (auto* f : {&state, &cond})
    for (int i = 0; i < 6; ++i) f->mutableEkf().mutableP()(i, i) = 1e-2;
  for (int k = 1; k <= t.so.frames; ++k) {
    const auto obs = frameObservations(t, k);
    ASSERT_TRUE(state.step(obs).ok()) << k;
    ASSERT_TRUE(cond.step(obs).ok()) << k;
    const Eigen::VectorXd xs = state.ekf().x().head<10>(), xc = cond.ekf().x();
    EXPECT_LT((xs - xc).cwiseAbs().maxCoeff(), 1e-9 * (1.0 + xs.cwiseAbs().maxCoeff())) << "frame " << k;
    EXPECT_LT((state.ekf().P().topLeftCorner<10, 10>() - cond.ekf().P()).cwiseAbs().maxCoeff(), 1e-9) << "frame " << k;
    for (int i = 0; i < 20; ++i)
      EXPECT_LT((state.model().reference(i) - cond.model().reference(i)).norm(), 1e-9) << "frame " << k << " point " << i;
  }
}

TEST(ConditionalReferences, TheVectorKernelsEqualTheEigenLoops) {
  // The one-plane model's conditional loops (process step, total Jacobian, gain update) have
  // AVX2/FMA kernels (filters/conditional_kernels.hpp) chosen at run time; they must give the
  // Eigen loops' results up to rounding. Table 1 scene, 60 points at 1 px, 30 frames, with the
  // default process noise (the process step runs) and gate; some points leave for a few frames
  // (the unobserved ones are marginalized) so every branch is taken. Tolerance 1e-9 relative.
  if (!Ekf::vectorKernelAvailable()) GTEST_SKIP() << "this CPU has no AVX2/FMA: the vector kernels cannot run here";
  const NoisyTable1 t = noisyTable1(60, 1.0, 17, 30);
  FilterOptions fo;
  fo.sigma_uv = 1.0 / t.so.scale_px;
  fo.reference = ReferenceModel::Conditional;
  RecursiveFilter<PlaneModel> eigen = table1PlaneFilter(t.scene, fo), vec = table1PlaneFilter(t.scene, fo);
  double worst = 0.0;
  for (int k = 1; k <= t.so.frames; ++k) {
    std::vector<Observation> obs = frameObservations(t, k);
    if (k % 7 == 3) obs.erase(obs.begin() + 10, obs.begin() + 20);  // points 10-19 unseen this frame
    const bool previous = Ekf::useVectorKernel(false);
    const FrameStats se = eigen.step(obs);
    Ekf::useVectorKernel(true);
    const FrameStats sv = vec.step(obs);
    Ekf::useVectorKernel(previous);
    ASSERT_TRUE(se.ok() && sv.ok()) << "frame " << k;
    ASSERT_EQ(se.update.gated, sv.update.gated) << "frame " << k;
    const Eigen::VectorXd& xe = eigen.ekf().x();
    worst = std::max(worst, (xe - vec.ekf().x()).cwiseAbs().maxCoeff() / (1.0 + xe.cwiseAbs().maxCoeff()));
    worst = std::max(worst, (eigen.ekf().P() - vec.ekf().P()).cwiseAbs().maxCoeff() / eigen.ekf().P().cwiseAbs().maxCoeff());
    for (int i = 0; i < 60; ++i) {
      worst = std::max(worst, (eigen.model().reference(i) - vec.model().reference(i)).norm());
      const Eigen::Matrix2d& ce = eigen.referenceCovariances()[i];
      worst = std::max(worst, (ce - vec.referenceCovariances()[i]).cwiseAbs().maxCoeff() / ce.cwiseAbs().maxCoeff());
    }
  }
  EXPECT_LT(worst, 1e-9);
  std::cout << "[ note ] largest relative difference, vector kernels against the Eigen loops: " << worst << "\n";
}

/// Normal error (deg), signed beta error (%) and beta's z^2 at the last frame of one run.
struct EndErrors {
  double normal_deg, beta_pct, beta_z2;
};
EndErrors runTable1Reference(const NoisyTable1& t, ReferenceModel reference) {
  FilterOptions fo;
  fo.sigma_uv = 1.0 / t.so.scale_px;
  fo.reference = reference;
  RecursiveFilter<PlaneModel> f = table1PlaneFilter(t.scene, fo);
  for (int k = 1; k <= t.so.frames; ++k) EXPECT_TRUE(f.step(frameObservations(t, k)).ok()) << k;
  const double e = f.beta() / t.so.beta - 1.0;
  return {normalAngle(f.ekf().x().tail<3>(), t.so.plane) / kDegToRad, 100.0 * e,
          std::pow(f.beta() - t.so.beta, 2) / f.ekf().P()(idx::kBeta, idx::kBeta)};
}

TEST(ConditionalReferences, KeepTheirAccuracyAsThePointsGrow) {
  // Refine copies the state's error into every reference (each refined from its own residual at
  // the posterior, the cross-covariance dropped), so from the paper's start (beta 50 % off) its
  // error stops falling with N; the conditional form's does not. Table 1 scene, 1 px, N = 1000,
  // 3 seeds, mean at frame 100. Measured from the paper's start: refine 0.27 deg, conditional
  // 0.029 deg / 0.37 %, exact 0.005 deg (what is left of the conditional's error is the first
  // frames' linearization far from the truth, imprinted on the references: docs/filter.md).
  double refine = 0.0, cond = 0.0, cond_beta = 0.0;
  for (std::uint64_t seed : {1, 2, 3}) {
    const NoisyTable1 t = noisyTable1(1000, 1.0, 100 + seed);
    refine += runTable1Reference(t, ReferenceModel::Refine).normal_deg / 3.0;
    const EndErrors c = runTable1Reference(t, ReferenceModel::Conditional);
    cond += c.normal_deg / 3.0;
    cond_beta += std::abs(c.beta_pct) / 3.0;
  }
  EXPECT_LT(cond, 0.1);
  EXPECT_LT(cond_beta, 0.8);
  EXPECT_GT(refine, 3.0 * cond) << "refine no longer loses accuracy with N: revisit the pipeline's default";
}

TEST(ConditionalReferences, BetaIsConsistentWithFewPoints) {
  // With 30 points the conditional form's beta sd covers its error (mean z^2 over 10 seeds near
  // its dof 1; measured 0.4), where refine's is overconfident (measured 53) and exact's too (37).
  double z2 = 0.0, z2_refine = 0.0;
  for (std::uint64_t seed = 1; seed <= 10; ++seed) {
    const NoisyTable1 t = noisyTable1(30, 1.0, 200 + seed);
    z2 += runTable1Reference(t, ReferenceModel::Conditional).beta_z2 / 10.0;
    z2_refine += runTable1Reference(t, ReferenceModel::Refine).beta_z2 / 10.0;
  }
  EXPECT_LT(z2, 3.0);
  EXPECT_GT(z2_refine, 10.0);
}

TEST(PlaneFilter, NoiselessConvergesResetReading) {
  const NoiselessResult r = runNoiselessPlane(RotationReading::Reset);
  std::cout << "reset: normal " << r.normal_err_deg << " deg, beta err " << r.beta_err << ", t err "
            << r.t_err << ", rotation " << r.rot_err_deg << " deg\n";
  EXPECT_LT(r.normal_err_deg, 0.05);
  EXPECT_LT(r.beta_err, 0.005);
  EXPECT_LT(r.t_err, 2e-3);
  EXPECT_LT(r.rot_err_deg, 0.05);
  EXPECT_EQ(r.nz_final, 2.0);  // the gauge never moves
}

TEST(PlaneFilter, NoiselessConvergesRateReading) {
  // The rate reading carries omega as the per-frame rotation (constant angular velocity, which
  // the Table 1 motion is). The accumulated rotation R_g has no covariance in this reading, so
  // early errors are only corrected through omega: it converges, more slowly than reset.
  const NoiselessResult r = runNoiselessPlane(RotationReading::Rate);
  std::cout << "rate: normal " << r.normal_err_deg << " deg, beta err " << r.beta_err << ", t err "
            << r.t_err << ", rotation " << r.rot_err_deg << " deg\n";
  EXPECT_LT(r.normal_err_deg, 0.5);
  EXPECT_LT(r.beta_err, 0.02);
  EXPECT_LT(r.t_err, 0.01);
  EXPECT_LT(r.rot_err_deg, 0.5);
  EXPECT_EQ(r.nz_final, 2.0);
}

TEST(PlaneFilter, NoiselessConvergesIteratedUpdate) {
  const NoiselessResult r = runNoiselessPlane(RotationReading::Reset, 5);
  EXPECT_LT(r.normal_err_deg, 0.05);
  EXPECT_LT(r.beta_err, 0.005);
  EXPECT_LT(r.t_err, 2e-3);
  EXPECT_EQ(r.nz_final, 2.0);
}

TEST(PlaneFilter, UnknownFeatureIdIsReported) {
  const std::vector<Eigen::Vector2d> ref{{0.1, 0.1}, {-0.2, 0.3}, {0.3, -0.3}, {-0.4, -0.2}, {0.2, 0.25}, {0.0, -0.1}};
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(10);
  x0[6] = 1.0;
  x0.tail<3>() << 0.0, 0.0, 2.0;
  std::vector<bool> fixed(10, false);
  fixed[9] = true;
  RecursiveFilter<PlaneModel> f(PlaneModel(ref, std::vector<int>(ref.size(), 0)),
                                Ekf(x0, Eigen::MatrixXd::Identity(10, 10) * 0.01, fixed), FilterOptions{});
  std::vector<Observation> obs;
  for (int i = 0; i < 6; ++i) obs.push_back({i, ref[i]});
  obs.push_back({17, {0.0, 0.0}});
  obs.push_back({-1, {0.0, 0.0}});
  const FrameStats& fs = f.step(obs);
  EXPECT_EQ(fs.invalid, 2);
  EXPECT_EQ(fs.first_problem, MeasureStatus::UnknownFeature);
  EXPECT_TRUE(fs.update.applied);
  EXPECT_EQ(fs.update.used, 6);
}

// ---------------------------------------------------------------------------------------------
// The figures at 2 px, default options, fixed seed: plane normal < 1 deg and beta within
// 5 % at frame 100 (mean over 20 trials), and the plane filter beats the point filter's sigma_t.
TEST(Table1, PlaneFilterAtTwoPixels) {
  Table1Options o;
  o.trials = 20;
  o.seed = 1;
  o.noise_px = {2.0};
  const Table1Result r = runTable1(o);
  ASSERT_EQ(r.rows.size(), 4u);  // plane, plane-iekf, batch, point
  auto row = [&](const std::string& name) {
    for (const auto& x : r.rows)
      if (x.formulation == name) return x;
    ADD_FAILURE() << "no row " << name;
    return Table1Row{};
  };
  const Table1Row plane = row("plane"), point = row("point"), batch = row("batch");
  EXPECT_EQ(plane.failed, 0) << plane.first_failure;
  EXPECT_LT(plane.final_normal_err_deg, 1.0);
  EXPECT_LT(plane.final_beta_err_pct, 5.0);
  EXPECT_LT(plane.sigma_t, point.sigma_t);
  EXPECT_GE(plane.r_s, 1);  // converged (on the trial mean) within the sequence
  EXPECT_GE(plane.r_c, 1);
  // The batch optimum on the same tracks is better than the filter and meets its own bound.
  EXPECT_EQ(batch.failed, 0) << batch.first_failure;
  EXPECT_LT(batch.sigma_t, plane.sigma_t);
  EXPECT_LT(batch.final_normal_err_deg, plane.final_normal_err_deg);
  EXPECT_GT(batch.crb_normal_deg, 0.0);
  EXPECT_LT(batch.final_normal_err_deg, 2.0 * batch.crb_normal_deg);
}

TEST(Table1, ReproducibleWhateverTheThreadCount) {
  Table1Options o;
  o.trials = 4;
  o.noise_px = {6.0};
  o.scene.frames = 30;
  o.batch = false;
  o.threads = 1;
  const Table1Result a = runTable1(o);
  o.threads = 3;
  const Table1Result b = runTable1(o);
  ASSERT_EQ(a.rows.size(), b.rows.size());
  for (size_t i = 0; i < a.rows.size(); ++i) {
    EXPECT_EQ(a.rows[i].sigma_t, b.rows[i].sigma_t);
    EXPECT_EQ(a.rows[i].sigma_q, b.rows[i].sigma_q);
    EXPECT_EQ(a.rows[i].final_normal_err_deg, b.rows[i].final_normal_err_deg);
  }
  o.seed = 2;
  const Table1Result c = runTable1(o);
  EXPECT_NE(a.rows[0].sigma_t, c.rows[0].sigma_t);
}

TEST(Table1, RejectsBadOptions) {
  Table1Options o;
  o.trials = 0;
  EXPECT_FALSE(validateTable1Options(o).empty());
  o = Table1Options{};
  o.noise_px = {-1.0};
  EXPECT_FALSE(validateTable1Options(o).empty());
  o = Table1Options{};
  o.scene.points = 6;
  EXPECT_FALSE(validateTable1Options(o).empty());
  o = Table1Options{};
  o.scene.deg_per_frame = 1.0;  // 100 deg in total
  EXPECT_FALSE(validateTable1Options(o).empty());
  EXPECT_THROW(runTable1(o), std::invalid_argument);
  EXPECT_TRUE(validateTable1Options(Table1Options{}).empty());
}

// ---------------------------------------------------------------------------------------------
// Consistency: truth drawn from the filter's own assumptions (reset reading, random-walk motion
// with the filter's Q, Gaussian pixel noise with its R, exact reference coordinates, initial
// state drawn from the prior). The mean NEES of the whole free state at the last frame over M
// runs must lie in the two-sided 95 % band of chi2(M n) / M, and the mean NIS per dof near 1.
struct Consistency {
  double nees_mean = 0;
  int dof = 0;
  double nis_per_dof = 0;
  int runs = 0;
};

/// Rotation error with the same sign as the other components (estimate minus truth), as the
/// state's omega expresses it: R_est = R(dq(e)) R_true.
Eigen::Vector3d rotationError(const Eigen::Matrix3d& R_est, const Eigen::Matrix3d& R_true) {
  Eigen::Quaterniond q(R_est * R_true.transpose());
  q = canonical(q);
  return 2.0 * q.vec();
}

template <class Model>
Consistency consistencyRuns(int runs, int frames, int points, bool plane_model) {
  const double sigma = 2.0 / 256.0;
  const Eigen::Vector3d q_t(3e-4, 3e-4, 3e-4);
  const double q_w = 1e-4;
  Consistency c;
  double nis_sum = 0;
  long nis_dof = 0;
  for (int run = 0; run < runs; ++run) {
    std::mt19937_64 rng(1000 + run);
    std::normal_distribution<double> N01;
    std::uniform_real_distribution<double> U(-0.8, 0.8);
    // Prior.
    const double beta0 = 1.0, var_beta = 0.01;
    const Eigen::Vector3d N0(2.0 / std::sqrt(3.0), 0.0, 2.0);
    const double var_N = 0.02, var_alpha = 0.01;
    std::vector<Eigen::Vector2d> ref(points);
    for (auto& r : ref) r = {U(rng), U(rng)};
    const int n = plane_model ? 10 : 7 + points;
    Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
    Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
    std::vector<bool> fixed(n, false);
    x0[6] = beta0;
    P0(6, 6) = var_beta;
    Eigen::VectorXd xt = x0;  // truth
    xt[6] = beta0 + std::sqrt(var_beta) * N01(rng);
    if (plane_model) {
      x0.tail<3>() = N0;
      P0(7, 7) = P0(8, 8) = var_N;
      fixed[9] = true;
      xt.tail<3>() = N0 + Eigen::Vector3d(std::sqrt(var_N) * N01(rng), std::sqrt(var_N) * N01(rng), 0.0);
    } else {
      for (int i = 0; i < points; ++i) {
        x0[7 + i] = 0.6;
        P0(7 + i, 7 + i) = var_alpha;
        xt[7 + i] = 0.6 + std::sqrt(var_alpha) * N01(rng);
      }
      P0(7, 7) = 0.0;
      fixed[7] = true;
      xt[7] = 0.6;
    }
    Model model = [&] {
      if constexpr (std::is_same_v<Model, PlaneModel>) return PlaneModel(ref, std::vector<int>(points, 0));
      else return PointModel(ref);
    }();
    FilterOptions fo;
    fo.reading = RotationReading::Reset;
    fo.sigma_uv = sigma;
    fo.q_motion << q_t, q_w, q_w, q_w, 0.0;
    fo.update.gate_probability = 0.0;  // no gating: NEES/NIS of the plain filter
    RecursiveFilter<Model> f(model, Ekf(x0, P0, fixed), fo);
    Eigen::Matrix3d Rt = Eigen::Matrix3d::Identity();
    bool ok = true;
    for (int k = 1; k <= frames && ok; ++k) {
      for (int j = 0; j < 3; ++j) xt[j] += std::sqrt(q_t[j]) * N01(rng);
      const Eigen::Vector3d w(std::sqrt(q_w) * N01(rng), std::sqrt(q_w) * N01(rng), std::sqrt(q_w) * N01(rng));
      Rt = incrementalRotation(w) * Rt;
      std::vector<Observation> obs;
      for (int i = 0; i < points; ++i) {
        Eigen::Vector2d h;
        if (model.measure(xt, Rt, i, &h, nullptr) != MeasureStatus::Ok) continue;
        obs.push_back({i, h + sigma * Eigen::Vector2d(N01(rng), N01(rng))});
      }
      const FrameStats& fs = f.step(obs);
      ok = fs.health == kHealthy && fs.update.applied;
      if (ok) {
        nis_sum += fs.update.nis;
        nis_dof += fs.update.nis_dof;
      }
    }
    EXPECT_TRUE(ok) << "run " << run << " stopped";
    if (!ok) continue;
    // Error of the whole free state: translation, rotation (as omega), beta, structure.
    const auto& x = f.ekf().x();
    Eigen::VectorXd e = x - xt;
    e.segment<3>(3) = rotationError(f.rotation(), Rt);
    std::vector<int> freeIdx = f.ekf().freeIndices();
    const Eigen::VectorXd ef = e(freeIdx);
    const Eigen::MatrixXd Pf = f.ekf().P()(freeIdx, freeIdx);
    c.nees_mean += ef.dot(Pf.ldlt().solve(ef));
    c.dof = static_cast<int>(freeIdx.size());
    ++c.runs;
  }
  c.nees_mean /= c.runs;
  c.nis_per_dof = nis_sum / nis_dof;
  return c;
}

void expectInBand(const Consistency& c, const std::string& what) {
  const double lo = chi2Quantile(0.025, static_cast<double>(c.dof) * c.runs) / c.runs;
  const double hi = chi2Quantile(0.975, static_cast<double>(c.dof) * c.runs) / c.runs;
  EXPECT_GT(c.nees_mean, lo) << what << ": NEES " << c.nees_mean << " below [" << lo << ", " << hi << "]";
  EXPECT_LT(c.nees_mean, hi) << what << ": NEES " << c.nees_mean << " above [" << lo << ", " << hi << "]";
  EXPECT_NEAR(c.nis_per_dof, 1.0, 0.05) << what;
  std::cout << what << ": mean NEES " << c.nees_mean << " (dof " << c.dof << ", band [" << lo << ", "
            << hi << "] over " << c.runs << " runs), NIS/dof " << c.nis_per_dof << "\n";
}

TEST(Consistency, PlaneFilterNeesInChi2Band) {
  expectInBand(consistencyRuns<PlaneModel>(100, 60, 30, true), "plane filter");
}

TEST(Consistency, PointFilterNeesInChi2Band) {
  expectInBand(consistencyRuns<PointModel>(100, 60, 20, false), "point filter");
}

// ---------------------------------------------------------------------------------------------
// Numerical trouble is detected and reported, never turned into NaN state.
TEST(PlaneFilter, HorizonIsReportedNotDividedByZero) {
  // Plane estimate such that the ray through (0.5, 0) is parallel to the plane.
  const std::vector<Eigen::Vector2d> ref{{0.5, 0.0}, {0.1, 0.1}, {-0.2, 0.3}, {0.3, -0.3}, {-0.4, -0.2}, {0.0, 0.4}};
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(10);
  x0[6] = 1.0;
  x0.tail<3>() << -2.0, 0.0, 1.0;  // beta N_X u + N_Z = -1 + 1 = 0 for u = 0.5
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Identity(10, 10) * 0.01;
  std::vector<bool> fixed(10, false);
  fixed[9] = true;
  RecursiveFilter<PlaneModel> f(PlaneModel(ref, std::vector<int>(ref.size(), 0)), Ekf(x0, P0, fixed), FilterOptions{});
  std::vector<Observation> obs;
  for (int i = 0; i < static_cast<int>(ref.size()); ++i) obs.push_back({i, ref[i]});
  const FrameStats& fs = f.step(obs);
  EXPECT_GE(fs.invalid, 1);
  EXPECT_TRUE(fs.first_problem == MeasureStatus::HorizonSingular ||
              fs.first_problem == MeasureStatus::BehindCamera);
  EXPECT_TRUE(f.ekf().x().allFinite());
  EXPECT_TRUE(f.ekf().P().allFinite());
}

TEST(PlaneFilter, TooFewPointsIsReported) {
  const std::vector<Eigen::Vector2d> ref{{0.1, 0.1}, {-0.2, 0.3}, {0.3, -0.3}, {-0.4, -0.2}};
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(10);
  x0[6] = 1.0;
  x0.tail<3>() << 0.0, 0.0, 2.0;
  std::vector<bool> fixed(10, false);
  fixed[9] = true;
  RecursiveFilter<PlaneModel> f(PlaneModel(ref, std::vector<int>(ref.size(), 0)),
                                Ekf(x0, Eigen::MatrixXd::Identity(10, 10) * 0.01, fixed), FilterOptions{});
  std::vector<Observation> obs;
  for (int i = 0; i < 4; ++i) obs.push_back({i, ref[i]});
  const FrameStats& fs = f.step(obs);
  EXPECT_FALSE(fs.update.applied);
  EXPECT_TRUE(fs.update.health & kTooFewMeasurements);
}

}  // namespace
}  // namespace rsfm
