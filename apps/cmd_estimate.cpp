// `rsfm estimate --tracks FILE | --patches FILE` and `rsfm run INPUT [--model patches]`: plane finding, the recursive filter on the
// tracks, and the report (docs/estimate.md, docs/outputs.md).
#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <sstream>

#include "cli_common.hpp"
#include "rsfm/io/atomic_file.hpp"
#include "rsfm/io/estimate_report.hpp"
#include "rsfm/io/patch_report.hpp"
#include "rsfm/io/patches_io.hpp"
#include "rsfm/pipeline/patch_pipeline.hpp"
#include "rsfm/io/tracks_io.hpp"
#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/vision/overlay.hpp"
#include "rsfm/vision/plane_finder.hpp"
#include "rsfm/vision/plane_init.hpp"
#include "track_options.hpp"

namespace rsfm::cli {

namespace {

/// Printed when the homography start's focal length is at an end of its grid (PlaneStart::at_grid_end).
constexpr const char* kGridEndWarning =
    "the start's focal length is at the end of its grid (0.3-3 x max(width, height)): the homographies do not "
    "determine it; consider --focal-px or --focal0-px";

/// summary.json's `start` of a successful homography start (docs/outputs.md).
nlohmann::json startJson(const vision::PlaneStart& start) {
  return {{"focal_px", start.focal_px}, {"disagreement_deg", start.score}, {"focal_at_grid_end", start.at_grid_end}};
}

struct EstimateCli {
  std::string model = "planes";
  bool patches = false;  ///< --model patches: Calway's patch filter on affine patches
  PatchPipelineOptions patch;
  std::string centres = "fused", measurement = "exact";
  TrackFilterOptions filter;
  vision::PlaneFinderOptions finder;
  std::string plane_rois;  ///< "x,y,...;x,y,..."
  double q_trans = 3e-4, q_omega = 1e-4, q_beta = 0.0;
  std::string reference = "refine";
  double gate = 0.999;
  int iterations = 1;
  int iekf_after = 10;
  bool plots = true;
  bool init = true;
  double normal_sd0 = -1.0, beta_sd0 = -1.0;  // < 0: automatic
  bool quiet = false;
  std::string out = "out";
};

void addEstimateOptions(CLI::App* a, EstimateCli* e) {
  a->add_option("--model", e->model,
                "point | plane (dominant plane) | planes (rigid multi-plane) | patches (Calway's filter on affine patches)")
      ->capture_default_str();
  a->add_option("--patch-sigma-px", e->patch.sigma_px, "patches: centre noise sd (px)")->capture_default_str();
  a->add_option("--sigma-affine", e->patch.sigma_affine, "patches: noise sd of each entry of the inter-frame map A")
      ->capture_default_str();
  a->add_option("--centres", e->centres, "patches: centres measured | predicted | fused | state (docs/patches.md)")
      ->capture_default_str();
  a->add_option("--measurement", e->measurement, "patches: affine measurement exact | instantaneous")->capture_default_str();
  a->add_option("--fused-maps", e->patch.fused_maps, "patches: estimate each patch's cumulative map beside the filter (true/false)")
      ->capture_default_str();
  a->add_option("--sigma-map", e->patch.sigma_map, "patches: noise sd of the tracker's cumulative map entries (--fused-maps)")
      ->capture_default_str();
  a->add_option("--anneal-frames", e->patch.anneal_frames, "patches: frames over which R is annealed (0: none)")
      ->capture_default_str();
  a->add_option("--patch-q-omega", e->patch.q_omega, "patches: process variance of the inter-frame rotation")
      ->capture_default_str();
  a->add_option("--patch-q-trans-rel", e->patch.q_trans_rel,
                "patches: per-frame sd of the inter-frame translation's change, relative to the start depth")
      ->capture_default_str();
  a->add_option("--focal-px", e->filter.focal_px, "known focal length in px (0: estimate it)")->capture_default_str();
  a->add_option("--focal0-px", e->filter.focal0_px, "initial focal guess in px (0: max(width, height))")
      ->capture_default_str();
  a->add_option("--sigma-px", e->filter.sigma_px, "tracking noise sd (px)")->capture_default_str();
  a->add_option("--q-trans-rel", e->filter.q_trans_rel,
                 "plane models: per-frame translation sd relative to the main plane's depth")
      ->capture_default_str();
  a->add_option("--q-trans", e->q_trans, "process variance of t per frame (point model; plane models with --q-trans-rel 0)")
      ->capture_default_str();
  a->add_option("--q-omega", e->q_omega, "process variance of omega per frame")->capture_default_str();
  a->add_option("--q-beta", e->q_beta, "process variance of beta per frame")->capture_default_str();
  a->add_option("--reference", e->reference, "reference positions: exact | inflate | refine")->capture_default_str();
  a->add_option("--gate", e->gate, "chi-square gate probability per point (0: off)")->capture_default_str();
  a->add_option("--iterations", e->iterations, "update iterations (1: EKF, >1: iterated EKF)")->capture_default_str();
  a->add_option("--iekf-after", e->iekf_after, "with --iterations > 1: first frames updated by the plain EKF (docs/filter.md)")
      ->capture_default_str();
  a->add_option("--passes", e->filter.passes, "passes over the sequence (>1: restart from the previous pass's planes and focal)")
      ->capture_default_str();
  a->add_option("--max-planes", e->finder.max_planes, "planes kept at most")->capture_default_str();
  a->add_option("--min-plane-tracks", e->finder.min_plane_tracks, "reference tracks a plane needs")
      ->capture_default_str();
  a->add_option("--ransac-px", e->finder.ransac_px, "homography RANSAC threshold (px)")->capture_default_str();
  a->add_option("--plane-roi", e->plane_rois,
                "manual planes: one polygon per plane in first-frame px, x,y,x,y,...;x,y,... (skips RANSAC)");
  a->add_flag("!--keep-static", e->finder.reject_static, "keep planes that do not move in the image");
  a->add_flag("!--no-plots", e->plots, "skip the PNG/SVG plots");
  a->add_flag("!--no-init", e->init, "start every plane frontal at the default focal guess (no homography start)");
  a->add_option("--max-tracks-per-plane", e->filter.max_tracks_per_plane, "tracks per plane in the filter at a time (0: all)")->capture_default_str();
  a->add_option("--normal-sd0", e->filter.normal_sd0, "initial sd of each plane's N components relative to N_Z0")->capture_default_str();
  a->add_option("--beta-sd0", e->filter.beta_sd0, "initial sd of beta relative to beta0")->capture_default_str();
  a->add_option("--depth0", e->filter.depth0, "start: planes frontal at this many (initial) focal lengths (scale gauge)")->capture_default_str();
  a->add_flag("!--no-new-tracks", e->filter.add_new_tracks, "only tracks of the reference frame enter the plane models");
  a->add_option("--out", e->out, "output directory")->capture_default_str();
  a->add_flag("--quiet", e->quiet, "no progress on stderr");
}

std::string finishEstimateOptions(EstimateCli* e) {
  e->patches = e->model == "patches";
  if (!e->patches && !parseTrackModel(e->model, &e->filter.model))
    return "--model must be point, plane, planes or patches, got '" + e->model + "'";
  if (!parsePatchCentres(e->centres, &e->patch.centres))
    return "--centres must be measured, predicted, fused or state, got '" + e->centres + "'";
  if (e->patch.centres == PatchCentres::State && e->measurement != "exact")
    return "--centres state needs --measurement exact";
  if (e->patch.centres == PatchCentres::State && e->patch.fused_maps)
    return "--centres state and --fused-maps exclude each other (the maps are already in the state)";
  if (e->measurement == "exact") e->patch.measurement = AffineMeasurement::Exact;
  else if (e->measurement == "instantaneous") e->patch.measurement = AffineMeasurement::Instantaneous;
  else return "--measurement must be exact or instantaneous, got '" + e->measurement + "'";
  if (!(e->patch.sigma_px > 0) || !(e->patch.sigma_affine > 0)) return "--patch-sigma-px and --sigma-affine must be positive";
  if (!(e->patch.q_omega >= 0) || !(e->patch.q_trans_rel >= 0)) return "process variances must be >= 0";
  if (e->patch.anneal_frames < 0) return "--anneal-frames must be >= 0";
  if (!(e->filter.depth0 > 0)) return "--depth0 must be positive";
  e->patch.focal_px = e->filter.focal_px;
  e->patch.focal0_px = e->filter.focal0_px;
  e->patch.depth0 = e->filter.depth0;
  ReferenceModel rm;
  if (!parseReferenceModel(e->reference, &rm)) return "--reference must be exact, inflate or refine";
  e->filter.filter.reference = rm;
  if (!(e->filter.focal_px >= 0) || !(e->filter.focal0_px >= 0)) return "--focal-px and --focal0-px must be >= 0";
  if (!(e->filter.sigma_px > 0)) return "--sigma-px must be positive";
  if (e->normal_sd0 == 0 || !std::isfinite(e->normal_sd0)) return "--normal-sd0 must be positive";
  if (e->beta_sd0 < 0 && e->beta_sd0 != -1.0) return "--beta-sd0 must be >= 0";
  if (!(e->q_trans >= 0) || !(e->q_omega >= 0) || !(e->q_beta >= 0)) return "process variances must be >= 0";
  if (!(e->gate >= 0 && e->gate < 1)) return "--gate must be in [0, 1)";
  if (e->iterations < 1) return "--iterations must be >= 1";
  if (e->iekf_after < 0) return "--iekf-after must be >= 0";
  if (e->filter.passes < 1 || e->filter.passes > 10) return "--passes must be in 1..10";
  if (e->finder.max_planes < 1) return "--max-planes must be >= 1";
  if (e->finder.min_plane_tracks < 5) return "--min-plane-tracks must be >= 5";
  if (!(e->finder.ransac_px > 0)) return "--ransac-px must be positive";
  e->filter.filter.q_motion << e->q_trans, e->q_trans, e->q_trans, e->q_omega, e->q_omega, e->q_omega, e->q_beta;
  e->filter.filter.update.gate_probability = e->gate;
  e->patch.gate_probability = e->gate;
  e->filter.filter.iterations = e->iterations;
  e->filter.filter.iterate_after_frames = e->iekf_after;
  if (!e->plane_rois.empty()) {
    std::stringstream ss(e->plane_rois);
    std::string poly;
    while (std::getline(ss, poly, ';')) {
      std::vector<cv::Point2f> p;
      if (auto m = parsePolygon(poly, &p); !m.empty()) return "--plane-roi: " + m;
      e->finder.rois.push_back(p);
    }
  }
  return "";
}

double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

/// Plane finding + filter + report (+ overlay when `overlay_input` is set). Returns the exit code.
int estimateAndReport(const Tracks& tracks, const EstimateCli& e, const std::string& overlay_input,
                      vision::FrameRange range, double t_start, bool write_tracks) {
  vision::PlaneFinding pf;
  try {
    vision::PlaneFinderOptions fo = e.finder;
    if (e.filter.model == TrackModel::Plane && fo.rois.empty()) fo.max_planes = 1;  // the dominant plane only
    pf = vision::findPlanes(tracks, fo);
  } catch (const std::exception& ex) {
    return fail(kBadInput, ex.what());
  }
  const int m = pf.numPlanes();
  if (m == 0)
    return fail(kBadInput, fmt::format("no plane with at least {} tracks found in the reference frame (tracks: {}; "
                                       "try --min-plane-tracks, --ransac-px or --plane-roi)",
                                       e.finder.min_plane_tracks, tracks.frames[0].size()));
  if (!e.quiet) {
    fmt::print(stderr, "planes: {} accepted (pair frame {}):", m, tracks.first_frame + pf.pair_frame);
    for (const auto& c : pf.candidates)
      fmt::print(stderr, " [{} {} tracks, motion {:.1f} px{}]", vision::toString(c.verdict), c.members.size(),
                 c.median_motion_px,
                 c.same_motion_fraction >= 0 ? fmt::format(", same-motion {:.2f}", c.same_motion_fraction) : "");
    fmt::print(stderr, "; outliers {}\n", pf.count(-1));
  }
  TrackFilterOptions fopt = e.filter;
  vision::PlaneStart start;
  if (e.init && fopt.model != TrackModel::Point) {
    start = vision::planeStart(tracks, pf, fopt.focal_px);
    if (start.ok) {
      if (fopt.focal_px <= 0 && fopt.focal0_px <= 0) fopt.focal0_px = start.focal_px;
      fopt.normal_sd0 = 0.1;
      fopt.beta_sd0 = 0.1;
      const int m = fopt.model == TrackModel::Plane ? 1 : static_cast<int>(start.normals.size());
      fopt.initial_normals.assign(start.normals.begin(), start.normals.begin() + m);
      fopt.initial_distance_ratios.assign(start.distance_ratios.begin(), start.distance_ratios.begin() + m);
    }
    if (!e.quiet) {
      if (start.ok) {
        fmt::print(stderr, "start: focal {:.0f} px from the homographies (disagreement {:.2f} deg), normals", start.focal_px,
                   start.score);
        for (const auto& n : start.normals) fmt::print(stderr, " ({:.2f}, {:.2f}, {:.2f})", n.x(), n.y(), n.z());
        fmt::print(stderr, "\n");
        if (start.at_grid_end) fmt::print(stderr, "warning: {}\n", kGridEndWarning);
      } else {
        fmt::print(stderr, "start: {}; planes start frontal\n", start.note);
      }
    }
  }
  if (e.normal_sd0 > 0) fopt.normal_sd0 = e.normal_sd0;
  if (e.beta_sd0 >= 0) fopt.beta_sd0 = e.beta_sd0;
  TrackFilterResult res;
  try {
    res = runTrackFilter(tracks, pf.labels, fopt, e.quiet ? std::function<void(int, int)>{} : progressReporter("estimate", "frames"));
  } catch (const std::invalid_argument& ex) {
    return fail(kBadInput, ex.what());
  } catch (const std::exception& ex) {
    return fail(kRuntimeFailure, ex.what());
  }
  if (!res.ok())
    return fail(kRuntimeFailure, "the filter stopped at " + res.stopped + " (no outputs written)");
  io::EstimateReport rep;
  rep.tracks = &tracks;
  rep.labels = &pf.labels;
  rep.result = &res;
  rep.model = e.filter.model;
  rep.command = invocation();
  nlohmann::json cands = nlohmann::json::array();
  for (const auto& c : pf.candidates)
    cands.push_back({{"verdict", vision::toString(c.verdict)}, {"label", c.label}, {"tracks", c.members.size()},
                     {"median_motion_px", c.median_motion_px}, {"same_motion_fraction", c.same_motion_fraction}});
  if (start.ok)
    rep.extra["start"] = startJson(start);
  rep.extra["plane_finding"] = {{"pair_frame", tracks.first_frame + pf.pair_frame}, {"candidates", cands},
                                {"manual", !e.finder.rois.empty()}};
  nlohmann::json summary;
  if (int rc = guarded([&] {
        io::AtomicFileSet files;
        rep.seconds = now() - t_start;
        summary = io::writeEstimateReport(rep, e.out, &files, e.plots);
        if (write_tracks) files.write(std::filesystem::path(e.out) / "tracks.csv", io::tracksToString(tracks));
        if (!overlay_input.empty())
          vision::writeOverlay(overlay_input, range, tracks, pf.labels, res,
                               files.temp(std::filesystem::path(e.out) / "overlay.mp4"));
        files.commit();
      }))
    return rc;
  if (!e.quiet) {
    const auto& s = summary;
    fmt::print(stderr, "estimate: {} frames, focal {:.1f} +- {:.1f} px", res.frames.size(), s["focal_px"].get<double>(),
               s["focal_sd_px"].get<double>());
    for (const auto& a : s["angles_between_planes_deg"])
      fmt::print(stderr, ", angle between planes {} and {}: {:.1f} deg", a["planes"][0].get<int>(), a["planes"][1].get<int>(),
                 a["angle_deg"].get<double>());
    fmt::print(stderr, "; wrote {}/summary.json, trajectory.tum, planes.csv, labels.csv{}{}{}\n", e.out,
               e.plots ? ", motion/normals/focal.png" : "", write_tracks ? ", tracks.csv" : "",
               overlay_input.empty() ? "" : ", overlay.mp4");
  }
  return 0;
}

/// The patch filter on affine patches + report (+ overlay when `overlay_input` is set).
int patchEstimateAndReport(const PatchTracks& tracks, const EstimateCli& e, const std::string& overlay_input,
                           vision::FrameRange range, double t_start, bool write_patches) {
  PatchPipelineOptions po = e.patch;
  po.beta_sd0 = e.filter.beta_sd0;
  nlohmann::json start_json;
  if (e.init && po.focal_px <= 0 && po.focal0_px <= 0) {
    // Focal start as for the plane models: homographies of the patch centres (as point tracks)
    // decomposed over a focal grid (vision/plane_init.hpp). Only the focal length is taken: every
    // patch still starts fronto-parallel, so its normal is the filter's own estimate.
    Tracks centres;
    centres.image = tracks.image;
    centres.first_frame = tracks.first_frame;
    for (const auto& f : tracks.frames) {
      std::vector<TrackPoint> pts;
      for (const auto& p : f) pts.push_back({p.id, p.px});
      centres.frames.push_back(std::move(pts));
    }
    vision::PlaneStart start;
    try {
      vision::PlaneFinderOptions fo = e.finder;
      fo.min_plane_tracks = std::min(fo.min_plane_tracks, 8);
      const vision::PlaneFinding pf = vision::findPlanes(centres, fo);
      if (pf.numPlanes() > 0) start = vision::planeStart(centres, pf, 0.0);
      else start.note = "no plane among the patch centres";
    } catch (const std::exception& ex) {
      start.note = ex.what();
    }
    if (start.ok) {
      po.focal0_px = start.focal_px;
      po.beta_sd0 = 0.1;
      start_json = startJson(start);
    }
    if (!e.quiet)
      fmt::print(stderr, "start: {}\n",
                 start.ok ? fmt::format("focal {:.0f} px from homographies of the patch centres{}", start.focal_px,
                                        start.at_grid_end ? fmt::format("\nwarning: {}", kGridEndWarning) : "")
                          : start.note + "; focal starts at max(width, height)");
  }
  PatchRunResult res;
  try {
    res = runPatchTracks(tracks, po, e.quiet ? std::function<void(int, int)>{} : progressReporter("estimate", "frames"));
  } catch (const std::invalid_argument& ex) {
    return fail(kBadInput, ex.what());
  } catch (const std::exception& ex) {
    return fail(kRuntimeFailure, ex.what());
  }
  if (!res.ok()) return fail(kRuntimeFailure, "the patch filter stopped at " + res.stopped + " (no outputs written)");
  io::PatchReport rep;
  rep.tracks = &tracks;
  rep.result = &res;
  rep.command = invocation();
  if (!start_json.is_null()) rep.extra["start"] = start_json;
  nlohmann::json summary;
  if (int rc = guarded([&] {
        io::AtomicFileSet files;
        rep.seconds = now() - t_start;
        summary = io::writePatchReport(rep, e.out, &files, e.plots);
        if (write_patches) files.write(std::filesystem::path(e.out) / "patches.csv", io::patchesToString(tracks));
        if (!overlay_input.empty())
          vision::writePatchOverlay(overlay_input, range, tracks, res, files.temp(std::filesystem::path(e.out) / "overlay.mp4"));
        files.commit();
      }))
    return rc;
  if (!e.quiet) {
    const auto& ln = summary["last_frame_normals"];
    fmt::print(stderr,
               "estimate: {} frames, {} patches ({} joined, {} left), focal {:.1f} +- {:.1f} px; last frame: {} of {} patch "
               "normals within 5 deg of their median (median {:.2f} deg); wrote {}/summary.json, trajectory.tum, "
               "patch_normals.csv{}{}{}\n",
               res.frames.size(), res.entered, res.joined, res.left, summary["focal_px"].get<double>(),
               summary["focal_sd_px"].get<double>(), ln["within_5deg"].get<int>(),
               summary["patches"]["live_last_frame"].get<int>(), ln["angle_to_median_deg"]["median"].get<double>(), e.out,
               e.plots ? ", patch_run.png" : "", write_patches ? ", patches.csv" : "", overlay_input.empty() ? "" : ", overlay.mp4");
  }
  return 0;
}

}  // namespace

void addEstimateCommands(CLI::App& app, std::vector<Command>& commands) {
  {
    struct Cli {
      EstimateCli e;
      std::string tracks, patches;
    };
    auto c = std::make_shared<Cli>();
    auto* es = app.add_subcommand("estimate", "camera motion, focal length and planes from a tracks (or patches) file");
    auto* ot = es->add_option("--tracks", c->tracks, "tracks file (docs/tracks.md)");
    auto* op = es->add_option("--patches", c->patches, "patches file (docs/tracks.md): implies --model patches");
    ot->excludes(op);
    op->excludes(ot);
    addEstimateOptions(es, &c->e);
    commands.push_back({es, [c]() -> int {
      const double t0 = now();
      if (c->tracks.empty() && c->patches.empty()) return fail(kBadInput, "one of --tracks or --patches is required");
      if (!c->patches.empty()) c->e.model = "patches";
      if (auto m = finishEstimateOptions(&c->e); !m.empty()) return fail(kBadInput, m);
      if (c->e.patches && c->patches.empty()) return fail(kBadInput, "--model patches needs --patches FILE (rsfm track --patches)");
      if (auto m = io::ensureWritableDirectory(c->e.out); !m.empty()) return fail(kBadInput, m);
      if (c->e.patches) {
        PatchTracks pt;
        try {
          pt = io::readPatches(c->patches);
        } catch (const std::exception& ex) {
          return fail(kBadInput, ex.what());
        }
        return patchEstimateAndReport(pt, c->e, "", {}, t0, false);
      }
      Tracks tracks;
      try {
        tracks = io::readTracks(c->tracks);
      } catch (const std::exception& ex) {
        return fail(kBadInput, ex.what());
      }
      return estimateAndReport(tracks, c->e, "", {}, t0, false);
    }});
  }
  {
    struct Cli {
      EstimateCli e;
      TrackCli t;
      std::string input;
      bool overlay = true;
    };
    auto c = std::make_shared<Cli>();
    auto* rn = app.add_subcommand("run", "track a video, find planes, estimate and report (the whole chain)");
    rn->add_option("input", c->input, "video file, image pattern (frames/img%04d.png) or folder of images")->required();
    addEstimateOptions(rn, &c->e);
    addTrackerOptions(rn, &c->t);
    addPatchTrackerOptions(rn, &c->t);
    rn->add_flag("!--no-overlay", c->overlay, "skip overlay.mp4");
    commands.push_back({rn, [c]() -> int {
      const double t0 = now();
      if (auto m = finishEstimateOptions(&c->e); !m.empty()) return fail(kBadInput, m);
      if (auto m = finishTrackerOptions(&c->t); !m.empty()) return fail(kBadInput, m);
      if (auto m = io::ensureWritableDirectory(c->e.out); !m.empty()) return fail(kBadInput, m);
      const auto progress = c->e.quiet ? std::function<void(int, int)>{} : progressReporter("track", "frames");
      if (c->e.patches) {
        PatchTracks pt;
        if (int rc = guarded([&] { pt = vision::trackPatchesInput(c->input, c->t.patches, c->t.range, progress); })) return rc;
        return patchEstimateAndReport(pt, c->e, c->overlay ? c->input : "", c->t.range, t0, true);
      }
      Tracks tracks;
      if (int rc = guarded([&] { tracks = vision::trackInput(c->input, c->t.tracker, c->t.range, progress); })) return rc;
      // The tracks are part of the report.
      return estimateAndReport(tracks, c->e, c->overlay ? c->input : "", c->t.range, t0, true);
    }});
  }
}

}  // namespace rsfm::cli
