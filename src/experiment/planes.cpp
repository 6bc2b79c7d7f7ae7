#include "rsfm/experiment/planes.hpp"
#include "rsfm/units.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <mutex>
#include <stdexcept>
#include <thread>

#include "rsfm/batch/plane_batch.hpp"
#include "rsfm/camera.hpp"
#include "rsfm/experiment/parallel.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/models/point_model.hpp"
#include "rsfm/filters/recursive_filter.hpp"
#include "rsfm/sim/table1_scene.hpp"

namespace rsfm {
namespace {

const std::vector<std::string> kMethods{"point", "plane-per-face", "planes-rigid", "planes-rigid-iekf", "batch"};

/// What one method did in one trial.
struct MethodTrial {
  bool failed = false;
  std::string failure;
  double sum_t2 = 0, sum_q2 = 0;  // squared errors over components and frames 1..F (faces pooled)
  long n_t = 0, n_q = 0;
  std::vector<double> normal_err;  // per frame: mean over faces (radians)
  std::vector<double> t_err2;      // per frame: mean over pooled estimates of |t error|^2
  std::vector<Eigen::Vector3d> final_N;  // per face
  double beta_err = 0;             // mean over pooled estimates, last frame
  double crb_normal = -1, crb_beta = -1;
};

struct Truth {
  const BoxScene* scene;
  double beta;
};

int gaugeComponent(const Eigen::Vector3d& N) {
  int g = 0;
  N.cwiseAbs().maxCoeff(&g);
  return g;
}

void addMotionError(const Truth& tr, int k, const Eigen::Vector3d& t, const Eigen::Matrix3d& R,
                    MethodTrial* m, double weight_frames) {
  const Eigen::Vector3d et = t - tr.scene->t[k];
  const Eigen::Vector4d eq = canonical(Eigen::Quaterniond(R)).coeffs() -
                             canonical(Eigen::Quaterniond(tr.scene->R[k])).coeffs();
  m->sum_t2 += et.squaredNorm();
  m->n_t += 3;
  m->sum_q2 += eq.squaredNorm();
  m->n_q += 4;
  m->t_err2[k] += et.squaredNorm() * weight_frames;
}

FilterOptions filterOptions(const PlanesOptions& o, double noise_px) {
  FilterOptions fo;
  fo.reading = o.reading;
  // Noise-free data are filtered assuming 0.1 px (a zero R would make the first update absolute).
  fo.sigma_uv = std::max(noise_px, 0.1) / o.scene.scale_px;
  fo.q_motion << o.q_translation, o.q_translation, o.q_translation, o.q_omega, o.q_omega, o.q_omega, o.q_beta;
  fo.q_structure = o.q_structure;
  fo.update.gate_probability = o.gate_probability;
  parseReferenceModel(o.reference_model, &fo.reference);
  fo.beta_min = o.beta_min;
  fo.warmup_frames = o.warmup_frames;
  fo.iterate_after_frames = o.iekf_after;
  return fo;
}

/// Runs a plane filter over all frames on the points `ids` (labels `lab`, planes 0..m-1).
/// Returns false (and fills failure) on numerical trouble.
bool runPlaneFilterOnce(const PlanesOptions& o, double beta0, const FilterOptions& fo,
                    const std::vector<std::vector<Eigen::Vector2d>>& uv, const std::vector<int>& ids,
                    const std::vector<int>& lab, const std::vector<Eigen::Vector3d>& N0,
                    const std::vector<double>& nvar, int gauge_plane, int gauge_comp, std::vector<Eigen::Matrix3d>* Rs,
                    std::vector<Eigen::Vector3d>* ts, std::vector<std::vector<Eigen::Vector3d>>* Ns,
                    std::vector<double>* betas, std::vector<Eigen::Vector2d>* refs, std::string* failure) {
  const int m = static_cast<int>(N0.size());
  const int F = o.scene.frames;
  std::vector<Eigen::Vector2d> ref;
  for (int id : ids) ref.push_back(uv[0][id]);
  const int n = 7 + 3 * m;
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
  x0[idx::kBeta] = beta0;
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
  P0(idx::kBeta, idx::kBeta) = o.beta_var0;
  std::vector<bool> fixed(n, false);
  for (int j = 0; j < m; ++j) {
    x0.segment<3>(7 + 3 * j) = N0[j];
    for (int c = 0; c < 3; ++c) P0(7 + 3 * j + c, 7 + 3 * j + c) = nvar[j];
  }
  const int gi = 7 + 3 * gauge_plane + gauge_comp;
  P0(gi, gi) = 0.0;
  fixed[gi] = true;
  RecursiveFilter<PlaneModel> f(PlaneModel(ref, lab, m), Ekf(x0, P0, fixed), fo);
  Rs->assign(1, Eigen::Matrix3d::Identity());
  ts->assign(1, Eigen::Vector3d::Zero());
  Ns->assign(1, N0);
  betas->assign(1, beta0);
  std::vector<Observation> obs(ids.size());
  for (int k = 1; k <= F; ++k) {
    for (size_t i = 0; i < ids.size(); ++i) obs[i] = {static_cast<int>(i), uv[k][ids[i]]};
    const FrameStats& fs = f.step(obs);
    if (fs.health != kHealthy || !fs.update.applied) {
      *failure = "frame " + std::to_string(k) + ": " +
                 describeHealth(fs.health != kHealthy ? fs.health : fs.update.health);
      return false;
    }
    Rs->push_back(f.rotation());
    ts->push_back(f.ekf().x().head<3>());  // (t_X, t_Y, t_Z beta)
    std::vector<Eigen::Vector3d> N;
    for (int j = 0; j < m; ++j) N.push_back(f.ekf().x().segment<3>(7 + 3 * j));
    Ns->push_back(N);
    betas->push_back(f.beta());
  }
  if (refs) {
    refs->clear();
    for (size_t i = 0; i < ids.size(); ++i) refs->push_back(f.model().reference(static_cast<int>(i)));
  }
  return true;
}

/// The rigid filter over `o.passes` passes: pass p > 1 restarts from the reference frame with the
/// previous pass's final planes and beta as the initial state (same prior widths), which moves
/// only the linearization point (as `rsfm estimate --passes`, docs/estimate.md).
bool runPlaneFilter(const PlanesOptions& o, const FilterOptions& fo,
                    const std::vector<std::vector<Eigen::Vector2d>>& uv, const std::vector<int>& ids,
                    const std::vector<int>& lab, const std::vector<Eigen::Vector3d>& N0,
                    const std::vector<double>& nvar, int gauge_plane, int gauge_comp, std::vector<Eigen::Matrix3d>* Rs,
                    std::vector<Eigen::Vector3d>* ts, std::vector<std::vector<Eigen::Vector3d>>* Ns,
                    std::vector<double>* betas, std::vector<Eigen::Vector2d>* refs, std::string* failure) {
  std::vector<Eigen::Vector3d> N_start = N0;
  double beta_start = o.beta0;
  for (int pass = 1; pass <= std::max(1, o.passes); ++pass) {
    if (!runPlaneFilterOnce(o, beta_start, fo, uv, ids, lab, N_start, nvar, gauge_plane, gauge_comp, Rs, ts, Ns, betas,
                            refs, failure))
      return false;
    N_start = Ns->back();
    beta_start = betas->back();
  }
  return true;
}

struct TrialOut {
  std::vector<MethodTrial> methods;  // kMethods order
};

TrialOut runTrial(const PlanesOptions& o, const BoxScene& scene, double noise_px, std::uint64_t seed) {
  TrialOut out;
  out.methods.resize(kMethods.size());
  const int F = o.scene.frames;
  const int m = scene.faces();
  const int Np = static_cast<int>(scene.points.size());
  for (auto& mt : out.methods) {
    mt.normal_err.assign(F + 1, 0.0);
    mt.t_err2.assign(F + 1, 0.0);
  }
  std::mt19937_64 rng(seed);
  const auto uv = addUniformNoise(scene.uv, noise_px, o.scene.scale_px, rng);
  // Initial planes (seeded): truth + N(0, (n_rel |N|)^2) on the free components.
  std::normal_distribution<double> N01;
  std::vector<Eigen::Vector3d> N0(m);
  std::vector<double> nvar(m);
  std::vector<int> gauge(m);
  for (int j = 0; j < m; ++j) {
    gauge[j] = gaugeComponent(scene.planes[j]);
    N0[j] = scene.planes[j];
    const double sd = o.n_rel * scene.planes[j].norm();
    nvar[j] = sd * sd;
    for (int c = 0; c < 3; ++c)
      if (c != gauge[j]) N0[j][c] += sd * N01(rng);
  }
  const Truth truth{&scene, o.scene.beta};
  const FilterOptions fo = filterOptions(o, noise_px);
  std::vector<int> all(Np);
  for (int i = 0; i < Np; ++i) all[i] = i;

  auto recordPlanes = [&](MethodTrial* mt, int k, const std::vector<Eigen::Vector3d>& N) {
    double e = 0;
    for (int j = 0; j < m; ++j) e += normalAngle(N[j], scene.normals[j]) / m;
    mt->normal_err[k] = e;
  };

  // ---- planes-rigid (and its iterated variant) ----
  std::vector<Eigen::Matrix3d> Rs;
  std::vector<Eigen::Vector3d> ts;
  std::vector<std::vector<Eigen::Vector3d>> Ns;
  std::vector<double> betas;
  std::vector<Eigen::Vector2d> refs;
  for (int variant = 0; variant < 2; ++variant) {
    MethodTrial& mt = out.methods[variant == 0 ? 2 : 3];
    FilterOptions fv = fo;
    if (variant == 1) {
      if (o.iekf_iterations <= 1) {
        mt.failed = true;
        mt.failure = "not run (--iekf-iterations <= 1)";
        continue;
      }
      fv.iterations = o.iekf_iterations;
    }
    std::vector<Eigen::Matrix3d> R_;
    std::vector<Eigen::Vector3d> t_;
    std::vector<std::vector<Eigen::Vector3d>> N_;
    std::vector<double> b_;
    std::vector<Eigen::Vector2d> r_;
    if (!runPlaneFilter(o, fv, uv, all, scene.labels, N0, nvar, 0, gauge[0], &R_, &t_, &N_, &b_, &r_, &mt.failure)) {
      mt.failed = true;
      continue;
    }
    for (int k = 0; k <= F; ++k) {
      if (k > 0) addMotionError(truth, k, Eigen::Vector3d(t_[k].x(), t_[k].y(), t_[k].z() / b_[k]), R_[k], &mt, 1.0);
      recordPlanes(&mt, k, N_[k]);
    }
    mt.final_N = N_.back();
    mt.beta_err = std::abs(b_.back() - truth.beta) / truth.beta;
    if (variant == 0) Rs = R_, ts = t_, Ns = N_, betas = b_, refs = r_;
  }

  // ---- plane-per-face ----
  {
    MethodTrial& mt = out.methods[1];
    mt.final_N.resize(m);
    for (int j = 0; j < m && !mt.failed; ++j) {
      std::vector<int> ids;
      for (int i = 0; i < Np; ++i)
        if (scene.labels[i] == j) ids.push_back(i);
      std::vector<Eigen::Matrix3d> R_;
      std::vector<Eigen::Vector3d> t_;
      std::vector<std::vector<Eigen::Vector3d>> N_;
      std::vector<double> b_;
      if (!runPlaneFilter(o, fo, uv, ids, std::vector<int>(ids.size(), 0), {N0[j]}, {nvar[j]}, 0, gauge[j], &R_, &t_, &N_,
                          &b_, nullptr, &mt.failure)) {
        mt.failed = true;
        mt.failure = "face " + std::to_string(j) + " " + mt.failure;
        break;
      }
      for (int k = 0; k <= F; ++k) {
        // Per frame, the faces' filters are averaged (weight 1/m); the RMS pools them all.
        if (k > 0) addMotionError(truth, k, Eigen::Vector3d(t_[k].x(), t_[k].y(), t_[k].z() / b_[k]), R_[k], &mt, 1.0 / m);
        mt.normal_err[k] += normalAngle(N_[k][0], scene.normals[j]) / m;
      }
      mt.final_N[j] = N_.back()[0];
      mt.beta_err += std::abs(b_.back() - truth.beta) / truth.beta / m;
    }
  }

  // ---- point (A&P on all points; faces fitted to its 3-D points) ----
  {
    MethodTrial& mt = out.methods[0];
    const int n = 7 + Np;
    Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
    x0[idx::kBeta] = o.beta0;
    Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
    P0(idx::kBeta, idx::kBeta) = o.beta_var0;
    int g = 0;
    double best = HUGE_VAL;
    for (int i = 0; i < Np; ++i) {
      Eigen::Vector3d p, dpb;
      Eigen::Matrix3d dpN;
      const int l = scene.labels[i];
      double alpha = 1.0, var = 0.1;
      if (PlaneModel::point(N0[l], o.beta0, uv[0][i], &p, &dpb, &dpN) == MeasureStatus::Ok) {
        alpha = p.z();
        var = dpb.z() * dpb.z() * o.beta_var0;
        for (int c = 0; c < 3; ++c)
          if (c != gauge[l]) var += dpN(2, c) * dpN(2, c) * nvar[l];
      }
      x0[7 + i] = alpha;
      P0(7 + i, 7 + i) = std::max(var, 1e-6);
      if (uv[0][i].norm() < best) best = uv[0][i].norm(), g = i;
    }
    std::vector<bool> fixed(n, false);
    x0[7 + g] = scene.points[g].z();
    P0(7 + g, 7 + g) = 0.0;
    fixed[7 + g] = true;
    RecursiveFilter<PointModel> f{PointModel(uv[0]), Ekf(x0, P0, fixed), fo};
    auto fitFaces = [&](std::vector<Eigen::Vector3d>* N) {
      N->assign(m, Eigen::Vector3d::Zero());
      for (int j = 0; j < m; ++j) {
        std::vector<Eigen::Vector3d> pts;
        for (int i = 0; i < Np; ++i)
          if (scene.labels[i] == j) pts.push_back(PointModel::point(uv[0][i], f.ekf().x()[7 + i], f.beta()));
        Eigen::Vector3d nn;
        double d;
        if (!fitPlane(pts, &nn, &d)) return false;
        (*N)[j] = nn;  // unit normal suffices for the angle errors
      }
      return true;
    };
    std::vector<Eigen::Vector3d> N;
    recordPlanes(&mt, 0, N0);
    std::vector<Observation> obs(Np);
    for (int k = 1; k <= F; ++k) {
      for (int i = 0; i < Np; ++i) obs[i] = {i, uv[k][i]};
      const FrameStats& fs = f.step(obs);
      if (fs.health != kHealthy || !fs.update.applied) {
        mt.failed = true;
        mt.failure = "frame " + std::to_string(k) + ": " + describeHealth(fs.health != kHealthy ? fs.health : fs.update.health);
        break;
      }
      if (!fitFaces(&N)) {
        mt.failed = true;
        mt.failure = "frame " + std::to_string(k) + ": plane fit failed";
        break;
      }
      addMotionError(truth, k, f.translation(), f.rotation(), &mt, 1.0);
      recordPlanes(&mt, k, N);
    }
    if (!mt.failed) {
      mt.final_N = N;
      mt.beta_err = std::abs(f.beta() - truth.beta) / truth.beta;
    }
  }

  // ---- batch (multi-plane, references estimated), from planes-rigid ----
  {
    MethodTrial& mt = out.methods[4];
    if (!o.batch) {
      mt.failed = true;
      mt.failure = "not run (--batch false)";
    } else if (out.methods[2].failed) {
      mt.failed = true;
      mt.failure = "no start (planes-rigid stopped)";
    } else {
      PlaneBatchData data;
      data.frames.resize(F + 1);
      for (int k = 0; k <= F; ++k)
        for (int i = 0; i < Np; ++i) data.frames[k].push_back({i, uv[k][i]});
      data.labels = scene.labels;
      data.num_planes = m;
      data.sigma_uv = std::max(noise_px, 1e-3) / o.scene.scale_px;
      data.gauge_plane = 0;
      data.gauge_component = gauge[0];
      PlaneBatchState start;
      start.R = Rs;
      start.t = ts;
      start.beta = betas.back();
      start.N = Ns.back();
      start.ref = refs;
      const PlaneBatchResult r = solvePlaneBatch(data, start);
      if (!r.converged) {
        mt.failed = true;
        mt.failure = r.message;
      } else {
        const double b = r.state.beta;
        for (int k = 0; k <= F; ++k) {
          if (k > 0) addMotionError(truth, k, Eigen::Vector3d(r.state.t[k].x(), r.state.t[k].y(), r.state.t[k].z() / b), r.state.R[k], &mt, 1.0);
          recordPlanes(&mt, k, r.state.N);
        }
        mt.final_N = r.state.N;
        mt.beta_err = std::abs(b - truth.beta) / truth.beta;
        if (r.covariance_ok) {
          double cn = 0;
          for (int j = 0; j < m; ++j) cn += directionRmsAngle(r.state.N[j], r.cov_N[j]) / m;
          mt.crb_normal = cn;
          mt.crb_beta = std::sqrt(std::max(0.0, r.var_beta)) / truth.beta;
        }
      }
    }
  }
  return out;
}

}  // namespace

std::string validatePlanesOptions(const PlanesOptions& o) {
  if (auto msg = validateTrialsNoiseFrames(o.trials, o.noise_px, o.scene.frames); !msg.empty()) return msg;
  if (o.passes < 1 || o.passes > 10) return "--passes must be in 1..10";
  if (o.scene.points_per_face < PlaneModel::kMinPoints) return "--points-per-face must be at least 5";
  if (!(std::abs(o.scene.deg_per_frame * o.scene.frames) < 60.0))
    return "total rotation (--deg-per-frame x --frames) must stay under 60 degrees";
  if (!(o.beta0 > 0.0) || !(o.beta_var0 >= 0.0)) return "--beta0 must be positive, --beta-var non-negative";
  if (!(o.n_rel > 0.0) || !std::isfinite(o.n_rel)) return "--n-rel must be positive";
  for (double q : {o.q_translation, o.q_omega, o.q_beta, o.q_structure})
    if (!(q >= 0.0) || !std::isfinite(q)) return "process variances must be finite and non-negative";
  if (ReferenceModel r; !parseReferenceModel(o.reference_model, &r))
    return "--reference must be 'exact', 'inflate', 'refine', 'state' or 'conditional'";
  if (o.iekf_iterations < 0) return "--iekf-iterations must be non-negative";
  if (o.iekf_after < 0) return "--iekf-after must be non-negative";
  if (!(o.beta_min >= 0.0) || !(o.beta_min < o.beta0)) return "--beta-min must be non-negative and below --beta0";
  if (o.warmup_frames < 0) return "--warmup-frames must be non-negative";
  if (o.threads < 0) return "--threads must be non-negative";
  return {};
}

PlanesResult runPlanes(const PlanesOptions& o) {
  if (auto msg = validatePlanesOptions(o); !msg.empty()) throw std::invalid_argument(msg);
  const auto t0 = std::chrono::steady_clock::now();
  PlanesResult res;
  res.options = o;
  const int L = static_cast<int>(o.noise_px.size()), T = o.trials, F = o.scene.frames;
  std::vector<BoxScene> scenes;
  for (int i = 0; i < T; ++i) {
    std::mt19937_64 rng(mixSeed(o.seed, static_cast<std::uint64_t>(i), 0x9b0c5));
    scenes.push_back(makeBoxScene(o.scene, rng));
  }
  res.faces = scenes[0].faces();
  std::vector<TrialOut> outs(static_cast<size_t>(L) * T);
  runJobs(L, T, o.threads,
          [&](int l, int i) {
            outs[static_cast<size_t>(l) * T + i] = runTrial(o, scenes[i], o.noise_px[l], noiseSeed(o.seed, i, o.noise_px[l]));
          },
          o.progress);

  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (size_t mi = 0; mi < kMethods.size(); ++mi) {
    if (kMethods[mi] == "planes-rigid-iekf" && o.iekf_iterations <= 1) continue;
    if (kMethods[mi] == "batch" && !o.batch) continue;
    for (int l = 0; l < L; ++l) {
      PlanesRow row;
      row.method = kMethods[mi];
      row.noise_px = o.noise_px[l];
      row.trials = T;
      double st = 0, sq = 0, crbn = 0, crbb = 0;
      long nt = 0, nq = 0;
      int ok = 0, crb = 0, pairs = 0;
      row.normal_err_by_frame.assign(F + 1, 0.0);
      row.t_err_by_frame.assign(F + 1, 0.0);
      for (int i = 0; i < T; ++i) {
        const MethodTrial& mt = outs[static_cast<size_t>(l) * T + i].methods[mi];
        if (mt.failed) {
          if (row.failed++ == 0) row.first_failure = mt.failure;
          continue;
        }
        ++ok;
        st += mt.sum_t2, nt += mt.n_t, sq += mt.sum_q2, nq += mt.n_q;
        const BoxScene& sc = scenes[i];
        for (int j = 0; j < sc.faces(); ++j) row.normal_err_deg += normalAngle(mt.final_N[j], sc.normals[j]) * kRadToDeg / sc.faces();
        for (int a = 0; a < sc.faces(); ++a)
          for (int b = a + 1; b < sc.faces(); ++b) {
            const double ang = std::acos(std::clamp(std::abs(mt.final_N[a].normalized().dot(mt.final_N[b].normalized())), 0.0, 1.0));
            row.face_angle_err_deg += std::abs(ang * kRadToDeg - 90.0);
            ++pairs;
          }
        row.beta_err_pct += 100.0 * mt.beta_err;
        for (int k = 0; k <= F; ++k) {
          row.normal_err_by_frame[k] += mt.normal_err[k] * kRadToDeg;
          row.t_err_by_frame[k] += mt.t_err2[k];
        }
        if (mt.crb_normal >= 0) crbn += mt.crb_normal * kRadToDeg, crbb += 100.0 * mt.crb_beta, ++crb;
      }
      if (ok == 0) {
        row.rms_t = row.rms_q = row.normal_err_deg = row.face_angle_err_deg = row.beta_err_pct = nan;
      } else {
        row.rms_t = std::sqrt(st / nt);
        row.rms_q = std::sqrt(sq / nq);
        row.normal_err_deg /= ok;
        row.face_angle_err_deg = pairs ? row.face_angle_err_deg / pairs : nan;
        row.beta_err_pct /= ok;
        for (int k = 0; k <= F; ++k) {
          row.normal_err_by_frame[k] /= ok;
          row.t_err_by_frame[k] = std::sqrt(row.t_err_by_frame[k] / ok);
        }
        if (crb) row.crb_normal_deg = crbn / crb, row.crb_beta_pct = crbb / crb;
      }
      res.rows.push_back(row);
    }
  }
  // ratio_to_batch: the method's rms_t over the batch's, both on the trials where both succeeded.
  const size_t bi = std::find(kMethods.begin(), kMethods.end(), "batch") - kMethods.begin();
  for (auto& row : res.rows) {
    if (!o.batch) break;
    const size_t mi = std::find(kMethods.begin(), kMethods.end(), row.method) - kMethods.begin();
    const int l = static_cast<int>(std::find(o.noise_px.begin(), o.noise_px.end(), row.noise_px) - o.noise_px.begin());
    double sm = 0, sb = 0;
    long nm = 0, nb = 0;
    for (int i = 0; i < T; ++i) {
      const auto& tr = outs[static_cast<size_t>(l) * T + i].methods;
      if (tr[mi].failed || tr[bi].failed) continue;
      sm += tr[mi].sum_t2, nm += tr[mi].n_t, sb += tr[bi].sum_t2, nb += tr[bi].n_t;
    }
    if (nm > 0 && nb > 0 && sb / nb > 1e-18) row.ratio_to_batch = std::sqrt(sm / nm) / std::sqrt(sb / nb);
  }
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace rsfm
