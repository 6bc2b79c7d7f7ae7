#include "rsfm/pipeline/refine.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/clock.hpp"
#include "rsfm/units.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <numeric>
#include <cmath>
#include <optional>

#include "rsfm/batch/plane_batch.hpp"
#include "rsfm/camera.hpp"
#include "rsfm/chi2.hpp"
#include "rsfm/rotation.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include "rsfm/determinacy.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/models/radial_camera.hpp"
#include "rsfm/residual_correlation.hpp"

namespace rsfm {
namespace {

/// The batch problem of the labelled tracks: points, their reference positions (from the
/// filter), the start state. data.point_ids: the track id of each point.
struct Problem {
  PlaneBatchData data;
  PlaneBatchState start;
  int unpredictable = 0;  ///< observations left out: the start cannot predict them
  /// Per plane, later tracks left out because the start cannot carry them to the reference frame
  /// (behind the reference camera or at the plane's horizon).
  std::vector<int> transfer_failed;
  /// Per plane, tracks left out because their reference position lies at the plane's horizon
  /// line in the reference image (RefineResult::plane_horizon_tracks).
  std::vector<int> horizon;
};

/// A reference position closer than this many measurement sds (TrackFilterOptions::sigma_px) to
/// its plane's horizon line in the reference image is on a side of it the data do not decide
/// (docs/estimate.md section 4, "Planes seen edge-on from the reference frame").
constexpr double kHorizonSigmas = 3.0;
/// A plane with half its tracks or more at its horizon, or left with fewer tracks than this once
/// those are out, loses the rest too: five points determine a plane (the seed's section 3.1).
constexpr int kMinPlaneTracksAtHorizon = 5;

double robustSd(std::vector<double> v) {
  if (v.empty()) return 0.0;
  for (double& x : v) x = std::abs(x);
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return 1.4826 * v[v.size() / 2];
}

/// Residuals (pixels, components) of every observation at `st`, grouped per point.
std::vector<std::vector<double>> residualsPx(const Problem& p, const PlaneBatchState& st, double s, bool camera) {
  std::vector<std::vector<double>> out(p.data.labels.size());
  const int F = static_cast<int>(p.data.frames.size()) - 1;
  for (int k = 0; k <= F; ++k)
    for (std::size_t j = 0; j < p.data.frames[k].size(); ++j) {
      const Observation& o = p.data.frames[k][j];
      Eigen::Vector2d r;
      if (k == 0) {
        planeBatchReferenceResidual(st.ref[o.id], st.beta, st.camera, o.uv, 1.0, &r, nullptr, nullptr, nullptr);
        r += st.readout * p.data.shift(k, j);
      } else if (planeBatchResidual(st.t[k], Eigen::Vector3d::Zero(), st.R[k], st.beta, st.N[p.data.labels[o.id]],
                                    st.ref[o.id], o.uv, 1.0, &r, nullptr, nullptr, nullptr, nullptr,
                                    camera ? &st.camera : nullptr, nullptr) != MeasureStatus::Ok) {
        r = Eigen::Vector2d::Constant(1e3 / s);  // unprojectable: counts as far off
      } else {
        r += st.readout * p.data.shift(k, j);  // a rolling shutter's (0 without one)
      }
      out[o.id].push_back(r.x() * s);
      out[o.id].push_back(r.y() * s);
    }
  return out;
}

}  // namespace

RefineResult refine(const Tracks& tracks, const std::vector<int>& labels, const TrackFilterResult& online,
                    const TrackFilterOptions& fo, const RefineOptions& ro, const std::function<void(const std::string&)>& note) {
  const double t_start = steadySeconds();
  RefineResult r;
  r.labels = labels;
  const int F = tracks.numFrames();
  const int m = online.planes;
  if (!online.ok() || m < 1 || static_cast<int>(online.frames.size()) != F || F < 2) {
    r.message = m < 1 ? "the point model has no planes to refine" : "no complete online estimate to refine";
    return r;
  }
  const double s = online.scale_px, cx = tracks.image.cx, cy = tracks.image.cy;
  const auto spans = trackSpans(tracks);
  const int n_ids = tracks.idBound();  // O(observations): computed once
  const TrackFrame& last = online.frames.back();
  r.camera_free = {ro.estimate_principal_point, ro.estimate_principal_point, ro.estimate_distortion, ro.estimate_distortion};
  const bool known_focal = fo.focal_px > 0;

  // Planes seen edge-on from the reference frame by some build: left out of every later one (their
  // tracks, carried back through a state whose plane has moved off the camera's centre, came back
  // and the last solve crawled along that plane to its iteration limit).
  std::vector<char> edge_on(m, 0);
  // Whether reference `ref` lies at plane N's horizon line in the reference image, and whether a
  // plane with `at` tracks there and `off` elsewhere is seen edge-on (half its tracks or more at
  // the line: the rest are near it; or too few left to place it).
  auto atHorizon = [&](const Eigen::Vector3d& N, double beta, const Eigen::Vector2d& ref) {
    return s * PlaneModel::horizonDistance(N, beta, ref) < kHorizonSigmas * fo.sigma_px;
  };
  auto seenEdgeOn = [](int at, int off) { return at > 0 && (at >= off || off < kMinPlaneTracksAtHorizon); };
  // Builds the problem over the tracks labelled >= 0 in `lab`, started at `from` (the filter's
  // state when null) for the points it knows.
  auto build = [&](const std::vector<int>& lab, const PlaneBatchState* from, const std::vector<int>* from_track_of_point) {
    Problem p;
    p.transfer_failed.assign(m, 0);
    p.horizon.assign(m, 0);
    p.data.frames.resize(F);
    p.data.num_planes = m;
    p.data.gauge_plane = 0;
    p.data.gauge_component = 2;
    for (int k = 0; k < F; ++k) p.data.frame_numbers.push_back(tracks.frameNumber(k));
    p.start.beta = from ? from->beta : last.beta;
    p.start.N = from ? from->N : last.N;
    p.start.camera = from ? from->camera : Eigen::Vector4d::Zero();
    p.start.readout = from ? from->readout : 0.0;
    if (ro.estimate_readout) p.data.readout_shift.resize(F);
    for (int k = 0; k < F; ++k) {
      const TrackFrame& f = online.frames[k];
      p.start.R.push_back(from ? from->R[k] : f.R);
      p.start.t.push_back(from ? from->t[k] : Eigen::Vector3d(f.t.x(), f.t.y(), f.t.z() * f.beta));
    }
    std::vector<int> point_of_track_from;
    if (from) {
      point_of_track_from.assign(n_ids, -1);
      for (std::size_t i = 0; i < from_track_of_point->size(); ++i) point_of_track_from[(*from_track_of_point)[i]] = static_cast<int>(i);
    }
    std::vector<int> point_of_track(n_ids, -1);
    // Each track's reference, and whether it lies at its plane's horizon line in the reference
    // image (PlaneModel::horizonDistance, x s: px). A plane seen edge-on from the reference camera
    // (one that nearly contains its centre) has every point there: a point's depth along its
    // reference ray then turns on a fraction of a pixel, and the solver's steps carry it behind
    // the camera.
    struct Candidate {
      int id;
      Eigen::Vector2d ref;
      bool at_horizon;
    };
    std::vector<Candidate> cands;
    std::vector<int> at(m, 0), off(m, 0);  // per plane: tracks at its horizon, and the rest
    for (int id = 0; id < n_ids; ++id) {
      if (lab[id] < 0 || lab[id] >= m || spans[id].length() < std::max(2, fo.min_track_frames)) continue;
      Eigen::Vector2d ref;
      if (from && point_of_track_from[id] >= 0) {
        ref = from->ref[point_of_track_from[id]];
      } else {
        const int k1 = spans[id].first;
        const Eigen::Vector2d px = tracks.find(k1, id)->px;
        const Eigen::Vector2d uv((px.x() - cx) / s, (px.y() - cy) / s);
        if (k1 == 0) {
          ref = uv;
        } else {
          // Through the state the problem starts from (a track the previous problem left out:
          // at a plane's horizon there), else the filter's.
          const TrackFrame& f = online.frames[k1];
          const MeasureStatus st =
              from ? PlaneModel::transferToReference(
                         from->N[lab[id]], from->beta, from->R[k1],
                         Eigen::Vector3d(from->t[k1].x(), from->t[k1].y(), from->t[k1].z() / from->beta), uv, &ref)
                   : PlaneModel::transferToReference(last.N[lab[id]], f.beta, f.R, f.t, uv, &ref);
          if (st != MeasureStatus::Ok) {
            ++p.transfer_failed[lab[id]];
            continue;
          }
        }
      }
      const bool at_horizon = atHorizon(p.start.N[lab[id]], p.start.beta, ref);
      cands.push_back({id, ref, at_horizon});
      ++(at_horizon ? at : off)[lab[id]];
    }
    for (int j = 0; j < m; ++j)
      if (seenEdgeOn(at[j], off[j])) edge_on[j] = 1;
    for (const Candidate& c : cands) {
      const int j = lab[c.id];
      // A plane with half its tracks or more at its horizon is seen edge-on: the rest are near it.
      if (c.at_horizon || edge_on[j]) {
        ++p.horizon[j];
        continue;
      }
      point_of_track[c.id] = static_cast<int>(p.data.point_ids.size());
      p.data.point_ids.push_back(c.id);
      p.data.labels.push_back(j);
      p.start.ref.push_back(c.ref);
    }
    for (int k = 0; k < F; ++k)
      for (const TrackPoint& tp : tracks.frames[k]) {
        if (tp.id >= static_cast<int>(point_of_track.size()) || point_of_track[tp.id] < 0) continue;
        const int i = point_of_track[tp.id];
        const Eigen::Vector2d uv((tp.px.x() - cx) / s, (tp.px.y() - cy) / s);
        // An observation the start cannot predict (behind a camera, at a plane's horizon: a poor
        // online estimate) is left out; Ceres cannot start from a point it cannot evaluate.
        Eigen::Vector2d res;
        if (k > 0 && planeBatchResidual(p.start.t[k], Eigen::Vector3d::Zero(), p.start.R[k], p.start.beta,
                                        p.start.N[p.data.labels[i]], p.start.ref[i], uv, 1.0, &res, nullptr, nullptr, nullptr,
                                        nullptr, &p.start.camera, nullptr) != MeasureStatus::Ok) {
          ++p.unpredictable;
          continue;
        }
        p.data.frames[k].push_back({i, uv});
        if (ro.estimate_readout) p.data.readout_shift[k].push_back(rollingShutterShift(tracks, k, tp) / s);
      }
    return p;
  };

  auto pooled = [](const std::vector<std::vector<double>>& per) {
    std::vector<double> all;
    for (const auto& v : per) all.insert(all.end(), v.begin(), v.end());
    return all;
  };
  PlaneBatchOptions bo;
  bo.loss = PlaneBatchOptions::Loss::Huber;
  bo.loss_scale = ro.loss_sigmas;
  bo.max_iterations = ro.max_iterations;
  bo.function_tolerance = 1e-7;   // relative cost change: far below the noise's own spread
  bo.parameter_tolerance = 1e-8;
  bo.compute_covariance = false;
  bo.camera_free = r.camera_free;
  bo.readout_prior_sd = ro.readout_prior_sd;
  bo.hold_beta = known_focal;  // a known focal length stays known
  {
    const double pp_sd = ro.principal_point_prior_sd * std::max(tracks.image.width, tracks.image.height) / s;
    bo.camera_prior_sd = {pp_sd, pp_sd, ro.distortion_prior_sd, ro.distortion_prior_sd};
  }
  bo.eliminate_motions_first = true;
  bo.trust_region = PlaneBatchOptions::TrustRegion::Dogleg;
  // Progress: what is being solved, said every ro.progress_seconds (through every copy of `bo`).
  std::string phase;
  double next_note = t_start + ro.progress_seconds;
  if (note)
    bo.on_iteration = [&](int iteration, double) {
      const double now = steadySeconds();
      if (now < next_note) return;
      next_note = now + ro.progress_seconds;
      note(fmt::format("refine: {:.0f} s so far; {}: iteration {}", now - t_start, phase, iteration));
    };
  auto solve = [&](Problem& p, double sigma_px, PlaneBatchResult* out) {
    std::vector<std::string> free;
    if (bo.camera_free[0] || bo.camera_free[1]) free.emplace_back("the principal point");
    if (bo.camera_free[2] || bo.camera_free[3]) free.emplace_back("the distortion");
    if (bo.readout_free) free.emplace_back("the readout");
    std::string what = free.empty() ? "the camera held" : "estimating " + free[0];
    for (std::size_t i = 1; i < free.size(); ++i) what += (i + 1 == free.size() ? " and " : ", ") + free[i];
    phase = fmt::format("{} tracks, {}", p.data.point_ids.size(), what);
    p.data.sigma_uv = sigma_px / s;
    *out = solvePlaneBatch(p.data, p.start, bo);
    return out->converged;
  };

  // Tracks: the longest first, while some frame of their life lacks tracks on their plane.
  std::vector<int> selected = labels;
  if (ro.tracks_per_plane_and_frame > 0) {
    std::vector<int> order;
    for (int id = 0; id < n_ids; ++id)
      if (labels[id] >= 0 && labels[id] < m && spans[id].length() >= std::max(2, fo.min_track_frames)) order.push_back(id);
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return spans[a].length() > spans[b].length(); });
    std::vector<std::vector<int>> count(m, std::vector<int>(F, 0));
    for (int id : order) {
      auto& c = count[labels[id]];
      bool needed = false;
      for (int k = spans[id].first; k <= spans[id].last && !needed; ++k) needed = c[k] < ro.tracks_per_plane_and_frame;
      if (!needed) {
        selected[id] = -2;  // not used (still on its plane: not an outlier)
        continue;
      }
      for (int k = spans[id].first; k <= spans[id].last; ++k) ++c[k];
    }
  }
  // 1. The start's residuals set the noise and the loss's scale.
  Problem p = build(selected, nullptr, nullptr);
  if (static_cast<int>(p.data.point_ids.size()) < 5) {
    r.message = "fewer than 5 tracks on planes to refine";
    return r;
  }
  {
    long total = p.unpredictable;
    for (const auto& f : p.data.frames) total += static_cast<long>(f.size());
    if (p.unpredictable > 0.2 * total) {
      r.message = fmt::format("the online estimate cannot predict {} of {} observations (behind a camera or at a plane's "
                              "horizon): no start to refine from",
                              p.unpredictable, total);
      return r;
    }
  }
  const std::vector<double> start_res = pooled(residualsPx(p, p.start, s, false));
  const double sigma0 = std::max(1e-3, robustSd(start_res));
  double sigma_loss = sigma0;  // the noise (px) that scaled the last accepted solve's loss
  {
    double ss = 0;
    for (double x : start_res) ss += x * x;
    r.initial_rms_px = start_res.empty() ? 0.0 : std::sqrt(ss / start_res.size());
  }
  // Stage 1: the camera held (the principal point at the tracks', no distortion): the filter's
  // start is close to this problem's optimum.
  const std::array<bool, 4> wanted = r.camera_free;
  const bool wanted_readout = ro.estimate_readout;
  bo.camera_free = {false, false, false, false};
  bo.readout_free = false;
  PlaneBatchResult res;
  // Stage 1 stops as soon as one of its planes is seen edge-on from the reference frame: the
  // optimum of such a plane lies where it contains the reference camera's centre, which a solve
  // only approaches, each step a few per cent shorter than the one before (the 1200-frame box
  // orbit: 51 iterations to the limit, 8.5 s, and the plane left out afterwards all the same;
  // stopped when the rule holds, 41). Its tracks are then left out (build: the long orbit's box
  // face that nearly contains the reference camera's centre) and the problem solved again from
  // where it stopped, before the later stages crawl along it; until no plane turns edge-on.
  const Problem* watched = &p;
  bo.stop_when = [&](double beta, const Eigen::Ref<const Eigen::Matrix3Xd>& N, const Eigen::Ref<const Eigen::Matrix2Xd>& ref) {
    std::vector<int> at(m, 0), off(m, 0);
    for (std::size_t i = 0; i < watched->data.labels.size(); ++i) {
      const int j = watched->data.labels[i];
      ++(atHorizon(N.col(j), beta, ref.col(static_cast<Eigen::Index>(i))) ? at : off)[j];
    }
    for (int j = 0; j < m; ++j)
      if (!edge_on[j] && seenEdgeOn(at[j], off[j])) return true;
    return false;
  };
  if (!solve(p, sigma0, &res)) {
    r.message = "the refinement did not converge: " + res.message;
    return r;
  }
  r.iterations = res.iterations;
  for (int round = 0; round <= m; ++round) {
    Problem p2 = build(selected, &res.state, &p.data.point_ids);
    PlaneBatchResult res2;
    watched = &p2;
    if (std::accumulate(p2.horizon.begin(), p2.horizon.end(), 0) > std::accumulate(p.horizon.begin(), p.horizon.end(), 0) &&
        static_cast<int>(p2.data.point_ids.size()) >= 5 && solve(p2, sigma0, &res2)) {
      p = std::move(p2);
      watched = &p;
      res = std::move(res2);
      r.iterations += res.iterations;
      if (res.stopped_early) continue;
    }
    watched = &p;  // p2 goes out of scope
    if (res.stopped_early) {
      // Stopped, but the rebuild left nothing more out: the solve goes on from there.
      bo.stop_when = nullptr;
      p.start = res.state;
      if (solve(p, sigma0, &res2)) {
        res = std::move(res2);
        r.iterations += res.iterations;
      }
    }
    break;
  }
  bo.stop_when = nullptr;
  std::vector<std::string> why;
  const double fmax = std::max(tracks.image.width, tracks.image.height);
  r.camera_free = wanted;
  r.readout_free = wanted_readout;
  // The final residuals' spread, and their correlation along tracks, scale the bound; the bound
  // treats the camera components in `bound_camera` (and the readout with `bound_readout`) as
  // parameters (with their priors).
  std::vector<std::vector<double>> per;
  double ss = 0, sigma_final = 0;
  auto spreadAndBound = [&](const PlaneBatchState& st, const std::array<bool, 4>& bound_camera, bool bound_readout) {
    per = residualsPx(p, st, s, true);
    const std::vector<double> all = pooled(per);
    ss = 0;
    for (double x : all) ss += x * x;
    const int n_cam = static_cast<int>(std::count(bound_camera.begin(), bound_camera.end(), true)) +
                      (bound_readout ? 1 : 0);  // the bound's parameters
    const int n_params = 6 * (F - 1) + 1 + (3 * m - 1) + 2 * static_cast<int>(p.data.point_ids.size()) + n_cam;
    const int n_res = static_cast<int>(all.size());
    r.final_rms_px = all.empty() ? 0.0 : std::sqrt(ss / all.size());
    r.sigma_px = n_res > n_params ? std::sqrt(ss / (n_res - n_params)) : r.final_rms_px;
    r.robust_sigma_px = robustSd(all);
    r.tracks = static_cast<int>(p.data.point_ids.size());
    r.observations = n_res / 2;
    // The residuals' correlation along tracks widens the bound (rsfm/residual_correlation.hpp).
    r.correlation_inflation = alongTrackCorrelationInflation(per);
    sigma_final = r.sigma_px * std::sqrt(r.correlation_inflation);
    p.data.sigma_uv = sigma_final / s;
    PlaneBatchBoundOptions bopt;
    bopt.camera_free = bound_camera;
    bopt.camera_prior_sd = bo.camera_prior_sd;
    bopt.readout_free = bound_readout;
    bopt.readout_prior_sd = bo.readout_prior_sd;
    bopt.motion_covariance = true;
    bopt.skip_undetermined_frames = true;
    bopt.hold_beta = known_focal;
    bopt.track_clustered = ro.track_clustered_sd;
    bopt.spatial_grid = ro.spatial_grid;
    return planeBatchBound(p.data, st, bopt);
  };
  // Stage 2: the camera released from there. A camera no camera could be (the principal point
  // beyond max_principal_offset, a distortion folding the image) is held again and the rest
  // solved once more.
  // A distortion no lens has: |k1| or |k2| above 1, or the image's farthest corner beyond the
  // radius where the radial map stops being monotonic (it folds the image).
  auto distortionFolds = [&](const PlaneBatchState& st) {
    const double k1 = st.camera[2], k2 = st.camera[3], f1 = s / st.beta;
    double rcorner = 0;  // farthest corner, pinhole units
    const Eigen::Vector2d c(cx + s * st.camera[0], cy + s * st.camera[1]);
    for (double x : {-0.5, tracks.image.width - 0.5})
      for (double y : {-0.5, tracks.image.height - 0.5}) rcorner = std::max(rcorner, std::hypot(x - c.x(), y - c.y()) / f1);
    return std::abs(k1) > 1 || std::abs(k2) > 1 || rcorner >= RadialCamera::monotonicRadius(k1, k2);
  };
  // Holds (in r.camera_free, with the reason in `why`) the components of the camera in `st` that
  // no camera could have; true when it held any.
  auto holdImplausible = [&](const PlaneBatchState& st) {
    bool held = false;
    if (r.camera_free[0]) {
      const Eigen::Vector2d off = s * st.camera.head<2>();
      if (off.cwiseAbs().maxCoeff() > ro.max_principal_offset * fmax) {
        why.push_back(fmt::format("principal point not determined: the data pull it to ({:.0f}, {:.0f}) px, farther than "
                                  "{:.0f} % of the image from its centre; held at ({:.1f}, {:.1f})",
                                  cx + off.x(), cy + off.y(), 100 * ro.max_principal_offset, cx, cy));
        r.camera_free[0] = r.camera_free[1] = false;
        held = true;
      }
    }
    if (r.camera_free[2] && distortionFolds(st)) {
      why.push_back(fmt::format("distortion not determined: k1 {:.3f}, k2 {:.3f} would fold the image; held at 0", st.camera[2],
                                st.camera[3]));
      r.camera_free[2] = r.camera_free[3] = false;
      held = true;
    }
    if (r.readout_free && !(std::abs(st.readout) <= kMaxRollingShutterReadout)) {
      why.push_back(fmt::format("rolling shutter readout not determined: the data pull it to {:.2f} frame intervals, beyond "
                                "{:g}; held at 0 (a global shutter)",
                                st.readout, kMaxRollingShutterReadout));
      r.readout_free = false;
      held = true;
    }
    return held;
  };
  // The camera's held components back at the nominal camera (principal point at the tracks',
  // no distortion).
  auto resetHeld = [&](PlaneBatchState* st) {
    for (int c = 0; c < 4; ++c)
      if (!r.camera_free[c]) st->camera[c] = 0.0;
    if (!r.readout_free) st->readout = 0.0;
  };
  // A principal point the data do not determine is held before it is released (issue 13 item
  // 4): released, it wanders in a flat valley (box.mp4's overlapping windows: 288-365 px in x
  // from nearly the same frames, and the focal length following it), and the solve along that
  // valley took 20 of the refinement's ~30 iterations on 150 frames. The distortion is solved
  // first with the principal point held (an unmodelled distortion's residuals would make the
  // point look undetermined: box-k1-neg); the bound there, with every wanted camera component a
  // parameter with its prior, says whether the data determine the point. Its prior stays in the
  // final bound, so its uncertainty still widens the focal length's sd.
  const double pp_limit = kDeterminedPrincipalPointSdFraction * fmax;
  // Whether bound `bd` leaves the principal point undetermined (rsfm/determinacy.hpp), with its
  // sds (px) in *sx, *sy.
  auto ppUndetermined = [&](const PlaneBatchBound& bd, double* sx, double* sy) {
    *sx = s * std::sqrt(std::max(0.0, bd.cov_camera(0, 0)));
    *sy = s * std::sqrt(std::max(0.0, bd.cov_camera(1, 1)));
    return !(bd.camera_estimable[0] && bd.camera_estimable[1] && std::max(*sx, *sy) <= pp_limit);
  };
  bool pp_held_undetermined = false, camera_solved = false;
  std::optional<PlaneBatchBound> b_held;  // that bound, when it is already the final one (below)
  if (ro.hold_undetermined_principal_point && wanted[0]) {
    PlaneBatchResult rd;
    bool have_rd = false;
    if (wanted[2] || wanted[3] || wanted_readout) {
      bo.camera_free = {false, false, wanted[2], wanted[3]};
      bo.readout_free = wanted_readout;
      p.start = res.state;
      have_rd = solve(p, sigma0, &rd) && !distortionFolds(rd.state) &&
                std::abs(rd.state.readout) <= kMaxRollingShutterReadout;
    }
    const PlaneBatchBound b0 = spreadAndBound(have_rd ? rd.state : res.state, wanted, wanted_readout);
    double sx = 0, sy = 0;
    if (b0.ok && ppUndetermined(b0, &sx, &sy)) {
      r.camera_free[0] = r.camera_free[1] = false;
      pp_held_undetermined = true;
      camera_solved = have_rd;  // that solve was this problem's
      if (camera_solved) b_held = b0;
      why.push_back(fmt::format("principal point not determined (sd {:.1f}, {:.1f} px); held at ({:.1f}, {:.1f}) with its "
                                "prior sd {:.0f} px in the bound",
                                sx, sy, cx, cy, s * bo.camera_prior_sd[0]));
    }
    if (have_rd) {
      r.iterations += rd.iterations;
      res = std::move(rd);
    }
  }
  // Each round either accepts its solve or holds one more of the principal point, the distortion
  // and the readout: at most four rounds, the last one's solve accepted unless it failed.
  for (int round = 0; round < 4 && !camera_solved &&
                      (r.readout_free || std::any_of(r.camera_free.begin(), r.camera_free.end(), [](bool b) { return b; }));
       ++round) {
    bo.camera_free = r.camera_free;
    bo.readout_free = r.readout_free;
    p.start = res.state;
    if (!r.readout_free) p.start.readout = 0.0;  // held implausible: at a global shutter's
    PlaneBatchResult rc;
    if (!solve(p, sigma0, &rc)) {
      why.push_back("the camera's refinement did not converge (" + rc.message + "); held");
      r.camera_free = {false, false, false, false};
      r.readout_free = false;
      break;
    }
    r.iterations += rc.iterations;
    const bool held = holdImplausible(rc.state);
    if (!held) {
      res = std::move(rc);
      break;
    }
  }
  bo.camera_free = r.camera_free;
  bo.readout_free = r.readout_free;
  // A readout held after an earlier solve estimated it (the principal point's decision solve; a
  // later solve failed or found it implausible) is held at 0, a global shutter's, as reported:
  // solved again from there (where it stood with the readout at 0 if that fails).
  if (!r.readout_free && res.state.readout != 0.0) {
    p.start = res.state;
    p.start.readout = 0.0;
    PlaneBatchResult rz;
    if (solve(p, sigma0, &rz)) {
      r.iterations += rz.iterations;
      res = std::move(rz);
    } else {
      res.state.readout = 0.0;
    }
  }
  // Stage 3: tracks off their plane under the final model become outliers; solve again without
  // them, with the noise and the loss's scale from the remaining residuals.
  {
    const auto per = residualsPx(p, res.state, s, true);
    const double sigma1 = std::max(1e-3, robustSd(pooled(per)));
    std::vector<int> lab = selected;
    r.plane_tracks.assign(m, 0);
    r.plane_relabelled.assign(m, 0);
    for (std::size_t i = 0; i < per.size(); ++i) {
      double ss = 0;
      for (double x : per[i]) ss += x * x;
      const double rms = per[i].empty() ? 0.0 : std::sqrt(ss / per[i].size());
      const int j = p.data.labels[i];
      ++r.plane_tracks[j];
      if (rms > ro.outlier_sigmas * sigma1) {
        lab[p.data.point_ids[i]] = -1;
        ++r.relabelled;
        ++r.plane_relabelled[j];
      }
    }
    if (r.relabelled > 0) {
      Problem q = build(lab, &res.state, &p.data.point_ids);
      PlaneBatchResult res2;
      const std::array<bool, 4> free_before = r.camera_free;
      const bool readout_before = r.readout_free;
      const std::size_t why_before = why.size();
      bool solved = static_cast<int>(q.data.point_ids.size()) >= 5 && solve(q, sigma1, &res2);
      for (int round = 0; round < 3 && solved && holdImplausible(res2.state); ++round) {
        // Without the outliers the data pull the camera where no camera is (box.mp4's windows
        // 14 and 18: the principal point 195 px below the centre): held, as in stage 2, and
        // solved again from there with the held components at the nominal camera.
        r.iterations += res2.iterations;
        bo.camera_free = r.camera_free;
        bo.readout_free = r.readout_free;
        q.start = res2.state;
        resetHeld(&q.start);
        solved = solve(q, sigma1, &res2);
      }
      if (!solved) {  // the previous solve stands, with its camera
        r.camera_free = free_before;
        r.readout_free = readout_before;
        bo.camera_free = r.camera_free;
        bo.readout_free = r.readout_free;
        why.resize(why_before);
      }
      if (solved) {
        p = std::move(q);
        res = std::move(res2);
        sigma_loss = sigma1;
        r.iterations += res.iterations;
        for (int id = 0; id < n_ids; ++id)
          if (lab[id] == -1 && selected[id] >= 0) r.labels[id] = -1;
      } else {
        r.relabelled = 0;  // keep the previous solve
        r.plane_relabelled.assign(m, 0);
      }
    }
  }
  std::array<bool, 4> bound_camera = r.camera_free;
  if (pp_held_undetermined) bound_camera[0] = bound_camera[1] = true;  // its prior in the bound
  // With the principal point held after the distortion's solve and no track relabelled, the
  // state and the bound's parameters are those of the decision's bound: it is the final one.
  const bool bound_readout = r.readout_free;
  const bool reuse = b_held && r.relabelled == 0 && bound_camera == wanted && bound_readout == wanted_readout;
  PlaneBatchBound b = reuse ? std::move(*b_held) : spreadAndBound(res.state, bound_camera, bound_readout);
  if (ro.hold_undetermined_principal_point && b.ok && r.camera_free[0]) {
    // Judged determined before the release, but not at the final optimum (the outliers gone, the
    // camera released): held there as well, and the rest solved again from the nominal centre.
    double sx = 0, sy = 0;
    if (ppUndetermined(b, &sx, &sy)) {
      const Eigen::Vector2d at(cx + s * res.state.camera[0], cy + s * res.state.camera[1]);
      const std::array<bool, 4> free_before = r.camera_free;
      r.camera_free[0] = r.camera_free[1] = false;
      bo.camera_free = r.camera_free;
      p.start = res.state;
      resetHeld(&p.start);
      PlaneBatchResult rh;
      if (solve(p, sigma_loss, &rh)) {
        r.iterations += rh.iterations;
        res = std::move(rh);
        why.push_back(fmt::format("principal point not determined (sd {:.1f}, {:.1f} px at ({:.0f}, {:.0f}) px); held at "
                                  "({:.1f}, {:.1f}) with its prior sd {:.0f} px in the bound",
                                  sx, sy, at.x(), at.y(), cx, cy, s * bo.camera_prior_sd[0]));
        b = spreadAndBound(res.state, bound_camera, bound_readout);
      } else {
        r.camera_free = free_before;
        bo.camera_free = r.camera_free;
      }
    }
  }
  const PlaneBatchState& st = res.state;
  r.at_iteration_limit = res.at_iteration_limit;
  if (r.at_iteration_limit)
    why.push_back(fmt::format("the last solve stopped at its iteration limit ({}) with the cost still falling: a flat valley, "
                              "its figures are where it stopped, not an optimum",
                              ro.max_iterations));
  r.stalled = res.stalled;
  if (r.stalled)
    why.push_back("the last solve stopped where its steps could not be evaluated (a point carried behind a camera or past its "
                  "plane's horizon) with the cost still falling: its figures are where it stopped, not an optimum");
  if (!b.ok) {
    r.message = "the refinement converged but its uncertainty could not be computed: " + b.message;
    return r;
  }
  r.null_dim = b.null_dim;
  r.clustered_focal_factor = b.clustered_beta;
  r.clustered_focal_ratio = b.clustered_beta_ratio;
  r.clustered_plane_factor = b.clustered_N;
  r.jackknife_plane_factor = b.jackknife_N;
  r.undetermined_frames = b.skipped_frames;
  // Determinacy (rsfm/determinacy.hpp).
  const double beta = st.beta, f = s / beta;
  const double focal_sd = known_focal ? 0.0 : b.beta_estimable ? s * std::sqrt(std::max(0.0, b.var_beta)) / (beta * beta) : INFINITY;
  // An optimum with beta <= 0 (a focal length through infinity to the negative side: a camera
  // that only turns, with noise) determines nothing, however its relative sd reads.
  r.focal_determined = known_focal || (b.beta_estimable && beta > 0 && focal_sd / f <= kDeterminedFocalRelSd);
  if (!r.focal_determined)
    why.push_back(!b.beta_estimable ? "the focal length is in the null space (e.g. translation only: the affine ambiguity)"
                  : !(beta > 0)     ? fmt::format("the focal length's optimum is not positive (beta {:.3g})", beta)
                                    : fmt::format("focal length sd {:.1f} % (limit {:.0f} %)", 100 * focal_sd / f,
                                                  100 * kDeterminedFocalRelSd));
  // Wald statistics of each frame's translation (its centre of projection) and rotation against
  // their covariances: far beyond any test level (chi2 > 1000 on 3 dof), the likelihood ratio
  // tests below would be too, and their extra solves are skipped.
  double wald_t = 0, wald_r = 0;
  for (int k = 1; k < F; ++k) {
    if (b.cov_motion.size() <= static_cast<std::size_t>(k) || b.cov_motion[k].isZero(0.0)) continue;
    const MotionWald w = motionWald(st.R[k], st.t[k], beta, b.cov_motion[k]);
    wald_t = std::max(wald_t, w.translation);
    wald_r = std::max(wald_r, w.rotation);
  }
  constexpr double kObvious = 1000.0;
  r.wald_translation_chi2 = wald_t;
  r.wald_rotation_chi2 = wald_r;
  r.rotation_lr = r.translation_lr = INFINITY;  // skipped: obviously significant
  // Is there a translation at all? Without one (a camera turning about its centre of projection)
  // the planes are not determined whatever their bound says: an optimum that fitted a translation
  // to the noise sees structure in it. Likelihood ratio against the degenerate model (every frame
  // a pure rotation, the same camera): its extra residual, in units of the noise variance
  // (inflated for the correlation), against chi2 with the plane model's extra parameters
  // (3 per frame for the translation, 3m - 1 for the planes) at 0.1 %: structure is claimed only
  // on strong evidence.
  if (wald_t <= kObvious) {
    PlaneBatchOptions ro_opt = bo;
    ro_opt.rotation_only = true;
    // Started from the plane model's rotations, a pure rotation that fits converges in a few
    // iterations; one that does not leaves a residual far beyond the test in as few.
    ro_opt.max_iterations = 15;
    p.start = st;
    p.data.sigma_uv = sigma_final / s;
    phase = "the test against a pure rotation";
    const PlaneBatchResult rot = solvePlaneBatch(p.data, p.start, ro_opt);
    double ss_rot = 0;
    for (int k = 0; k < F; ++k)
      for (std::size_t j = 0; j < p.data.frames[k].size(); ++j) {
        const Observation& o = p.data.frames[k][j];
        Eigen::Vector2d rr;
        bool projected = true;
        if (k == 0)
          planeBatchReferenceResidual(rot.state.ref[o.id], rot.state.beta, rot.state.camera, o.uv, 1.0, &rr, nullptr, nullptr,
                                      nullptr);
        else
          projected = planeBatchRotationResidual(Eigen::Vector3d::Zero(), rot.state.R[k], rot.state.beta, rot.state.ref[o.id],
                                                 o.uv, 1.0, &rot.state.camera, &rr, nullptr, nullptr, nullptr,
                                                 nullptr) == MeasureStatus::Ok;
        if (projected)
          rr += rot.state.readout * p.data.shift(k, j);  // a rolling shutter's (0 without one)
        else
          rr = Eigen::Vector2d::Constant(1e3 / s);
        ss_rot += rr.squaredNorm() * s * s;
      }
    const int dof = 3 * (F - 1) + 3 * m - 1;
    r.rotation_lr = rot.converged ? (ss_rot - ss) / (r.sigma_px * r.sigma_px * r.correlation_inflation) : INFINITY;
    // Both tests must find the translation (issue 17): the likelihood ratio over the whole
    // sequence, and the largest per-frame Wald statistic at the same level corrected for the F - 1
    // frames tested (Bonferroni). On a camera that only turns, errors the noise model does not
    // capture (correlated across tracks: interpolation, texture) pushed the likelihood ratio of
    // Calway's patch centres just past its quantile (406 against 375 on 299 dof) while no single
    // frame showed a translation (Wald 15 against 26): the planes it then "determined" were 40 deg
    // off with a 3 deg sd.
    const double wald_quantile = chi2Quantile(1.0 - 0.001 / std::max(1, F - 1), 3.0);
    const bool lr_significant = r.rotation_lr > chi2Quantile(0.999, dof);
    r.translation_significant = lr_significant && wald_t > wald_quantile;
    if (!r.translation_significant)
      why.push_back(fmt::format("the camera only turns: a pure rotation fits as well (likelihood ratio {:.0f} on {} dof, "
                                "limit {:.0f}; largest frame translation Wald chi2 {:.1f}, limit {:.1f}), which shows no "
                                "structure",
                                r.rotation_lr, dof, chi2Quantile(0.999, dof), wald_t, wald_quantile));
  }
  // Is there a rotation at all? Without one (a camera that only translates) the focal length and
  // the planes' tilt are one null direction (the affine ambiguity): any focal length fits. The
  // same likelihood ratio test against a translation-only fit (every frame's rotation held at
  // the identity), on 3 dof per frame at 0.1 %.
  bool rotates = true;
  if (!known_focal && wald_r <= kObvious) {
    PlaneBatchOptions to = bo;
    to.translation_only = true;
    to.max_iterations = 15;
    p.start = st;
    for (auto& R : p.start.R) R.setIdentity();
    phase = "the test against a translation alone";
    const PlaneBatchResult tr = solvePlaneBatch(p.data, p.start, to);
    double ss_tr = 0;
    for (double x : pooled(residualsPx(p, tr.state, s, true))) ss_tr += x * x;
    r.translation_lr = tr.converged ? (ss_tr - ss) / (r.sigma_px * r.sigma_px * r.correlation_inflation) : INFINITY;
    rotates = r.translation_lr > chi2Quantile(0.999, 3.0 * (F - 1));
    if (!rotates) {
      r.focal_determined = false;
      why.push_back(fmt::format("the camera only translates: no rotation is needed (likelihood ratio {:.0f} on {} dof), so "
                                "the focal length and the planes' tilt are not determined (the affine ambiguity)",
                                r.translation_lr, 3 * (F - 1)));
    }
  }
  if (!r.focal_determined && !known_focal) {
    // The interval the data support: the 95 % interval of beta (in which the model is nearly
    // linear: [AS99] eq. 7) mapped to f = s / beta, widened by the profile below; unbounded when
    // nothing rotates or beta is in the null space. [lo, hi] is where the profile searches.
    const double lo = 0.3 * fmax, hi = 3.0 * fmax;
    const double sb = std::sqrt(std::max(0.0, b.var_beta));
    const double blo = beta - 1.96 * sb, bhi = beta + 1.96 * sb;
    // A side the data do not limit is unbounded (0 below, infinity above; null in summary.json):
    // nothing rotating, beta in the null space, a linear interval reaching beta <= 0, or a profile
    // still supported at the last step it explored on that side. The range 0.3-3 x the larger
    // image side is where the profile searches, not a bound the data set (tele-translate's 2500 px
    // on a 640 px image lies beyond it).
    r.focal_interval_px = rotates && b.beta_estimable
                              ? std::array<double, 2>{s / bhi, blo > 0 ? s / blo : INFINITY}
                              : std::array<double, 2>{0.0, INFINITY};
    // An interval inverted or wholly beyond the range (the optimum far beyond it, e.g. 441000 px,
    // where the linearization says nothing): unbounded.
    if (!((*r.focal_interval_px)[0] <= (*r.focal_interval_px)[1]) || (*r.focal_interval_px)[0] > hi)
      r.focal_interval_px = std::array<double, 2>{0.0, INFINITY};
    if (rotates && b.beta_estimable) {
      // That interval is local to this optimum. The focal length's profile over the whole range
      // widens it where the data fit as well elsewhere: from the optimum outwards, one solve per
      // step of a log grid (12 steps over the range) with beta held and the rest started from the
      // previous step's solution (continuation), the residual's increase over the optimum's in
      // units of the inflated noise variance against chi2(1) at 95 %. Every grid focal within it
      // joins the interval, with the half-step to its neighbours (the boundary lies between).
      // A focal length that fits better than the estimate beyond the test means the estimate is
      // a local optimum: the interval is then the whole range, and `why` says so (test
      // Refine.AnUndeterminedFocalLengthGetsItsProfileInterval: 152 px estimated, 223 px fits
      // better by 28, the truth 512 px). The profile cannot see a bias the model does not hold
      // (webcam-object: 1760 px, the render's 600 px fits worse by 110 with k1 = -0.1 not
      // determinable from its 21 tracks).
      constexpr int kSteps = 12;
      const double ratio = std::pow(hi / lo, 1.0 / kSteps);
      const double unit = r.sigma_px * r.sigma_px * r.correlation_inflation;
      const double limit = chi2Quantile(0.95, 1.0);
      PlaneBatchOptions po = bo;
      // The profile maximizes over every nuisance parameter, a principal point held because the
      // data do not determine it included (free with its prior, as before the hold): held, the
      // profile would be conditional on the centre and narrower than the data allow.
      po.camera_free = bound_camera;
      po.hold_beta = true;
      po.max_iterations = 50;
      po.compute_covariance = false;
      p.data.sigma_uv = sigma_final / s;
      std::vector<std::pair<double, double>> profile;  // (focal, residual increase over the optimum's)
      std::vector<std::vector<Eigen::Vector3d>> profile_N;  // the planes at each step
      // The profile's own value at the estimate is its baseline (the optimum's residual when
      // nothing was held; lower when the principal point was: it is free here).
      PlaneBatchState base = st;
      double ss_base = ss;
      if (po.camera_free != r.camera_free) {
        phase = "the focal length's profile at the estimate";
        const PlaneBatchResult pr = solvePlaneBatch(p.data, st, po);
        r.iterations += pr.iterations;
        double ssk = 0;
        for (double x : pooled(residualsPx(p, pr.state, s, true))) ssk += x * x;
        if (std::isfinite(ssk)) ss_base = ssk, base = pr.state;
      }
      // A side where a step's solve failed (Ceres found no usable solution from there: e.g. the
      // distortion of the last step cannot map this focal length's projections) is not explored
      // beyond it, and nothing on it is excluded (ViSP Castle-simu, 18 frames, 20 tracks: the
      // steps below the 918-px estimate failed at once with k1 0.58, their cost at the start
      // was read as the profile's, and "740-1209 px" left out the true 700 px). A step stopped
      // at its iteration limit is kept: its increase is an upper bound, but one of thousands of
      // chi2 units is not undone by more iterations (taken as supported, box.mp4@2's interval
      // went from 533-652 px to 363 px and above).
      bool unexplored[2] = {false, false};
      for (const double step : {1.0 / ratio, ratio}) {
        PlaneBatchState cur = base;
        for (double fk = f * step; fk >= lo / std::sqrt(ratio) && fk <= hi * std::sqrt(ratio); fk *= step) {
          cur.beta = s / fk;
          phase = fmt::format("the focal length's profile at {:.0f} px", fk);
          const PlaneBatchResult pr = solvePlaneBatch(p.data, cur, po);
          r.iterations += pr.iterations;
          if (!pr.converged) {
            unexplored[step > 1.0] = true;
            why.push_back(fmt::format("the focal length's profile has no solution at {:.0f} px: nothing {} it is excluded", fk,
                                      step > 1.0 ? "above" : "below"));
            break;
          }
          double ssk = 0;
          for (double x : pooled(residualsPx(p, pr.state, s, true))) ssk += x * x;
          if (!std::isfinite(ssk)) break;
          profile.emplace_back(fk, (ssk - ss_base) / unit);
          profile_N.push_back(pr.state.N);
          cur = pr.state;
        }
      }
      double best_f = f, best_d = 0.0;
      for (const auto& [fk, d] : profile)
        if (d < best_d) best_d = d, best_f = fk;
      std::array<double, 2>& iv = *r.focal_interval_px;
      r.focal_profile_best_px = best_f;
      if (best_d < -limit) {
        // The solver stopped in a local optimum, so the search is not global either: no part of
        // the range can be excluded (a profile around the better point excluded the truth on
        // the test's seed 32: 203-246 px, truth 512 px).
        iv = {0.0, INFINITY};
        why.push_back(fmt::format("the estimate {:.0f} px is a local optimum ({:.0f} px fits better by {:.1f} in chi2 units): "
                                  "no focal length is excluded",
                                  f, best_f, -best_d));
      } else {
        double f_min = INFINITY, f_max = 0.0, d_at_min = 0.0, d_at_max = 0.0;  // the steps explored farthest out
        for (const auto& [fk, d] : profile) {
          if (d <= limit) {
            iv[0] = std::min(iv[0], fk / std::sqrt(ratio));
            iv[1] = std::max(iv[1], fk * std::sqrt(ratio));
          }
          if (fk < f_min) f_min = fk, d_at_min = d;
          if (fk > f_max) f_max = fk, d_at_max = d;
        }
        if ((!profile.empty() && d_at_min <= limit) || unexplored[0]) iv[0] = 0.0;
        if ((!profile.empty() && d_at_max <= limit) || unexplored[1]) iv[1] = INFINITY;
      }
      // The planes over the focal lengths the data support: a normal that turns with the focal
      // length along the profile is no better known than the focal length (the disabled test
      // PlaneStart.DISABLED_TheBranchAndTheFocalMinimumAreChosenRight: 1153 px estimated, the
      // plane 49 deg off and called determined by its bound at that focal length). Its largest
      // turn from the estimate over the supported steps (every step when no focal length is
      // excluded) is taken as a 95 % half-width and added to the bound's normal variance below.
      r.plane_profile_spread_deg.assign(m, 0.0);
      for (std::size_t i = 0; i < profile.size(); ++i) {
        if (!(best_d < -limit) && profile[i].second > limit) continue;
        for (int j = 0; j < m && j < static_cast<int>(profile_N[i].size()); ++j) {
          const double c = std::abs(profile_N[i][j].normalized().dot(st.N[j].normalized()));
          r.plane_profile_spread_deg[j] = std::max(r.plane_profile_spread_deg[j], std::acos(std::min(1.0, c)) * kRadToDeg);
        }
      }
    }
  }
  // The normals' covariance with that spread added (isotropic in the tangent plane):
  // sd_total^2 = sd_bound^2 + (spread / 1.96)^2.
  std::vector<Eigen::Matrix3d> cov_N = b.cov_N;
  for (int j = 0; j < m && j < static_cast<int>(r.plane_profile_spread_deg.size()); ++j) {
    const Eigen::Vector3d N = st.N[j], n = N.normalized();
    const double v = std::pow(r.plane_profile_spread_deg[j] / kRadToDeg / 1.96, 2);
    cov_N[j] += 0.5 * v * N.squaredNorm() * (Eigen::Matrix3d::Identity() - n * n.transpose());
  }
  r.plane_horizon_tracks = p.horizon;
  for (int j = 0; j < m; ++j) {
    const double sd = directionRmsAngle(st.N[j], cov_N[j]) * kRadToDeg;
    // A plane that lost most of its tracks as outliers was not one surface (two faces one
    // homography carried at the pair frame, edges, shadows): what is left of it says little.
    const bool mixed = j < static_cast<int>(r.plane_relabelled.size()) && 2 * r.plane_relabelled[j] > r.plane_tracks[j];
    const int left = j < static_cast<int>(r.plane_tracks.size()) ? r.plane_tracks[j] - r.plane_relabelled[j] : 0;
    // A plane with a direction that one of its tracks alone decides (the jackknife's leverage 1,
    // PlaneBatchBound::jackknife_N) has nothing that tests it there.
    const bool single = j < static_cast<int>(b.jackknife_N.size()) && !std::isfinite(b.jackknife_N[j]);
    const bool det =
        r.translation_significant && rotates && b.normal_estimable[j] && sd <= kDeterminedNormalSdDeg && !mixed && !single;
    r.plane_determined.push_back(det);
    if (mixed)
      why.push_back(fmt::format("plane {}: {} of its {} tracks were off it (not one surface)", j, r.plane_relabelled[j],
                                r.plane_tracks[j]));
    else if (!det && p.horizon[j] > 0 && std::count(p.data.labels.begin(), p.data.labels.end(), j) == 0)
      why.push_back(fmt::format("plane {}: seen edge-on from the reference frame (its tracks' reference positions within "
                                "{:.1f} px of its horizon line there, where their depth is not determined): its {} tracks left "
                                "out of the refinement",
                                j, kHorizonSigmas * fo.sigma_px, p.horizon[j]));
    else if (single && r.translation_significant && rotates && b.normal_estimable[j])
      why.push_back(fmt::format("plane {}: one of its tracks alone decides its normal (no other track tests it)", j));
    else if (!det && r.translation_significant && rotates)
      why.push_back(b.normal_estimable[j] ? fmt::format("plane {} normal sd {} deg (limit {:.0f} deg){}", j,
                                                        sd > 180.0 ? std::string("above 180") : fmt::format("{:.1f}", sd), kDeterminedNormalSdDeg,
                                                        j < static_cast<int>(r.plane_profile_spread_deg.size()) &&
                                                                r.plane_profile_spread_deg[j] > 0
                                                            ? fmt::format(", turning {:.1f} deg over the supported focal lengths",
                                                                          r.plane_profile_spread_deg[j])
                                                            : "")
                                          : left < 3 ? fmt::format("plane {}: {} of its tracks left (too few to place it)", j, left)
                                                     : fmt::format("plane {} is in the null space (e.g. pure rotation: no parallax)", j));
  }
  for (int c = 0; c < 4; ++c) {
    if (!r.camera_free[c]) continue;
    const double sd = std::sqrt(std::max(0.0, b.cov_camera(c, c))) * (c < 2 ? s : 1.0);
    r.camera_determined[c] = b.camera_estimable[c] && sd <= (c < 2 ? pp_limit : kDeterminedDistortionSd);
  }
  if (r.camera_free[0] && !(r.camera_determined[0] && r.camera_determined[1]))
    why.push_back(fmt::format("principal point not determined (sd {:.1f}, {:.1f} px)", s * std::sqrt(std::max(0.0, b.cov_camera(0, 0))),
                              s * std::sqrt(std::max(0.0, b.cov_camera(1, 1)))));
  for (int c = 2; c < 4; ++c)
    if (r.camera_free[c] && !r.camera_determined[c])
      why.push_back(fmt::format("k{} not determined (sd {:.3f}, limit {})", c - 1, std::sqrt(std::max(0.0, b.cov_camera(c, c))),
                                kDeterminedDistortionSd));
  if (r.readout_free) {
    r.readout_sd = b.readout_index >= 0 ? std::sqrt(std::max(0.0, b.var_readout)) : INFINITY;
    r.readout_determined = b.readout_estimable && r.readout_sd <= kDeterminedReadoutSd;
    if (!r.readout_determined)
      why.push_back(fmt::format("rolling shutter readout not determined (sd {:.2f} frame intervals, limit {})", r.readout_sd,
                                kDeterminedReadoutSd));
  }
  r.readout = st.readout;
  for (std::size_t i = 0; i < why.size(); ++i) r.why += (i ? "; " : "") + why[i];
  r.camera = st.camera;
  r.cov_camera = b.cov_camera;
  r.principal_point_px = Eigen::Vector2d(cx + s * st.camera[0], cy + s * st.camera[1]);
  r.cov_motion = b.cov_motion;
  // The refined sequence in the filter's form.
  TrackFilterResult& out = r.state;
  out.scale_px = s;
  out.planes = m;
  out.plane_tracks.assign(m, 0);
  out.plane_new_tracks.assign(m, 0);
  out.transfer_failed = p.transfer_failed;  // the tracks the refinement could not take
  std::vector<double> plane_ss(m, 0.0);
  std::vector<long> plane_n(m, 0);
  for (std::size_t i = 0; i < p.data.point_ids.size(); ++i) {
    const int l = p.data.labels[i];
    ++out.plane_tracks[l];
    if (spans[p.data.point_ids[i]].first > 0) ++out.plane_new_tracks[l];
    for (double x : per[i]) plane_ss[l] += x * x, ++plane_n[l];
  }
  for (int j = 0; j < m; ++j) out.plane_rms_px.push_back(plane_n[j] ? std::sqrt(plane_ss[j] / plane_n[j]) : 0.0);
  std::vector<double> frame_ss(F, 0.0);
  std::vector<int> frame_n(F, 0);
  {
    std::vector<std::size_t> cursor(p.data.labels.size(), 0);
    for (int k = 0; k < F; ++k)
      for (const Observation& o : p.data.frames[k]) {
        const auto& v = per[o.id];
        frame_ss[k] += v[cursor[o.id]] * v[cursor[o.id]] + v[cursor[o.id] + 1] * v[cursor[o.id] + 1];
        cursor[o.id] += 2;
        ++frame_n[k];
      }
  }
  for (int k = 0; k < F; ++k) {
    TrackFrame tf;
    tf.frame = online.frames[k].frame;
    tf.R = st.R[k];
    tf.t = Eigen::Vector3d(st.t[k].x(), st.t[k].y(), st.t[k].z() / beta);
    tf.beta = beta;
    tf.var_beta = b.beta_estimable ? b.var_beta : 0.0;
    tf.N = st.N;
    tf.cov_N = cov_N;
    tf.cov_beta_N = b.cov_beta_N;
    // The planes' cross-covariances, for the angles between them: the bound's. The profile's turn
    // enters each plane's own block above only: an angle takes both planes' turns as independent.
    tf.cov_N_pair = b.cov_N_pair;
    tf.observed = tf.used = frame_n[k];
    tf.rms_px = frame_n[k] ? std::sqrt(frame_ss[k] / (2.0 * frame_n[k])) : 0.0;
    out.frames.push_back(tf);
  }
  out.plane_of_label = online.plane_of_label;
  out.plane_first_frame = online.plane_first_frame;  // where the filter placed each plane (one that came into view later)
  out.passes = 1;
  out.pass_focal_px = {f};
  out.pass_N = {st.N};
  r.ok = true;
  r.message = fmt::format("camera pp ({:.1f}, {:.1f}) +- ({:.1f}, {:.1f}) px, k1 {:.4f} +- {:.4f}, k2 {:.4f} +- {:.4f}; {} ({} iterations; {} tracks, {} observations, {} relabelled outliers; residual sd {:.3f} px)",
                          r.principal_point_px.x(), r.principal_point_px.y(), s * std::sqrt(std::max(0.0, r.cov_camera(0, 0))),
                          s * std::sqrt(std::max(0.0, r.cov_camera(1, 1))), r.camera[2], std::sqrt(std::max(0.0, r.cov_camera(2, 2))),
                          r.camera[3], std::sqrt(std::max(0.0, r.cov_camera(3, 3))), res.message, r.iterations, r.tracks,
                          r.observations, r.relabelled, r.sigma_px);
  if (r.readout_free) r.message += fmt::format(", rolling shutter readout {:.3f} +- {:.3f} frame intervals", r.readout, r.readout_sd);
  r.message += fmt::format(", correlation inflation {:.1f}", r.correlation_inflation);
  r.message += fmt::format(", sd widened by the track-clustered check: focal x{:.2f}, planes x{:.2f}", r.clustered_focal_factor,
                           fmt::join(r.clustered_plane_factor, "/x"));
  if (!r.jackknife_plane_factor.empty()) {
    std::vector<std::string> jk;
    for (double x : r.jackknife_plane_factor) jk.push_back(std::isfinite(x) ? fmt::format("x{:.2f}", x) : std::string("one track decides"));
    r.message += fmt::format(", planes' track jackknife {}", fmt::join(jk, "/"));
  }
  r.seconds = steadySeconds() - t_start;
  return r;
}

}  // namespace rsfm
