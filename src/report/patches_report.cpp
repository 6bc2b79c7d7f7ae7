#include "rsfm/report/patches_report.hpp"

#include <fmt/format.h>

#include <cmath>

#include "rsfm/report/report.hpp"

namespace rsfm::report {

namespace {

std::string num(double v, int prec = 4) { return formatNumber(v, prec); }

}  // namespace

std::string patchesCsv(const PatchesResult& r) {
  std::string s = "scene,measurement,noise,rms_t,rms_q,normal_err_deg,beta_err_pct,frames_to_converge\n";
  for (const auto& row : r.rows)
    s += fmt::format("{},{},{},{},{},{},{},{}\n", row.scene, row.measurement, num(row.noise, 3), num(row.rms_t, 5),
                     num(row.rms_q, 5), num(row.normal_err_deg, 3), num(row.beta_err_pct, 3), row.frames_to_converge);
  return s;
}

std::string patchesMarkdown(const PatchesResult& r, const std::string& command_line) {
  const auto& o = r.options;
  std::string s = "# Affine patches: Calway's filter against the point filter on the patch centres\n\n";
  s += fmt::format("Command: `{}`  \n{} trials per noise level, seed {}, {:.1f} s.\n\n", command_line, o.trials, o.seed,
                   r.seconds);
  s += "Rows: `exact` and `instantaneous` are the patch filter (state 7 + 3K) with the two affine measurement "
       "functions; `point-centres` is the A&P point filter (state 7 + K) on the same patches' centres. Noise rho: "
       "each of the six flow parameters (h - c, A - I) gets Gaussian noise of standard deviation rho times its "
       "largest magnitude over the scene; the centres carry the same noise as h.\n\n";
  s += "Columns: rms_t / rms_q = RMS error of the camera position (first-frame units) / of the quaternion's "
       "components over frames 1..F and trials. Normal error at the last frame, mean over trials: on the sphere the "
       "patch filter's mean over patches of each patch normal's angle error (a point has no normal: NA for the point "
       "filter); on the plane the plane fitted to each filter's 3-D patch centres (Table 1's protocol, the same for "
       "every method). Patch normals: the patch filter's own per-patch normal errors, mean over patches / largest "
       "patch (mean over trials) / largest patch in any trial. Frames to converge = first frame from which the "
       "trial-mean normal error stays within " +
       num(o.converge_normal_deg, 1) + " deg and beta within " + num(o.converge_beta_pct, 1) +
       " % (the point filter on the sphere: beta only; -1 = never).\n\n";
  s += "| scene | measurement | noise | rms_t | rms_q | normal err (deg) | patch normals: mean / worst / worst in any trial (deg) | normal err frame 100 | beta err (%): mean / worst trial / trials within " + num(o.converge_beta_pct, 1) + " % | frames to converge | failed |\n";
  s += "|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& row : r.rows)
    s += fmt::format("| {} | {} | {} | {} | {} | {} | {} / {} / {} | {} | {} / {} / {} | {} | {}/{} |\n", row.scene,
                     row.measurement, num(row.noise, 3), num(row.rms_t, 4), num(row.rms_q, 4),
                     num(row.normal_err_deg, 2), num(row.patch_normal_err_deg, 2), num(row.max_normal_err_deg, 2),
                     num(row.worst_normal_err_deg, 2), num(row.normal_err_frame100, 2), num(row.beta_err_pct, 2),
                     num(row.worst_beta_err_pct, 2), row.trials_beta_within,
                     row.frames_to_converge, row.failed, row.trials);
  s += "\n## Failures\n\n";
  bool any = false;
  for (const auto& row : r.rows)
    if (row.failed) {
      any = true;
      s += fmt::format("- {} {} rho {}: {} of {} trials; first: {}\n", row.scene, row.measurement, num(row.noise, 3),
                       row.failed, row.trials, row.first_failure);
    }
  if (!any) s += "None.\n";
  const auto& sp = o.sphere;
  const auto& pl = o.plane;
  s += "\n## Options\n\n| option | value |\n|---|---|\n";
  s += fmt::format("| sphere | {} frames, {} clusters of {} points ({} deg across) within {} deg of the point facing the "
                   "camera, at least {} deg apart, each in the image and seen at most {} deg obliquely in every frame; radius {}, centre ({}, {}, {}); over one period of the sequence the "
                   "centre moves by ({} sin, {} sin(+1), {} (1 - cos)) and the sphere turns {} sin deg about x and {} "
                   "sin(+1) deg about y; beta {} (f = 1, half-width 0.5) |\n",
                   sp.frames, sp.patches, sp.cluster_points + 1, sp.cluster_deg, sp.max_off_axis_deg,
                   sp.min_separation_deg, sp.max_obliquity_deg, sp.radius, sp.centre.x(), sp.centre.y(), sp.centre.z(), sp.amplitude.x(),
                   sp.amplitude.y(), sp.amplitude.z(), sp.angle_x_deg, sp.angle_y_deg, sp.beta);
  s += fmt::format("| plane | Table 1 scene: {} frames, {} deg per frame about y through (0, 0, 2), N = 2(1/sqrt3, 0, "
                   "1); {} clusters of {} points ({} deg across) centred on Table 1 points; s = {} px |\n",
                   pl.table1.frames, pl.table1.deg_per_frame, pl.patches, pl.cluster_points + 1, pl.cluster_deg,
                   pl.table1.scale_px);
  s += fmt::format("| prior | beta0 {} (var {}); patches fronto-parallel at the gauge patch's true depth (p1, p2 var "
                   "{}; p4 sd {} of it); point depths the same; gauge = the patch nearest the image centre at its "
                   "true value |\n",
                   o.beta0, o.beta_var0, o.normal_var0, o.depth_rel_sd0);
  s += fmt::format("| patch filter | inter-frame motion prior var {:g}; q_trans {:g}, q_omega {:g} per frame "
                   "(constant velocity); R = the true noise variances, annealed over the first {} from {:g} times; "
                   "{} centres; {} update iteration(s); q_structure {:g}; gate {:g} |\n",
                   o.motion_var0, o.q_translation, o.q_omega,
                   o.anneal_frames >= 0 ? fmt::format("{} frames", o.anneal_frames) : std::string("half of each sequence"),
                   o.anneal_factor,
                   toString(o.centres), o.iterations, o.q_structure, o.gate_probability);
  s += fmt::format("| point filter | reset reading, q_trans {:g}, q_omega {:g}, refined references, sigma = the "
                   "centre noise |\n",
                   o.point_q_translation, o.point_q_omega);
  return s;
}

std::string patchesFigureData(const PatchesResult& r) {
  std::string s = "scene,measurement,noise,frame,normal_err_deg,beta_err_pct\n";
  for (const auto& row : r.rows)
    for (size_t k = 0; k < row.normal_by_frame.size(); ++k)
      s += fmt::format("{},{},{},{},{},{}\n", row.scene, row.measurement, num(row.noise, 3), k,
                       num(row.normal_by_frame[k], 4), num(row.beta_by_frame[k], 4));
  return s;
}

Figures writePatchesReport(const PatchesResult& r, const std::filesystem::path& dir, const std::string& command_line) {
  return writeFigureReport(dir, "patches", patchesCsv(r), patchesMarkdown(r, command_line), "patches_data",
                    patchesFigureData(r), "patches", "plot_patches.py");
}

}  // namespace rsfm::report
