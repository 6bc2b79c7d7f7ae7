#include "rsfm/report/patch_report.hpp"
#include "rsfm/units.hpp"

#include <fmt/format.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "rsfm/geometry.hpp"
#include "rsfm/report/estimate_report.hpp"
#include "rsfm/report/report.hpp"
#include "rsfm/io/tum.hpp"
#include "rsfm/io/json_text.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm::report {

using namespace rsfm::io;  // the file formats the reports write

namespace {

std::string num(double v, int prec = 6) { return formatNumber(v, prec); }

}  // namespace

nlohmann::json patchSummary(const PatchReport& r) {
  const PatchTracks& t = *r.tracks;
  const PatchRunResult& res = *r.result;
  const PatchRunFrame& last = res.frames.back();
  nlohmann::json j = summaryHead("patches", static_cast<int>(res.frames.size()), res.frames.front().frame, last.frame,
                                 t.image, res.scale_px, last.beta, last.var_beta);
  // No planes: the per-plane lists of the shared schema stay empty.
  j["planes"] = nlohmann::json::array();
  j["plane_distances"] = nlohmann::json::array();
  j["plane_tracks"] = nlohmann::json::array();
  j["plane_reprojection_rms_px"] = nlohmann::json::array();
  j["patch_radius_px"] = t.radius;
  j["patches"] = {{"entered", res.entered}, {"joined", res.joined}, {"left", res.left},
                  {"live_last_frame", static_cast<int>(last.patches.size())}, {"still_frames", res.still_frames}};
  const NormalAgreement a = normalAgreement(last);
  nlohmann::json per = nlohmann::json::array();
  for (size_t i = 0; i < a.ids.size(); ++i) {
    const auto& p = last.patches[i];
    const Eigen::Vector3d n0 = last.R.transpose() * p.normal;
    per.push_back({{"patch", p.id}, {"normal_reference", {n0.x(), n0.y(), n0.z()}}, {"angle_to_median_deg", a.angle_deg[i]},
                   {"normal_sd_deg", p.normal_sd_deg}});
  }
  j["last_frame_normals"] = {{"median_normal_reference", {a.median.x(), a.median.y(), a.median.z()}},
                             {"angle_to_median_deg", {{"median", a.median_deg}, {"p90", a.p90_deg}, {"max", a.max_deg}}},
                             {"within_5deg", a.within_5deg},
                             {"patches", per}};
  long gated = 0, used = 0;
  double rms2 = 0;
  int nr = 0;
  for (const auto& f : res.frames) {
    gated += f.gated;
    used += f.used;
    if (f.used > 0) rms2 += f.rms_px * f.rms_px, ++nr;
  }
  // What the data determine (issue 17): the motion check's verdict. A camera that only turns
  // determines no normal (and Calway's filter, which assumes a translation, not its focal length
  // either: the check's rotation-only fit gives it); one that does not rotate (nearly affine)
  // determines neither the focal length nor the tilts.
  j["patch_filter_focal_px"] = j["focal_px"];
  j["patch_filter_focal_sd_px"] = j["focal_sd_px"];
  if (r.motion) {
    const PatchMotionCheck& m = *r.motion;
    nlohmann::json mc = {{"checked", m.checked}, {"note", m.note}, {"translates", m.translates},
                         {"rotates_or_focal_known", m.focal_determined}, {"rotation_lr", finiteOrNull(m.rotation_lr)},
                         {"translation_lr", finiteOrNull(m.translation_lr)}, {"why", m.why}};
    if (m.checked) {
      mc["focal_px"] = m.focal_determined ? nlohmann::json(m.focal_px) : nlohmann::json(nullptr);
      mc["focal_sd_px"] = m.focal_determined ? nlohmann::json(m.focal_sd_px) : nlohmann::json(nullptr);
    }
    j["motion_check"] = mc;
  }
  const bool checked = r.motion && r.motion->checked;
  const bool structure = !checked || r.motion->structureDetermined();
  j["structure_determined"] = structure;
  j["focal_determined"] = !checked || r.motion->focal_determined;
  j["not_determined_why"] = checked ? r.motion->why : std::string();
  if (checked && !r.motion->focal_determined) {
    j["focal_px"] = nullptr;
    j["focal_sd_px"] = nullptr;
    if (r.motion->focal_interval_px) j["focal_interval_px"] = io::focalIntervalJson((*r.motion->focal_interval_px)[0], (*r.motion->focal_interval_px)[1]);
    j["focal_source"] = "not determined (motion check)";
  } else if (checked) {
    // The check's bundle adjustment over every frame is the better estimate of the focal length
    // (the refinement the plane models report too); the filter's stays beside it with its
    // disagreement in sigmas: on a nearly affine sequence it was 1802 +- 0.8 px against 4010 +- 14
    // (truth 4000), on a camera that only turns 194 +- 2 against 518 +- 1 (truth 520).
    const PatchMotionCheck& m = *r.motion;
    j["focal_px"] = m.focal_px;
    j["focal_sd_px"] = m.focal_sd_px;
    j["focal_source"] = m.translates ? "motion check: bundle adjustment of the patch centres (plane model)"
                                     : "motion check: bundle adjustment of the patch centres (a camera that only turns)";
    const double pf = j["patch_filter_focal_px"].get<double>(), psd = j["patch_filter_focal_sd_px"].get<double>();
    const double den = std::hypot(psd, m.focal_sd_px);
    j["patch_filter_focal_z"] = den > 0 ? nlohmann::json((pf - m.focal_px) / den) : nlohmann::json(nullptr);
  } else {
    j["focal_source"] = "patch filter";
  }
  if (!structure)
    for (auto& p : j["last_frame_normals"]["patches"]) p["normal_sd_deg"] = nullptr;
  j["gated_observations"] = gated;
  j["accepted_observations"] = used;
  j["centre_rms_px"] = nr ? std::sqrt(rms2 / nr) : 0.0;
  summaryTail(&j, res.stopped, r.command, r.seconds,
              "poses: camera in the first camera frame, x right, y down, z forward, COP-centred, first-frame units of "
              "the gauge patch (docs/patches.md); normals: unit, pointing from the camera towards the patch plane; "
              "normal_reference = in the first camera frame",
              r.extra);
  return j;
}

std::vector<TumPose> patchTrajectory(const PatchRunResult& res, const ImageInfo& image) {
  std::vector<TumPose> poses;
  for (const auto& f : res.frames) {
    TumPose tp;
    tp.t = image.timestamp(f.frame);
    const Eigen::Matrix3d Rc = f.R.transpose();
    tp.p = -Rc * f.T;
    tp.q = canonical(Eigen::Quaterniond(Rc));
    poses.push_back(tp);
  }
  return poses;
}

nlohmann::json writePatchReport(const PatchReport& r, const std::filesystem::path& dir, AtomicFileSet* files, bool plots,
                                Figures* figures) {
  const PatchRunResult& res = *r.result;
  std::ostringstream tum;
  writeTum(tum, patchTrajectory(res, r.tracks->image));
  files->write(dir / "trajectory.tum", tum.str());
  std::string pc = "frame,patch,x,y,nx,ny,nz,rx,ry,rz,normal_sd_deg,depth,angle_to_median_deg,beta,focal_px\n";
  for (const auto& f : res.frames) {
    const NormalAgreement a = normalAgreement(f);
    for (size_t i = 0; i < f.patches.size(); ++i) {
      const auto& p = f.patches[i];
      const Eigen::Vector3d n0 = f.R.transpose() * p.normal;
      pc += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", f.frame, p.id, num(p.px.x(), 4), num(p.px.y(), 4),
                        num(p.normal.x()), num(p.normal.y()), num(p.normal.z()), num(n0.x()), num(n0.y()), num(n0.z()),
                        num(p.normal_sd_deg, 4), num(p.depth), num(a.angle_deg[i], 4), num(f.beta),
                        num(res.scale_px / f.beta, 3));
    }
  }
  const auto normals_tmp = files->write(dir / "patch_normals.csv", pc);
  nlohmann::json summary = patchSummary(r);
  if (plots) {
    const Figures fig = makeFigures(files, dir, "plot_patch_run.py", {normals_tmp.string()}, {"patch_run.png", "patch_run.svg"});
    summary["figures"] = figuresJson(fig);
    if (figures) *figures = fig;
  }
  files->write(dir / "summary.json", summary.dump(2) + "\n");
  return summary;
}

}  // namespace rsfm::report
