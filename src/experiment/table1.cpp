#include "rsfm/experiment/table1.hpp"
#include "rsfm/units.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <thread>

#include "rsfm/batch/plane_batch.hpp"
#include "rsfm/camera.hpp"
#include "rsfm/experiment/parallel.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/models/point_model.hpp"
#include "rsfm/filters/recursive_filter.hpp"

namespace rsfm {
namespace {


/// Per-frame record of one filter in one trial.
struct Track {
  std::vector<Eigen::Vector3d> t;     // (t_X, t_Y, t_Z)
  std::vector<double> t_zb;           // t_Z beta (state component)
  std::vector<Eigen::Quaterniond> q;  // canonical
  std::vector<Eigen::Vector3d> N;     // plane N (N . X = 1)
  std::vector<double> beta;
  std::vector<double> normal_err;     // radians
  bool failed = false;
  std::string failure;
  double nees_static = 0.0;
  double nis_per_dof_sum = 0.0;
  int nis_frames = 0;
  long gated = 0;
  long invalid = 0;
  bool crb_ok = false;          // batch only: Cramer-Rao bounds at the optimum
  double crb_beta_sd = 0.0;
  double crb_normal_rad = 0.0;
};

struct Job {
  Track plane, point, plane_iekf, batch;
};

Eigen::VectorXd motionPrior(int n, double beta0) {
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n);
  x[idx::kBeta] = beta0;
  return x;
}

template <class Model>
void recordFrame(const RecursiveFilter<Model>& f, const Eigen::Vector3d& N, const Eigen::Vector3d& n_true,
                 Track* tr) {
  tr->t.push_back(f.translation());
  tr->t_zb.push_back(f.ekf().x()[idx::kTzB]);
  tr->q.push_back(canonical(Eigen::Quaterniond(f.rotation())));
  tr->N.push_back(N);
  tr->beta.push_back(f.beta());
  tr->normal_err.push_back(normalAngle(N, n_true));
}

std::string failureText(int frame, const FrameStats& fs, int points) {
  std::ostringstream os;
  os << "frame " << frame << ": ";
  if (fs.health != kHealthy) os << describeHealth(fs.health);
  else os << describeHealth(fs.update.health);
  if (fs.invalid > 0)
    os << " (" << fs.invalid << " of " << points << " predictions failed: " << toString(fs.first_problem) << ")";
  return os.str();
}

/// Fitted plane of the point model's current 3-D points ([AS99] §4: "fitting a plane").
bool pointModelPlane(const RecursiveFilter<PointModel>& f, Eigen::Vector3d* N) {
  const auto& x = f.ekf().x();
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < f.model().numPoints(); ++i)
    pts.push_back(PointModel::point(f.model().reference(i), x[PointModel::alphaIndex(i)], f.beta()));
  Eigen::Vector3d n;
  double d;
  return fitPlane(pts, &n, &d) && planeFromNormalOffset(n, d, N);
}

/// Runs frames 1..F of one filter on all points, recording each frame; stops the trial on
/// numerical trouble (failed predictions are left out of their frame and counted).
template <class Model, class PlaneOf>
void runFrames(RecursiveFilter<Model>& f, const std::vector<std::vector<Eigen::Vector2d>>& uv, int F,
               const std::string& name, const Eigen::Vector3d& n_true, PlaneOf planeOf, Track* tr) {
  const int Np = static_cast<int>(uv[0].size());
  std::vector<Observation> obs(Np);
  for (int k = 1; k <= F; ++k) {
    for (int i = 0; i < Np; ++i) obs[i] = {i, uv[k][i]};
    const FrameStats& fs = f.step(obs);
    tr->gated += fs.update.gated;
    tr->invalid += fs.invalid;
    if (fs.health != kHealthy || !fs.update.applied) {
      tr->failed = true;
      tr->failure = name + " " + failureText(k, fs, f.model().numPoints());
      return;
    }
    if (fs.update.nis_dof > 0) {
      tr->nis_per_dof_sum += fs.update.nis / fs.update.nis_dof;
      ++tr->nis_frames;
    }
    Eigen::Vector3d N;
    if (!planeOf(f, &N)) {
      tr->failed = true;
      tr->failure = name + " frame " + std::to_string(k) + ": plane fit failed";
      return;
    }
    recordFrame(f, N, n_true, tr);
  }
}

/// The plane filter on all points; records into *tr and, if asked, returns its per-frame
/// estimates (and final references) as a batch start.
void runPlaneFilter(const Table1Options& o, const FilterOptions& fo,
                    const std::vector<std::vector<Eigen::Vector2d>>& uv, const Eigen::Vector3d& n_true,
                    Track* tr, PlaneBatchState* start) {
  const int F = o.scene.frames;
  const int Np = static_cast<int>(uv[0].size());
  PlaneModel model(uv[0], std::vector<int>(Np, 0), 1);
  Eigen::VectorXd x0 = motionPrior(10, o.beta0);
  x0.segment<3>(7) = o.N0;
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(10, 10);
  P0(idx::kBeta, idx::kBeta) = o.beta_var0;
  std::vector<bool> fixed(10, false);
  for (int j = 0; j < 3; ++j) {
    P0(7 + j, 7 + j) = o.N_var0[j];
    fixed[7 + j] = o.N_var0[j] == 0.0;  // the scale gauge (paper: N_Z)
  }
  RecursiveFilter<PlaneModel> f(std::move(model), Ekf(x0, P0, fixed), fo);
  recordFrame(f, o.N0, n_true, tr);
  runFrames(f, uv, F, "plane", n_true,
            [](const RecursiveFilter<PlaneModel>& ff, Eigen::Vector3d* N) {
              *N = ff.ekf().x().segment<3>(7);
              return true;
            },
            tr);
  if (tr->failed) return;
  // NEES of the free static parameters (beta, N_X, N_Y) at the last frame.
  const auto& x = f.ekf().x();
  const Eigen::Vector3d e(x[6] - o.scene.beta, x[7] - o.scene.plane.x(), x[8] - o.scene.plane.y());
  const Eigen::Matrix3d Ps = f.ekf().P().block<3, 3>(6, 6);
  tr->nees_static = e.dot(Ps.ldlt().solve(e));
  if (start) {
    start->R.clear();
    start->t.clear();
    for (int k = 0; k <= F; ++k) {
      start->R.push_back(tr->q[k].toRotationMatrix());
      start->t.push_back(Eigen::Vector3d(tr->t[k].x(), tr->t[k].y(), tr->t_zb[k]));
    }
    start->beta = f.beta();
    start->N = {x.segment<3>(7)};
    start->ref.clear();
    for (int i = 0; i < Np; ++i) start->ref.push_back(f.model().reference(i));
  }
}

/// The batch (maximum-likelihood) reference started from the plane filter's estimates.
void runBatch(const Table1Options& o, const std::vector<std::vector<Eigen::Vector2d>>& uv,
              double noise_px, const Eigen::Vector3d& n_true, const Track& plane,
              const PlaneBatchState& start, Track* tr) {
  const int F = o.scene.frames;
  const int Np = static_cast<int>(uv[0].size());
  if (plane.failed) {
    tr->failed = true;
    tr->failure = "batch: no start (the plane filter stopped)";
    return;
  }
  PlaneBatchData data;
  data.frames.resize(F + 1);
  for (int k = 0; k <= F; ++k)
    for (int i = 0; i < Np; ++i) data.frames[k].push_back({i, uv[k][i]});
  data.labels.assign(Np, 0);
  data.sigma_uv = std::max(noise_px, 1e-3) / o.scene.scale_px;
  data.gauge_component = 2;
  for (int j = 0; j < 3; ++j)
    if (o.N_var0[j] == 0.0) data.gauge_component = j;
  PlaneBatchOptions bo;
  bo.estimate_references = o.reference_noise;
  const PlaneBatchResult r = solvePlaneBatch(data, start, bo);
  if (!r.converged) {
    tr->failed = true;
    tr->failure = "batch: " + r.message;
    return;
  }
  const double beta = r.state.beta;
  const Eigen::Vector3d N = r.state.N[0];
  for (int k = 0; k <= F; ++k) {
    const Eigen::Vector3d& t = r.state.t[k];
    tr->t.push_back(Eigen::Vector3d(t.x(), t.y(), t.z() / beta));
    tr->t_zb.push_back(t.z());
    tr->q.push_back(canonical(Eigen::Quaterniond(r.state.R[k])));
    tr->N.push_back(N);
    tr->beta.push_back(beta);
    tr->normal_err.push_back(normalAngle(N, n_true));
  }
  if (r.covariance_ok) {
    // Cramer-Rao bounds: beta's standard deviation and the RMS angle of the unit normal,
    // cov(n) = J cov(N) J^T with J = (I - n n^T) / |N|.
    tr->crb_beta_sd = std::sqrt(std::max(0.0, r.var_beta));
    tr->crb_normal_rad = directionRmsAngle(N, r.cov_N[0]);
    tr->crb_ok = true;
  }
}

Job runJob(const Table1Options& o, const Table1Scene& scene, double noise_px, std::uint64_t noise_seed) {
  Job job;
  std::mt19937_64 rng(noise_seed);
  auto uv = addUniformNoise(scene.uv, noise_px, o.scene.scale_px, rng);
  if (!o.reference_noise) uv[0] = scene.uv[0];
  const int F = o.scene.frames;
  const int Np = static_cast<int>(scene.points.size());
  const Eigen::Vector3d n_true = scene.unitNormal();

  FilterOptions fo;
  fo.reading = o.reading;
  fo.sigma_uv = std::sqrt(o.r_scale) * std::max(noise_px, 1e-3) / o.scene.scale_px;
  fo.q_motion << o.q_translation, o.q_translation, o.q_translation, o.q_omega, o.q_omega,
      o.q_omega, o.q_beta;
  fo.q_structure = o.q_structure;
  fo.iterations = o.iterations;
  fo.iterate_after_frames = o.iekf_after;
  parseReferenceModel(o.reference_model, &fo.reference);
  // The reference frame carries the same noise as the others (or none).
  fo.reference_sigma = o.reference_noise ? fo.sigma_uv / std::sqrt(o.r_scale) : 0.0;
  fo.update.gate_probability = o.gate_probability;

  // ---- plane filter (state 10), its iterated variant, and the batch reference ----
  PlaneBatchState from_filter;
  runPlaneFilter(o, fo, uv, n_true, &job.plane, &from_filter);
  if (o.iekf_iterations > 1) {
    FilterOptions fi = fo;
    fi.iterations = o.iekf_iterations;
    runPlaneFilter(o, fi, uv, n_true, &job.plane_iekf, nullptr);
  }
  if (o.batch) runBatch(o, uv, noise_px, n_true, job.plane, from_filter, &job.batch);

  // ---- point filter (state 7 + N) ----
  {
    PointModel model(uv[0]);
    const int n = 7 + Np;
    Eigen::VectorXd x0 = motionPrior(n, o.beta0);
    Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
    P0(idx::kBeta, idx::kBeta) = o.beta_var0;
    int gauge = o.point_gauge;
    if (gauge < 0) {
      double best = HUGE_VAL;
      for (int i = 0; i < Np; ++i)
        if (uv[0][i].norm() < best) best = uv[0][i].norm(), gauge = i;
    }
    std::vector<bool> fixed(n, false);
    for (int i = 0; i < Np; ++i) {
      Eigen::Vector3d p, dpb;
      Eigen::Matrix3d dpN;
      double alpha = 1.0 / o.N0.z(), var = o.alpha_var;
      if (PlaneModel::point(o.N0, o.beta0, uv[0][i], &p, &dpb, &dpN) == MeasureStatus::Ok) {
        if (o.alpha_init == "plane") alpha = p.z();
        if (var <= 0.0) {
          var = dpb.z() * dpb.z() * o.beta_var0;
          for (int j = 0; j < 3; ++j) var += dpN(2, j) * dpN(2, j) * o.N_var0[j];
        }
      } else if (var <= 0.0) {
        var = 0.1;
      }
      x0[7 + i] = alpha;
      P0(7 + i, 7 + i) = var;
    }
    x0[7 + gauge] = scene.points[gauge].z();  // true depth: same scale as the plane's N_Z
    fixed[7 + gauge] = true;
    RecursiveFilter<PointModel> f(std::move(model), Ekf(x0, P0, fixed), fo);
    Track& tr = job.point;
    Eigen::Vector3d N;
    if (!pointModelPlane(f, &N)) N = o.N0;
    recordFrame(f, N, n_true, &tr);
    runFrames(f, uv, F, "point", n_true, pointModelPlane, &tr);
  }
  return job;
}

int convergenceFrame(const std::vector<double>& err, double tol) {
  // First frame from which err stays <= tol through the last frame; -1 if never.
  int r = -1;
  for (int k = static_cast<int>(err.size()) - 1; k >= 0; --k) {
    if (!(err[k] <= tol)) break;
    r = k;
  }
  return r;
}

void aggregate(const Table1Options& o, const Table1Scene& scene0, const std::vector<const Track*>& tracks,
               const std::string& name, double noise, Table1Row* row, Table1Series* ser) {
  const int F = o.scene.frames;
  row->formulation = ser->formulation = name;
  row->noise_px = ser->noise_px = noise;
  row->trials = static_cast<int>(tracks.size());
  std::vector<const Track*> ok;
  for (const Track* t : tracks) {
    if (t->failed) {
      if (row->failed == 0) row->first_failure = t->failure;
      ++row->failed;
    } else {
      ok.push_back(t);
    }
    row->gated += t->gated;
    row->invalid += t->invalid;
  }
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (ok.empty()) {  // every trial stopped: nothing can be computed (written NA)
    row->m_t = row->sigma_t = row->m_q = row->sigma_q = nan;
    row->median_trial_sigma_t = row->median_trial_sigma_q = nan;
    row->final_normal_err_deg = row->final_beta_err_pct = nan;
    row->mean_nis_per_dof = row->nees_static = nan;
    row->r_s = row->r_c = Table1Row::kNotComputed;
    return;
  }
  const double K = static_cast<double>(ok.size());
  double st = 0, st2 = 0, sq = 0, sq2 = 0, nis = 0;
  long ct = 0, cq = 0, nisn = 0;
  for (auto* v : {&ser->t_x, &ser->t_zb, &ser->q0, &ser->q2, &ser->n_x, &ser->n_y, &ser->beta,
                  &ser->normal_err_deg})
    v->assign(F + 1, 0.0);
  std::vector<double> trial_t, trial_q;
  for (const Track* t : ok) {
    double tt2 = 0, tq2 = 0;
    for (int k = 0; k <= F; ++k) {
      const Eigen::Quaterniond qt = canonical(Eigen::Quaterniond(scene0.R[k]));
      if (k > 0) {
        const Eigen::Vector3d et = t->t[k] - scene0.t[k];
        for (int j = 0; j < 3; ++j) st += et[j], st2 += et[j] * et[j], ++ct;
        const Eigen::Vector4d eq = t->q[k].coeffs() - qt.coeffs();
        for (int j = 0; j < 4; ++j) sq += eq[j], sq2 += eq[j] * eq[j], ++cq;
        tt2 += et.squaredNorm();
        tq2 += eq.squaredNorm();
      }
      ser->t_x[k] += t->t[k].x() / K;
      ser->t_zb[k] += t->t_zb[k] / K;
      ser->q0[k] += t->q[k].w() / K;
      ser->q2[k] += t->q[k].y() / K;
      ser->n_x[k] += t->N[k].x() / K;
      ser->n_y[k] += t->N[k].y() / K;
      ser->beta[k] += t->beta[k] / K;
      ser->normal_err_deg[k] += t->normal_err[k] * kRadToDeg / K;
    }
    trial_t.push_back(std::sqrt(tt2 / (3.0 * F)));
    trial_q.push_back(std::sqrt(tq2 / (4.0 * F)));
    row->final_normal_err_deg += t->normal_err[F] * kRadToDeg / K;
    row->final_beta_err_pct += 100.0 * std::abs(t->beta[F] - o.scene.beta) / o.scene.beta / K;
    row->nees_static += t->nees_static / K;
    nis += t->nis_per_dof_sum;
    nisn += t->nis_frames;
  }
  row->m_t = st / ct;
  row->sigma_t = std::sqrt(st2 / ct);
  row->m_q = sq / cq;
  row->sigma_q = std::sqrt(sq2 / cq);
  row->mean_nis_per_dof = nisn ? nis / nisn : nan;
  auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    const size_t n = v.size();
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
  };
  row->median_trial_sigma_t = median(trial_t);
  row->median_trial_sigma_q = median(trial_q);
  row->nees_dof = (name == "plane" || name == "plane-iekf") ? 3 : 0;
  if (row->nees_dof == 0) row->nees_static = 0;
  int crb_n = 0;
  row->crb_beta_pct = row->crb_normal_deg = 0.0;
  for (const Track* t : ok)
    if (t->crb_ok) {
      row->crb_beta_pct += 100.0 * t->crb_beta_sd / o.scene.beta;
      row->crb_normal_deg += t->crb_normal_rad * kRadToDeg;
      ++crb_n;
    }
  if (crb_n > 0) {
    row->crb_beta_pct /= crb_n;
    row->crb_normal_deg /= crb_n;
  } else {
    row->crb_beta_pct = row->crb_normal_deg = -1.0;
  }
  // Convergence on the trial-averaged estimates (the curves of [AS99] Fig. 1).
  std::vector<double> nerr(F + 1), berr(F + 1);
  std::vector<Eigen::Vector3d> Nm(F + 1, Eigen::Vector3d::Zero());
  for (const Track* t : ok)
    for (int k = 0; k <= F; ++k) Nm[k] += t->N[k] / K;
  for (int k = 0; k <= F; ++k) {
    nerr[k] = normalAngle(Nm[k], scene0.unitNormal()) * kRadToDeg;
    berr[k] = std::abs(ser->beta[k] - o.scene.beta) / o.scene.beta;
  }
  row->r_s = convergenceFrame(nerr, 0.5);
  row->r_c = convergenceFrame(berr, 0.05);
}

}  // namespace

std::string validateTable1Options(const Table1Options& o) {
  if (auto msg = validateTrialsNoiseFrames(o.trials, o.noise_px, o.scene.frames); !msg.empty()) return msg;
  if (o.scene.points < PointModel::kMinPoints)
    return "--points must be at least 7 (A&P need 7 points; the plane model 5)";
  if (!(o.scene.scale_px > 0.0)) return "--scale-px must be positive";
  if (!(std::abs(o.scene.deg_per_frame * o.scene.frames) < 60.0))
    return "total rotation (--deg-per-frame x --frames) must stay under 60 degrees";
  if (!(o.beta0 > 0.0)) return "--beta0 must be positive";
  if (!(o.N_var0.minCoeff() == 0.0) || !(o.N_var0.maxCoeff() >= 0.0))
    return "the initial plane variances must be non-negative with one component 0 (the scale gauge)";
  if (!(o.beta_var0 >= 0.0)) return "--beta-var must be non-negative";
  for (double q : {o.q_translation, o.q_omega, o.q_beta, o.q_structure})
    if (!(q >= 0.0) || !std::isfinite(q)) return "process variances must be finite and non-negative";
  if (!(o.r_scale > 0.0)) return "--r-scale must be positive";
  if (o.alpha_init != "plane" && o.alpha_init != "constant")
    return "--alpha-init must be 'plane' or 'constant'";
  if (o.point_gauge >= o.scene.points) return "--point-gauge must be below --points";
  if (o.threads < 0) return "--threads must be non-negative";
  if (o.iterations < 1) return "--iterations must be at least 1";
  if (o.iekf_iterations < 0) return "--iekf-iterations must be non-negative";
  if (o.iekf_after < 0) return "--iekf-after must be non-negative";
  if (ReferenceModel r; !parseReferenceModel(o.reference_model, &r))
    return "--reference must be 'exact', 'inflate', 'refine', 'state' or 'conditional'";
  return {};
}

Table1Result runTable1(const Table1Options& o) {
  if (auto msg = validateTable1Options(o); !msg.empty()) throw std::invalid_argument(msg);
  const auto t0 = std::chrono::steady_clock::now();
  Table1Result res;
  res.options = o;
  const int L = static_cast<int>(o.noise_px.size());
  const int T = o.trials;
  // Scenes: one per trial, shared by all noise levels and both formulations.
  std::vector<Table1Scene> scenes;
  for (int i = 0; i < T; ++i) {
    std::mt19937_64 rng(mixSeed(o.seed, static_cast<std::uint64_t>(i)));
    scenes.push_back(makeTable1Scene(o.scene, rng));
  }
  std::vector<Job> jobs(static_cast<size_t>(L) * T);
  runJobs(L, T, o.threads,
          [&](int l, int i) {
            jobs[static_cast<size_t>(l) * T + i] = runJob(o, scenes[i], o.noise_px[l], noiseSeed(o.seed, i, o.noise_px[l]));
          },
          o.progress);

  // Truth series (the scene's motion is the same in every trial).
  const Table1Scene& s0 = scenes[0];
  for (int k = 0; k <= o.scene.frames; ++k) {
    const Eigen::Quaterniond q = canonical(Eigen::Quaterniond(s0.R[k]));
    res.truth.t_x.push_back(s0.t[k].x());
    res.truth.t_zb.push_back(s0.t[k].z() * o.scene.beta);
    res.truth.q0.push_back(q.w());
    res.truth.q2.push_back(q.y());
  }
  res.truth.n_x = o.scene.plane.x();
  res.truth.n_y = o.scene.plane.y();
  res.truth.beta = o.scene.beta;

  std::vector<std::string> names{"plane"};
  if (o.iekf_iterations > 1) names.push_back("plane-iekf");
  if (o.batch) names.push_back("batch");
  names.push_back("point");
  for (const std::string& name : names)
    for (int l = 0; l < L; ++l) {
      std::vector<const Track*> tracks;
      for (int i = 0; i < T; ++i) {
        const Job& jb = jobs[static_cast<size_t>(l) * T + i];
        tracks.push_back(name == "plane"        ? &jb.plane
                         : name == "plane-iekf" ? &jb.plane_iekf
                         : name == "batch"      ? &jb.batch
                                                : &jb.point);
      }
      Table1Row row;
      Table1Series ser;
      aggregate(o, s0, tracks, name, o.noise_px[l], &row, &ser);
      res.rows.push_back(row);
      res.series.push_back(ser);
    }
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace rsfm
