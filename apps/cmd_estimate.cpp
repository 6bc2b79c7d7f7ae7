// `rsfm estimate --tracks FILE | --patches FILE` and `rsfm run INPUT [--model patches]`: plane finding, the recursive filter on the
// tracks, and the report (docs/estimate.md, docs/outputs.md).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>
#include <sstream>

#include "cli_common.hpp"
#include "estimate_cli.hpp"
#include "track_options.hpp"
#include "rsfm/clock.hpp"
#include "rsfm/io/atomic_file.hpp"
#include "rsfm/io/json_text.hpp"
#include "rsfm/report/estimate_report.hpp"
#include "rsfm/report/patch_report.hpp"
#include "rsfm/report/html_report.hpp"
#include "rsfm/io/patches_io.hpp"
#include "rsfm/pipeline/estimate.hpp"
#include "rsfm/pipeline/patch_pipeline.hpp"
#include "rsfm/io/tracks_io.hpp"
#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/vision/camera_file.hpp"
#include "rsfm/vision/plane_finder.hpp"
#include "rsfm/vision/plane_init.hpp"

namespace rsfm::cli {

namespace {

/// summary.json's `start`: the hypotheses considered, their scores and the one used (docs/outputs.md).
nlohmann::json startJson(const vision::PlaneStart& start) {
  nlohmann::json hyps = nlohmann::json::array();
  for (const auto& h : start.hypotheses) {
    nlohmann::json normals = nlohmann::json::array();
    for (const auto& n : h.normals) normals.push_back({n.x(), n.y(), n.z()});
    nlohmann::json j = {{"kind", h.frontal ? "frontal" : "decomposition"},
                        {"focal_px", h.frontal ? nlohmann::json(nullptr) : nlohmann::json(h.focal_px)},
                        {"normals", normals},
                        {"disagreement_deg", io::finiteOrNull(h.disagreement_deg)},
                        {"score", io::finiteOrNull(h.score)}};
    if (!h.frontal) {
      j["focal_minimum"] = h.focal_minimum;
      j["branch"] = h.branch;
      j["focal_at_grid_end"] = h.at_grid_end;
    }
    if (!h.stopped.empty()) j["stopped"] = h.stopped;
    hyps.push_back(j);
  }
  const vision::StartHypothesis& c = start.used();
  nlohmann::json j = {{"chosen", start.chosen},
                      {"frontal", c.frontal},
                      {"focal_px", c.frontal ? nlohmann::json(nullptr) : nlohmann::json(c.focal_px)},
                      {"disagreement_deg", io::finiteOrNull(c.disagreement_deg)},
                      {"focal_at_grid_end", c.at_grid_end},
                      {"hypotheses", hyps}};
  if (start.scored_from >= 0) j["scored_frames"] = {start.scored_from, start.scored_to};
  if (!start.note.empty()) j["note"] = start.note;
  return j;
}

}  // namespace

/// "x,y,x,y,..." -> polygon vertices (--roi, --plane-roi). Here rather than in cmd_track.cpp: both
/// executables use it (apps/rsfm_main.cpp).
std::string parsePolygon(const std::string& s, std::vector<cv::Point2f>* out) {
  out->clear();
  std::vector<double> v;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      size_t used = 0;
      const double d = std::stod(item, &used);
      if (used != item.size() || !std::isfinite(d)) throw std::invalid_argument("bad");
      v.push_back(d);
    } catch (const std::exception&) {
      return fmt::format("polygon '{}': '{}' is not a number", s, item);
    }
  }
  if (v.size() % 2 != 0) return fmt::format("polygon '{}': odd number of coordinates", s);
  if (v.size() < 6) return fmt::format("polygon '{}': needs at least 3 vertices (x,y,x,y,x,y)", s);
  for (size_t i = 0; i < v.size(); i += 2) out->emplace_back(static_cast<float>(v[i]), static_cast<float>(v[i + 1]));
  return "";
}

void addEstimateOptions(CLI::App* a, EstimateCli* e) {
  TrackFilterOptions& f = e->est.filter;
  PatchPipelineOptions& pp = e->pat.patch;
  a->add_option("--model", e->model,
                "point | plane (dominant plane) | planes (rigid multi-plane) | patches (Calway's filter on affine patches)")
      ->capture_default_str();
  a->add_option("--patch-sigma-px", pp.sigma_px, "patches: centre noise sd (px)")->capture_default_str();
  a->add_option("--sigma-affine", pp.sigma_affine, "patches: noise sd of each entry of the inter-frame map A")
      ->capture_default_str();
  a->add_option("--centres", e->centres, "patches: centres measured | predicted | fused | state (docs/patches.md)")
      ->capture_default_str();
  a->add_option("--measurement", e->measurement, "patches: affine measurement exact | instantaneous")->capture_default_str();
  a->add_option("--fused-maps", pp.fused_maps, "patches: estimate each patch's cumulative map beside the filter (true/false)")
      ->capture_default_str();
  a->add_option("--sigma-map", pp.sigma_map, "patches: noise sd of the tracker's cumulative map entries (--fused-maps)")
      ->capture_default_str();
  a->add_option("--anneal-frames", pp.anneal_frames, "patches: frames over which R is annealed (0: none)")
      ->capture_default_str();
  a->add_option("--patch-q-omega", pp.q_omega, "patches: process variance of the inter-frame rotation")
      ->capture_default_str();
  a->add_option("--patch-q-trans-rel", pp.q_trans_rel,
                "patches: per-frame sd of the inter-frame translation's change, relative to the start depth")
      ->capture_default_str();
  a->add_option("--focal-px", f.focal_px, "known focal length in px (0: estimate it)")->capture_default_str();
  a->add_option("--focal0-px", f.focal0_px, "initial focal guess in px (0: from the homographies, else max(width, height))")
      ->capture_default_str();
  a->add_option("--sigma-px", f.sigma_px,
                "the filter's measurement noise sd per axis (px): a floor, raised to the tracking noise (--tracking-noise-px)")
      ->capture_default_str();
  // The motion's process noise comes from the data and adapts online (TrackFilterOptions::
  // q_from_data); giving any of these fixes it at the values given (defaults as shown).
  a->add_option_function<double>(
       "--q-trans-rel", [pf = &f](double v) { pf->q_trans_rel = v, pf->q_from_data = false; },
       "fixed process noise: per-frame translation sd relative to the main plane's depth (default: from the motion "
       "the start measured, adapted online)")
      ->default_str(fmt::format("{}", f.q_trans_rel));
  Eigen::Matrix<double, 7, 1>& q = f.filter.q_motion;
  a->add_option_function<double>("--q-trans", [pf = &f](double v) { pf->filter.q_motion.head<3>().setConstant(v), pf->q_from_data = false; },
                                 "fixed process noise: variance of t per frame (with --q-trans-rel 0)")
      ->default_str(fmt::format("{}", q[0]));
  a->add_option_function<double>("--q-omega", [pf = &f](double v) { pf->filter.q_motion.segment<3>(3).setConstant(v), pf->q_from_data = false; },
                                 "fixed process noise: variance of omega per frame (rad^2)")
      ->default_str(fmt::format("{}", q[3]));
  a->add_option_function<double>("--q-beta", [&q](double v) { q[6] = v; }, "process variance of beta per frame")
      ->default_str(fmt::format("{}", q[6]));
  a->add_option("--reference", e->reference,
                "reference positions: conditional (on the filter's state) | refine | inflate | exact (docs/filter.md)")
      ->capture_default_str();
  a->add_option("--gate", f.filter.update.gate_probability, "chi-square gate probability per point (0: off)")
      ->capture_default_str();
  a->add_option("--iterations", f.filter.iterations, "update iterations (1: EKF, >1: iterated EKF)")->capture_default_str();
  a->add_option("--iekf-after", f.filter.iterate_after_frames,
                "with --iterations > 1: first frames updated by the plain EKF (docs/filter.md)")
      ->capture_default_str();
  a->add_option("--passes", f.passes, "passes over the sequence (>1: restart from the previous pass's planes and focal)")
      ->capture_default_str();
  a->add_option_function<double>("--still-px", [e](double v) { e->est.still_px = e->pat.patch.still_px = v; },
                                 "still frames: motion below this (px) is still; the reference frame is the last still frame "
                                 "of the start, later stretches of 10 still frames are held (plane models: the tracks' "
                                 "homography or a plane's worth of tracks; patches: the median, start only; <= 0: off)")
      ->default_str(fmt::format("{}", e->est.still_px));
  a->add_option("--max-planes", e->est.finder.max_planes, "planes kept at most")->capture_default_str();
  a->add_option("--min-plane-tracks", e->est.finder.min_plane_tracks, "reference tracks a plane needs")
      ->capture_default_str();
  a->add_option("--ransac-px", e->est.finder.ransac_px,
                "homography RANSAC threshold (px; at least this, widened to what the tracking noise needs)")
      ->capture_default_str();
  a->add_option("--tracking-noise-px", e->est.finder.noise_px,
                "tracking noise per axis (px): it widens the plane finder's pixel tolerances and raises the filter's "
                "measurement sd above --sigma-px (< 0: measured from the tracks' second differences; 0: neither)")
      ->capture_default_str();
  a->add_option("--plane-roi", e->plane_rois,
                "manual planes: one polygon per plane in first-frame px, x,y,x,y,...;x,y,... (skips RANSAC)");
  a->add_flag("!--keep-static", e->est.finder.reject_static, "keep planes that do not move in the image");
  a->add_flag("!--no-late-planes", e->est.late_planes,
              "--model planes: only the reference frame's planes (no search for planes that come into view later, "
              "docs/estimate.md section 1)");
  a->add_flag("!--no-plots", e->plots, "skip the PNG/SVG plots");
  a->add_flag("!--no-init", e->est.homography_start, "start every plane frontal at the default focal guess (no homography start)");
  a->add_option("--max-tracks-per-plane", f.max_tracks_per_plane, "tracks per plane in the filter at a time (0: all)")
      ->capture_default_str();
  a->add_option_function<double>("--normal-sd0", [f = &f](double v) { f->normal_sd0 = v; },
                                 "initial sd of each plane's N components relative to N_Z0 (default: 0.1 after a "
                                 "homography start, 1 without)");
  a->add_option_function<double>("--beta-sd0", [e](double v) { e->beta_sd0 = v; },
                                 "initial sd of beta relative to beta0 (default: 0.1 after a homography start, 0.3 without)");
  a->add_option("--depth0", f.depth0, "start: planes frontal at this many (initial) focal lengths (scale gauge)")
      ->capture_default_str();
  a->add_flag("!--no-new-tracks", f.add_new_tracks, "only tracks of the reference frame enter the plane models");
  a->add_option("--camera", e->camera_file,
                "a calibrated camera (OpenCV FileStorage YAML/XML: camera_matrix, distortion_coefficients, image_width, "
                "image_height; or ROS camera_info, Kalibr or EuRoC YAML): tracks undistorted, intrinsics known");
  a->add_option("--principal-point", e->principal_point, "a known principal point X,Y (px), held")
      ->delimiter(',')
      ->expected(2);
  a->add_option("--rolling-shutter-readout", e->est.rolling_shutter_readout,
                "a rolling shutter's known readout time in frame intervals (0: a global shutter): the tracks are moved "
                "to a global shutter's positions with their own velocities first and the refinement does not "
                "estimate it (default: estimated; docs/estimate.md section 6)");
  std::vector<std::string> directions;
  for (ReadoutDirection d : kReadoutDirections) directions.emplace_back(readoutDirectionName(d));
  a->add_option("--readout-direction", e->readout_direction,
                "down | up | right | left: the way the rolling shutter's readout travels across the image (default: "
                "the tracks' own, down unless the video's rotation metadata turned the frames; docs/estimate.md "
                "section 6)")
      ->check(CLI::IsMember(directions));
  a->add_option("--refine", e->refine,
                "final | none (final: a bundle adjustment of the plane model over every frame after the filter, also for the point model's run; docs/estimate.md section 4)")
      ->capture_default_str();
  a->add_option("--out", e->out, "output directory")->capture_default_str();
  a->add_flag("--quiet", e->quiet, "no progress on stderr");
}

std::string finishEstimateOptions(EstimateCli* e) {
  TrackFilterOptions& f = e->est.filter;
  PatchPipelineOptions& pp = e->pat.patch;
  e->patches = e->model == "patches";
  if (!e->patches && !parseTrackModel(e->model, &f.model))
    return "--model must be point, plane, planes or patches, got '" + e->model + "'";
  if (!parsePatchCentres(e->centres, &pp.centres))
    return "--centres must be measured, predicted, fused or state, got '" + e->centres + "'";
  if (pp.centres == PatchCentres::State && e->measurement != "exact") return "--centres state needs --measurement exact";
  if (pp.centres == PatchCentres::State && pp.fused_maps)
    return "--centres state and --fused-maps exclude each other (the maps are already in the state)";
  if (e->measurement == "exact") pp.measurement = AffineMeasurement::Exact;
  else if (e->measurement == "instantaneous") pp.measurement = AffineMeasurement::Instantaneous;
  else return "--measurement must be exact or instantaneous, got '" + e->measurement + "'";
  if (!(pp.sigma_px > 0) || !(pp.sigma_affine > 0)) return "--patch-sigma-px and --sigma-affine must be positive";
  if (!(pp.q_omega >= 0) || !(pp.q_trans_rel >= 0)) return "process variances must be >= 0";
  if (pp.anneal_frames < 0) return "--anneal-frames must be >= 0";
  if (!(f.depth0 > 0)) return "--depth0 must be positive";
  if (!parseReferenceModel(e->reference, &f.filter.reference) || f.filter.reference == ReferenceModel::State)
    return "--reference must be conditional, refine, inflate or exact ('state' takes no tracks that start later)";
  if (!(f.focal_px >= 0) || !(f.focal0_px >= 0)) return "--focal-px and --focal0-px must be >= 0";
  if (!(f.sigma_px > 0)) return "--sigma-px must be positive";
  if (f.normal_sd0 && !(*f.normal_sd0 > 0 && std::isfinite(*f.normal_sd0))) return "--normal-sd0 must be positive";
  if (e->beta_sd0 && !(*e->beta_sd0 >= 0 && std::isfinite(*e->beta_sd0))) return "--beta-sd0 must be >= 0";
  for (int i = 0; i < 7; ++i)
    if (!(f.filter.q_motion[i] >= 0)) return "process variances must be >= 0";
  if (!(f.filter.update.gate_probability >= 0 && f.filter.update.gate_probability < 1)) return "--gate must be in [0, 1)";
  if (f.filter.iterations < 1) return "--iterations must be >= 1";
  if (f.filter.iterate_after_frames < 0) return "--iekf-after must be >= 0";
  if (f.passes < 1 || f.passes > 10) return "--passes must be in 1..10";
  if (std::isnan(e->est.still_px)) return "--still-px must be a number";
  if (e->est.finder.max_planes < 1) return "--max-planes must be >= 1";
  if (e->est.finder.min_plane_tracks < 5) return "--min-plane-tracks must be >= 5";
  if (!(e->est.finder.ransac_px > 0)) return "--ransac-px must be positive";
  if (!e->plane_rois.empty()) {
    std::stringstream ss(e->plane_rois);
    std::string poly;
    while (std::getline(ss, poly, ';')) {
      std::vector<cv::Point2f> p;
      if (auto m = parsePolygon(poly, &p); !m.empty()) return "--plane-roi: " + m;
      e->est.finder.rois.push_back(p);
    }
  }
  if (!e->camera_file.empty()) {
    if (f.focal_px > 0) return "--camera and --focal-px exclude each other (the file gives the focal length)";
    if (!e->principal_point.empty()) return "--camera and --principal-point exclude each other (the file gives it)";
    try {
      e->est.camera = vision::readCameraFile(e->camera_file);
    } catch (const std::exception& ex) {
      return ex.what();
    }
  }
  if (!e->principal_point.empty()) {
    if (!std::isfinite(e->principal_point[0]) || !std::isfinite(e->principal_point[1]))
      return "--principal-point must be two finite numbers X,Y";
    e->est.principal_point = Eigen::Vector2d(e->principal_point[0], e->principal_point[1]);
  }
  if (e->patches && e->est.rolling_shutter_readout.value_or(0.0) != 0.0)
    return "--rolling-shutter-readout applies to the point and plane models (--model patches does not correct its patches)";
  if (e->patches && e->est.camera && e->est.camera->rolling_shutter_readout.value_or(0.0) != 0.0)
    return e->camera_file + ": its rolling_shutter_readout applies to the point and plane models (--model patches does not "
                            "correct its patches)";
  if (!e->readout_direction.empty()) {
    if (e->patches) return "--readout-direction applies to the point and plane models (--model patches has no readout)";
    ReadoutDirection d;
    if (!parseReadoutDirection(e->readout_direction, &d)) return "--readout-direction must be down, up, right or left";
    e->est.readout_direction = d;
  }
  try {
    knownReadout(e->est);  // given twice and different, or out of range: said here, before anything runs
  } catch (const std::invalid_argument& ex) {
    return ex.what();
  }
  if (e->refine == "final") e->est.refine.enabled = true;
  else if (e->refine == "none") e->est.refine.enabled = false;
  else return "--refine must be final or none, got '" + e->refine + "'";
  // One flag, the chosen pipeline's option.
  f.beta_sd0 = e->beta_sd0;
  pp.beta_sd0 = e->beta_sd0;
  pp.focal_px = f.focal_px;
  pp.focal0_px = f.focal0_px;
  pp.depth0 = f.depth0;
  pp.gate_probability = f.filter.update.gate_probability;
  e->pat.finder = e->est.finder;
  e->pat.homography_start = e->est.homography_start;
  return "";
}

/// camera.yaml: the camera the run ended with (OpenCV FileStorage YAML, docs/outputs.md): the
/// given calibration, or the refinement's estimate with its sds and what is determined. Empty
/// when there is neither (no refinement).
namespace {

std::string cameraYamlOf(const EstimateResult& r, const EstimateOptions& o, const ImageInfo& image) {
  // The rolling shutter's readout: a node `--camera` reads as known when it is (given, or
  // determined by the refinement); an estimate not determined only as a comment.
  auto readoutLines = [&](std::vector<std::string>* extra) {
    const RefineResult& f = r.refined;
    if (const std::optional<double> tau = knownReadout(o)) {
      extra->push_back(fmt::format("rolling_shutter_readout: {:.17g}", *tau));
      extra->push_back("rolling_shutter_readout_given: 1");
    } else if (f.ok && f.readout_free && f.readout_determined) {
      extra->push_back(fmt::format("rolling_shutter_readout: {:.6g}", f.readout));
      extra->push_back(fmt::format("rolling_shutter_readout_sd: {:.6g}", f.readout_sd));
    } else if (f.ok && f.readout_free) {
      extra->push_back(fmt::format("# rolling shutter readout {:.3f} +- {:.3f} frame intervals: not determined (not a node, "
                                   "so --camera does not take it as known)",
                                   f.readout, f.readout_sd));
    }
  };
  if (r.camera) {
    const vision::CameraCalibration& c = *r.camera;  // turned to the tracks' frames if their video was
    std::vector<std::string> extra{fmt::format("source: \"{} (given)\"", c.source)};
    if (c.distortion.size() > 2) {
      std::string all;
      for (double d : c.distortion) all += fmt::format("{}{:.17g}", all.empty() ? "" : ", ", d);
      extra.push_back("# the given distortion (OpenCV's order k1, k2, p1, p2, k3, ...): " + all);
    }
    readoutLines(&extra);
    return io::cameraYaml(c.width, c.height, c.focal(), c.cx, c.cy, c.distortion.size() > 0 ? c.distortion[0] : 0.0,
                              c.distortion.size() > 1 ? c.distortion[1] : 0.0, extra);
  }
  if (!r.refined.ok) return {};
  const RefineResult& f = r.refined;
  const double s = f.state.scale_px, beta = f.state.frames.back().beta;
  auto sd = [&](int c) { return std::sqrt(std::max(0.0, f.cov_camera(c, c))); };
  const double focal_sd = s * std::sqrt(std::max(0.0, f.state.frames.back().var_beta)) / (beta * beta);
  std::vector<std::string> extra{
      "source: \"estimated by rsfm's refinement (docs/estimate.md)\"",
      fmt::format("focal_determined: {}", f.focal_determined ? 1 : 0),
      fmt::format("focal_sd_px: {:.6g}", focal_sd),
      fmt::format("principal_point_estimated: {}", f.camera_free[0] ? 1 : 0),
      fmt::format("principal_point_determined: {}", f.camera_determined[0] && f.camera_determined[1] ? 1 : 0),
      fmt::format("principal_point_sd_px: [ {:.6g}, {:.6g} ]", s * sd(0), s * sd(1)),
      fmt::format("distortion_estimated: {}", f.camera_free[2] ? 1 : 0),
      fmt::format("distortion_determined: {}", f.camera_determined[2] && f.camera_determined[3] ? 1 : 0),
      fmt::format("distortion_sd: [ {:.6g}, {:.6g} ]", sd(2), sd(3))};
  readoutLines(&extra);
  return io::cameraYaml(image.width, image.height, s / beta, f.principal_point_px.x(), f.principal_point_px.y(),
                            f.camera[2], f.camera[3], extra);
}

/// The overlay's codec into summary.json's "overlay", its fallback warning into `warnings`.
void recordOverlay(const vision::OverlayInfo& ov, nlohmann::json* extra, std::vector<std::string>* warnings) {
  (*extra)["overlay"] = {{"file", "overlay.mp4"}, {"codec", ov.codec}};
  if (!ov.warning.empty()) warnings->push_back(ov.warning);
}

/// The patch filter's focal length far (> 3 sigma) from the motion check's, or "".
std::string patchFocalDisagreement(const nlohmann::json& summary) {
  if (!summary.contains("patch_filter_focal_z") || !summary["patch_filter_focal_z"].is_number() ||
      std::abs(summary["patch_filter_focal_z"].get<double>()) <= 3)
    return {};
  return fmt::format("the patch filter's focal length {:.1f} +- {:.1f} px disagrees with the motion check's "
                     "({:.1f} sigma); the check's bundle adjustment is reported",
                     summary["patch_filter_focal_px"].get<double>(), summary["patch_filter_focal_sd_px"].get<double>(),
                     summary["patch_filter_focal_z"].get<double>());
}

/// The pipeline's notes: printed unless quiet; its warnings (lines "warning: ...") also kept for
/// report.html.
std::function<void(const std::string&)> noteTo(bool quiet, std::vector<std::string>* warnings) {
  return [quiet, warnings](const std::string& m) {
    if (m.rfind("warning: ", 0) == 0) warnings->push_back(m.substr(9));
    if (!quiet) fmt::print(stderr, "{}\n", m);
  };
}

/// Captions of the figures report.html embeds (the PNGs; the SVGs are the same plots).
std::string captionOf(const std::string& name) {
  if (name == "motion.png") return "Camera motion per frame: position and rotation in the first camera frame (trajectory.tum)";
  if (name == "normals.png") return "Plane normals per frame, the filter's online estimate with its sd (planes.csv)";
  if (name == "focal.png") return "Focal length per frame, the filter's online estimate with its sd (planes.csv)";
  if (name == "process_noise.png")
    return "Process noise of the filter's prediction per frame: from the motion the start measured, adapted to the measured "
           "motion (planes.csv)";
  if (name == "angles.png")
    return "Angles between planes per frame, the filter's online estimate with its sd, and the refined angle with its 95 % "
           "interval (angles.csv)";
  if (name == "patch_run.png") return "Patch normals per frame (patch_normals.csv)";
  return name;
}

/// report.html (docs/outputs.md): added to `files` last, so that it lists every file of the run.
void writeHtmlReport(io::AtomicFileSet* files, const std::string& dir, const nlohmann::json& summary,
                     const report::Figures& fig, bool plots, const std::vector<std::string>& warnings,
                     const vision::OverlayInfo* overlay, const std::string& source) {
  report::HtmlReport h;
  h.title = "rsfm report: " + (source.empty() ? std::string("tracks") : source);
  h.summary = summary;
  for (size_t i = 0; i < fig.written.size() && i < fig.files.size(); ++i)
    if (fig.written[i].size() > 4 && fig.written[i].compare(fig.written[i].size() - 4, 4, ".png") == 0)
      h.figures.emplace_back(captionOf(fig.written[i]), fig.files[i]);
  h.figures_note = !plots ? "--no-plots" : fig.why;
  h.warnings = warnings;
  if (overlay) {
    h.overlay_file = "overlay.mp4";
    h.overlay_codec = overlay->codec;
    h.poster_png = overlay->poster_png;
  }
  for (const auto& f : files->finals()) h.files.push_back(f.filename().string());
  h.files.push_back("report.html");
  std::sort(h.files.begin(), h.files.end());
  files->write(std::filesystem::path(dir) / "report.html", report::htmlReport(h));
}


/// A tracks or patches file whose first frames have none: they are left out
/// (trimLeadingEmptyFrames) and the run says so ("tracks: frames A-B of FILE have no tracks").
template <class T>
void trimAndSay(T* t, const char* what, const std::string& file, bool quiet) {
  const int first = t->first_frame;
  if (trimLeadingEmptyFrames(t) > 0 && !quiet)
    fmt::print(stderr, "{}: frames {}-{} of {} have no {}: the estimate starts at frame {}\n", what, first, t->first_frame - 1, file,
               what, t->first_frame);
}

}  // namespace

namespace {
/// The held frames as input frame numbers, one [first, last] pair per stretch.
nlohmann::json heldFrames(const Tracks& tracks, const vision::StillStart& s) {
  nlohmann::json runs = nlohmann::json::array();
  for (const auto& [first, last] : vision::heldStretches(s)) runs.push_back({tracks.frameNumber(first), tracks.frameNumber(last)});
  return runs;
}
}  // namespace

EstimateRunReport::EstimateRunReport(const Tracks& tracks, const EstimateResult& r, const EstimateCli& e) {
  const vision::PlaneFinding& pf = r.planes;
  rep.tracks = &tracks;
  rep.labels = &r.labels();
  rep.last_used = &r.last_used;
  rep.result = &r.online;
  rep.refined = &r.refined;
  if (r.camera) {
    const vision::CameraCalibration& c = *r.camera;
    given = report::GivenCamera{c.focal(), c.cx, c.cy, c.distortion, c.source};
    rep.given_camera = &*given;
  }
  rep.focal_given = e.est.camera.has_value() || e.est.filter.focal_px > 0;
  rep.model = e.est.filter.model;
  rep.command = invocation();
  nlohmann::json cands = nlohmann::json::array();
  const int reference = tracks.frameNumber(r.still.still_frames);
  // An index counted from the reference frame, as an input frame number (a video's dropped frames
  // leave gaps in the numbers: Tracks::frame_numbers).
  auto fromReference = [&](int offset) {
    const int k = r.still.still_frames + offset;
    return k >= 0 && k < tracks.numFrames() ? tracks.frameNumber(k) : reference + offset;
  };
  for (const auto& c : pf.candidates)
    cands.push_back({{"verdict", vision::toString(c.verdict)}, {"label", c.label}, {"tracks", c.members.size()},
                     {"median_motion_px", c.median_motion_px}, {"same_motion_fraction", c.same_motion_fraction},
                     {"reference_frame", fromReference(c.first_frame)},
                     {"pair_frame", c.pair_frame >= 0 ? nlohmann::json(fromReference(c.pair_frame)) : nlohmann::json(nullptr)}});
  if (!r.start.hypotheses.empty()) rep.extra["start"] = startJson(r.start);
  // The frame from which the filter estimates each plane (a plane that came into view later: the
  // frame it joined; docs/estimate.md section 1).
  nlohmann::json from = nlohmann::json::array();
  for (int k : r.online.plane_first_frame) from.push_back(k > 0 ? tracks.frameNumber(k) : reference);
  rep.extra["still_start"] = {{"reference_frame", reference},
                              {"still_frames", r.still.still_frames},
                              {"threshold_px", r.still.threshold_px},
                              {"noise_px", r.still.noise_px},
                              {"moving_tracks", r.still.moving_tracks},
                              {"held_frames", heldFrames(tracks, r.still)},
                              {"still_px", e.est.still_px}};
  // The frames with no observation at all, as [first, last] stretches of input frame numbers.
  rep.extra["unobserved_frames"] = consecutiveStretches(r.unobserved_frames);
  nlohmann::json tries = nlohmann::json::array();
  for (const auto& tr : pf.pair_frame_tries)
    tries.push_back({{"frame", fromReference(tr.frame)}, {"planes", tr.planes}, {"tracks_in_planes", tr.tracks_in_planes}, {"loses_plane", tr.loses_plane}});
  const vision::PlaneTolerances& tol = pf.tolerances;
  rep.extra["plane_finding"] = {{"pair_frame", fromReference(pf.pair_frame)}, {"pair_frames_tried", tries}, {"candidates", cands},
                                {"tracking_noise_px", tol.noise_px > 0 ? nlohmann::json(tol.noise_px) : nlohmann::json(nullptr)},
                                {"tolerances_px", {{"ransac", tol.ransac_px}, {"stray", tol.verify_px}, {"static", tol.static_px},
                                                   {"same_motion", tol.motion_px}, {"still", tol.still_px}}},
                                {"tolerances_widened", pf.widened},
                                {"tracks_cut", pf.tracksCut()},
                                {"observations_cut", r.observations_cut},
                                {"planes_estimated_from_frame", from},
                                {"manual", !e.est.finder.rois.empty()}};
  // The filter's measurement noise: the --sigma-px floor raised to the tracking noise (estimate()).
  rep.extra["measurement_noise"] = {{"sigma_px", r.filter_used.sigma_px},
                                    {"floor_px", e.est.filter.sigma_px},
                                    {"from_tracking_noise", r.filter_used.sigma_px > e.est.filter.sigma_px}};
  const std::optional<double> readout = knownReadout(e.est);  // checked by finishEstimateOptions
  rep.extra["rolling_shutter_readout"] = readout ? nlohmann::json(*readout) : nlohmann::json(nullptr);
  rep.extra["rolling_shutter_readout_direction"] = readoutDirectionName(r.image.readout_direction);
  rep.extra["stage_seconds"] = {{"plane_finding", r.seconds.plane_finding}, {"start", r.seconds.start},
                                {"filter", r.seconds.filter}, {"refinement", r.seconds.refinement}};
}

PatchRunReport::PatchRunReport(const PatchTracks& tracks, const PatchEstimateResult& pr) {
  rep.tracks = &tracks;
  rep.result = &pr.run;
  rep.motion = &pr.motion;
  rep.command = invocation();
  if (!pr.start.hypotheses.empty()) rep.extra["start"] = startJson(pr.start);
}

std::function<void(int, int)> estimateProgress(const EstimateCli& e) {
  if (e.quiet) return {};
  const int passes = e.patches || e.est.filter.model == TrackModel::Point ? 1 : std::max(1, e.est.filter.passes);
  return progressReporter("estimate", passes > 1 ? fmt::format("frames over {} passes", passes) : "frames");
}

/// The pipeline (pipeline/estimate.hpp) + report (+ overlay when `overlay_input` is set). Returns the exit code.
int estimateAndReport(const Tracks& tracks, const EstimateCli& e, const TrackOverlay& overlay, double t_start,
                      bool write_tracks, const RunTracking* tracking) {
  EstimateResult r;
  std::vector<std::string> warnings;
  try {
    r = estimate(tracks, e.est, noteTo(e.quiet, &warnings), estimateProgress(e));
  } catch (const std::invalid_argument& ex) {
    return fail(kBadInput, ex.what());
  } catch (const io::InputError& ex) {
    return fail(kBadInput, ex.what());
  } catch (const std::exception& ex) {
    return fail(kRuntimeFailure, ex.what());
  }
  const TrackFilterResult& res = r.online;
  if (!res.ok()) return fail(kRuntimeFailure, "the filter stopped at " + res.stopped + " (no outputs written)");
  EstimateRunReport run(tracks, r, e);
  report::EstimateReport& rep = run.rep;
  if (tracking) {
    rep.extra["stage_seconds"]["tracking"] = tracking->seconds;
    rep.extra["tracking"] = {{"steps", tracking->steps},
                             {"exposure_compensated_steps", tracking->exposure_compensated_steps},
                             {"dropped_frames", tracking->dropped_frames}};
  }
  nlohmann::json summary;
  report::Figures fig;
  if (int rc = guarded([&] {
        io::AtomicFileSet files;
        rep.seconds = steadySeconds() - t_start;
        vision::OverlayInfo ov;
        if (overlay) {
          ov = overlay(r, files.temp(std::filesystem::path(e.out) / "overlay.mp4"));
          recordOverlay(ov, &rep.extra, &warnings);
        }
        summary = report::writeEstimateReport(rep, e.out, &files, e.plots, &fig);
        if (!fig.missing.empty()) warnings.push_back(fig.warning());
        if (write_tracks) files.write(std::filesystem::path(e.out) / "tracks.csv", io::tracksToString(tracks));
        if (const std::string yaml = cameraYamlOf(r, e.est, tracks.image); !yaml.empty())
          files.write(std::filesystem::path(e.out) / "camera.yaml", yaml);
        writeHtmlReport(&files, e.out, summary, fig, e.plots, warnings, overlay ? &ov : nullptr, tracks.source);
        files.commit();
        if (!ov.warning.empty()) fmt::print(stderr, "rsfm: warning: {}\n", ov.warning);
      }))
    return rc;
  warnFigures(fig);
  const bool plotted = !fig.written.empty();
  if (!e.quiet) {
    const auto& s = summary;
    if (s["focal_px"].is_null())
      fmt::print(stderr, "estimate: {} frames, focal length not determined{}", res.frames.size(),
                 s.contains("focal_interval_px")
                     ? fmt::format(" (the data support {})", io::focalIntervalText(s["focal_interval_px"]))
                     : "");
    else
      fmt::print(stderr, "estimate: {} frames, focal {:.1f} {}", res.frames.size(), s["focal_px"].get<double>(),
                 s.contains("focal_given") ? fmt::format("px (given: {})", r.camera ? r.camera->source : "--focal-px")
                                           : fmt::format("+- {:.1f} px{}", s["focal_sd_px"].get<double>(),
                                                         r.refined.ok ? " (refined)" : ""));
    for (const auto& a : s["angles_between_planes_deg"])
      fmt::print(stderr, ", angle between planes {} and {}: {:.1f}{} deg{}", a["planes"][0].get<int>(), a["planes"][1].get<int>(),
                 a["angle_deg"].get<double>(),
                 a.contains("sd_deg") && a["sd_deg"].is_number() ? fmt::format(" +- {:.1f}", a["sd_deg"].get<double>()) : std::string(),
                 a.contains("determined") && !a["determined"].get<bool>() ? " (not determined)" : "");
    fmt::print(stderr, "; wrote {}/summary.json, trajectory.tum{}, planes.csv, angles.csv, poses.csv, labels.csv, report.html{}{}{}\n",
               e.shown_out.empty() ? e.out : e.shown_out,
               r.refined.ok ? ", trajectory_online.tum" : "",
               plotted ? ", motion/normals/focal/process_noise/angles.png" : "", write_tracks ? ", tracks.csv" : "",
               overlay ? ", overlay.mp4" : "");
  }
  return 0;
}

/// The patch pipeline (pipeline/estimate.hpp) + report (+ overlay when `overlay_input` is set).
int patchEstimateAndReport(const PatchTracks& tracks, const EstimateCli& e, const PatchOverlay& overlay,
                           double t_start, bool write_patches) {
  PatchEstimateResult pr;
  std::vector<std::string> warnings;
  try {
    pr = estimatePatches(tracks, e.pat, noteTo(e.quiet, &warnings), estimateProgress(e));
  } catch (const std::invalid_argument& ex) {
    return fail(kBadInput, ex.what());
  } catch (const std::exception& ex) {
    return fail(kRuntimeFailure, ex.what());
  }
  const PatchRunResult& res = pr.run;
  if (!res.ok()) return fail(kRuntimeFailure, "the patch filter stopped at " + res.stopped + " (no outputs written)");
  PatchRunReport run(tracks, pr);
  report::PatchReport& rep = run.rep;
  nlohmann::json summary;
  report::Figures fig;
  std::string disagreement;
  if (int rc = guarded([&] {
        io::AtomicFileSet files;
        rep.seconds = steadySeconds() - t_start;
        vision::OverlayInfo ov;
        if (overlay) {
          ov = overlay(res, files.temp(std::filesystem::path(e.out) / "overlay.mp4"));
          recordOverlay(ov, &rep.extra, &warnings);
        }
        summary = report::writePatchReport(rep, e.out, &files, e.plots, &fig);
        if (!fig.missing.empty()) warnings.push_back(fig.warning());
        disagreement = patchFocalDisagreement(summary);
        if (!disagreement.empty()) warnings.push_back(disagreement);
        if (write_patches) files.write(std::filesystem::path(e.out) / "patches.csv", io::patchesToString(tracks));
        writeHtmlReport(&files, e.out, summary, fig, e.plots, warnings, overlay ? &ov : nullptr, tracks.source);
        files.commit();
        if (!ov.warning.empty()) fmt::print(stderr, "rsfm: warning: {}\n", ov.warning);
      }))
    return rc;
  warnFigures(fig);
  const bool plotted = !fig.written.empty();
  if (!e.quiet && !summary["structure_determined"].get<bool>()) {
    // One line for what the data do not determine (issue 17), instead of confident numbers.
    const std::string focal =
        summary["focal_px"].is_null()
            ? std::string("focal length not determined") +
                  (summary.contains("focal_interval_px")
                       ? fmt::format(" (the data support {})", io::focalIntervalText(summary["focal_interval_px"]))
                       : "")
            : fmt::format("focal {:.1f} +- {:.1f} px (from the motion check)", summary["focal_px"].get<double>(),
                          summary["focal_sd_px"].get<double>());
    fmt::print(stderr, "estimate: {} frames, {} patches, {}; patch normals not determined: {}; wrote {}/summary.json, "
               "trajectory.tum, patch_normals.csv, report.html{}{}{}\n",
               res.frames.size(), res.entered, focal, summary["not_determined_why"].get<std::string>(),
               e.shown_out.empty() ? e.out : e.shown_out, plotted ? ", patch_run.png" : "", write_patches ? ", patches.csv" : "",
               overlay ? ", overlay.mp4" : "");
  } else if (!e.quiet) {
    if (!disagreement.empty()) fmt::print(stderr, "warning: {}\n", disagreement);
    const auto& ln = summary["last_frame_normals"];
    fmt::print(stderr,
               "estimate: {} frames, {} patches ({} joined, {} left), focal {:.1f} +- {:.1f} px; last frame: {} of {} patch "
               "normals within 5 deg of their median (median {:.2f} deg); wrote {}/summary.json, trajectory.tum, "
               "patch_normals.csv, report.html{}{}{}\n",
               res.frames.size(), res.entered, res.joined, res.left, summary["focal_px"].get<double>(),
               summary["focal_sd_px"].get<double>(), ln["within_5deg"].get<int>(),
               summary["patches"]["live_last_frame"].get<int>(), ln["angle_to_median_deg"]["median"].get<double>(),
               e.shown_out.empty() ? e.out : e.shown_out,
               plotted ? ", patch_run.png" : "", write_patches ? ", patches.csv" : "", overlay ? ", overlay.mp4" : "");
  }
  return 0;
}

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
      const double t0 = steadySeconds();
      if (c->tracks.empty() && c->patches.empty()) return fail(kBadInput, "one of --tracks or --patches is required");
      if (!c->patches.empty()) c->e.model = "patches";
      if (auto m = finishEstimateOptions(&c->e); !m.empty()) return fail(kBadInput, m);
      if (c->e.patches && c->patches.empty()) return fail(kBadInput, "--model patches needs --patches FILE (rsfm track --patches)");
      io::OutputDir od;
      if (auto m = od.open(c->e.out, {c->tracks, c->patches, c->e.camera_file}); !m.empty()) return fail(kBadInput, m);
      EstimateCli e = c->e;
      e.shown_out = e.out;
      e.out = od.path().string();
      int rc = 0;
      if (e.patches) {
        PatchTracks pt;
        try {
          pt = io::readPatches(c->patches);
        } catch (const std::exception& ex) {
          return fail(kBadInput, ex.what());
        }
        trimAndSay(&pt, "patches", c->patches, e.quiet);
        rc = patchEstimateAndReport(pt, e, {}, t0, false);
      } else {
        Tracks tracks;
        try {
          tracks = io::readTracks(c->tracks);
        } catch (const std::exception& ex) {
          return fail(kBadInput, ex.what());
        }
        trimAndSay(&tracks, "tracks", c->tracks, e.quiet);
        rc = estimateAndReport(tracks, e, {}, t0, false);
      }
      if (rc == 0) rc = guarded([&] { od.commit(); });
      return rc;
    }});
  }
}

}  // namespace rsfm::cli
