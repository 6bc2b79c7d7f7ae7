#include "rsfm/render/determinacy.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/units.hpp"

#include <fmt/format.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "rsfm/batch/plane_batch.hpp"
#include "rsfm/determinacy.hpp"
#include "rsfm/render/scene_render.hpp"

namespace rsfm::render {
namespace {


struct Point {
  Eigen::Vector3d X;  // reference camera frame (COP-centred)
  int plane = 0;      // truth plane index
};

}  // namespace

Determinacy analyseDeterminacy(const Scene& scene, const DeterminacyOptions& opt) {
  Determinacy out;
  io::Determinable& det = out.summary;
  const io::Summary truth = scene.truth();
  const int F = scene.frames();
  const int P = static_cast<int>(truth.planes.size());
  det.crb_normal_sd_deg.assign(P, std::nullopt);
  for (int k = 1; k < F && !out.moves; ++k) {
    const io::TumPose p = scene.pose(k);
    out.moves = p.p.norm() > 0 || std::abs(p.q.w()) < 1.0 - 1e-15;
  }
  if (!out.moves) {
    det.focal = det.structure = false;
    det.why = "nothing moves: no frame differs from the first";
    return out;
  }
  const RenderOptions& ro = scene.options();
  const double f = *truth.focal_px;
  auto inImage = [&](const Eigen::Vector2d& x) {
    return x.x() >= opt.margin_px && x.y() >= opt.margin_px && x.x() <= ro.width - 1 - opt.margin_px &&
           x.y() <= ro.height - 1 - opt.margin_px;
  };
  // Points: a grid over every textured face of the moving body, kept where frame 0 sees them.
  std::vector<Point> pts;
  {
    const cv::Mat lab0 = scene.labels(0);
    std::vector<std::vector<Point>> per(P);
    for (const auto& face : scene.faces()) {
      if (face.still_body || !face.textured || face.truth_index < 0) continue;
      const auto& c = face.corners;
      const int g = 24;
      for (int i = 0; i < g; ++i)
        for (int j = 0; j < g; ++j) {
          const double u = (i + 0.5) / g, v = (j + 0.5) / g;
          const Eigen::Vector3d X = c[0] + u * (c[1] - c[0]) + v * (c[3] - c[0]);
          const auto x = scene.project(X, 0);
          if (!x || !inImage(*x)) continue;
          if (lab0.at<uchar>(static_cast<int>(std::lround(x->y())), static_cast<int>(std::lround(x->x()))) !=
              face.truth_index + 1)
            continue;
          per[face.truth_index].push_back({X, face.truth_index});
        }
    }
    for (auto& v : per) {
      if (static_cast<int>(v.size()) < 5) continue;  // a plane needs 5 points ([AS99] §3.1)
      const double stride = std::max(1.0, static_cast<double>(v.size()) / opt.points_per_plane);
      for (double s = 0; s < v.size(); s += stride) pts.push_back(v[static_cast<std::size_t>(s)]);
    }
  }
  // Planes in the problem (those with points), renumbered.
  std::vector<int> plane_of(P, -1), truth_of;
  for (const Point& p : pts)
    if (plane_of[p.plane] < 0) {
      plane_of[p.plane] = static_cast<int>(truth_of.size());
      truth_of.push_back(p.plane);
    }
  const int m = static_cast<int>(truth_of.size());
  if (m == 0) {
    det.focal = det.structure = false;
    det.why = "no textured plane seen in the first frame with at least 5 points";
    return out;
  }
  // The A&P frame ([AS99] eqs. 5-7; camera.hpp) with s = f, so beta = 1, after scaling the scene so
  // that the points' median depth is 10 (the image-plane origin, 1 unit before the centre of
  // projection, then lies far from every plane). The bound on f/f and on directions is the same
  // at any scale.
  std::vector<double> depths;
  for (const Point& p : pts) depths.push_back(p.X.z());
  std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
  const double scale = 10.0 / depths[depths.size() / 2];
  const Eigen::Vector3d ez = Eigen::Vector3d::UnitZ();
  PlaneBatchData data;
  data.frames.resize(F);
  data.num_planes = m;
  data.sigma_uv = opt.track_sd_px / f;
  PlaneBatchState start;
  start.beta = 1.0;
  for (const Point& p : pts) data.labels.push_back(plane_of[p.plane]);
  start.N.resize(m);
  for (int j = 0; j < m; ++j) {
    const Eigen::Vector3d n = truth.planes[truth_of[j]];
    const double d = truth.plane_distances[truth_of[j]] * scale;
    start.N[j] = n / (d - n.z());  // n . X = d - n_z for X = Y - e_z (origin on the image plane)
  }
  start.N[0].cwiseAbs().maxCoeff(&data.gauge_component);
  data.gauge_plane = 0;
  start.R.resize(F);
  start.t.resize(F);
  for (int k = 0; k < F; ++k) {
    const io::TumPose pose = scene.pose(k);
    const Eigen::Matrix3d R = pose.q.toRotationMatrix().transpose();  // reference -> camera k
    const Eigen::Vector3d t_cop = -R * (pose.p * scale);
    start.R[k] = R;
    start.t[k] = t_cop - (Eigen::Matrix3d::Identity() - R) * ez;  // A&P translation (beta = 1)
    if (k == 0) {
      start.R[k].setIdentity();
      start.t[k].setZero();
    }
  }
  const std::vector<cv::Mat> labels = [&] {
    std::vector<cv::Mat> l;
    for (int k = 0; k < F; ++k) l.push_back(scene.labels(k));
    return l;
  }();
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const Eigen::Vector3d Xs = pts[i].X * scale;
    start.ref.push_back(Xs.head<2>() / Xs.z());
    for (int k = 0; k < F; ++k) {
      const auto x = scene.project(pts[i].X, k);
      if (!x || !inImage(*x)) continue;
      if (labels[k].at<uchar>(static_cast<int>(std::lround(x->y())), static_cast<int>(std::lround(x->x()))) !=
          pts[i].plane + 1)
        continue;
      // The undistorted observation (the model is a pinhole; distortion is a separate question).
      const io::TumPose pose = scene.pose(k);
      const Eigen::Vector3d Xc = pose.q.conjugate() * (pts[i].X - pose.p);
      data.frames[k].push_back({static_cast<int>(i), Xc.head<2>() / Xc.z()});
      ++out.observations;
    }
  }
  // Frames that see fewer than 4 points leave their motion undetermined: leave them out.
  {
    PlaneBatchData kept = data;
    PlaneBatchState ks = start;
    kept.frames.clear();
    ks.R.clear();
    ks.t.clear();
    for (int k = 0; k < F; ++k)
      if (k == 0 || data.frames[k].size() >= 4) {
        kept.frames.push_back(data.frames[k]);
        ks.R.push_back(start.R[k]);
        ks.t.push_back(start.t[k]);
      } else {
        out.observations -= static_cast<int>(data.frames[k].size());
      }
    data = std::move(kept);
    start = std::move(ks);
  }
  out.points = static_cast<int>(pts.size());
  const PlaneBatchBound b = planeBatchBound(data, start);
  out.batch_message = b.message;
  out.full_rank = b.ok && b.null_dim == 0;
  out.null_dim = b.null_dim;
  if (b.ok && b.beta_estimable) det.crb_focal_rel_sd = std::sqrt(std::max(0.0, b.var_beta));
  for (int j = 0; b.ok && j < m; ++j) {
    if (!b.normal_estimable[j]) continue;
    det.crb_normal_sd_deg[truth_of[j]] = directionRmsAngle(start.N[j], b.cov_N[j]) * kRadToDeg;
  }
  det.focal = det.crb_focal_rel_sd && *det.crb_focal_rel_sd <= kDeterminedFocalRelSd;
  double worst = 0;
  bool all = b.ok;
  for (int j = 0; j < m; ++j) {
    const auto& v = det.crb_normal_sd_deg[truth_of[j]];
    if (!v || *v > kDeterminedNormalSdDeg) all = false;
    if (v) worst = std::max(worst, *v);
  }
  det.structure = all;
  const std::string focal_part = det.crb_focal_rel_sd ? fmt::format("focal sd {:.2g} %", 100 * *det.crb_focal_rel_sd)
                                                      : std::string("focal not estimable (in the null space)");
  std::string structure_part = fmt::format("worst normal sd {:.2g} deg", worst);
  for (int j = 0; j < m; ++j)
    if (!det.crb_normal_sd_deg[truth_of[j]]) structure_part = "some normals not estimable (in the null space)";
  if (!b.ok) structure_part = b.message;
  det.why = fmt::format("Cramer-Rao bound at the truth, {} points on {} plane(s), {} px tracks, null space {}: {}; {}",
                        out.points, m, opt.track_sd_px, b.null_dim, focal_part, structure_part);
  return out;
}

std::string determinacyToJson(const Determinacy& d) {
  nlohmann::ordered_json j;
  j["moves"] = d.moves;
  j["points"] = d.points;
  j["observations"] = d.observations;
  j["full_rank"] = d.full_rank;
  j["null_dim"] = d.null_dim;
  j["batch"] = d.batch_message;
  j["focal"] = d.summary.focal;
  j["structure"] = d.summary.structure;
  j["why"] = d.summary.why;
  j["limits"] = {{"focal_rel_sd", kDeterminedFocalRelSd}, {"normal_sd_deg", kDeterminedNormalSdDeg}};
  return j.dump();
}

}  // namespace rsfm::render
