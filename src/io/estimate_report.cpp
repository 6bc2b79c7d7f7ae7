#include "rsfm/io/estimate_report.hpp"

#include <fmt/format.h>

#include <cmath>
#include <sstream>

#include "rsfm/camera.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/io/report.hpp"
#include "rsfm/io/tum.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm::io {

void poseOf(const TrackFrame& f, Eigen::Vector3d* position, Eigen::Quaterniond* q) {
  const CameraPose p = copCentredPose(f.R, f.t, f.beta);
  *position = p.position;
  *q = canonical(p.orientation);
}

namespace {

Eigen::Matrix4d covBetaN(const TrackFrame& f, int j) {
  Eigen::Matrix4d c = Eigen::Matrix4d::Zero();
  c(0, 0) = f.var_beta;
  if (j < static_cast<int>(f.cov_N.size())) {
    c.bottomRightCorner<3, 3>() = f.cov_N[j];
    c.block<1, 3>(0, 1) = f.cov_beta_N[j].transpose();
    c.block<3, 1>(1, 0) = f.cov_beta_N[j];
  }
  return c;
}

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

nlohmann::json estimateSummary(const EstimateReport& r) {
  const Tracks& t = *r.tracks;
  const TrackFilterResult& res = *r.result;
  const TrackFrame& last = res.frames.back();
  nlohmann::json j = summaryHead(toString(r.model), static_cast<int>(res.frames.size()), res.frames.front().frame,
                                 last.frame, t.image, res.scale_px, last.beta, last.var_beta);
  nlohmann::json normals = nlohmann::json::array(), dist = nlohmann::json::array(), nsd = nlohmann::json::array();
  for (int p = 0; p < static_cast<int>(last.N.size()); ++p) {
    const MetricPlane mp = metricPlane(last.N[p], last.beta, covBetaN(last, p));
    normals.push_back({mp.n.x(), mp.n.y(), mp.n.z()});
    dist.push_back(mp.d);
    nsd.push_back(mp.sd_angle_deg);
  }
  j["planes"] = normals;
  j["plane_distances"] = dist;
  j["plane_normal_sd_deg"] = nsd;
  if (r.model == TrackModel::Point) {
    // No planes: the per-plane lists stay empty (the summary schema pairs them with "planes").
    j["plane_tracks"] = nlohmann::json::array();
    j["plane_new_tracks"] = nlohmann::json::array();
    j["plane_transfer_failed"] = nlohmann::json::array();
    j["plane_reprojection_rms_px"] = nlohmann::json::array();
    j["point_tracks"] = res.plane_tracks.empty() ? 0 : res.plane_tracks[0];
    j["reprojection_rms_px"] = res.plane_rms_px.empty() ? 0.0 : res.plane_rms_px[0];
  } else {
    j["plane_tracks"] = res.plane_tracks;
    j["plane_new_tracks"] = res.plane_new_tracks;
    j["plane_transfer_failed"] = res.transfer_failed;
    j["plane_reprojection_rms_px"] = res.plane_rms_px;
  }
  nlohmann::json angles = nlohmann::json::array();
  for (size_t a = 0; a < last.N.size(); ++a)
    for (size_t b = a + 1; b < last.N.size(); ++b)
      angles.push_back({{"planes", {a, b}}, {"angle_deg", normalAngle(last.N[a], last.N[b]) * 180.0 / M_PI}});
  j["angles_between_planes_deg"] = angles;
  int outliers = 0, unused = 0, labelled = 0;
  for (int l : *r.labels) {
    outliers += l == -1;
    unused += l == -2;
    labelled += l >= 0;
  }
  j["tracks"] = {{"total", static_cast<int>(r.labels->size())}, {"on_planes", labelled}, {"outliers", outliers},
                 {"too_short", unused}};
  long gated = 0, used = 0;
  for (const auto& f : res.frames) {
    gated += f.gated;
    used += f.used;
  }
  j["gated_observations"] = gated;
  j["accepted_observations"] = used;
  // Final focal length and normals of every pass (--passes): their spread is an honest measure
  // of how well the sequence determines them, which the filter's own sd does not capture.
  j["passes"] = res.passes;
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
  summaryTail(&j, res.stopped, r.command, r.seconds,
              "poses: camera in the reference (first) camera frame, x right, y down, z forward, COP-centred; "
              "normals: unit, reference camera frame, pointing from the camera to the plane (n.X = d > 0); "
              "units: the main plane's N_Z gauge (docs/estimate.md)",
              r.extra);
  return j;
}

nlohmann::json writeEstimateReport(const EstimateReport& r, const std::filesystem::path& dir, AtomicFileSet* files,
                         bool plots) {
  const TrackFilterResult& res = *r.result;
  // trajectory.tum
  std::vector<TumPose> poses;
  for (const auto& f : res.frames) {
    TumPose tp;
    tp.t = f.frame;
    poseOf(f, &tp.p, &tp.q);
    poses.push_back(tp);
  }
  std::ostringstream tum;
  writeTum(tum, poses);
  const auto tum_tmp = files->write(dir / "trajectory.tum", tum.str());
  // planes.csv
  std::string pc =
      "frame,plane,nx,ny,nz,normal_sd_deg,distance,distance_sd,beta,beta_sd,focal_px,focal_sd_px,used,gated,rms_px\n";
  for (const auto& f : res.frames) {
    const double bsd = std::sqrt(std::max(0.0, f.var_beta));
    const double focal = res.scale_px / f.beta, fsd = res.scale_px * bsd / (f.beta * f.beta);
    if (f.N.empty()) {
      pc += fmt::format("{},-1,NA,NA,NA,NA,NA,NA,{},{},{},{},{},{},{}\n", f.frame, num(f.beta), num(bsd), num(focal, 3),
                        num(fsd, 3), f.used, f.gated, num(f.rms_px, 4));
      continue;
    }
    for (size_t p = 0; p < f.N.size(); ++p) {
      const MetricPlane mp = metricPlane(f.N[p], f.beta, covBetaN(f, static_cast<int>(p)));
      pc += fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", f.frame, p, num(mp.n.x()), num(mp.n.y()),
                        num(mp.n.z()), num(mp.sd_angle_deg, 4), num(mp.d), num(mp.sd_d), num(f.beta), num(bsd),
                        num(focal, 3), num(fsd, 3), f.used, f.gated, num(f.rms_px, 4));
    }
  }
  const auto planes_tmp = files->write(dir / "planes.csv", pc);
  // labels.csv
  std::string lc = "track,label,first_frame,last_frame\n";
  const auto spans = trackSpans(*r.tracks);
  for (size_t id = 0; id < spans.size(); ++id) {
    if (spans[id].first < 0) continue;
    lc += fmt::format("{},{},{},{}\n", id, (*r.labels)[id], r.tracks->first_frame + spans[id].first,
                      r.tracks->first_frame + spans[id].last);
  }
  files->write(dir / "labels.csv", lc);
  nlohmann::json summary = estimateSummary(r);
  files->write(dir / "summary.json", summary.dump(2) + "\n");
  if (plots) {
    std::vector<std::string> args = {tum_tmp.string(), planes_tmp.string()};
    for (const char* stem : {"motion", "normals", "focal"}) {
      args.push_back(files->temp(dir / (std::string(stem) + ".png")).string());
      args.push_back(files->temp(dir / (std::string(stem) + ".svg")).string());
    }
    runScript("plot_estimate.py", args);
  }
  return summary;
}

}  // namespace rsfm::io
