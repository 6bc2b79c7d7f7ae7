#include "rsfm/report/table1_report.hpp"

#include <fmt/format.h>

#include <cmath>
#include <map>

#include "rsfm/report/report.hpp"

namespace rsfm::report {

namespace {

std::string num(double v, int prec = 4) { return formatNumber(v, prec); }

std::string frameOr(int r, int frames) {
  if (r == Table1Row::kNotComputed) return "NA";
  return r < 0 ? fmt::format(">{}", frames) : std::to_string(r);
}
std::string frameCsv(int r) { return r == Table1Row::kNotComputed ? "NA" : std::to_string(r); }

/// The paper's Table 1 ([AS99], docs/bibliography.md): m_t, sigma_t, m_q, sigma_q, r_s, r_c (-1 = ">100").
struct PaperRow {
  double m_t, s_t, m_q, s_q;
  int r_s, r_c;
};
const std::map<std::pair<std::string, int>, PaperRow>& paperTable() {
  static const std::map<std::pair<std::string, int>, PaperRow> t = {
      {{"plane", 2}, {-0.0012, 0.0129, -0.0037, 0.0298, 7, 9}},
      {{"plane", 6}, {-0.0018, 0.0304, 0.0009, 0.0584, 7, 14}},
      {{"plane", 10}, {-0.0033, 0.0634, -0.0058, 0.3352, 7, 19}},
      {{"point", 2}, {0.0002, 0.0325, -0.0638, 0.3195, 12, 25}},
      {{"point", 6}, {0.0012, 0.0790, -0.0810, 0.3274, 14, 25}},
      {{"point", 10}, {-0.0238, 0.3316, -0.2366, 0.4673, -1, 19}},
  };
  return t;
}

const Table1Row* findRow(const Table1Result& r, const std::string& f, double noise) {
  for (const auto& row : r.rows)
    if (row.formulation == f && row.noise_px == noise) return &row;
  return nullptr;
}

}  // namespace

std::string table1Csv(const Table1Result& r) {
  std::string s = "formulation,noise_px,m_t,sigma_t,m_q,sigma_q,r_s,r_c\n";
  for (const auto& row : r.rows)
    s += fmt::format("{},{},{},{},{},{},{},{}\n", row.formulation, num(row.noise_px, 1),
                     num(row.m_t, 5), num(row.sigma_t, 5), num(row.m_q, 5), num(row.sigma_q, 5),
                     frameCsv(row.r_s), frameCsv(row.r_c));
  return s;
}

std::string table1Markdown(const Table1Result& r, const std::string& command_line) {
  const auto& o = r.options;
  const int F = o.scene.frames;
  std::string s;
  s += "# Table 1: point (A&P) vs plane (Alon & Sclaroff) filters on the same noisy tracks\n\n";
  s += fmt::format("Command: `{}`  \n{} trials per noise level, seed {}, {:.1f} s.\n\n", command_line,
                   o.trials, o.seed, r.seconds);
  s += "m_t, sigma_t: mean and RMS error of the translation (t_X, t_Y, t_Z, scene units) over all "
       "components, frames 1..F and successful trials; m_q, sigma_q: the same for the rotation "
       "quaternion (w, x, y, z; Hamilton, sign with w >= 0). r_s: first frame from which the "
       "trial-averaged normal stays within 0.5 deg of truth; r_c: first frame from which the "
       "trial-averaged beta stays within 5 % (-1 / >F: never). Paper values from [AS99] Table 1 (docs/bibliography.md).\n\n";
  s += "| formulation | noise px | m_t | sigma_t | m_q | sigma_q | r_s | r_c | paper sigma_t | paper "
       "sigma_q | paper r_s | paper r_c | normal err at F (deg) | beta err at F (%) | median trial sigma_t | median trial sigma_q | failed trials |\n";
  s += "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& row : r.rows) {
    const auto it = paperTable().find({row.formulation, static_cast<int>(std::lround(row.noise_px))});
    const bool hasPaper = it != paperTable().end() && std::abs(row.noise_px - std::lround(row.noise_px)) < 1e-9;
    s += fmt::format("| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {}/{} |\n",
                     row.formulation, num(row.noise_px, 1), num(row.m_t), num(row.sigma_t),
                     num(row.m_q), num(row.sigma_q), frameOr(row.r_s, F), frameOr(row.r_c, F),
                     hasPaper ? num(it->second.s_t) : "-", hasPaper ? num(it->second.s_q) : "-",
                     hasPaper ? frameOr(it->second.r_s, 100) : "-",
                     hasPaper ? frameOr(it->second.r_c, 100) : "-", num(row.final_normal_err_deg, 3),
                     num(row.final_beta_err_pct, 2), num(row.median_trial_sigma_t),
                     num(row.median_trial_sigma_q), row.failed, row.trials);
  }
  bool any_batch = false;
  for (const auto& row : r.rows) any_batch |= row.formulation == "batch";
  if (any_batch) {
    s += "\n## Batch reference and Cramer-Rao bounds\n\n";
    s += "`batch`: bundle adjustment over all frames with the plane parameterization (per-frame motion, "
         "beta, N with the same gauge, and each point's reference position), solved with Ceres from the "
         "plane filter's estimates: the maximum-likelihood estimate for Gaussian noise. Its covariance at "
         "the optimum gives the Cramer-Rao bounds below (mean over trials). Being a batch estimate, its "
         "structure is one value for the whole sequence, so its r_s / r_c are 0 (within tolerance) or never.\n\n";
    s += "| noise px | CRB beta sd (%) | CRB normal RMS angle (deg) | batch normal err (deg) | batch beta err (%) | plane / batch sigma_t | plane-iekf / batch sigma_t |\n";
    s += "|---|---|---|---|---|---|---|\n";
    for (double nz : o.noise_px) {
      const Table1Row* b = findRow(r, "batch", nz);
      const Table1Row* p = findRow(r, "plane", nz);
      const Table1Row* pi = findRow(r, "plane-iekf", nz);
      if (!b) continue;
      auto ratio = [&](const Table1Row* x) {
        return x && std::isfinite(x->sigma_t) && std::isfinite(b->sigma_t) && b->sigma_t > 0
                   ? num(x->sigma_t / b->sigma_t, 2)
                   : std::string("-");
      };
      s += fmt::format("| {} | {} | {} | {} | {} | {} | {} |\n", num(nz, 1),
                       b->crb_beta_pct >= 0 ? num(b->crb_beta_pct, 2) : "NA",
                       b->crb_normal_deg >= 0 ? num(b->crb_normal_deg, 3) : "NA",
                       num(b->final_normal_err_deg, 3), num(b->final_beta_err_pct, 2), ratio(p), ratio(pi));
    }
  }
  s += "\n## Ordering checks (the paper's claims)\n\n";
  s += "| noise px | plane sigma_t < point | plane sigma_q < point | plane r_s no later | plane r_c no later |\n";
  s += "|---|---|---|---|---|\n";
  auto later = [](int a, int b) {  // is a no later than b (-1 = never)
    if (a == Table1Row::kNotComputed || b == Table1Row::kNotComputed) return false;
    if (a < 0) return b < 0;
    return b < 0 || a <= b;
  };
  for (double nz : o.noise_px) {
    const Table1Row* pl = findRow(r, "plane", nz);
    const Table1Row* pt = findRow(r, "point", nz);
    if (!pl || !pt) continue;
    s += fmt::format("| {} | {} | {} | {} | {} |\n", num(nz, 1),
                     pl->sigma_t < pt->sigma_t ? "yes" : "NO", pl->sigma_q < pt->sigma_q ? "yes" : "NO",
                     later(pl->r_s, pt->r_s) ? "yes" : "NO", later(pl->r_c, pt->r_c) ? "yes" : "NO");
  }
  s += "\n## Consistency and gating\n\n";
  s += "| formulation | noise px | mean NIS/dof | NEES (beta, N_X, N_Y) at F, mean over trials (dof 3) | points gated | predictions failed | first failure |\n";
  s += "|---|---|---|---|---|---|---|\n";
  for (const auto& row : r.rows)
    s += fmt::format("| {} | {} | {} | {} | {} | {} | {} |\n", row.formulation, num(row.noise_px, 1),
                     num(row.mean_nis_per_dof, 3), row.nees_dof ? num(row.nees_static, 2) : "-",
                     row.gated, row.invalid, row.first_failure.empty() ? "-" : row.first_failure);
  s += "\nNIS/dof near 1 means the per-frame noise model is right. NEES of the static parameters far "
       "above its dof means the filter is overconfident about them: the reference-frame positions' "
       "noise is a constant error per point that the EKF's white-noise model cannot average out "
       "([AS99] §2's \"known weakness\"; see docs/table1.md).\n";
  s += "\n## Options (every choice the paper leaves open)\n\n| option | value | meaning |\n|---|---|---|\n";
  auto opt = [&](const std::string& k, const std::string& v, const std::string& m) {
    s += fmt::format("| `{}` | {} | {} |\n", k, v, m);
  };
  const auto& sc = o.scene;
  opt("--frames", std::to_string(sc.frames), "frames after the reference frame 0");
  opt("--points", std::to_string(sc.points), "points uniformly on the plane, visible in every frame");
  opt("--deg-per-frame", num(sc.deg_per_frame, 3), "rotation about the y axis through (0,0,2) per frame (total " + num(sc.deg_per_frame * sc.frames, 1) + " deg)");
  opt("--scale-px", num(sc.scale_px, 1), fmt::format("s, pixels per normalized unit ({:.1f} deg field of view on a {:.0f} px image at beta = 1)", 2 * std::atan(sc.image_px / 2 / sc.scale_px) * 180 / M_PI, sc.image_px));
  opt("(fixed)", "N = 2(1/sqrt3, 0, 1), beta = 1", "true plane and inverse focal length (paper)");
  opt("--reading", std::string(toString(o.reading)), "rotation reading of omega (rate: kept as per-frame rotation; reset: folded and zeroed)");
  opt("--beta0 / --beta-var", num(o.beta0, 3) + " / " + num(o.beta_var0, 3), "initial beta and variance (paper)");
  opt("(fixed)", "N0 = (1.5, 0.5, 2), var (0.1, 0.1, 0)", "initial plane (paper); N_Z is the scale gauge");
  opt("--q-trans", fmt::format("{:g}", o.q_translation), "per-frame process variance of t_X, t_Y, t_Z beta");
  opt("--q-omega", fmt::format("{:g}", o.q_omega), "per-frame process variance of each omega component");
  opt("--q-beta", fmt::format("{:g}", o.q_beta), "per-frame process variance of beta");
  opt("--q-structure", fmt::format("{:g}", o.q_structure), "per-frame process variance of each free structure component (N_X, N_Y; alpha_i)");
  opt("--reference-noise", o.reference_noise ? "true" : "false", "noise on the reference frame too (its noisy positions are the filters' first-frame coordinates)");
  opt("--r-scale", fmt::format("{:g}", o.r_scale), "R = r-scale x (noise/s)^2: measurement variance used by the filters");
  opt("--iterations", std::to_string(o.iterations), "measurement-update iterations (1 = EKF, > 1 = iterated EKF)");
  opt("--iekf-iterations", std::to_string(o.iekf_iterations), "iterations of the plane-iekf row (<= 1: no row)");
  opt("--iekf-after", std::to_string(o.iekf_after), "iterated updates: the first frames use the plain EKF");
  opt("--batch", o.batch ? "true" : "false", "batch (Ceres, maximum-likelihood) row");
  opt("--reference", o.reference_model, "first-frame positions: exact (as published: taken as exact), inflate (their noise added to R through dh/du1), refine (and re-estimated per point from later frames)");
  opt("--gate", fmt::format("{:g}", o.gate_probability), "per-point chi-square gate probability (0 disables)");
  opt("--alpha-init", o.alpha_init, "point model initial depths: from the initial plane (plane) or the plane's axis depth (constant)");
  opt("--alpha-var", o.alpha_var > 0 ? fmt::format("{:g}", o.alpha_var) : "propagate", "point model initial depth variance (propagate: implied by the plane prior)");
  opt("--point-gauge", o.point_gauge < 0 ? "centre" : std::to_string(o.point_gauge), "the point model's fixed alpha (set to its true depth)");
  opt("--seed", std::to_string(o.seed), "base seed: scene per trial, noise per trial and level");
  s += "\nNoise: uniform, zero mean, the given standard deviation in pixels on both coordinates, all "
       "frames including the reference frame (whose noisy positions are the filters' first-frame "
       "coordinates, as in A&P). The point formulation's plane is the total-least-squares fit to its "
       "3-D points at each frame.\n";
  return s;
}

std::string table1FigureData(const Table1Result& r) {
  std::string s =
      "formulation,noise_px,frame,t_x,t_zb,q0,q2,n_x,n_y,beta,normal_err_deg,true_t_x,true_t_zb,"
      "true_q0,true_q2,true_n_x,true_n_y,true_beta\n";
  for (const auto& ser : r.series) {
    if (ser.t_x.empty()) continue;  // every trial failed
    for (size_t k = 0; k < ser.t_x.size(); ++k)
      s += fmt::format("{},{},{},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g}\n",
                       ser.formulation, ser.noise_px, k, ser.t_x[k], ser.t_zb[k], ser.q0[k], ser.q2[k],
                       ser.n_x[k], ser.n_y[k], ser.beta[k], ser.normal_err_deg[k], r.truth.t_x[k],
                       r.truth.t_zb[k], r.truth.q0[k], r.truth.q2[k], r.truth.n_x, r.truth.n_y,
                       r.truth.beta);
  }
  return s;
}

Figures writeTable1Report(const Table1Result& r, const std::filesystem::path& dir,
                       const std::string& command_line) {
  return writeFigureReport(dir, "table1", table1Csv(r), table1Markdown(r, command_line), "fig1_data",
                    table1FigureData(r), "fig1", "plot_table1.py");
}

}  // namespace rsfm::report
