// Calway's synthetic experiment ([Cal00]; docs/patches.md). See patches.hpp.
#include "rsfm/experiment/patches.hpp"
#include "rsfm/units.hpp"

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <stdexcept>

#include "rsfm/camera.hpp"
#include "rsfm/experiment/parallel.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/models/point_model.hpp"
#include "rsfm/filters/patch_filter.hpp"
#include "rsfm/filters/recursive_filter.hpp"

namespace rsfm {

namespace {


/// One filter's run over one trial.
struct Run {
  bool failed = false;
  std::string failure;
  std::vector<double> normal, beta_pct, plane_fit;  // per frame 0..F
  double max_normal_last = 0;
  double sq_t = 0, sq_q = 0;  // sums of squared component errors, frames 1..F
  int n_t = 0, n_q = 0;
};

struct TrialData {
  PatchScene scene;
  std::vector<std::vector<Vector6d>> z;             // [frame >= 1][patch] noisy (h, A)
  std::vector<std::vector<Eigen::Vector2d>> centre;  // [frame][patch] noisy centres (= z's h for k >= 1)
  Vector6d sd;
  int gauge = 0;
};

void poseErrors(const Eigen::Vector3d& pos, const Eigen::Quaterniond& q, const PatchScene& s, int k, Run* r) {
  const CameraPose truth = copCentredPose(s.R[k], s.t[k], s.beta);
  r->sq_t += (pos - truth.position).squaredNorm();
  r->n_t += 3;
  const Eigen::Quaterniond a = canonical(q), b = canonical(truth.orientation);
  r->sq_q += (a.coeffs() - b.coeffs()).squaredNorm();
  r->n_q += 4;
}

bool fitNormal(const std::vector<Eigen::Vector3d>& pts, Eigen::Vector3d* n) {
  double d;
  return pts.size() >= 3 && fitPlane(pts, n, &d);
}

Run runPatchFilter(const PatchesOptions& o, const TrialData& td, AffineMeasurement kind, bool plane_scene) {
  const PatchScene& s = td.scene;
  const int K = s.patches(), F = s.frames(), n = 7 + 3 * K;
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
  x0[6] = o.beta0;
  for (int j = 0; j < 6; ++j) P0(j, j) = o.motion_var0;
  P0(6, 6) = o.beta_var0;
  const double g0 = s.structure[0][td.gauge][2];  // the gauge's true p4 (first frame)
  for (int k = 0; k < K; ++k) {
    const int i = PatchModel::structureIndex(k);
    x0.segment<3>(i) << 0.0, 0.0, g0;
    P0(i, i) = P0(i + 1, i + 1) = o.normal_var0;
    P0(i + 2, i + 2) = std::pow(o.depth_rel_sd0 * g0, 2);
  }
  PatchFilterOptions fo;
  fo.measurement = kind;
  fo.measurement_sd = td.sd;
  fo.q_motion << o.q_translation, o.q_translation, o.q_translation, o.q_omega, o.q_omega, o.q_omega, 0.0;
  fo.update.gate_probability = o.gate_probability;
  fo.anneal_frames = o.anneal_frames >= 0 ? o.anneal_frames : F / 2;
  fo.anneal_factor = o.anneal_factor;
  fo.centres = o.centres;
  fo.centre_sd = 0.5 * (td.sd[0] + td.sd[1]);
  fo.iterations = o.iterations;
  fo.q_structure = o.q_structure;
  PatchFilter f(PatchModel(td.centre[0]), Ekf(x0, P0, std::vector<bool>(n, false)), td.gauge, fo);
  Run r;
  auto record = [&](int k) {
    double sum = 0, mx = 0;
    std::vector<Eigen::Vector3d> pts;
    for (int p = 0; p < K; ++p) {
      const double e = normalAngle(f.normal(p), s.normal[k][p]) * kRadToDeg;
      sum += e;
      mx = std::max(mx, e);
      const Eigen::Vector2d c = f.model().centre(p);
      const double Z = PatchModel::depthAt(f.structure(p), f.beta(), c);
      pts.emplace_back(c.x() * (1.0 + f.beta() * Z), c.y() * (1.0 + f.beta() * Z), Z);
    }
    r.normal.push_back(sum / K);
    r.max_normal_last = mx;
    r.beta_pct.push_back(100.0 * std::abs(f.beta() - s.beta) / s.beta);
    Eigen::Vector3d nf;
    r.plane_fit.push_back(plane_scene && fitNormal(pts, &nf) ? normalAngle(nf, s.R[k] * s.plane_normal0) * kRadToDeg
                                                           : NAN);
  };
  record(0);
  std::vector<AffineObservation> obs(K);
  for (int k = 1; k <= F; ++k) {
    for (int p = 0; p < K; ++p) obs[p] = {p, td.z[k][p]};
    const PatchFrameStats fs = f.step(obs);
    if (fs.health != kHealthy || fs.transition != MeasureStatus::Ok) {
      r.failed = true;
      r.failure = "frame " + std::to_string(k) + ": " +
                  (fs.transition != MeasureStatus::Ok ? std::string(toString(fs.transition)) : describeHealth(fs.health));
      return r;
    }
    record(k);
    const Eigen::Matrix3d Rc = f.rotation().transpose();
    poseErrors(-Rc * f.translation(), Eigen::Quaterniond(Rc), s, k, &r);
  }
  return r;
}

Run runPointFilter(const PatchesOptions& o, const TrialData& td, bool plane_scene) {
  const PatchScene& s = td.scene;
  const int K = s.patches(), F = s.frames(), n = 7 + K;
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
  x0[6] = o.beta0;
  P0(6, 6) = o.beta_var0;
  const double z0 = s.centre_points0[td.gauge].z();  // the gauge's true depth
  std::vector<bool> fixed(n, false);
  for (int k = 0; k < K; ++k) {
    x0[7 + k] = z0;
    P0(7 + k, 7 + k) = std::pow(o.depth_rel_sd0 * z0, 2);
  }
  P0(7 + td.gauge, 7 + td.gauge) = 0.0;
  fixed[7 + td.gauge] = true;
  FilterOptions fo;
  fo.reading = RotationReading::Reset;
  fo.sigma_uv = 0.5 * (td.sd[0] + td.sd[1]);
  fo.q_motion << o.point_q_translation, o.point_q_translation, o.point_q_translation, o.point_q_omega,
      o.point_q_omega, o.point_q_omega, 0.0;
  fo.reference = ReferenceModel::Refine;
  fo.update.gate_probability = o.gate_probability;
  RecursiveFilter<PointModel> f(PointModel(td.centre[0]), Ekf(x0, P0, fixed), fo);
  Run r;
  auto record = [&] {
    std::vector<Eigen::Vector3d> pts;
    for (int p = 0; p < K; ++p)
      pts.push_back(PointModel::point(f.model().reference(p), f.ekf().x()[7 + p], f.beta()));
    Eigen::Vector3d nf;
    const double e = plane_scene && fitNormal(pts, &nf) ? normalAngle(nf, s.plane_normal0) * kRadToDeg : NAN;
    r.normal.push_back(e);
    r.plane_fit.push_back(e);
    r.beta_pct.push_back(100.0 * std::abs(f.beta() - s.beta) / s.beta);
  };
  record();
  std::vector<Observation> obs(K);
  for (int k = 1; k <= F; ++k) {
    for (int p = 0; p < K; ++p) obs[p] = {p, td.centre[k][p]};
    const FrameStats& fs = f.step(obs);
    if (fs.health != kHealthy) {
      r.failed = true;
      r.failure = "frame " + std::to_string(k) + ": " + describeHealth(fs.health);
      return r;
    }
    record();
    const CameraPose pose = copCentredPose(f.rotation(), f.translation(), f.beta());
    poseErrors(pose.position, pose.orientation, s, k, &r);
  }
  return r;
}

TrialData makeTrial(const PatchesOptions& o, bool plane_scene, int trial, double rho) {
  TrialData td;
  std::mt19937_64 scene_rng(mixSeed(o.seed, static_cast<std::uint64_t>(trial), plane_scene ? 2 : 1));
  td.scene = plane_scene ? makePlanePatchScene(o.plane, scene_rng) : makeSphereScene(o.sphere, scene_rng);
  const PatchScene& s = td.scene;
  td.sd = relativeNoiseSd(s, rho);
  std::mt19937_64 rng(noiseSeed(o.seed, trial, rho * 1000.0 + (plane_scene ? 0.5 : 0.0)));
  std::normal_distribution<double> gauss(0.0, 1.0);
  const int K = s.patches(), F = s.frames();
  td.z.assign(F + 1, std::vector<Vector6d>(K, Vector6d::Zero()));
  td.centre.assign(F + 1, std::vector<Eigen::Vector2d>(K));
  for (int p = 0; p < K; ++p)
    td.centre[0][p] = s.centre[0][p] + Eigen::Vector2d(gauss(rng) * td.sd[0], gauss(rng) * td.sd[1]);
  for (int k = 1; k <= F; ++k)
    for (int p = 0; p < K; ++p) {
      Vector6d e;
      for (int j = 0; j < 6; ++j) e[j] = gauss(rng) * td.sd[j];
      td.z[k][p] = s.affine[k][p] + e;
      td.centre[k][p] = td.z[k][p].head<2>();
    }
  // Sd of zero (a parameter that never moves) would make R singular: floor it.
  for (int j = 0; j < 6; ++j) td.sd[j] = std::max(td.sd[j], 1e-9);
  double best = HUGE_VAL;
  for (int p = 0; p < K; ++p)
    if (s.centre[0][p].norm() < best) best = s.centre[0][p].norm(), td.gauge = p;
  return td;
}

int convergenceFrame(const std::vector<double>& normal, const std::vector<double>& beta, double tn, double tb) {
  int r = -1;
  for (int k = static_cast<int>(beta.size()) - 1; k >= 0; --k) {
    const bool nok = !std::isfinite(normal[k]) || normal[k] <= tn;
    if (!(nok && beta[k] <= tb)) break;
    r = k;
  }
  return r;
}

}  // namespace

std::string validatePatchesOptions(const PatchesOptions& o) {
  if (o.trials < 1) return "--trials must be at least 1";
  if (o.sphere_noise.empty() && o.plane_noise.empty()) return "at least one noise level is required";
  for (const auto* v : {&o.sphere_noise, &o.plane_noise})
    for (double r : *v)
      if (!(r > 0.0) || !std::isfinite(r)) return "noise levels must be finite and positive (R is built from them)";
  if (o.sphere.frames < 1 || o.plane.table1.frames < 1) return "--frames must be at least 1";
  if (o.sphere.patches < PatchModel::kMinPatches || o.plane.patches < PointModel::kMinPoints)
    return "too few patches (the sphere needs 3, the plane scene 7 for the point filter)";
  if (!(o.beta0 > 0.0)) return "beta0 must be positive";
  if (!(o.sphere.max_obliquity_deg > 0.0 && o.sphere.max_obliquity_deg <= 90.0))
    return "--sphere-max-obliquity must be in (0, 90] degrees";
  if (o.anneal_frames < -1) return "--anneal-frames must be -1 (half of each sequence), 0 (none) or a frame count";
  return {};
}

PatchesResult runPatches(const PatchesOptions& o) {
  if (const std::string e = validatePatchesOptions(o); !e.empty()) throw std::invalid_argument(e);
  const auto t0 = std::chrono::steady_clock::now();
  struct Level {
    bool plane;
    double rho;
  };
  std::vector<Level> levels;
  for (double r : o.sphere_noise) levels.push_back({false, r});
  for (double r : o.plane_noise) levels.push_back({true, r});
  const char* names[3] = {"exact", "instantaneous", "point-centres"};
  // runs[level][trial][method]
  std::vector<std::vector<std::array<Run, 3>>> runs(levels.size(), std::vector<std::array<Run, 3>>(o.trials));
  runJobs(static_cast<int>(levels.size()), o.trials, o.threads,
          [&](int l, int trial) {
            TrialData td;
            try {
              td = makeTrial(o, levels[l].plane, trial, levels[l].rho);
            } catch (const std::exception& e) {
              for (Run& r : runs[l][trial]) r.failed = true, r.failure = e.what();
              return;
            }
            runs[l][trial][0] = runPatchFilter(o, td, AffineMeasurement::Exact, levels[l].plane);
            runs[l][trial][1] = runPatchFilter(o, td, AffineMeasurement::Instantaneous, levels[l].plane);
            runs[l][trial][2] = runPointFilter(o, td, levels[l].plane);
          },
          o.progress);
  PatchesResult res;
  res.options = o;
  res.options.progress = nullptr;
  for (size_t l = 0; l < levels.size(); ++l)
    for (int m = 0; m < 3; ++m) {
      PatchesRow row;
      row.scene = levels[l].plane ? "plane" : "sphere";
      row.measurement = names[m];
      row.noise = levels[l].rho;
      row.trials = o.trials;
      const int F = levels[l].plane ? o.plane.table1.frames : o.sphere.frames;
      row.normal_by_frame.assign(F + 1, 0.0);
      row.beta_by_frame.assign(F + 1, 0.0);
      std::vector<double> patch_by_frame(F + 1, 0.0);
      double st = 0, sq = 0;
      int nt = 0, nq = 0, ok = 0;
      for (int t = 0; t < o.trials; ++t) {
        const Run& r = runs[l][t][m];
        if (r.failed) {
          if (row.failed++ == 0) row.first_failure = r.failure;
          continue;
        }
        ++ok;
        for (int k = 0; k <= F; ++k) {
          row.normal_by_frame[k] += levels[l].plane ? r.plane_fit[k] : r.normal[k];
          row.beta_by_frame[k] += r.beta_pct[k];
          patch_by_frame[k] += r.normal[k];
        }
        row.max_normal_err_deg += r.max_normal_last;
        row.worst_normal_err_deg = std::max(row.worst_normal_err_deg, r.max_normal_last);
        row.worst_beta_err_pct = std::max(row.worst_beta_err_pct, r.beta_pct.back());
        row.trials_beta_within += r.beta_pct.back() <= o.converge_beta_pct;
        st += r.sq_t, sq += r.sq_q, nt += r.n_t, nq += r.n_q;
      }
      if (ok == 0) {
        for (int k = 0; k <= F; ++k) row.normal_by_frame[k] = row.beta_by_frame[k] = NAN;
        row.rms_t = row.rms_q = row.normal_err_deg = row.patch_normal_err_deg = row.max_normal_err_deg = row.worst_normal_err_deg =
            row.normal_err_frame100 = row.beta_err_pct = row.worst_beta_err_pct = NAN;
        res.rows.push_back(row);
        continue;
      }
      for (int k = 0; k <= F; ++k) {
        row.normal_by_frame[k] /= ok;
        row.beta_by_frame[k] /= ok;
        patch_by_frame[k] /= ok;
      }
      row.max_normal_err_deg = m == 2 ? NAN : row.max_normal_err_deg / ok;
      if (m == 2) row.worst_normal_err_deg = NAN;
      row.rms_t = std::sqrt(st / nt);
      row.rms_q = std::sqrt(sq / nq);
      row.normal_err_deg = row.normal_by_frame[F];
      row.patch_normal_err_deg = m == 2 ? NAN : patch_by_frame[F];
      row.normal_err_frame100 = row.normal_by_frame[std::min(F, 100)];
      row.beta_err_pct = row.beta_by_frame[F];
      row.frames_to_converge =
          convergenceFrame(row.normal_by_frame, row.beta_by_frame, o.converge_normal_deg, o.converge_beta_pct);
      res.rows.push_back(row);
    }
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace rsfm
