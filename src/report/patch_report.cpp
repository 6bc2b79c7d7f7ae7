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

nlohmann::json writePatchReport(const PatchReport& r, const std::filesystem::path& dir, AtomicFileSet* files, bool plots) {
  const PatchRunResult& res = *r.result;
  std::vector<TumPose> poses;
  for (const auto& f : res.frames) {
    TumPose tp;
    tp.t = f.frame;
    const Eigen::Matrix3d Rc = f.R.transpose();
    tp.p = -Rc * f.T;
    tp.q = canonical(Eigen::Quaterniond(Rc));
    poses.push_back(tp);
  }
  std::ostringstream tum;
  writeTum(tum, poses);
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
  files->write(dir / "summary.json", summary.dump(2) + "\n");
  if (plots)
    runPlotScript("plot_patch_run.py", normals_tmp, files->temp(dir / "patch_run.png"), files->temp(dir / "patch_run.svg"));
  return summary;
}

}  // namespace rsfm::report
