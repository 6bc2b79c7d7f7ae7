#include "rsfm/experiment/two_object.hpp"
#include "rsfm/units.hpp"

#include <chrono>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

#include "rsfm/experiment/parallel.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/filters/independent_filter.hpp"
#include "rsfm/rotation.hpp"
#include "rsfm/sim/table1_scene.hpp"

namespace rsfm {
namespace {


struct TrialOut {
  bool failed = false;
  std::string failure;
  std::vector<double> rot[2], t[2], normal[2], beta;  // per frame 0..F
};

TrialOut runTrial(const TwoObjectOptions& o, const TwoObjectScene& s, double noise_px, std::uint64_t seed) {
  TrialOut out;
  const int F = o.scene.frames;
  std::mt19937_64 rng(seed);
  auto uv = addUniformNoise(s.uv, noise_px, o.scale_px, rng);
  if (!o.reference_noise) uv[0] = s.uv[0];
  std::normal_distribution<double> N01;
  const int n = 1 + IndependentPlanesModel::kBlock * 2;
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
  std::vector<bool> fixed(n, false);
  x0[IndependentPlanesModel::betaIndex()] = o.beta0;
  P0(0, 0) = o.beta_var0;
  for (int j = 0; j < 2; ++j) {
    int g = 0;
    s.N[j].cwiseAbs().maxCoeff(&g);
    const int b = IndependentPlanesModel::planeIndex(j);
    const double sd = o.n_rel * s.N[j].norm();
    for (int c = 0; c < 3; ++c) {
      x0[b + c] = s.N[j][c] + (c == g ? 0.0 : sd * N01(rng));
      P0(b + c, b + c) = c == g ? 0.0 : sd * sd;
    }
    fixed[b + g] = true;  // one gauge per independently moving plane
  }
  IndependentFilterOptions fo;
  // Noise-free data are filtered assuming 0.1 px (a zero R would make the first update absolute).
  fo.sigma_uv = std::max(noise_px, 0.1) / o.scale_px;
  fo.q_motion << o.q_translation, o.q_translation, o.q_translation, o.q_omega, o.q_omega, o.q_omega;
  fo.update.gate_probability = o.gate_probability;
  parseReferenceModel(o.reference_model, &fo.reference);
  // Exact references: nothing to inflate or refine.
  if (!o.reference_noise) fo.reference = ReferenceModel::Exact;
  IndependentPlanesFilter f(IndependentPlanesModel(uv[0], s.labels, 2), Ekf(x0, P0, fixed), fo);
  auto record = [&](int k) {
    for (int j = 0; j < 2; ++j) {
      out.rot[j].push_back(rotationAngle(f.rotation(j), s.R[j][k]) * kRadToDeg);
      out.t[j].push_back((f.translation(j) - s.t[j][k]).norm());
      out.normal[j].push_back(normalAngle(f.plane(j), s.N[j]) * kRadToDeg);
    }
    out.beta.push_back(100.0 * std::abs(f.beta() - 1.0));
  };
  record(0);
  std::vector<Observation> obs(s.points.size());
  for (int k = 1; k <= F; ++k) {
    for (size_t i = 0; i < s.points.size(); ++i) obs[i] = {static_cast<int>(i), uv[k][i]};
    const FrameStats& fs = f.step(obs);
    if (fs.health != kHealthy || !fs.update.applied) {
      out.failed = true;
      out.failure = "frame " + std::to_string(k) + ": " +
                    describeHealth(fs.health != kHealthy ? fs.health : fs.update.health);
      return out;
    }
    record(k);
  }
  return out;
}

}  // namespace

std::string validateTwoObjectOptions(const TwoObjectOptions& o) {
  if (auto msg = validateTrialsNoiseFrames(o.trials, o.noise_px, o.scene.frames); !msg.empty()) return msg;
  if (o.scene.points_per_object < IndependentPlanesModel::kMinPoints) return "--points-per-object must be at least 5";
  if (!(o.scale_px > 0.0) || !std::isfinite(o.scale_px)) return "--scale-px must be positive";
  if (!(o.beta0 > 0.0) || !std::isfinite(o.beta0) || !(o.beta_var0 >= 0.0) || !std::isfinite(o.beta_var0))
    return "--beta0 must be positive, --beta-var non-negative";
  if (!(o.n_rel > 0.0) || !std::isfinite(o.n_rel)) return "--n-rel must be positive";
  for (double q : {o.q_translation, o.q_omega})
    if (!(q >= 0.0) || !std::isfinite(q)) return "process variances must be finite and non-negative";
  if (ReferenceModel r; !parseReferenceModel(o.reference_model, &r) || r == ReferenceModel::State ||
                            r == ReferenceModel::Conditional)
    return "--reference must be 'exact', 'inflate' or 'refine' (the independent-motion filter keeps no references in its state, "
           "nor conditional on it)";
  if (o.threads < 0) return "--threads must be non-negative";
  return {};
}

TwoObjectResult runTwoObject(const TwoObjectOptions& o) {
  if (auto msg = validateTwoObjectOptions(o); !msg.empty()) throw std::invalid_argument(msg);
  const auto t0 = std::chrono::steady_clock::now();
  TwoObjectResult res;
  res.options = o;
  const int L = static_cast<int>(o.noise_px.size()), T = o.trials, F = o.scene.frames;
  std::vector<TwoObjectScene> scenes;
  for (int i = 0; i < T; ++i) {
    std::mt19937_64 rng(mixSeed(o.seed, static_cast<std::uint64_t>(i), 0x2b0b7));
    scenes.push_back(makeTwoObjectScene(o.scene, rng));
  }
  for (int j = 0; j < 2; ++j) {
    res.motion_rot_deg[j] = rotationAngle(scenes[0].R[j][F], Eigen::Matrix3d::Identity()) * kRadToDeg;
    res.motion_t[j] = scenes[0].t[j][F].norm();
  }
  std::vector<TrialOut> outs(static_cast<size_t>(L) * T);
  runJobs(L, T, o.threads,
          [&](int l, int i) {
            outs[static_cast<size_t>(l) * T + i] =
                runTrial(o, scenes[i], o.noise_px[l], noiseSeed(o.seed, i, o.noise_px[l]));
          },
          o.progress);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (int l = 0; l < L; ++l) {
    TwoObjectRow row;
    row.noise_px = o.noise_px[l];
    row.trials = T;
    for (int j = 0; j < 2; ++j) {
      row.rot_by_frame[j].assign(F + 1, 0.0);
      row.t_by_frame[j].assign(F + 1, 0.0);
      row.normal_by_frame[j].assign(F + 1, 0.0);
    }
    row.beta_by_frame.assign(F + 1, 0.0);
    int ok = 0;
    for (int i = 0; i < T; ++i) {
      const TrialOut& tr = outs[static_cast<size_t>(l) * T + i];
      if (tr.failed) {
        if (row.failed++ == 0) row.first_failure = tr.failure;
        continue;
      }
      ++ok;
      const TwoObjectScene& s = scenes[i];
      for (int j = 0; j < 2; ++j) {
        row.rot_err_deg[j] += tr.rot[j][F];
        row.t_err_pct[j] += 100.0 * tr.t[j][F] / s.t[j][F].norm();
        row.normal_err_deg[j] += tr.normal[j][F];
        for (int k = 0; k <= F; ++k) {
          row.rot_by_frame[j][k] += tr.rot[j][k];
          row.t_by_frame[j][k] += tr.t[j][k];
          row.normal_by_frame[j][k] += tr.normal[j][k];
        }
      }
      row.beta_err_pct += tr.beta[F];
      for (int k = 0; k <= F; ++k) row.beta_by_frame[k] += tr.beta[k];
    }
    auto finish = [&](double* v) { *v = ok ? *v / ok : nan; };
    for (int j = 0; j < 2; ++j) {
      finish(&row.rot_err_deg[j]);
      finish(&row.t_err_pct[j]);
      finish(&row.normal_err_deg[j]);
      for (int k = 0; k <= F; ++k) {
        finish(&row.rot_by_frame[j][k]);
        finish(&row.t_by_frame[j][k]);
        finish(&row.normal_by_frame[j][k]);
      }
    }
    finish(&row.beta_err_pct);
    for (int k = 0; k <= F; ++k) finish(&row.beta_by_frame[k]);
    res.rows.push_back(std::move(row));
  }
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace rsfm
