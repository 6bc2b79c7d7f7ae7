#include "rsfm/report/planes_report.hpp"

#include <fmt/format.h>

#include <cmath>

#include "rsfm/report/report.hpp"

namespace rsfm::report {

namespace {

std::string num(double v, int prec = 4) { return formatNumber(v, prec); }


}  // namespace

std::string planesCsv(const PlanesResult& r) {
  std::string s = "method,noise_px,rms_t,rms_q,normal_err_deg,face_angle_err_deg,beta_err_pct,ratio_to_batch\n";
  for (const auto& row : r.rows)
    s += fmt::format("{},{},{},{},{},{},{},{}\n", row.method, num(row.noise_px, 1), num(row.rms_t, 5),
                     num(row.rms_q, 5), num(row.normal_err_deg, 3), num(row.face_angle_err_deg, 3),
                     num(row.beta_err_pct, 2), row.ratio_to_batch > 0 ? num(row.ratio_to_batch, 3) : "NA");
  return s;
}

std::string planesMarkdown(const PlanesResult& r, const std::string& command_line) {
  const auto& o = r.options;
  std::string s = "# Multi-plane experiment: box scene\n\n";
  s += fmt::format("Command: `{}`  \n{} trials per noise level, seed {}, {} faces, {:.1f} s.\n\n", command_line,
                   o.trials, o.seed, r.faces, r.seconds);
  s += "rms_t, rms_q: RMS error of the translation (t_X, t_Y, t_Z) and of the quaternion (w, x, y, z) over "
       "all components, frames 1..F and trials (plane-per-face: its per-face filters pooled). Normal error: "
       "last frame, mean over faces and trials; face angle error: |angle between estimated normals - 90 deg|, "
       "mean over face pairs and trials; beta error: |beta - 1| at the last frame; ratio_to_batch: rms_t over "
       "the batch's on the same trials.\n\n";
  s += "| method | noise px | rms_t | rms_q | normal err (deg) | face angle err (deg) | beta err (%) | ratio to batch | failed |\n";
  s += "|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& row : r.rows)
    s += fmt::format("| {} | {} | {} | {} | {} | {} | {} | {} | {}/{} |\n", row.method, num(row.noise_px, 1),
                     num(row.rms_t), num(row.rms_q), num(row.normal_err_deg, 3), num(row.face_angle_err_deg, 3),
                     num(row.beta_err_pct, 2), row.ratio_to_batch > 0 ? num(row.ratio_to_batch, 2) : "NA",
                     row.failed, row.trials);
  s += "\n## Cramer-Rao bounds (batch covariance at the optimum, mean over trials)\n\n";
  s += "| noise px | normal RMS angle bound (deg) | beta sd bound (%) |\n|---|---|---|\n";
  for (const auto& row : r.rows)
    if (row.method == "batch")
      s += fmt::format("| {} | {} | {} |\n", num(row.noise_px, 1),
                       row.crb_normal_deg >= 0 ? num(row.crb_normal_deg, 3) : "NA",
                       row.crb_beta_pct >= 0 ? num(row.crb_beta_pct, 2) : "NA");
  s += "\n## Failures\n\n";
  bool any = false;
  for (const auto& row : r.rows)
    if (row.failed) {
      any = true;
      s += fmt::format("- {} at {} px: {} of {} trials; first: {}\n", row.method, num(row.noise_px, 1), row.failed,
                       row.trials, row.first_failure);
    }
  if (!any) s += "None.\n";
  const auto& sc = o.scene;
  s += "\n## Options\n\n| option | value |\n|---|---|\n";
  s += fmt::format("| scene | cube side {}, centre ({}, {}, {}), yaw {} deg, pitch {} deg, orbit {} deg/frame about its centre, {} frames, {} points per face, s = {} px, {} px image |\n",
                   sc.side, sc.centre.x(), sc.centre.y(), sc.centre.z(), sc.yaw_deg, sc.pitch_deg, sc.deg_per_frame,
                   sc.frames, sc.points_per_face, sc.scale_px, sc.image_px);
  s += fmt::format("| prior | beta0 {} (var {}); planes: truth + N(0, ({} |N|)^2) on each free component, the same variance; gauge: each plane's largest component at its true value (planes-rigid, batch: plane 0's only) |\n",
                   o.beta0, o.beta_var0, o.n_rel);
  s += fmt::format("| filters | reading {}, q_trans {:g}, q_omega {:g}, q_beta {:g}, q_structure {:g}, gate {:g}, reference {}, iekf iterations {} (plain EKF in the first {} frames), beta_min {:g}, warm-up frames {} |\n",
                   toString(o.reading), o.q_translation, o.q_omega, o.q_beta, o.q_structure, o.gate_probability, o.reference_model,
                   o.iekf_iterations, o.iekf_after, o.beta_min, o.warmup_frames);
  s += "| point | A&P on all points; initial depths from each face's initial plane; gauge: the point nearest the image centre at its true depth; faces fitted to its 3-D points |\n";
  s += "| batch | Ceres, all frames, per-point reference positions estimated, started from planes-rigid |\n";
  return s;
}

std::string planesFigureData(const PlanesResult& r) {
  std::string s = "method,noise_px,frame,normal_err_deg,t_err\n";
  for (const auto& row : r.rows)
    for (size_t k = 0; k < row.normal_err_by_frame.size(); ++k)
      if (std::isfinite(row.normal_err_by_frame[k]))
        s += fmt::format("{},{},{},{:.6g},{:.6g}\n", row.method, row.noise_px, k, row.normal_err_by_frame[k],
                         row.t_err_by_frame[k]);
  return s;
}

Figures writePlanesReport(const PlanesResult& r, const std::filesystem::path& dir, const std::string& command_line) {
  return writeFigureReport(dir, "planes", planesCsv(r), planesMarkdown(r, command_line), "planes_data",
                    planesFigureData(r), "planes", "plot_planes.py");
}

}  // namespace rsfm::report
