#include "rsfm/report/estimate_report.hpp"

#include <fmt/format.h>

#include <cmath>
#include <sstream>
#include <string_view>

#include "rsfm/camera.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/report/report.hpp"
#include "rsfm/io/json_text.hpp"
#include "rsfm/io/tum.hpp"
#include "rsfm/rotation.hpp"

#include <algorithm>

namespace rsfm::report {

using namespace rsfm::io;  // the file formats the reports write

void poseOf(const TrackFrame& f, Eigen::Vector3d* position, Eigen::Quaterniond* q) {
  const CameraPose p = copCentredPose(f.R, f.t, f.beta);
  *position = p.position;
  *q = canonical(p.orientation);
}

namespace {

std::string num(double v, int prec = 6) { return formatNumber(v, prec); }

}  // namespace

nlohmann::json summaryHead(const std::string& model, int frames, int first_frame, int last_frame, const ImageInfo& image,
                           double scale_px, double beta, double var_beta) {
  nlohmann::json j;
  j["format"] = "rsfm-summary";
  j["version"] = 1;
  j["model"] = model;
  j["frames"] = frames;
  j["first_frame"] = first_frame;
  j["last_frame"] = last_frame;
  j["image"] = {{"width", image.width}, {"height", image.height}};
  j["principal_point_px"] = {image.cx, image.cy};
  // Timestamps of trajectory.tum: seconds at the source's frame rate, else frame numbers.
  j["fps"] = image.fps > 0 ? nlohmann::json(image.fps) : nlohmann::json(nullptr);
  j["timestamps"] = image.fps > 0 ? "seconds" : "frame";
  // Images named by their timestamps: trajectory.tum's seconds count from frame 0's time.
  j["time_origin_s"] = image.fps > 0 && image.time_origin != 0 ? nlohmann::json(image.time_origin) : nlohmann::json(nullptr);
  j["scale_px"] = scale_px;
  j["focal_px"] = scale_px / beta;
  j["focal_sd_px"] = scale_px * std::sqrt(std::max(0.0, var_beta)) / (beta * beta);
  j["beta"] = beta;
  return j;
}

void summaryTail(nlohmann::json* j, const std::string& stopped, const std::string& command, double seconds,
                 const std::string& conventions, const nlohmann::json& extra) {
  (*j)["stopped"] = stopped;
  (*j)["command"] = command;
  (*j)["seconds"] = seconds;
  (*j)["conventions"] = conventions;
  for (auto it = extra.begin(); it != extra.end(); ++it) (*j)[it.key()] = it.value();
}

namespace {

bool refinedOk(const EstimateReport& r) { return r.refined && r.refined->ok; }

/// Final focal length, its sd, normals, distances and normal sds of a run.
nlohmann::json finalEstimates(const TrackFilterResult& res) {
  const TrackFrame& last = res.frames.back();
  nlohmann::json normals = nlohmann::json::array(), dist = nlohmann::json::array(), nsd = nlohmann::json::array(),
                 dsd = nlohmann::json::array();
  for (int p = 0; p < static_cast<int>(last.N.size()); ++p) {
    const MetricPlane mp = metricPlane(last.N[p], last.beta, covBetaN(last, p));
    normals.push_back({mp.n.x(), mp.n.y(), mp.n.z()});
    dist.push_back(mp.d);
    nsd.push_back(mp.sd_angle_deg);
    dsd.push_back(mp.sd_d);
  }
  return {{"focal_px", res.scale_px / last.beta},
          {"focal_sd_px", res.scale_px * std::sqrt(std::max(0.0, last.var_beta)) / (last.beta * last.beta)},
          {"planes", normals},
          {"plane_distances", dist},
          {"plane_normal_sd_deg", nsd},
          {"plane_distance_sd", dsd},
          {"plane_reprojection_rms_px", res.plane_rms_px}};
}

/// summary.json's "online" section: the filter's final figures, with the sds of their errors
/// against the refinement when it ran (OnlineAccuracy; `sd_basis` "refinement") instead of the
/// filter's own ("filter": its covariance calibrated by its residuals).
nlohmann::json onlineEstimates(const TrackFilterResult& res, const OnlineAccuracy& a,
                               const std::optional<std::array<double, 2>>& focal_interval_px) {
  nlohmann::json j = finalEstimates(res);
  j["sd_basis"] = a.checked ? "refinement" : "filter";
  if (!a.checked) return j;
  j["filter_focal_sd_px"] = j["focal_sd_px"];  // the filter's own (calibrated) sds, kept beside
  j["filter_plane_normal_sd_deg"] = j["plane_normal_sd_deg"];
  j["focal_determined"] = a.focal_determined;
  if (a.focal_determined) {
    j["focal_sd_px"] = a.focal_sd_px;
  } else {
    j["focal_sd_px"] = nullptr;
    j["focal_interval_px"] = focal_interval_px ? io::focalIntervalJson((*focal_interval_px)[0], (*focal_interval_px)[1])
                                               : nlohmann::json{nullptr, nullptr};
  }
  nlohmann::json nsd = nlohmann::json::array(), dsd = nlohmann::json::array();
  for (std::size_t p = 0; p < a.plane_determined.size(); ++p) {
    nsd.push_back(a.plane_determined[p] ? nlohmann::json(a.normal_sd_deg[p]) : nlohmann::json(nullptr));
    dsd.push_back(a.plane_determined[p] ? nlohmann::json(a.distance_sd[p]) : nlohmann::json(nullptr));
  }
  j["plane_determined"] = a.plane_determined;
  j["plane_normal_sd_deg"] = nsd;
  j["plane_distance_sd"] = dsd;
  return j;
}

}  // namespace

std::vector<TumPose> trajectoryPoses(const TrackFilterResult& res, const ImageInfo& image) {
  std::vector<TumPose> poses;
  for (const auto& f : res.frames) {
    if (f.unobserved) continue;  // no observation: where the camera was is not known
    TumPose tp;
    tp.t = image.timestamp(f.frame);
    poseOf(f, &tp.p, &tp.q);
    poses.push_back(tp);
  }
  return poses;
}

nlohmann::json figuresJson(const Figures& f) {
  nlohmann::json j = {{"written", f.written}, {"missing", f.missing}};
  if (!f.missing.empty()) j["why"] = f.why;
  return j;
}

namespace {

/// The determinacy keys of summary.json (docs/outputs.md), from a verdict (the refinement's or
/// the filter's): `focal_determined` (false: `focal_px` and `focal_sd_px` null, the value kept as
/// `focal_estimate_px` for inspection only); with `plane_determined` (null: no planes to judge)
/// the list, a plane not determined without sds (issue 17: 3.5 deg was reported for a normal 43
/// deg off under pure rotation; its normal and distance are kept for inspection), each angle
/// between planes `determined` when both are, and `structure_determined`; `not_determined_why`.
void markDeterminacy(nlohmann::json* out, bool focal_determined, const std::vector<bool>* plane_determined, const std::string& why) {
  nlohmann::json& j = *out;
  j["focal_determined"] = focal_determined;
  if (!focal_determined) {
    j["focal_estimate_px"] = j["focal_px"];
    j["focal_px"] = nullptr;
    j["focal_sd_px"] = nullptr;
  }
  if (plane_determined) {
    const std::vector<bool>& pd = *plane_determined;
    j["plane_determined"] = pd;
    for (std::size_t i = 0; i < pd.size() && i < j["plane_normal_sd_deg"].size(); ++i)
      if (!pd[i]) j["plane_normal_sd_deg"][i] = j["plane_distance_sd"][i] = nullptr;
    for (auto& a : j["angles_between_planes_deg"]) {
      const auto pa = a["planes"][0].get<std::size_t>(), pb = a["planes"][1].get<std::size_t>();
      a["determined"] = pa < pd.size() && pb < pd.size() && pd[pa] && pd[pb];
      if (!a["determined"].get<bool>()) a["sd_deg"] = a["interval_deg"] = nullptr;
    }
    j["structure_determined"] = std::all_of(pd.begin(), pd.end(), [](bool b) { return b; });
  }
  j["not_determined_why"] = why;
}

}  // namespace

nlohmann::json estimateSummary(const EstimateReport& r) {
  const Tracks& t = *r.tracks;
  const bool refined = refinedOk(r);
  const TrackFilterResult& res = refined ? r.refined->state : *r.result;
  const TrackFrame& last = res.frames.back();
  nlohmann::json j = summaryHead(toString(r.model), static_cast<int>(res.frames.size()), res.frames.front().frame,
                                 last.frame, t.image, res.scale_px, last.beta, last.var_beta);
  const nlohmann::json fin = finalEstimates(res);
  for (const char* key : {"planes", "plane_distances", "plane_normal_sd_deg", "plane_distance_sd"}) j[key] = fin[key];
  if (r.model == TrackModel::Point) {
    // The point filter's own tracks and residuals (the online estimate's).
    j["point_tracks"] = r.result->plane_tracks.empty() ? 0 : r.result->plane_tracks[0];
    j["reprojection_rms_px"] = r.result->plane_rms_px.empty() ? 0.0 : r.result->plane_rms_px[0];
  }
  if (r.model == TrackModel::Point && !refined) {
    // No planes: the per-plane lists stay empty (the summary schema pairs them with "planes").
    j["plane_tracks"] = nlohmann::json::array();
    j["plane_new_tracks"] = nlohmann::json::array();
    j["plane_transfer_failed"] = nlohmann::json::array();
    j["plane_reprojection_rms_px"] = nlohmann::json::array();
  } else {
    j["plane_tracks"] = res.plane_tracks;
    j["plane_new_tracks"] = res.plane_new_tracks;
    j["plane_transfer_failed"] = res.transfer_failed;
    j["plane_reprojection_rms_px"] = res.plane_rms_px;
  }
  nlohmann::json angles = nlohmann::json::array();
  for (size_t a = 0; a < last.N.size(); ++a)
    for (size_t b = a + 1; b < last.N.size(); ++b) {
      // With its sd and 95 % interval (planeAngle; null without the planes' joint covariance, and
      // for a pair not determined, markDeterminacy).
      const PlaneAngle pa = planeAngle(last, static_cast<int>(a), static_cast<int>(b));
      nlohmann::json e = {{"planes", {a, b}}, {"angle_deg", pa.angle_deg}};
      e["sd_deg"] = pa.has_sd ? finiteOrNull(pa.sd_deg) : nlohmann::json(nullptr);
      e["interval_deg"] = pa.has_sd ? nlohmann::json::array({pa.lo_deg, pa.hi_deg}) : nlohmann::json(nullptr);
      angles.push_back(e);
    }
  j["angles_between_planes_deg"] = angles;
  int outliers = 0, unused = 0, labelled = 0;
  for (int l : *r.labels) {
    outliers += l == -1;
    unused += l == -2;
    labelled += l >= 0;
  }
  j["tracks"] = {{"total", static_cast<int>(r.labels->size())}, {"on_planes", labelled}, {"outliers", outliers},
                 {"too_short", unused}};
  long gated = 0, used = 0;  // the online filter's chi-square gate
  for (const auto& f : r.result->frames) {
    gated += f.gated;
    used += f.used;
  }
  j["gated_observations"] = gated;
  j["accepted_observations"] = used;
  // Frames the online filter took again with more process noise (a model mismatch: the motion
  // was faster or more sudden than its covariance allowed).
  nlohmann::json mism = nlohmann::json::array();
  for (const auto& f : r.result->frames)
    if (f.q_scale > 1.0) mism.push_back({{"frame", f.frame}, {"process_noise_factor", f.q_scale}});
  j["filter_mismatch_frames"] = mism;
  // The motion's process noise (TrackFilterOptions::q_from_data, FilterOptions::Adaptation): where
  // it started and the range it took over the frames (each frame's value in planes.csv).
  {
    const TrackFilterResult& on = *r.result;
    nlohmann::json pn;
    pn["from_data"] = on.q_from_data;
    pn["adapted"] = on.q_adapted;
    pn["image_motion_px"] = on.image_motion_px;
    pn["start_rotation_deg_per_frame"] = on.start_rotation_deg_per_frame;
    pn["start_translation_rel_per_frame"] = on.start_translation_rel_per_frame;
    pn["initial_omega_sd_deg"] = on.q0_omega_sd_deg;
    pn["initial_translation_sd_rel"] = on.q0_trans_sd_rel;
    std::vector<double> w, t;
    for (std::size_t k = static_cast<std::size_t>(on.still_frames) + 1; k < on.frames.size(); ++k) {
      if (on.frames[k].still) continue;  // no prediction there
      w.push_back(on.frames[k].q_omega_sd_deg);
      t.push_back(on.frames[k].q_trans_sd_rel);
    }
    auto range = [](std::vector<double> v) {
      if (v.empty()) return nlohmann::json(nullptr);
      std::sort(v.begin(), v.end());
      return nlohmann::json{{"min", v.front()}, {"median", v[v.size() / 2]}, {"max", v.back()}};
    };
    pn["omega_sd_deg"] = range(w);
    pn["translation_sd_rel"] = range(t);
    j["process_noise"] = pn;
  }
  // The online filter's reported sds: its covariance widened by its residuals' along-track
  // correlation and spread (TrackFilterResult::SdCalibration).
  {
    const TrackFilterResult::SdCalibration& c = r.result->sd_calibration;
    j["filter_sd_calibration"] = {{"applied", c.applied},
                                  {"filter_sigma_px", c.filter_sigma_px},
                                  {"residual_sd_px", c.residual_sd_px},
                                  {"correlation_inflation", c.correlation_inflation},
                                  {"variance_factor", c.variance_factor}};
  }
  // The tracks on the planes ran out before the input's last frame (TrackFilterResult::ended).
  j["ended_early"] = r.result->ended.empty() ? nlohmann::json(nullptr) : nlohmann::json(r.result->ended);
  // Final focal length and normals of every pass (--passes): their spread is an honest measure
  // of how well the sequence determines them, which the filter's own sd does not capture.
  j["passes"] = res.passes;
  // A later pass that stopped: the result is the pass before it (TrackFilterResult::pass_stopped).
  j["pass_stopped"] = r.result->pass_stopped.empty() ? nlohmann::json(nullptr) : nlohmann::json(r.result->pass_stopped);
  j["pass_focal_px"] = res.pass_focal_px;
  nlohmann::json pn = nlohmann::json::array();
  for (const auto& Ns : res.pass_N) {
    nlohmann::json one = nlohmann::json::array();
    for (const auto& N : Ns) {
      const MetricPlane mp = metricPlane(N, res.scale_px / res.pass_focal_px[pn.size()]);
      one.push_back({mp.n.x(), mp.n.y(), mp.n.z()});
    }
    pn.push_back(one);
  }
  j["pass_planes"] = pn;
  // The point model's run is refined from the planes model's filter (estimate(),
  // docs/estimate.md section 4); without a refinement it has no plane to report on.
  if (r.model != TrackModel::Point || refined || (r.refined && !r.refined->message.empty())) {
    // What is determined (rsfm/determinacy.hpp): the refinement's verdict, else none was made.
    if (refined) {
      const RefineResult& rf = *r.refined;
      markDeterminacy(&j, rf.focal_determined, &rf.plane_determined, rf.why);
      if (!rf.focal_determined) {
        if (rf.focal_interval_px) j["focal_interval_px"] = io::focalIntervalJson((*rf.focal_interval_px)[0], (*rf.focal_interval_px)[1]);
        if (rf.focal_profile_best_px > 0) j["focal_profile_best_px"] = rf.focal_profile_best_px;
      }
      const double sp = res.scale_px;
      auto sd = [&](int c) { return std::sqrt(std::max(0.0, rf.cov_camera(c, c))); };
      j["camera"] = {{"principal_point_px", {rf.principal_point_px.x(), rf.principal_point_px.y()}},
                     {"principal_point_sd_px", {sp * sd(0), sp * sd(1)}},
                     {"principal_point_estimated", rf.camera_free[0]},
                     {"principal_point_determined", rf.camera_determined[0] && rf.camera_determined[1]},
                     {"k1", rf.camera[2]},
                     {"k2", rf.camera[3]},
                     {"k_sd", {sd(2), sd(3)}},
                     {"distortion_estimated", rf.camera_free[2]},
                     {"distortion_determined", rf.camera_determined[2] && rf.camera_determined[3]},
                     {"k_determined", {rf.camera_determined[2], rf.camera_determined[3]}},
                     // A rolling shutter's readout, frame intervals (RefineOptions::estimate_readout):
                     // null when not estimated (a readout given, or held).
                     {"readout", rf.readout_free ? nlohmann::json(rf.readout) : nlohmann::json(nullptr)},
                     {"readout_sd", rf.readout_free && std::isfinite(rf.readout_sd) ? nlohmann::json(rf.readout_sd)
                                                                                      : nlohmann::json(nullptr)},
                     {"readout_estimated", rf.readout_free},
                     {"readout_determined", rf.readout_determined}};
      j["principal_point_px"] = {rf.principal_point_px.x(), rf.principal_point_px.y()};
      j["radial_distortion"] = {rf.camera[2], rf.camera[3]};
      // Frames whose pose the observations do not determine, as input frame numbers (the
      // refinement counts them from the first frame of its records).
      std::vector<int> undetermined;
      for (int k : rf.undetermined_frames)
        undetermined.push_back(k >= 0 && k < static_cast<int>(rf.state.frames.size()) ? rf.state.frames[static_cast<std::size_t>(k)].frame : k);
      j["refinement"] = {{"ok", true},
                         {"message", rf.message},
                         {"sigma_px", rf.sigma_px},
                         {"robust_sigma_px", rf.robust_sigma_px},
                         {"correlation_inflation", rf.correlation_inflation},
                         {"clustered_focal_factor", rf.clustered_focal_factor},
                         {"clustered_plane_factor", rf.clustered_plane_factor},
                         {"jackknife_plane_factor", rf.jackknife_plane_factor},
                         {"plane_profile_spread_deg", rf.plane_profile_spread_deg},
                         {"tracks", rf.tracks},
                         {"observations", rf.observations},
                         {"relabelled_outliers", rf.relabelled},
                         {"plane_tracks", rf.plane_tracks},
                         {"plane_relabelled", rf.plane_relabelled},
                         {"plane_horizon_tracks", rf.plane_horizon_tracks},
                         {"null_space_dim", rf.null_dim},
                         {"rotation_likelihood_ratio", rf.rotation_lr},
                         {"translation_likelihood_ratio", rf.translation_lr},
                         {"wald_translation_chi2", rf.wald_translation_chi2},
                         {"wald_rotation_chi2", rf.wald_rotation_chi2},
                         {"translation_significant", rf.translation_significant},
                         {"undetermined_frames", undetermined},
                         {"at_iteration_limit", rf.at_iteration_limit},
                         {"stalled", rf.stalled},
                         {"iterations", rf.iterations},
                         {"initial_rms_px", rf.initial_rms_px},
                         {"final_rms_px", rf.final_rms_px},
                         {"seconds", rf.seconds}};
      j["online"] = onlineEstimates(*r.result, rf.online_accuracy, rf.focal_interval_px);
    } else if (r.refined) {
      j["refinement"] = {{"ok", false}, {"message", r.refined->message}};
    }
  }
  j["determined_by"] = refined ? "refinement" : "filter";
  if (!refined) {
    // No refinement: the filter alone's verdict from its calibrated sds (FilterDeterminacy,
    // pipeline/track_filter.hpp; the refinement's limits).
    // No focal_interval_px for a focal length not determined: without the refinement's profile
    // no interval is known to be supported (not_determined_why gives the filter's linear one).
    const FilterDeterminacy d = filterDeterminacy(res, r.focal_given);
    markDeterminacy(&j, d.focal_determined, r.model != TrackModel::Point ? &d.plane_determined : nullptr, d.why);
  }
  if (r.focal_given) j["focal_given"] = true;
  if (r.given_camera) {
    // The tracks were undistorted onto the given pinhole: the camera is the given one, not an
    // estimate (its focal length and principal point are held; sds zero).
    const GivenCamera& g = *r.given_camera;
    const double k1 = g.distortion.size() > 0 ? g.distortion[0] : 0.0, k2 = g.distortion.size() > 1 ? g.distortion[1] : 0.0;
    j["camera"] = {{"given", true},
                   {"source", g.source},
                   {"focal_px", g.focal_px},
                   {"principal_point_px", {g.cx, g.cy}},
                   {"distortion", g.distortion},
                   {"k1", k1},
                   {"k2", k2},
                   {"principal_point_estimated", false},
                   {"distortion_estimated", false}};
    j["principal_point_px"] = {g.cx, g.cy};
    j["radial_distortion"] = {k1, k2};
  }
  summaryTail(&j, res.stopped, r.command, r.seconds,
              "poses: camera in the reference (first) camera frame, x right, y down, z forward, COP-centred; "
              "normals: unit, reference camera frame, pointing from the camera to the plane (n.X = d > 0); "
              "units: the main plane's N_Z gauge (docs/estimate.md)",
              r.extra);
  return j;
}

namespace {

std::string tumText(const TrackFilterResult& res, const ImageInfo& image) {
  std::ostringstream tum;
  writeTum(tum, trajectoryPoses(res, image));
  return tum.str();
}

/// planes.csv rows of one frame's estimate (`estimate`: online or refined).
/// `online` (may be null): the run frame `f` is frame index `k` of; a plane it had not yet
/// estimated there (one that came into view later) gets no row. `refined` (may be null): the
/// refinement whose final estimate `f` is; what it reports not determined has NA sds (the
/// focal length: beta_sd and focal_sd_px; a plane: normal_sd_deg and distance_sd), the values
/// kept for inspection as summary.json's `focal_estimate_px` and normals.
std::string planeRows(const TrackFrame& f, double scale_px, const char* estimate, const TrackFilterResult* online = nullptr,
                      int k = 0, const RefineResult* refined = nullptr) {
  const double bsd = std::sqrt(std::max(0.0, f.var_beta));
  const double focal = scale_px / f.beta, fsd = scale_px * bsd / (f.beta * f.beta);
  const bool focal_det = !refined || refined->focal_determined;
  const std::string bsd_s = focal_det ? num(bsd) : "NA", fsd_s = focal_det ? num(fsd, 3) : "NA";
  // The prediction's process noise of an online frame after the first (NA: the reference frame,
  // the refined row).
  const bool has_q = std::string_view(estimate) == "online" && f.q_omega_sd_deg > 0.0;
  const std::string qw = has_q ? num(f.q_omega_sd_deg, 4) : "NA", qt = has_q ? num(f.q_trans_sd_rel, 4) : "NA";
  const std::string rms = f.still ? std::string("NA") : num(f.rms_px, 4);  // a still frame: no observations
  if (f.N.empty())
    return fmt::format("{},-1,NA,NA,NA,NA,NA,NA,{},{},{},{},{},{},{},{},{},{}\n", f.frame, num(f.beta), bsd_s,
                       num(focal, 3), fsd_s, f.used, f.gated, rms, estimate, qw, qt);
  std::string out;
  for (size_t p = 0; p < f.N.size(); ++p) {
    if (online && !online->planeEstimatedAt(static_cast<int>(p), k)) continue;
    const MetricPlane mp = metricPlane(f.N[p], f.beta, covBetaN(f, static_cast<int>(p)));
    const bool plane_det =
        !refined || p >= refined->plane_determined.size() || refined->plane_determined[p];
    out += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", f.frame, p, num(mp.n.x()), num(mp.n.y()),
                       num(mp.n.z()), plane_det ? num(mp.sd_angle_deg, 4) : "NA", num(mp.d),
                       plane_det ? num(mp.sd_d) : "NA", num(f.beta), bsd_s, num(focal, 3), fsd_s, f.used, f.gated, rms,
                       estimate, qw, qt);
  }
  return out;
}

/// angles.csv rows of one frame's estimate: each pair of planes with its angle, sd and 95 %
/// interval (planeAngle; NA without the pair's covariance, or where `determined` says a plane of
/// the pair is not determined). `online` and `k` as planeRows'.
std::string angleRows(const TrackFrame& f, const char* estimate, const TrackFilterResult* online = nullptr, int k = 0,
                      const std::vector<bool>* determined = nullptr) {
  std::string out;
  const int m = static_cast<int>(f.N.size());
  for (int a = 0; a < m; ++a)
    for (int b = a + 1; b < m; ++b) {
      if (online && !(online->planeEstimatedAt(a, k) && online->planeEstimatedAt(b, k))) continue;
      const PlaneAngle pa = planeAngle(f, a, b);
      const bool det = !determined || (static_cast<std::size_t>(b) < determined->size() && (*determined)[static_cast<std::size_t>(a)] &&
                                       (*determined)[static_cast<std::size_t>(b)]);
      const bool sd = pa.has_sd && det && std::isfinite(pa.sd_deg);
      out += fmt::format("{},{},{},{},{},{},{},{}\n", f.frame, a, b, num(pa.angle_deg), sd ? num(pa.sd_deg, 4) : "NA",
                         sd ? num(pa.lo_deg, 4) : "NA", sd ? num(pa.hi_deg, 4) : "NA", estimate);
    }
  return out;
}

/// poses.csv: each frame's pose (as trajectory.tum) with first-order sds of the camera centre
/// (trajectory units) and of the rotation (deg) from the motion's covariance (the refinement's;
/// beta's own uncertainty left out), by central differences of the pose map.
std::string posesCsv(const TrackFilterResult& res, const std::vector<Eigen::Matrix<double, 6, 6>>* cov) {
  std::string out = "frame,tx,ty,tz,qx,qy,qz,qw,position_sd,rotation_sd_deg\n";
  for (std::size_t k = 0; k < res.frames.size(); ++k) {
    const TrackFrame& f = res.frames[k];
    if (f.unobserved) continue;  // as trajectory.tum
    Eigen::Vector3d p;
    Eigen::Quaterniond q;
    poseOf(f, &p, &q);
    std::string psd = "NA", rsd = "NA";
    if (cov && k < cov->size()) {
      // Position as a function of (t_X, t_Y, t_Z beta, omega) about the estimate.
      auto position = [&](const Eigen::Matrix<double, 6, 1>& d) {
        const Eigen::Matrix3d R = incrementalRotation(d.tail<3>()) * f.R;
        const Eigen::Vector3d t(f.t.x() + d[0], f.t.y() + d[1], f.t.z() + d[2] / f.beta);
        return copCentredPose(R, t, f.beta).position;
      };
      Eigen::Matrix<double, 3, 6> J;
      for (int c = 0; c < 6; ++c) {
        Eigen::Matrix<double, 6, 1> d = Eigen::Matrix<double, 6, 1>::Zero();
        const double h = 1e-6 * std::max(1.0, c < 3 ? std::abs(f.t[c]) : 1.0);
        d[c] = h;
        const Eigen::Vector3d pp = position(d);
        d[c] = -h;
        J.col(c) = (pp - position(d)) / (2 * h);
      }
      const Eigen::Matrix<double, 6, 6>& C = (*cov)[k];
      psd = num(std::sqrt(std::max(0.0, (J * C * J.transpose()).trace())), 4);
      rsd = num(std::sqrt(std::max(0.0, C.bottomRightCorner<3, 3>().trace())) * 180.0 / M_PI, 4);
    }
    out += fmt::format("{},{},{},{},{},{},{},{},{},{}\n", f.frame, num(p.x(), 9), num(p.y(), 9), num(p.z(), 9),
                       num(q.x(), 9), num(q.y(), 9), num(q.z(), 9), num(q.w(), 9), psd, rsd);
  }
  return out;
}

}  // namespace

nlohmann::json writeEstimateReport(const EstimateReport& r, const std::filesystem::path& dir, AtomicFileSet* files,
                                   bool plots, Figures* figures) {
  const bool refined = refinedOk(r);
  const TrackFilterResult& online = *r.result;
  const TrackFilterResult& res = refined ? r.refined->state : online;
  const auto tum_tmp = files->write(dir / "trajectory.tum", tumText(res, r.tracks->image));
  if (refined) files->write(dir / "trajectory_online.tum", tumText(online, r.tracks->image));
  files->write(dir / "poses.csv", posesCsv(res, refined ? &r.refined->cov_motion : nullptr));
  // planes.csv: the filter's frame by frame, then the refinement's final estimate.
  std::string pc =
      "frame,plane,nx,ny,nz,normal_sd_deg,distance,distance_sd,beta,beta_sd,focal_px,focal_sd_px,used,gated,rms_px,estimate,"
      "q_omega_sd_deg,q_trans_sd_rel\n";
  for (std::size_t k = 0; k < online.frames.size(); ++k)
    pc += planeRows(online.frames[k], online.scale_px, "online", &online, static_cast<int>(k));
  if (refined) {
    TrackFrame fin = res.frames.back();
    fin.used = r.refined->observations;
    fin.gated = r.refined->relabelled;
    fin.rms_px = r.refined->final_rms_px;
    pc += planeRows(fin, res.scale_px, "refined", nullptr, 0, &*r.refined);
  }
  const auto planes_tmp = files->write(dir / "planes.csv", pc);
  // angles.csv: the angles between planes, the filter's frame by frame, then the refinement's.
  std::string ac = "frame,plane_a,plane_b,angle_deg,sd_deg,lo_deg,hi_deg,estimate\n";
  for (std::size_t k = 0; k < online.frames.size(); ++k)
    ac += angleRows(online.frames[k], "online", &online, static_cast<int>(k));
  if (refined) ac += angleRows(res.frames.back(), "refined", nullptr, 0, &r.refined->plane_determined);
  const auto angles_tmp = files->write(dir / "angles.csv", ac);
  // labels.csv
  // last_frame_used: the last frame whose observation the estimate used (a track that left its
  // plane: the last frame before it left it), -1 for a track on no plane.
  std::string lc = "track,label,first_frame,last_frame,last_frame_used\n";
  const auto spans = trackSpans(*r.tracks);
  for (size_t id = 0; id < spans.size(); ++id) {
    if (spans[id].first < 0) continue;
    const int label = (*r.labels)[id];
    const int k_used = !r.last_used ? spans[id].last : id < r.last_used->size() ? (*r.last_used)[id] : -1;
    const int used = label < 0 || k_used < 0 ? -1 : r.tracks->frameNumber(k_used);
    lc += fmt::format("{},{},{},{},{}\n", id, label, r.tracks->frameNumber(spans[id].first), r.tracks->frameNumber(spans[id].last), used);
  }
  files->write(dir / "labels.csv", lc);
  nlohmann::json summary = estimateSummary(r);
  if (plots) {
    const Figures fig = makeFigures(files, dir, "plot_estimate.py", {tum_tmp.string(), planes_tmp.string(), angles_tmp.string()},
                                    {"motion.png", "motion.svg", "normals.png", "normals.svg", "focal.png", "focal.svg",
                                     "process_noise.png", "process_noise.svg", "angles.png", "angles.svg"});
    summary["figures"] = figuresJson(fig);
    if (figures) *figures = fig;
  }
  files->write(dir / "summary.json", summary.dump(2) + "\n");
  return summary;
}

}  // namespace rsfm::report
