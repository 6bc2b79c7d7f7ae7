// `rsfm experiment table1|planes|two-object|patches`: the papers' synthetic experiments (docs/table1.md,
// docs/planes.md).
#include <fmt/format.h>

#include <memory>
#include <string>

#include "cli_common.hpp"
#include "rsfm/experiment/planes.hpp"
#include "rsfm/experiment/table1.hpp"
#include "rsfm/experiment/two_object.hpp"
#include "rsfm/io/atomic_file.hpp"
#include "rsfm/report/planes_report.hpp"
#include "rsfm/report/table1_report.hpp"
#include "rsfm/report/two_object_report.hpp"
#include "rsfm/report/patches_report.hpp"
#include "rsfm/experiment/patches.hpp"

namespace rsfm::cli {

void addExperimentCommands(CLI::App& app, std::vector<Command>& commands) {
  auto* exp = app.add_subcommand("experiment", "reproduce the papers' synthetic experiments");
  exp->require_subcommand(1);
  auto* t1 = exp->add_subcommand(
      "table1", "Alon & Sclaroff Table 1 / Fig. 1: point vs plane filter on the same noisy tracks");

  struct Table1Cli {
    rsfm::Table1Options o;
    std::string out = "out/table1";
    std::string reading = "reset";
    bool quiet = false;
  };
  auto t1s = std::make_shared<Table1Cli>();
  auto& o = t1s->o;
  auto& out = t1s->out;
  auto& reading = t1s->reading;
  auto& quiet = t1s->quiet;
  t1->add_option("--trials", o.trials, "trials per noise level")->capture_default_str();
  t1->add_option("--seed", o.seed, "base random seed")->capture_default_str();
  t1->add_option("--out", out, "output directory")->capture_default_str();
  t1->add_option("--noise", o.noise_px, "noise standard deviations in px (comma-separated)")
      ->delimiter(',')
      ->capture_default_str();
  t1->add_option("--frames", o.scene.frames, "frames after the reference frame")->capture_default_str();
  t1->add_option("--points", o.scene.points, "points on the plane")->capture_default_str();
  t1->add_option("--deg-per-frame", o.scene.deg_per_frame, "rotation about y per frame (deg)")
      ->capture_default_str();
  t1->add_option("--scale-px", o.scene.scale_px, "s: pixels per normalized unit (512 px image)")
      ->capture_default_str();
  t1->add_option("--reading", reading, "rotation reading: rate | reset")->capture_default_str();
  t1->add_option("--beta0", o.beta0, "initial beta")->capture_default_str();
  t1->add_option("--beta-var", o.beta_var0, "initial beta variance")->capture_default_str();
  t1->add_option("--q-trans", o.q_translation, "process variance of t_X, t_Y, t_Z beta per frame")
      ->capture_default_str();
  t1->add_option("--q-omega", o.q_omega, "process variance of omega per frame")->capture_default_str();
  t1->add_option("--q-beta", o.q_beta, "process variance of beta per frame")->capture_default_str();
  t1->add_option("--q-structure", o.q_structure, "process variance of structure per frame")
      ->capture_default_str();
  t1->add_option("--r-scale", o.r_scale, "filter measurement variance / true noise variance")
      ->capture_default_str();
  t1->add_option("--gate", o.gate_probability, "chi-square gate probability per point (0: off)")
      ->capture_default_str();
  t1->add_option("--iterations", o.iterations, "update iterations (1: EKF, >1: iterated EKF)")
      ->capture_default_str();
  t1->add_option("--iekf-iterations", o.iekf_iterations,
                 "iterations of the plane-iekf row (<= 1: no such row)")
      ->capture_default_str();
  t1->add_option("--iekf-after", o.iekf_after, "iterated updates: first frames updated by the plain EKF (docs/filter.md)")
      ->capture_default_str();
  t1->add_option("--batch", o.batch, "add the batch (Ceres, maximum-likelihood) row (true/false)")
      ->capture_default_str();
  t1->add_option("--reference", o.reference_model,
                 "reference positions: exact (as published) | inflate | refine | state | conditional (docs/filter.md)")
      ->capture_default_str();
  t1->add_option("--alpha-init", o.alpha_init, "point model initial depths: plane | constant")
      ->capture_default_str();
  t1->add_option("--alpha-var", o.alpha_var, "point model initial depth variance (<=0: propagate)")
      ->capture_default_str();
  t1->add_option("--point-gauge", o.point_gauge, "index of the point model's fixed depth (-1: centre)")
      ->capture_default_str();
  t1->add_option("--threads", o.threads, "worker threads (0: all cores)")->capture_default_str();
  t1->add_option("--reference-noise", o.reference_noise,
                 "add noise to the reference frame too (true/false)")
      ->capture_default_str();
  t1->add_flag("--quiet", quiet, "no progress on stderr");

  auto* pl = exp->add_subcommand("planes", "multi-plane filters on a box scene vs a batch optimum");
  struct PlanesCli {
    rsfm::PlanesOptions po;
    std::string out = "out/planes";
    std::string reading = "reset";
    bool quiet = false;
  };
  auto pls = std::make_shared<PlanesCli>();
  auto& po = pls->po;
  auto& pout = pls->out;
  auto& preading = pls->reading;
  auto& pquiet = pls->quiet;
  pl->add_option("--trials", po.trials, "trials per noise level")->capture_default_str();
  pl->add_option("--seed", po.seed, "base random seed")->capture_default_str();
  pl->add_option("--out", pout, "output directory")->capture_default_str();
  pl->add_option("--noise", po.noise_px, "noise standard deviations in px (comma-separated)")
      ->delimiter(',')
      ->capture_default_str();
  pl->add_option("--frames", po.scene.frames, "frames after the reference frame")->capture_default_str();
  pl->add_option("--points-per-face", po.scene.points_per_face, "points on each visible face")->capture_default_str();
  pl->add_option("--deg-per-frame", po.scene.deg_per_frame, "orbit about the box centre per frame (deg)")
      ->capture_default_str();
  pl->add_option("--side", po.scene.side, "cube side (scene units)")->capture_default_str();
  pl->add_option("--centre-z", po.scene.centre.z(), "cube centre depth (A&P z)")->capture_default_str();
  pl->add_option("--yaw", po.scene.yaw_deg, "cube yaw (deg)")->capture_default_str();
  pl->add_option("--pitch", po.scene.pitch_deg, "cube pitch (deg)")->capture_default_str();
  pl->add_option("--reading", preading, "rotation reading: rate | reset")->capture_default_str();
  pl->add_option("--n-rel", po.n_rel, "initial plane error and prior sd per component, relative to |N|")
      ->capture_default_str();
  pl->add_option("--q-trans", po.q_translation, "process variance of t per frame")->capture_default_str();
  pl->add_option("--q-omega", po.q_omega, "process variance of omega per frame")->capture_default_str();
  pl->add_option("--q-structure", po.q_structure, "process variance of each plane / depth component per frame")
      ->capture_default_str();
  pl->add_option("--reference", po.reference_model,
                 "reference positions: exact | inflate | refine | state (in the filter's state: O(N^3) per frame) | conditional (state's estimate at O(N))")
      ->capture_default_str();
  pl->add_option("--passes", po.passes, "passes of the plane filters (1: recursive; >1: restart from the last pass's planes and beta)")
      ->capture_default_str();
  pl->add_option("--iekf-iterations", po.iekf_iterations, "iterations of planes-rigid-iekf (<= 1: no row)")
      ->capture_default_str();
  pl->add_option("--iekf-after", po.iekf_after, "iterated rows: first frames updated by the plain EKF (docs/filter.md)")
      ->capture_default_str();
  pl->add_option("--batch", po.batch, "add the batch (Ceres) row (true/false)")->capture_default_str();
  pl->add_option("--beta-min", po.beta_min, "lower bound on beta, by estimate projection (0: none)")
      ->capture_default_str();
  pl->add_option("--warmup-frames", po.warmup_frames, "first frames with iterated updates (5 iterations; 0: none)")
      ->capture_default_str();
  pl->add_option("--threads", po.threads, "worker threads (0: all cores)")->capture_default_str();
  pl->add_flag("--quiet", pquiet, "no progress on stderr");

  auto* two = exp->add_subcommand("two-object", "independent-motion planes filter on two independently moving planes");
  struct TwoObjectCli {
    rsfm::TwoObjectOptions o;
    std::string out = "out/two-object";
    bool quiet = false;
  };
  auto tws = std::make_shared<TwoObjectCli>();
  auto& to = tws->o;
  two->add_option("--trials", to.trials, "trials per noise level")->capture_default_str();
  two->add_option("--seed", to.seed, "base random seed")->capture_default_str();
  two->add_option("--out", tws->out, "output directory")->capture_default_str();
  two->add_option("--noise", to.noise_px, "noise standard deviations in px (comma-separated)")
      ->delimiter(',')
      ->capture_default_str();
  two->add_option("--frames", to.scene.frames, "frames after the reference frame")->capture_default_str();
  two->add_option("--points-per-object", to.scene.points_per_object, "points on each object")->capture_default_str();
  two->add_option("--beta0", to.beta0, "initial beta")->capture_default_str();
  two->add_option("--beta-var", to.beta_var0, "initial beta variance")->capture_default_str();
  two->add_option("--n-rel", to.n_rel, "initial plane error and prior sd per component, relative to |N|")
      ->capture_default_str();
  two->add_option("--q-trans", to.q_translation, "process variance of each object's t per frame")->capture_default_str();
  two->add_option("--q-omega", to.q_omega, "process variance of each object's omega per frame")->capture_default_str();
  two->add_option("--reference-noise", to.reference_noise, "add noise to the reference frame too (true/false)")
      ->capture_default_str();
  two->add_option("--reference", to.reference_model, "reference positions: exact (as published) | inflate | refine")
      ->capture_default_str();
  two->add_option("--threads", to.threads, "worker threads (0: all cores)")->capture_default_str();
  two->add_flag("--quiet", tws->quiet, "no progress on stderr");

  auto* pat = exp->add_subcommand("patches", "Calway's affine-patch filter on a moving sphere and on the Table 1 plane");
  struct PatchesCli {
    rsfm::PatchesOptions o;
    std::string out = "out/patches";
    std::string centres = "fused";
    std::vector<double> amplitude, angles;  // the sphere scene's defaults, set below
    bool quiet = false;
  };
  auto pas = std::make_shared<PatchesCli>();
  auto& pa = pas->o;
  pas->amplitude = {pa.sphere.amplitude.x(), pa.sphere.amplitude.y(), pa.sphere.amplitude.z()};
  pas->angles = {pa.sphere.angle_x_deg, pa.sphere.angle_y_deg};
  pat->add_option("--trials", pa.trials, "trials per noise level")->capture_default_str();
  pat->add_option("--seed", pa.seed, "base random seed")->capture_default_str();
  pat->add_option("--out", pas->out, "output directory")->capture_default_str();
  pat->add_option("--sphere-noise", pa.sphere_noise,
                  "sphere scene noise levels rho (fraction of each affine parameter's largest magnitude; comma-separated)")
      ->delimiter(',')
      ->capture_default_str();
  pat->add_option("--plane-noise", pa.plane_noise, "plane scene noise levels rho (comma-separated)")
      ->delimiter(',')
      ->capture_default_str();
  pat->add_option("--sphere-frames", pa.sphere.frames, "sphere scene: frames after the first")->capture_default_str();
  pat->add_option("--plane-frames", pa.plane.table1.frames, "plane scene: frames after the first")->capture_default_str();
  pat->add_option("--sphere-patches", pa.sphere.patches, "sphere scene: clusters")->capture_default_str();
  pat->add_option("--sphere-off-axis", pa.sphere.max_off_axis_deg,
                  "sphere scene: clusters centred within this angle (deg) of the point facing the camera")
      ->capture_default_str();
  pat->add_option("--sphere-max-obliquity", pa.sphere.max_obliquity_deg,
                  "sphere scene: clusters seen more obliquely than this (deg) in any frame are re-drawn")
      ->capture_default_str();
  pat->add_option("--sphere-amplitude", pas->amplitude,
                  "sphere scene: amplitude of the centre's sinusoidal motion along x,y,z (scene units)")
      ->delimiter(',')
      ->expected(3)
      ->capture_default_str();
  pat->add_option("--sphere-angles", pas->angles,
                  "sphere scene: amplitude (deg) of the sphere's turn about the camera's x and y axes")
      ->delimiter(',')
      ->expected(2)
      ->capture_default_str();
  pat->add_option("--sphere-distance", pa.sphere.centre[2],
                  "sphere scene: z of the sphere's centre in frame 0 (A&P; the COP is at -1/beta)")
      ->capture_default_str();
  pat->add_option("--plane-patches", pa.plane.patches, "plane scene: clusters")->capture_default_str();
  pat->add_option("--beta0", pa.beta0, "initial beta")->capture_default_str();
  pat->add_option("--beta-var", pa.beta_var0, "initial beta variance")->capture_default_str();
  pat->add_option("--q-trans", pa.q_translation, "patch filter: process variance of the inter-frame translation")
      ->capture_default_str();
  pat->add_option("--q-omega", pa.q_omega, "patch filter: process variance of the inter-frame rotation")
      ->capture_default_str();
  pat->add_option("--anneal-frames", pa.anneal_frames, "patch filter: frames over which R is annealed (0: none, -1: half of each scene's sequence)")
      ->capture_default_str();
  pat->add_option("--anneal-factor", pa.anneal_factor, "patch filter: R inflation at the first frame")
      ->capture_default_str();
  pat->add_option("--centres", pas->centres, "patch filter: centres measured | predicted | fused (docs/patches.md)")
      ->capture_default_str();
  pat->add_option("--iterations", pa.iterations, "patch filter: measurement-update iterations (1 = EKF)")
      ->capture_default_str();
  pat->add_option("--q-structure", pa.q_structure, "patch filter: process variance of each structure parameter")
      ->capture_default_str();
  pat->add_option("--threads", pa.threads, "worker threads (0: all cores)")->capture_default_str();
  pat->add_flag("--quiet", pas->quiet, "no progress on stderr");


  commands.push_back({t1, [t1s]() -> int {
    auto& o = t1s->o;
    auto& out = t1s->out;
    auto& reading = t1s->reading;
    const bool quiet = t1s->quiet;
    if (!rsfm::parseRotationReading(reading, &o.reading))
      return fail(kBadInput, "--reading must be 'rate' or 'reset', got '" + reading + "'");
    if (auto msg = rsfm::validateTable1Options(o); !msg.empty()) return fail(kBadInput, msg);
    rsfm::io::OutputDir od;
    if (auto msg = od.open(out); !msg.empty()) return fail(kBadInput, msg);
    if (!quiet) {
      o.progress = progressReporter("table1");
    }
    rsfm::Table1Result res;
    try {
      res = rsfm::runTable1(o);
    } catch (const std::exception& e) {
      return fail(1, e.what());
    }
    rsfm::report::Figures fig;
    try {
      fig = rsfm::report::writeTable1Report(res, od.path(), invocation());
      od.commit();
    } catch (const std::exception& e) {
      return fail(1, e.what());
    }
    warnFigures(fig);
    int failed = 0;
    for (const auto& row : res.rows) failed += row.failed;
    if (!quiet)
      fmt::print(stderr, "table1: {:.1f} s; wrote {}/table1.csv, table1.md{}\n",
                 res.seconds, out, wroteFigures(fig));
    if (failed > 0)
      fmt::print(stderr, "rsfm: warning: {} trial runs stopped on numerical trouble (see table1.md)\n",
                 failed);
    return 0;
    }});
  commands.push_back({pl, [pls]() -> int {
    auto& po = pls->po;
    auto& pout = pls->out;
    auto& preading = pls->reading;
    const bool pquiet = pls->quiet;
    if (!rsfm::parseRotationReading(preading, &po.reading))
      return fail(kBadInput, "--reading must be 'rate' or 'reset', got '" + preading + "'");
    if (auto msg = rsfm::validatePlanesOptions(po); !msg.empty()) return fail(kBadInput, msg);
    rsfm::io::OutputDir od;
    if (auto msg = od.open(pout); !msg.empty()) return fail(kBadInput, msg);
    if (!pquiet) {
      po.progress = progressReporter("planes");
    }
    rsfm::PlanesResult res;
    rsfm::report::Figures fig;
    try {
      res = rsfm::runPlanes(po);
      fig = rsfm::report::writePlanesReport(res, od.path(), invocation());
      od.commit();
    } catch (const std::exception& e) {
      return fail(1, e.what());
    }
    warnFigures(fig);
    if (!pquiet)
      fmt::print(stderr, "planes: {:.1f} s; wrote {}/planes.csv, planes.md{}\n", res.seconds, pout,
                 wroteFigures(fig));
    return 0;
    }});
  commands.push_back({pat, [pas]() -> int {
    auto& o = pas->o;
    o.sphere.amplitude = Eigen::Vector3d(pas->amplitude[0], pas->amplitude[1], pas->amplitude[2]);
    o.sphere.angle_x_deg = pas->angles[0];
    o.sphere.angle_y_deg = pas->angles[1];
    if (!rsfm::parsePatchCentres(pas->centres, &o.centres))
      return fail(kBadInput, "--centres must be 'measured', 'predicted' or 'fused', got '" + pas->centres + "'");
    if (o.centres == rsfm::PatchCentres::State)
      return fail(kBadInput, "--centres state needs tracked (cumulative) maps; the experiment's measurements are inter-frame maps");
    if (auto msg = rsfm::validatePatchesOptions(o); !msg.empty()) return fail(kBadInput, msg);
    rsfm::io::OutputDir od;
    if (auto msg = od.open(pas->out); !msg.empty()) return fail(kBadInput, msg);
    if (!pas->quiet) o.progress = progressReporter("patches");
    rsfm::PatchesResult res;
    rsfm::report::Figures fig;
    try {
      res = rsfm::runPatches(o);
      fig = rsfm::report::writePatchesReport(res, od.path(), invocation());
      od.commit();
    } catch (const std::exception& e) {
      return fail(1, e.what());
    }
    warnFigures(fig);
    int failed = 0;
    for (const auto& row : res.rows) failed += row.failed;
    if (!pas->quiet)
      fmt::print(stderr, "patches: {:.1f} s; wrote {}/patches.csv, patches.md{}\n", res.seconds,
                 pas->out, wroteFigures(fig));
    if (failed > 0)
      fmt::print(stderr, "rsfm: warning: {} trial runs stopped on numerical trouble (see patches.md)\n", failed);
    return 0;
    }});
  commands.push_back({two, [tws]() -> int {
    auto& o = tws->o;
    if (auto msg = rsfm::validateTwoObjectOptions(o); !msg.empty()) return fail(kBadInput, msg);
    rsfm::io::OutputDir od;
    if (auto msg = od.open(tws->out); !msg.empty()) return fail(kBadInput, msg);
    if (!tws->quiet) o.progress = progressReporter("two-object");
    rsfm::TwoObjectResult res;
    rsfm::report::Figures fig;
    try {
      res = rsfm::runTwoObject(o);
      fig = rsfm::report::writeTwoObjectReport(res, od.path(), invocation());
      od.commit();
    } catch (const std::exception& e) {
      return fail(1, e.what());
    }
    warnFigures(fig);
    int failed = 0;
    for (const auto& row : res.rows) failed += row.failed;
    if (!tws->quiet)
      fmt::print(stderr, "two-object: {:.1f} s; wrote {}/two_object.csv, two_object.md{}\n",
                 res.seconds, tws->out, wroteFigures(fig));
    if (failed > 0)
      fmt::print(stderr, "rsfm: warning: {} trial runs stopped on numerical trouble (see two_object.md)\n", failed);
    return 0;
    }});
}

}  // namespace rsfm::cli
