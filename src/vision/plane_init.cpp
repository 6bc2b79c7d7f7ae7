#include "rsfm/vision/plane_init.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <functional>
#include <opencv2/calib3d.hpp>

namespace rsfm::vision {

namespace {

double rotAngleDeg(const cv::Mat& a, const cv::Mat& b) {
  const cv::Mat d = a.t() * b;
  const double c = std::clamp((cv::trace(d)[0] - 1.0) / 2.0, -1.0, 1.0);
  return std::acos(c) * 180.0 / M_PI;
}

double angleDeg(const cv::Vec3d& a, const cv::Vec3d& b) {
  const double c = std::clamp(a.dot(b) / (cv::norm(a) * cv::norm(b)), -1.0, 1.0);
  return std::acos(c) * 180.0 / M_PI;
}

struct Sol {
  cv::Mat R;
  cv::Vec3d t, n;
};

/// Decompositions of H at focal f whose plane is in front of the reference camera for (almost)
/// all of the plane's reference points.
std::vector<Sol> solutions(const cv::Matx33d& H, const cv::Matx33d& K, const std::vector<cv::Vec3d>& rays) {
  std::vector<cv::Mat> Rs, ts, ns;
  cv::decomposeHomographyMat(cv::Mat(H), cv::Mat(K), Rs, ts, ns);
  std::vector<Sol> out;
  for (size_t i = 0; i < Rs.size(); ++i) {
    const cv::Vec3d n(ns[i].at<double>(0), ns[i].at<double>(1), ns[i].at<double>(2));
    int front = 0;
    for (const auto& m : rays) front += n.dot(m) > 0;
    if (front < 0.8 * rays.size()) continue;
    out.push_back({Rs[i], cv::Vec3d(ts[i].at<double>(0), ts[i].at<double>(1), ts[i].at<double>(2)), n});
  }
  return out;
}

/// The median displacement (px) of the plane's reference points under its homography H[k], for
/// k = 0..k2 (empty when the plane has no reference points or fewer homographies).
std::vector<double> planeMotionPx(const Tracks& tracks, const FoundPlane& plane, int k2) {
  std::vector<cv::Vec3d> ref;
  for (int id : plane.members)
    if (const TrackPoint* p = tracks.find(0, id)) ref.push_back(cv::Vec3d(p->px.x(), p->px.y(), 1.0));
  auto motion = [&](int k) {
    std::vector<double> d;
    for (const auto& x : ref) {
      const cv::Vec3d y = plane.H[k] * x;
      if (std::abs(y[2]) > 1e-12) d.push_back(std::hypot(y[0] / y[2] - x[0], y[1] / y[2] - x[1]));
    }
    if (d.empty()) return 0.0;
    std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
    return d[d.size() / 2];
  };
  std::vector<double> out;
  if (!ref.empty() && static_cast<int>(plane.H.size()) > k2)
    for (int k = 0; k <= k2; ++k) out.push_back(motion(k));
  return out;
}

/// The first frame k in 1..k2-1 whose motion (planeMotionPx) reaches half of frame k2's.
/// pair_frame / 2 assumed the motion starts at once; after a still start (the ViSP cube's first
/// 17 frames) that frame had hardly moved, its decompositions fitted noise, and the focal
/// length agreed best at the end of the grid (1152 px; 617 px with the still frames cut off).
int halfMotionFrame(const std::vector<double>& motion, int k2) {
  if (static_cast<int>(motion.size()) > k2) {
    const double half = 0.5 * motion[k2];
    for (int k = 1; k < k2; ++k)
      if (motion[k] >= half) return k;
  }
  return std::max(1, k2 / 2);
}

/// Frames over which the plane moved up to k2: from the last frame whose motion was below 5 % of
/// frame k2's (a still start) to k2.
int movingFrames(const std::vector<double>& motion, int k2) {
  int k0 = 0;
  if (static_cast<int>(motion.size()) > k2)
    for (int k = 1; k < k2; ++k)
      if (motion[k] < 0.05 * motion[k2]) k0 = k;
  return std::max(1, k2 - k0);
}

}  // namespace

PlaneStart planeStart(const Tracks& tracks, const PlaneFinding& pf, double focal_px, int max_focal_minima) {
  PlaneStart out;
  std::vector<const FoundPlane*> planes;
  for (const auto& c : pf.candidates)
    if (c.verdict == PlaneVerdict::Accepted && c.label >= 0) planes.push_back(&c);
  std::sort(planes.begin(), planes.end(), [](auto* a, auto* b) { return a->label < b->label; });
  const int m = static_cast<int>(planes.size());
  StartHypothesis frontal;
  frontal.frontal = true;
  frontal.normals.assign(std::max(m, 1), Eigen::Vector3d::UnitZ());
  frontal.distance_ratios.assign(std::max(m, 1), 1.0);
  if (m == 0 || pf.pair_frame < 2) {
    out.note = "no plane or no motion to decompose";
    out.hypotheses.push_back(frontal);
    return out;
  }
  const int k2 = pf.pair_frame;
  const std::vector<double> motion0 = planeMotionPx(tracks, *planes[0], k2);
  const int k1 = halfMotionFrame(motion0, k2);
  const int moving = movingFrames(motion0, k2);
  const double W = std::max(tracks.image.width, tracks.image.height);
  std::vector<double> grid;
  if (focal_px > 0) grid.push_back(focal_px);
  else
    for (int i = 0; i <= 48; ++i) grid.push_back(W * 0.3 * std::pow(10.0, i / 48.0));  // 0.3 W .. 3 W
  // Per grid focal length and per decomposition of plane 0 at the pair frame (the branch): the
  // best joint choice of the other solutions and its disagreement.
  struct Branch {
    double cost = std::numeric_limits<double>::infinity();
    std::vector<Eigen::Vector3d> normals;
    std::vector<double> ratios;
    double rotation_deg = 0.0, translation_rel = 0.0;  ///< plane 0's decomposition at the pair frame
  };
  std::vector<std::vector<Branch>> at(grid.size());
  std::vector<double> best_cost(grid.size(), std::numeric_limits<double>::infinity());
  for (size_t gi = 0; gi < grid.size(); ++gi) {
    const double f = grid[gi];
    const cv::Matx33d K(f, 0, tracks.image.cx, 0, f, tracks.image.cy, 0, 0, 1);
    const cv::Matx33d Ki = K.inv();
    std::vector<std::vector<Sol>> s1(m), s2(m);
    bool ok = true;
    for (int j = 0; j < m && ok; ++j) {
      std::vector<cv::Vec3d> rays;
      for (int id : planes[j]->members)
        if (const TrackPoint* p = tracks.find(0, id)) rays.push_back(Ki * cv::Vec3d(p->px.x(), p->px.y(), 1.0));
      if (static_cast<int>(planes[j]->H.size()) <= k2) ok = false;
      else {
        s1[j] = solutions(planes[j]->H[k1], K, rays);
        s2[j] = solutions(planes[j]->H[k2], K, rays);
        ok = !s1[j].empty() && !s2[j].empty();
      }
    }
    if (!ok) continue;
    // Joint choice of one solution per plane at each frame (at most 4^(2m) combinations), the
    // best one for each choice of plane 0's solution at the pair frame.
    std::vector<Branch>& br = at[gi];
    br.resize(s2[0].size());
    std::vector<int> c1(m, 0), c2(m, 0);
    std::function<void(int)> rec = [&](int level) {
      if (level == 2 * m) {
        double cost = 0.0;
        for (int a = 0; a < m; ++a) {
          cost += angleDeg(s1[a][c1[a]].n, s2[a][c2[a]].n);
          for (int b = a + 1; b < m; ++b)
            cost += rotAngleDeg(s1[a][c1[a]].R, s1[b][c1[b]].R) + rotAngleDeg(s2[a][c2[a]].R, s2[b][c2[b]].R);
        }
        Branch& b = br[c2[0]];
        if (cost < b.cost) {
          b.cost = cost;
          b.normals.assign(m, Eigen::Vector3d::UnitZ());
          b.ratios.assign(m, 1.0);
          const double t0 = cv::norm(s2[0][c2[0]].t);
          // The decomposition's motion: R's angle, and t / d (d the plane's distance from the
          // reference centre) as a fraction of the depth at which the optical axis meets the
          // plane, d / n_z: |t / d| n_z.
          b.rotation_deg = rotAngleDeg(s2[0][c2[0]].R, cv::Mat::eye(3, 3, CV_64F));
          b.translation_rel = t0 * std::abs(s2[0][c2[0]].n[2]) / cv::norm(s2[0][c2[0]].n);
          for (int j = 0; j < m; ++j) {
            const cv::Vec3d n = s2[j][c2[j]].n;
            b.normals[j] = Eigen::Vector3d(n[0], n[1], n[2]).normalized();
            const double tj = cv::norm(s2[j][c2[j]].t);
            b.ratios[j] = (t0 > 1e-9 && tj > 1e-9) ? t0 / tj : 1.0;
          }
        }
        return;
      }
      const int j = level % m;
      auto& c = level < m ? c1 : c2;
      const auto& s = level < m ? s1 : s2;
      for (size_t i = 0; i < s[j].size(); ++i) {
        c[j] = static_cast<int>(i);
        rec(level + 1);
      }
    };
    rec(0);
    std::sort(br.begin(), br.end(), [](const Branch& a, const Branch& b) { return a.cost < b.cost; });
    while (!br.empty() && !std::isfinite(br.back().cost)) br.pop_back();
    if (!br.empty()) best_cost[gi] = br.front().cost;
  }
  // Local minima of the best disagreement over the grid (an end counts when it is below its
  // neighbour: no minimum inside, the focal length is then not determined), lowest first.
  std::vector<size_t> minima;
  for (size_t gi = 0; gi < grid.size(); ++gi) {
    if (!std::isfinite(best_cost[gi])) continue;
    const double left = gi > 0 ? best_cost[gi - 1] : std::numeric_limits<double>::infinity();
    const double right = gi + 1 < grid.size() ? best_cost[gi + 1] : std::numeric_limits<double>::infinity();
    if (best_cost[gi] <= right && best_cost[gi] < left) minima.push_back(gi);
  }
  std::sort(minima.begin(), minima.end(), [&](size_t a, size_t b) { return best_cost[a] < best_cost[b]; });
  if (static_cast<int>(minima.size()) > max_focal_minima) minima.resize(std::max(max_focal_minima, 1));
  for (size_t r = 0; r < minima.size(); ++r) {
    const size_t gi = minima[r];
    for (size_t b = 0; b < at[gi].size(); ++b) {
      StartHypothesis h;
      h.focal_px = grid[gi];
      h.normals = at[gi][b].normals;
      h.distance_ratios = at[gi][b].ratios;
      h.disagreement_deg = at[gi][b].cost;
      h.focal_minimum = static_cast<int>(r);
      h.branch = static_cast<int>(b);
      h.at_grid_end = grid.size() > 1 && (gi == 0 || gi + 1 == grid.size());
      h.rotation_deg_per_frame = at[gi][b].rotation_deg / moving;
      h.translation_rel_per_frame = at[gi][b].translation_rel / moving;
      out.hypotheses.push_back(std::move(h));
    }
  }
  std::stable_sort(out.hypotheses.begin(), out.hypotheses.end(),
                   [](const StartHypothesis& a, const StartHypothesis& b) { return a.disagreement_deg < b.disagreement_deg; });
  out.ok = !out.hypotheses.empty();
  if (!out.ok) out.note = "no homography decomposition with the planes in front of the camera";
  out.hypotheses.push_back(frontal);
  return out;
}

}  // namespace rsfm::vision
