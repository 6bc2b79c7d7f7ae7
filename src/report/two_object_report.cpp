#include "rsfm/report/two_object_report.hpp"

#include <fmt/format.h>

#include <cmath>

#include "rsfm/report/report.hpp"

namespace rsfm::report {

namespace {

std::string num(double v, int prec = 4) { return formatNumber(v, prec); }

}  // namespace

std::string twoObjectCsv(const TwoObjectResult& r) {
  std::string s = "noise_px,object,rot_err_deg,t_err_pct,normal_err_deg,beta_err_pct,failed\n";
  for (const auto& row : r.rows)
    for (int j = 0; j < 2; ++j)
      s += fmt::format("{},{},{},{},{},{},{}\n", num(row.noise_px, 2), j, num(row.rot_err_deg[j], 4),
                       num(row.t_err_pct[j], 3), num(row.normal_err_deg[j], 4), num(row.beta_err_pct, 3), row.failed);
  return s;
}

std::string twoObjectMarkdown(const TwoObjectResult& r, const std::string& command_line) {
  const auto& o = r.options;
  const auto& sc = o.scene;
  std::string s = "# Two independently moving planes\n\n";
  s += fmt::format("Command: `{}`  \n{} trials per noise level, seed {}, {:.1f} s.\n\n", command_line, o.trials,
                   o.seed, r.seconds);
  s += fmt::format(
      "Object 0 turns {:.1f} deg about the y axis through (0, 0, 2) (|t| = {:.3f} at the last frame); object 1 "
      "turns {:.1f} deg about the x axis through its centre while drifting (|t| = {:.3f}). One filter, state "
      "1 + 9 x 2 (shared beta; per object t, omega, N).\n\n",
      r.motion_rot_deg[0], r.motion_t[0], r.motion_rot_deg[1], r.motion_t[1]);
  s += "Errors at the last frame, mean over successful trials: rotation error = angle of R_est R_true^T; "
       "translation error = |t_est - t_true| / |t_true|; normal error = angle between the planes' normals; "
       "beta error = |beta - 1| (beta is shared by both objects).\n\n";
  s += "| noise px | object | rotation err (deg) | translation err (% of motion) | normal err (deg) | beta err (%) | failed |\n";
  s += "|---|---|---|---|---|---|---|\n";
  for (const auto& row : r.rows)
    for (int j = 0; j < 2; ++j)
      s += fmt::format("| {} | {} | {} | {} | {} | {} | {}/{} |\n", num(row.noise_px, 2), j,
                       num(row.rot_err_deg[j], 3), num(row.t_err_pct[j], 2), num(row.normal_err_deg[j], 3),
                       num(row.beta_err_pct, 2), row.failed, row.trials);
  s += "\n## Failures\n\n";
  bool any = false;
  for (const auto& row : r.rows)
    if (row.failed) {
      any = true;
      s += fmt::format("- {} px: {} of {} trials; first: {}\n", num(row.noise_px, 2), row.failed, row.trials,
                       row.first_failure);
    }
  if (!any) s += "None.\n";
  s += "\n## Options\n\n| option | value |\n|---|---|\n";
  s += fmt::format("| scene | {} frames, {} points per object; object 0: N = 2(1/sqrt3, 0, 1), {} deg/frame about y "
                   "through (0, 0, 2); object 1: tilt {} rad about x, centre ({}, {}, {}), {} deg/frame about x through "
                   "its centre, drift ({}, {}, {}) per frame, half side {}; s = {} px |\n",
                   sc.frames, sc.points_per_object, sc.deg_per_frame0, sc.tilt1_rad, sc.centre1.x(), sc.centre1.y(),
                   sc.centre1.z(), sc.deg_per_frame1, sc.drift1.x(), sc.drift1.y(), sc.drift1.z(), sc.half_size,
                   o.scale_px);
  s += fmt::format("| noise | uniform, zero mean, the given standard deviation, every frame{} |\n",
                   o.reference_noise ? " including the reference frame" : " except the reference frame (exact references)");
  s += fmt::format("| prior | beta0 {} (var {}); planes: truth + N(0, ({} |N|)^2) on each free component, the same "
                   "variance; gauge: each plane's largest component at its true value |\n",
                   o.beta0, o.beta_var0, o.n_rel);
  s += fmt::format("| filter | reset reading, q_trans {:g}, q_omega {:g} per object, q_beta 0, gate {:g}, reference "
                   "positions {} (docs/filter.md) |\n",
                   o.q_translation, o.q_omega, o.gate_probability, o.reference_noise ? o.reference_model : "exact");
  return s;
}

std::string twoObjectFigureData(const TwoObjectResult& r) {
  std::string s = "noise_px,frame,rot_err_deg_0,rot_err_deg_1,t_err_0,t_err_1,normal_err_deg_0,normal_err_deg_1,beta_err_pct\n";
  for (const auto& row : r.rows)
    for (size_t k = 0; k < row.beta_by_frame.size(); ++k)
      if (std::isfinite(row.beta_by_frame[k]))
        s += fmt::format("{},{},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g}\n", row.noise_px, k,
                         row.rot_by_frame[0][k], row.rot_by_frame[1][k], row.t_by_frame[0][k], row.t_by_frame[1][k],
                         row.normal_by_frame[0][k], row.normal_by_frame[1][k], row.beta_by_frame[k]);
  return s;
}

Figures writeTwoObjectReport(const TwoObjectResult& r, const std::filesystem::path& dir, const std::string& command_line) {
  return writeFigureReport(dir, "two_object", twoObjectCsv(r), twoObjectMarkdown(r, command_line), "two_object_data",
                    twoObjectFigureData(r), "two_object", "plot_two_object.py");
}

}  // namespace rsfm::report
