#include "rsfm/report/evaluation.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>

#include "rsfm/io/atomic_file.hpp"
#include "rsfm/io/tum.hpp"

#include <limits>

namespace rsfm::report {

using namespace rsfm::io;  // the file formats the reports write
namespace fs = std::filesystem;
namespace {

/// The poses sorted by timestamp, each timestamp mapped to origin + t x scale (a frame number ->
/// seconds: 1 / fps, and the other side's time origin). Two poses with one timestamp are refused
/// (issue 17: which would be matched?).
std::vector<TumPose> byTime(const fs::path& file, std::vector<TumPose> poses, double scale, double origin) {
  for (TumPose& p : poses) {
    if (!std::isfinite(p.t) || p.t < 0 || p.t > 1e12)
      throw InputError(fmt::format("{}: timestamp {} is not a time from 0 to 1e12", printable(file.string(), 300), p.t));
    p.t = origin + p.t * scale;
  }
  std::stable_sort(poses.begin(), poses.end(), [](const TumPose& a, const TumPose& b) { return a.t < b.t; });
  for (size_t i = 1; i < poses.size(); ++i)
    if (poses[i].t == poses[i - 1].t)
      throw InputError(fmt::format("{}: timestamp {} appears twice (two poses for one time)", printable(file.string(), 300),
                                   (poses[i].t - origin) / scale));
  return poses;
}

eval::Pose toPose(const TumPose& p) { return {p.p, p.q.normalized().toRotationMatrix()}; }

double rotDeg(const Eigen::Matrix3d& R) {
  const double c = std::clamp(0.5 * (R.trace() - 1.0), -1.0, 1.0);
  const Eigen::Vector3d w(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1));
  return std::atan2(0.5 * w.norm(), c) * 180.0 / M_PI;
}

template <class J>
J statsJson(const eval::ErrorStats& s) {
  return J{{"rmse", s.rmse}, {"mean", s.mean}, {"median", s.median}, {"max", s.max}, {"n", s.n}};
}

std::string num(double v, int prec = 6) {
  if (!std::isfinite(v)) return "NA";
  return fmt::format("{:.{}g}", v, prec);
}

}  // namespace

std::vector<std::pair<std::size_t, std::size_t>> associateByTime(const std::vector<double>& truth,
                                                                const std::vector<double>& est, double max_diff) {
  // Candidates: each truth time with the estimate times on either side of it, within max_diff.
  struct Candidate {
    double dt;
    std::size_t i, j;
  };
  std::vector<Candidate> cand;
  std::size_t j = 0;
  for (std::size_t i = 0; i < truth.size() && !est.empty(); ++i) {
    while (j + 1 < est.size() && est[j + 1] <= truth[i]) ++j;
    for (std::size_t k = j; k <= j + 1 && k < est.size(); ++k)
      if (std::abs(est[k] - truth[i]) <= max_diff) cand.push_back({std::abs(est[k] - truth[i]), i, k});
  }
  // Nearest pairs first, each pose used once; then in time order.
  std::stable_sort(cand.begin(), cand.end(), [](const Candidate& a, const Candidate& b) { return a.dt < b.dt; });
  std::vector<char> used_t(truth.size(), 0), used_e(est.size(), 0);
  std::vector<std::pair<std::size_t, std::size_t>> out;
  for (const Candidate& c : cand) {
    if (used_t[c.i] || used_e[c.j]) continue;
    used_t[c.i] = used_e[c.j] = 1;
    out.emplace_back(c.i, c.j);
  }
  std::sort(out.begin(), out.end());
  return out;
}

Evaluation evaluateDirectories(const fs::path& estimate_dir, const fs::path& truth_dir, const EvaluateOptions& opt) {
  Evaluation e;
  e.estimate_dir = estimate_dir;
  e.truth_dir = truth_dir;
  e.rpe_delta = opt.rpe_delta;
  std::error_code ec;
  if (!fs::is_directory(estimate_dir, ec)) throw InputError(estimate_dir.string() + ": no such directory");
  // The truth: a directory as rsfm writes one, or a bare TUM trajectory file (a dataset's ground
  // truth, e.g. TUM RGB-D's groundtruth.txt), whose timestamps are seconds by the format.
  const bool truth_file = fs::is_regular_file(truth_dir, ec);
  if (!truth_file && !fs::is_directory(truth_dir, ec))
    throw InputError(truth_dir.string() + ": no such directory or TUM trajectory file");
  const fs::path et = estimate_dir / "trajectory.tum", tt = truth_file ? truth_dir : truth_dir / "trajectory.tum";
  const fs::path es = estimate_dir / "summary.json", ts = truth_dir / "summary.json";
  const auto est_poses = readTum(et);
  const auto truth_poses = readTum(tt);
  const Summary est_sum = readSummary(es);
  Summary truth_sum;
  if (truth_file) {
    if (!est_sum.fps)
      throw InputError(fmt::format("{}: a truth trajectory file without summary.json is in seconds, and the estimate's "
                                   "timestamps are frame numbers ({} states no fps): give the truth as a directory "
                                   "whose summary.json states the rate",
                                   printable(tt.string(), 300), printable(es.string(), 300)));
    truth_sum.fps = est_sum.fps;  // seconds on both sides: associated as they are
    e.notes.push_back("the truth is a bare TUM trajectory (no summary.json): its timestamps are seconds; no planes, "
                      "focal length or scene size to compare");
  } else {
    truth_sum = readSummary(ts);
  }
  // Timestamps: seconds when the summary states a frame rate (fps), else frame numbers. When only
  // one side is in seconds, the other's frame numbers become seconds at that side's rate.
  if (!(opt.t_max_diff >= 0) || !std::isfinite(opt.t_max_diff))
    throw InputError(fmt::format("t_max_diff must be a finite number >= 0, got {}", opt.t_max_diff));
  // A side in seconds may count from a time origin (images named by their timestamps): the
  // other side's frame numbers are taken from it too.
  double est_scale = 1.0, truth_scale = 1.0, est_origin = 0.0, truth_origin = 0.0;
  std::optional<double> fps = truth_sum.fps ? truth_sum.fps : est_sum.fps;
  const auto fromOrigin = [](const Summary& s) {
    return s.time_origin != 0 ? fmt::format(" from the time origin {}", s.time_origin) : std::string();
  };
  if (est_sum.fps && !truth_sum.fps) {
    truth_scale = 1.0 / *est_sum.fps;
    truth_origin = est_sum.time_origin;
    e.notes.push_back(fmt::format("the truth's timestamps are frame numbers: taken as seconds at the estimate's {} fps{}",
                                  *est_sum.fps, fromOrigin(est_sum)));
  } else if (truth_sum.fps && !est_sum.fps) {
    est_scale = 1.0 / *truth_sum.fps;
    est_origin = truth_sum.time_origin;
    e.notes.push_back(fmt::format("the estimate's timestamps are frame numbers: taken as seconds at the truth's {} fps{}",
                                  *truth_sum.fps, fromOrigin(truth_sum)));
  } else if (est_sum.fps && truth_sum.fps && std::abs(*est_sum.fps - *truth_sum.fps) > 1e-9 * *truth_sum.fps) {
    e.notes.push_back(fmt::format("frame rates differ: estimate {} fps, truth {} fps (associated by time)", *est_sum.fps,
                                  *truth_sum.fps));
  }
  e.timestamps = fps ? "seconds" : "frame";
  e.t_max_diff = opt.t_max_diff;
  const std::vector<TumPose> em = byTime(et, est_poses, est_scale, est_origin),
                               tm = byTime(tt, truth_poses, truth_scale, truth_origin);
  e.estimate_poses = static_cast<int>(em.size());
  e.truth_poses = static_cast<int>(tm.size());

  std::vector<eval::Pose> E, T;
  std::vector<long long> frames;  // the truth's frame numbers (the RPE's frame distance)
  std::vector<double> tt_s, et_s;
  for (const auto& p : tm) tt_s.push_back(p.t);
  for (const auto& p : em) et_s.push_back(p.t);
  const auto pairs = associateByTime(tt_s, et_s, opt.t_max_diff);
  bool integral = true;
  for (const auto& [i, j] : pairs) integral = integral && std::abs(tm[i].t - std::round(tm[i].t)) < 1e-6;
  // In seconds, the frame numbers come from the side on rsfm's uniform grid, less its origin:
  // the truth's, or against a bare truth file (a dataset's own, jittered times) the estimate's.
  const double truth_grid_origin = truth_sum.fps ? truth_sum.time_origin : truth_origin;
  for (size_t n = 0; n < pairs.size(); ++n) {
    const auto [i, j] = pairs[n];
    T.push_back(toPose(tm[i]));
    E.push_back(toPose(em[j]));
    if (!fps)
      frames.push_back(integral ? std::llround(tm[i].t) : static_cast<long long>(n));
    else if (truth_file)
      frames.push_back(std::llround((em[j].t - est_sum.time_origin) * *fps));
    else
      frames.push_back(std::llround((tm[i].t - truth_grid_origin) * *fps));
  }
  if (!fps && !integral)
    e.notes.push_back("timestamps are neither seconds at a known frame rate nor frame numbers: the RPE's frame distance "
                      "counts matched poses");
  e.matched = static_cast<int>(frames.size());
  if (e.matched < 3)
    throw InputError(fmt::format(
        "{}: only {} pose{} match a timestamp of {} within {} {} (need at least 3; --t-max-diff){}", et.string(), e.matched,
        e.matched == 1 ? "" : "s", tt.string(), opt.t_max_diff, fps ? "s" : "frames",
        em.empty() || tm.empty() || (em.back().t >= tm.front().t && tm.back().t >= em.front().t)
            ? std::string()
            : fmt::format(": the times do not overlap, estimate {:.17g} to {:.17g}, truth {:.17g} to {:.17g} (a time origin "
                          "on one side only? summary.json time_origin_s)",
                          em.front().t, em.back().t, tm.front().t, tm.back().t)));
  // A Sim(3) alignment needs the camera centres of both trajectories to spread: name the file
  // whose centres do not (issue 17: a still truth was blamed on the estimate).
  for (const auto& [traj, file] : {std::pair{&E, &et}, std::pair{&T, &tt}}) {
    double spread = 0;
    for (const auto& p : *traj) spread = std::max(spread, (p.p - traj->front().p).norm());
    if (!(spread > 0))
      throw InputError(fmt::format("{}: cannot align: its camera centres are all equal over the {} matched frames (no "
                                   "translation: a Sim(3) alignment and the ATE need a moving camera)",
                                   printable(file->string(), 300), e.matched));
  }
  e.ate = eval::absoluteTrajectoryError(E, T, true);
  if (!e.ate.alignment.ok)
    throw std::runtime_error(fmt::format("{}: the Sim(3) alignment with {} failed (numerical trouble)", et.string(), tt.string()));
  const auto& sv = e.ate.alignment.singular_values;
  if (sv(1) < 1e-9 * sv(0))
    e.notes.push_back("the trajectories are (nearly) collinear: the alignment's rotation about their axis is undetermined");
  e.alignment_rotation_deg = rotDeg(e.ate.alignment.T.R);

  if (truth_sum.scene_size) {
    e.scale_ref = *truth_sum.scene_size;
  } else {
    Eigen::Vector3d lo = T[0].p, hi = T[0].p;
    for (const auto& p : T) {
      lo = lo.cwiseMin(p.p);
      hi = hi.cwiseMax(p.p);
    }
    e.scale_ref = (hi - lo).norm();
    e.relative_to_scene_size = false;
    e.notes.push_back(fmt::format("truth summary has no scene_size: relative ATE is relative to the truth trajectory's "
                                  "extent (bounding-box diagonal {:.6g})", e.scale_ref));
  }
  e.rpe = eval::relativePoseError(E, T, frames, opt.rpe_delta, e.ate.alignment.T.s);
  if (e.rpe.pairs == 0)
    e.notes.push_back(fmt::format("no matched pose pairs {} frames apart: RPE not computed", opt.rpe_delta));

  e.focal_truth = truth_sum.focal_px;
  e.focal_est = est_sum.focal_px;
  if (e.focal_truth && e.focal_est) e.focal_err_pct = 100.0 * (*e.focal_est - *e.focal_truth) / *e.focal_truth;
  if (!e.focal_est) e.notes.push_back("the estimate has no focal length (focal_px null)");
  // A bare truth file has no image to compare.
  if (!truth_file && (est_sum.width != truth_sum.width || est_sum.height != truth_sum.height))
    e.notes.push_back(fmt::format("image sizes differ: estimate {}x{}, truth {}x{}", est_sum.width, est_sum.height,
                                  truth_sum.width, truth_sum.height));
  if (!truth_file && (est_sum.principal_point_px - truth_sum.principal_point_px).norm() > 1e-6)
    e.notes.push_back(fmt::format("principal points differ: estimate ({}, {}), truth ({}, {})",
                                  est_sum.principal_point_px.x(), est_sum.principal_point_px.y(),
                                  truth_sum.principal_point_px.x(), truth_sum.principal_point_px.y()));

  const eval::PlaneMatch pm = eval::matchPlanes(truth_sum.planes, truth_sum.plane_distances, est_sum.planes,
                                                est_sum.plane_distances, e.ate.alignment.T.s);
  for (std::size_t i = 0; i < truth_sum.planes.size(); ++i) {
    PlaneEvaluation pe;
    pe.name = i < truth_sum.plane_names.size() ? truth_sum.plane_names[i] : fmt::format("plane{}", i);
    pe.estimate = pm.estimate_of_truth[i];
    pe.distance_truth = truth_sum.plane_distances[i];
    if (pe.estimate >= 0) {
      pe.angle_deg = pm.angle_deg[i];
      pe.distance_est_scaled = e.ate.alignment.T.s * est_sum.plane_distances[pe.estimate];
      pe.distance_err_pct = 100.0 * (pe.distance_est_scaled - pe.distance_truth) / pe.distance_truth;
    }
    e.planes.push_back(pe);
  }
  for (std::size_t j = 0; j < est_sum.planes.size(); ++j)
    if (pm.truth_of_estimate[j] < 0) e.unmatched_estimates.push_back(static_cast<int>(j));
  return e;
}

std::string evaluationJson(const Evaluation& e) {
  using J = nlohmann::ordered_json;
  J o;
  o["format"] = "rsfm-evaluation";
  o["version"] = 1;
  o["estimate"] = e.estimate_dir.string();
  o["truth"] = e.truth_dir.string();
  o["poses"] = {{"truth", e.truth_poses}, {"estimate", e.estimate_poses}, {"matched", e.matched},
                {"timestamps", e.timestamps}, {"t_max_diff", e.t_max_diff}};
  const auto& T = e.ate.alignment.T;
  J R = J::array();
  for (int r = 0; r < 3; ++r) R.push_back({T.R(r, 0), T.R(r, 1), T.R(r, 2)});
  o["alignment"] = {{"type", "sim3"},      {"direction", "estimate->truth"}, {"scale", T.s},
                    {"rotation_deg", e.alignment_rotation_deg}, {"rotation", R},
                    {"translation", {T.t.x(), T.t.y(), T.t.z()}}};
  J ate = statsJson<J>(e.ate.stats);
  ate["relative_to"] = e.relative_to_scene_size ? "scene_size" : "trajectory_extent";
  ate["reference_size"] = e.scale_ref;
  ate["rmse_pct"] = 100.0 * e.ate.stats.rmse / e.scale_ref;
  ate["mean_pct"] = 100.0 * e.ate.stats.mean / e.scale_ref;
  ate["median_pct"] = 100.0 * e.ate.stats.median / e.scale_ref;
  ate["max_pct"] = 100.0 * e.ate.stats.max / e.scale_ref;
  o["ate"] = ate;
  o["rpe"] = {{"delta_frames", e.rpe_delta},
              {"pairs", e.rpe.pairs},
              {"translation", statsJson<J>(e.rpe.translation)},
              {"rotation_deg", statsJson<J>(e.rpe.rotation_deg)}};
  auto opt = [](const std::optional<double>& v) { return v ? J(*v) : J(nullptr); };
  o["focal"] = {{"truth_px", opt(e.focal_truth)}, {"estimate_px", opt(e.focal_est)}, {"error_pct", opt(e.focal_err_pct)}};
  J planes = J::array();
  for (const auto& p : e.planes) {
    J pj;
    pj["name"] = p.name;
    pj["estimate"] = p.estimate >= 0 ? J(p.estimate) : J(nullptr);
    pj["angle_deg"] = p.estimate >= 0 ? J(p.angle_deg) : J(nullptr);
    pj["distance_truth"] = p.distance_truth;
    pj["distance_estimate_scaled"] = p.estimate >= 0 ? J(p.distance_est_scaled) : J(nullptr);
    pj["distance_error_pct"] = p.estimate >= 0 ? J(p.distance_err_pct) : J(nullptr);
    planes.push_back(pj);
  }
  o["planes"] = planes;
  o["unmatched_estimated_planes"] = e.unmatched_estimates;
  o["notes"] = e.notes;
  return o.dump(2) + "\n";
}

std::string evaluationTable(const Evaluation& e) {
  std::string s;
  s += fmt::format("rsfm evaluate: {} vs truth {}\n", e.estimate_dir.string(), e.truth_dir.string());
  s += fmt::format("poses: {} truth, {} estimate, {} matched by timestamp ({}, within {})\n", e.truth_poses,
                   e.estimate_poses, e.matched, e.timestamps, e.t_max_diff);
  const auto& T = e.ate.alignment.T;
  s += fmt::format("alignment (Sim(3), estimate -> truth): scale {}, rotation {} deg, translation ({}, {}, {})\n",
                   num(T.s), num(e.alignment_rotation_deg, 4), num(T.t.x(), 4), num(T.t.y(), 4), num(T.t.z(), 4));
  s += fmt::format("\n{:<34} {:>12} {:>12} {:>12} {:>12}\n", "metric", "rmse", "mean", "median", "max");
  auto row = [&](const std::string& name, const eval::ErrorStats& st, double f) {
    s += fmt::format("{:<34} {:>12} {:>12} {:>12} {:>12}\n", name, num(st.rmse * f), num(st.mean * f),
                     num(st.median * f), num(st.max * f));
  };
  row("ATE (truth units)", e.ate.stats, 1.0);
  row(fmt::format("ATE (% of {} {})", e.relative_to_scene_size ? "scene size" : "traj. extent", num(e.scale_ref, 4)),
      e.ate.stats, 100.0 / e.scale_ref);
  if (e.rpe.pairs > 0) {
    row(fmt::format("RPE translation ({} fr, {} pairs)", e.rpe_delta, e.rpe.pairs), e.rpe.translation, 1.0);
    row(fmt::format("RPE rotation, deg ({} fr)", e.rpe_delta), e.rpe.rotation_deg, 1.0);
  }
  s += fmt::format("\nfocal length: truth {}, estimate {}, error {}\n",
                   e.focal_truth ? num(*e.focal_truth) + " px" : "NA", e.focal_est ? num(*e.focal_est) + " px" : "NA",
                   e.focal_err_pct ? fmt::format("{:+.3f} %", *e.focal_err_pct) : "NA");
  s += "\nplanes (normals in the reference camera frame, best one-to-one matching):\n";
  s += fmt::format("{:<16} {:>8} {:>10} {:>10} {:>12} {:>10}\n", "truth plane", "estimate", "angle_deg", "d_truth",
                   "d_est*scale", "d_err_%");
  for (const auto& p : e.planes) {
    if (p.estimate >= 0)
      s += fmt::format("{:<16} {:>8} {:>10.3f} {:>10} {:>12} {:>+10.2f}\n", p.name, p.estimate, p.angle_deg,
                       num(p.distance_truth, 5), num(p.distance_est_scaled, 5),
                       std::abs(p.distance_err_pct) < 5e-3 ? 0.0 : p.distance_err_pct);  // no "-0.00"
    else
      s += fmt::format("{:<16} {:>8} {:>10} {:>10} {:>12} {:>10}\n", p.name, "none", "NA", num(p.distance_truth, 5),
                       "NA", "NA");
  }
  if (e.planes.empty()) s += "(the truth has no planes)\n";
  std::string um;
  for (int j : e.unmatched_estimates) um += (um.empty() ? "" : ", ") + std::to_string(j);
  s += fmt::format("unmatched estimated planes: {}\n", um.empty() ? "none" : um);
  for (const auto& n : e.notes) s += "note: " + n + "\n";
  return s;
}

std::string evaluationMarkdown(const Evaluation& e, const std::string& invocation) {
  std::string s = "# rsfm evaluation\n\n";
  s += "Metrics are defined in docs/evaluate.md. Poses are associated by timestamp (nearest within t_max_diff, as evo); the estimate is\n"
       "aligned to the truth by a Umeyama Sim(3) fit of the camera centres.\n\n```\n";
  s += evaluationTable(e);
  s += "```\n\nCommand: `" + invocation + "`\n";
  return s;
}

void writeEvaluation(const Evaluation& e, const fs::path& out_dir, const std::string& invocation) {
  AtomicFileSet files;
  files.write(out_dir / "evaluation.json", evaluationJson(e));
  files.write(out_dir / "evaluation.md", evaluationMarkdown(e, invocation));
  files.commit();
}

}  // namespace rsfm::report
