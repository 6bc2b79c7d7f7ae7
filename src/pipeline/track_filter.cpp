#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/camera.hpp"
#include "rsfm/rotation.hpp"
#include "rsfm/chi2.hpp"
#include "rsfm/determinacy.hpp"
#include "rsfm/residual_correlation.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/units.hpp"

#include <fmt/format.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "rsfm/models/plane_model.hpp"
#include "rsfm/models/point_model.hpp"

namespace rsfm {

const char* toString(TrackModel m) {
  return m == TrackModel::Point ? "point" : m == TrackModel::Plane ? "plane" : "planes";
}

bool parseTrackModel(const std::string& s, TrackModel* m) {
  if (s == "point") *m = TrackModel::Point;
  else if (s == "plane") *m = TrackModel::Plane;
  else if (s == "planes") *m = TrackModel::Planes;
  else return false;
  return true;
}

FilterOptions TrackFilterOptions::defaultFilter() {
  FilterOptions f;
  f.reference = ReferenceModel::Conditional;
  f.iterate_after_frames = 10;  // with iterations > 1 (docs/filter.md)
  f.mismatch_retries = 3;       // a fast or sudden motion: process noise x10, x100, x1000 (docs/estimate.md)
  f.adapt.enabled = true;       // the process noise follows the measured motion (TrackFilterOptions::q_from_data)
  // Q = 4 x the matched second moment (an sd twice the motion measured: a frame's motion may
  // change by its own size). Measured on the regime suite (docs/regimes.md): 1 / 4 / 16 gave the
  // filter alone a median focal error of 1.38 / 1.06 / 1.07 % and 9 / 13 / 12 of 75 normals
  // inside their 95 % intervals, the refinement the same figures within 0.01 %.
  f.adapt.inflation = 4.0;
  return f;
}

namespace {

/// The filter's posterior residuals along its tracks, for the calibration of its reported sds
/// (TrackFilterResult::sd_calibration).
struct ResidualSeries {
  std::vector<std::vector<double>> per;  ///< by filter point index: (x, y) in px, frame by frame
  double ss = 0.0;                       ///< sum of squares (px^2)
  double dof = 0.0;  ///< 2 per accepted observation less each frame's 6 motion parameters
};

/// Posterior residuals of the accepted observations, accumulated per group (plane, or 0), and
/// along each track in `series`.
template <class Model>
void accumulateResiduals(const RecursiveFilter<Model>& f, const std::vector<Observation>& obs, const FrameStats& fs,
                         const std::vector<int>& group_of_obs, double s, std::vector<double>* sum2,
                         std::vector<long>* count, double* frame_rms, ResidualSeries* series) {
  std::vector<Observation> acc;
  std::vector<int> grp;
  for (size_t b = 0; b < fs.used.size(); ++b) {
    if (b < fs.update.gated_mask.size() && fs.update.gated_mask[b]) continue;
    acc.push_back(obs[fs.used[b]]);
    grp.push_back(group_of_obs[fs.used[b]]);
  }
  BlockBatch batch;
  std::vector<int> used;
  int invalid = 0;
  MeasureStatus problem = MeasureStatus::Ok;
  f.model().linearize(f.ekf().x(), f.rotation(), acc, 1.0, nullptr, &batch, &invalid, &problem, &used);
  double fs2 = 0.0;
  for (size_t b = 0; b < used.size(); ++b) {
    const Eigen::Vector2d r = batch.residual.template segment<2>(2 * b) * s;
    const double r2 = r.squaredNorm();
    (*sum2)[grp[used[b]]] += r2;
    (*count)[grp[used[b]]] += 2;
    fs2 += r2;
    const auto id = static_cast<std::size_t>(acc[used[b]].id);
    if (id >= series->per.size()) series->per.resize(id + 1);
    series->per[id].push_back(r.x());
    series->per[id].push_back(r.y());
  }
  *frame_rms = used.empty() ? 0.0 : std::sqrt(fs2 / (2.0 * used.size()));
  series->ss += fs2;
  series->dof += std::max(0.0, 2.0 * static_cast<double>(used.size()) - 6.0);
}

/// The filter's covariance assumes independent measurement errors of sd `sigma_px`. Its tracks'
/// residuals say otherwise: scaled by the along-track correlation's inflation c
/// (rsfm/residual_correlation.hpp, as the refinement's bound) and by (sigma_res / sigma_px)^2 when
/// the residuals' sd sigma_res exceeds the sd assumed, every frame's covariance of beta and the
/// planes after the reference frame. A smaller sigma_res does not narrow it: the process noise's
/// part of the covariance does not scale with the measurement noise.
void calibrateSds(const ResidualSeries& series, double sigma_px, TrackFilterResult* res) {
  TrackFilterResult::SdCalibration& c = res->sd_calibration;
  c.filter_sigma_px = sigma_px;
  if (!(series.dof > 0) || !(sigma_px > 0)) return;
  c.residual_sd_px = std::sqrt(series.ss / series.dof);
  c.correlation_inflation = alongTrackCorrelationInflation(series.per);
  c.variance_factor = c.correlation_inflation * std::max(1.0, std::pow(c.residual_sd_px / sigma_px, 2));
  if (!std::isfinite(c.variance_factor)) {
    c.variance_factor = 1.0;
    return;
  }
  c.applied = true;
  for (std::size_t k = static_cast<std::size_t>(res->still_frames) + 1; k < res->frames.size(); ++k) {
    TrackFrame& tf = res->frames[k];
    tf.var_beta *= c.variance_factor;
    tf.cov_motion *= c.variance_factor;
    for (auto& C : tf.cov_N) C *= c.variance_factor;
    for (auto& C : tf.cov_beta_N) C *= c.variance_factor;
    for (auto& C : tf.cov_N_pair) C *= c.variance_factor;
  }
}

std::string stopReason(int frame, const FrameStats& fs, int min_points) {
  if (fs.health & kInvalidRotation) return "frame " + std::to_string(frame) + ": the rotation update left dq's domain (|omega| >= 2)";
  if (!fs.update.applied && fs.health == kHealthy && (fs.update.health & kTooFewMeasurements))
    return "frame " + std::to_string(frame) + ": only " + std::to_string(fs.update.used) + " of " +
           std::to_string(fs.update.blocks) + " observations accepted" +
           (fs.q_scale > 1.0 ? " (also with the process noise x" + std::to_string(static_cast<long>(fs.q_scale)) + ")" : "") +
           ", the model needs " + std::to_string(min_points);
  const std::uint32_t h = fs.health != kHealthy ? fs.health : fs.update.health;
  return "frame " + std::to_string(frame) + ": " + describeHealth(h);
}

/// The tracks on the planes ran out: fewer observations offered than the model needs (not a
/// failure of the filter: the sequence ends there for it).
constexpr int kMinFramesBeforeEnd = 10;  // an estimate of fewer frames is no estimate: stop instead

std::string ranOutNote(int frame, int offered, int min_points) {
  return "the tracks on the planes ran out at frame " + std::to_string(frame) + " (" + std::to_string(offered) +
         " observations, the model needs " + std::to_string(min_points) + "): the estimate ends at frame " +
         std::to_string(frame - 1);
}

bool ranOut(const FrameStats& fs, int min_points) {
  return !fs.update.applied && fs.health == kHealthy && (fs.update.health & kTooFewMeasurements) &&
         fs.update.blocks < min_points;
}

/// After one step: the reason to stop (empty: go on). Numerical trouble from the EKF, too few
/// accepted observations, or beta leaving the positive range.
template <class Model>
std::string afterStep(const RecursiveFilter<Model>& f, const FrameStats& fs, int frame) {
  if (!fs.ok()) return stopReason(frame, fs, Model::kMinPoints);
  if (!(f.beta() > 0.0))
    return "frame " + std::to_string(frame) + ": the focal length estimate left the positive range (beta = " +
           std::to_string(f.beta()) + ")";
  return "";
}

/// D of TrackFilterOptions::q_from_data: the 90th percentile over the frames of the median
/// displacement (px) between consecutive frames of the tracks `enters` admits (frames with fewer
/// than 5 such tracks are skipped; 0 when none is left).
template <class Enters>
double imageMotionPx(const Tracks& tracks, const Enters& enters) {
  std::vector<double> per_frame, d;
  for (int k = 1; k < tracks.numFrames(); ++k) {
    d.clear();
    for (const TrackPoint& p : tracks.frames[k]) {
      if (!enters(p.id)) continue;
      const TrackPoint* q = tracks.find(k - 1, p.id);
      if (q) d.push_back((p.px - q->px).norm());
    }
    if (d.size() < 5) continue;
    std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
    per_frame.push_back(d[d.size() / 2]);
  }
  if (per_frame.empty()) return 0.0;
  const std::size_t i = std::min(per_frame.size() - 1, static_cast<std::size_t>(0.9 * per_frame.size()));
  std::nth_element(per_frame.begin(), per_frame.begin() + i, per_frame.end());
  return per_frame[i];
}

/// Motion, beta and the update's counts of one frame.
/// `depth`: the main plane's starting depth, the unit of q_trans_sd_rel.
template <class Model>
TrackFrame frameOf(const RecursiveFilter<Model>& f, const FrameStats& fs, int frame, int observed, double depth) {
  TrackFrame tf;
  tf.frame = frame;
  tf.R = f.rotation();
  tf.t = f.translation();
  tf.beta = f.beta();
  tf.var_beta = f.ekf().P()(idx::kBeta, idx::kBeta);
  tf.cov_motion = f.ekf().P().template topLeftCorner<6, 6>();
  tf.observed = observed;
  tf.used = fs.update.used;
  tf.gated = fs.update.gated;
  tf.nis_per_dof = fs.update.nis_dof > 0 ? fs.update.nis / fs.update.nis_dof : 0.0;
  tf.q_scale = fs.q_scale;
  const FilterOptions& fo = f.options();
  tf.q_omega_sd_deg = std::sqrt(fo.q_motion[3] * fs.q_rotation_scale) * 180.0 / M_PI;
  tf.q_trans_sd_rel = std::sqrt(fo.q_motion[0] * fs.q_translation_scale) / depth;
  return tf;
}

/// A late plane within this angle (deg) of a plane in the state, whose points lie on that plane
/// within twice their scatter about their own fit plus this fraction of its distance, is that
/// plane seen again: its tracks join it (TrackFilterOptions::late_planes).
constexpr double kSamePlaneDeg = 3.0, kSamePlaneResidual = 0.02;

/// The sd (rad) of the direction of N under covariance C: the larger principal sd of C projected
/// on the plane orthogonal to N, over |N| (the tangent of the unit normal, (I - n n^T) / |N|).
double directionSd(const Eigen::Vector3d& N, const Eigen::Matrix3d& C) {
  if (!(N.norm() > 0.0) || !C.allFinite()) return 0.0;
  const Eigen::Matrix3d T = unitDirectionJacobian(N);
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(T * C * T.transpose(), Eigen::EigenvaluesOnly);
  return std::sqrt(std::max(es.eigenvalues()[2], 0.0));
}

/// A plane that joins mid-run (TrackFilterOptions::late_planes), triangulated at frame `now`.
struct LateStart {
  bool ok = false;    ///< N, cov_N and X are set
  bool gone = false;  ///< fewer than the model's points of the plane are alive: it cannot join
  Eigen::Vector3d N = Eigen::Vector3d::Zero();
  Eigen::Matrix3d cov_N = Eigen::Matrix3d::Zero();
  std::vector<int> alive;              ///< its tracks alive now
  std::vector<int> ids;                ///< of those, the ones transferLatePlane carried to the reference frame
  std::vector<Eigen::Vector2d> ref;    ///< their reference positions
  std::vector<Eigen::Vector3d> X;      ///< the triangulated points (reference frame)
};

/// Median |N . X - 1| over the points: their distances from plane N relative to its distance.
double medianPlaneResidual(const Eigen::Vector3d& N, const std::vector<Eigen::Vector3d>& X) {
  std::vector<double> r;
  r.reserve(X.size());
  for (const Eigen::Vector3d& x : X) r.push_back(std::abs(N.dot(x) - 1.0));
  if (r.empty()) return 0.0;
  std::nth_element(r.begin(), r.begin() + r.size() / 2, r.end());
  return r[r.size() / 2];
}

/// N . X = 1 fitted to reference-frame points by least squares, twice: the second time without
/// the points more than 3 robust sds (1.4826 MAD) off the first fit. False with fewer than the
/// model's points left or points on a line (no plane).
bool fitPlaneToPoints(const std::vector<Eigen::Vector3d>& X, Eigen::Vector3d* N, Eigen::Matrix3d* cov) {
  std::vector<char> in(X.size(), 1);
  std::vector<double> r(X.size());
  for (int round = 0; round < 2; ++round) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    int n = 0;
    for (size_t i = 0; i < X.size(); ++i)
      if (in[i]) {
        A.noalias() += X[i] * X[i].transpose();
        b += X[i];
        ++n;
      }
    if (n < PlaneModel::kMinPoints) return false;
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(A);
    if (es.info() != Eigen::Success || !(es.eigenvalues()[0] > 1e-12 * es.eigenvalues()[2])) return false;
    const Eigen::Matrix3d Ai = es.eigenvectors() * es.eigenvalues().cwiseInverse().asDiagonal() * es.eigenvectors().transpose();
    *N = Ai * b;
    double ss = 0.0;
    std::vector<double> a;
    for (size_t i = 0; i < X.size(); ++i) {
      r[i] = N->dot(X[i]) - 1.0;
      if (in[i]) {
        ss += r[i] * r[i];
        a.push_back(std::abs(r[i]));
      }
    }
    *cov = Ai * (ss / std::max(1, n - 3));
    if (round == 1) break;
    std::nth_element(a.begin(), a.begin() + a.size() / 2, a.end());
    const double limit = 3.0 * 1.4826 * a[a.size() / 2];
    bool dropped = false;
    for (size_t i = 0; i < X.size(); ++i)
      if (in[i] && std::abs(r[i]) > limit && limit > 0.0) in[i] = 0, dropped = true;
    if (!dropped) break;
  }
  return N->allFinite() && cov->allFinite();
}

/// Triangulates late plane `lp` from its tracks at its first frame (record `from`) and now
/// (record `now`, frame index now.frame's): each track seen in both whose rays meet at more than
/// `min_parallax` rad (3 tracking-noise sds) gives a point, and the plane is fitted to them. It
/// needs the model's points, and half its tracks seen in both frames; then every track alive
/// now is transferred to the reference frame through it.
template <class UvOf>
LateStart startLatePlane(const Tracks& tracks, const std::vector<int>& labels, const TrackFilterOptions::LatePlane& lp,
                         const std::vector<TrackSpan>& spans, int min_track_frames, const TrackFrame& from, int now_k,
                         const TrackFrame& now, const UvOf& uvOf, double min_parallax) {
  LateStart out;
  std::vector<int>& alive = out.alive;
  std::vector<Eigen::Vector3d> X;
  int both = 0;
  for (const TrackPoint& p : tracks.frames[static_cast<size_t>(now_k)]) {
    if (p.id >= static_cast<int>(labels.size()) || labels[p.id] != lp.label || spans[p.id].length() < min_track_frames) continue;
    alive.push_back(p.id);
    const TrackPoint* pa = tracks.find(lp.first_frame, p.id);
    if (!pa) continue;
    ++both;
    Eigen::Vector3d Xi;
    if (PlaneModel::twoViewPoint(now.beta, from.R, from.t, uvOf(pa->px), now.R, now.t, uvOf(p.px), min_parallax, &Xi) ==
        MeasureStatus::Ok)
      X.push_back(Xi);
  }
  if (static_cast<int>(alive.size()) < PlaneModel::kMinPoints) {
    out.gone = true;
    return out;
  }
  if (2 * static_cast<int>(X.size()) < both || !fitPlaneToPoints(X, &out.N, &out.cov_N)) return out;
  out.X = std::move(X);
  out.ok = true;
  return out;
}

/// The planes' start (N per plane, reference frame): every plane frontal where the scale gauge
/// puts the main plane, or the homography start's normals and relative distances
/// (TrackFilterOptions::initial_normals) with plane 0's N_Z at the gauge.
std::vector<Eigen::Vector3d> startPlanes(const TrackFilterOptions& o, double beta0, int m) {
  // Scale gauge: the main plane meets the optical axis depth0 / beta0 beyond the image-plane
  // origin (N_Z = beta0 / depth0), so that every plane in view lies well beyond the A&P origin
  // (which sits 1/beta from the centre of projection) and starts as a frontal plane there.
  const double nz0 = beta0 / o.depth0;
  std::vector<Eigen::Vector3d> N_start(m, Eigen::Vector3d(0.0, 0.0, nz0));
  if (!o.initial_normals.empty()) {
    if (static_cast<int>(o.initial_normals.size()) != m || o.initial_distance_ratios.size() != o.initial_normals.size())
      throw std::invalid_argument("estimate: initial normals/distances do not match the number of planes");
    // Plane 0: n_0 . Y = d_0 (COP-centred) with N_0Z = nz0: N_0 = n_0 / (d_0 - n_0Z / beta0).
    const Eigen::Vector3d n0 = o.initial_normals[0].normalized();
    if (n0.z() > 0.05) {
      const double d0 = n0.z() / nz0 + n0.z() / beta0;
      for (int j = 0; j < m; ++j) {
        const Eigen::Vector3d nj = o.initial_normals[j].normalized();
        const double dj = d0 * o.initial_distance_ratios[j];
        const double den = dj - nj.z() / beta0;
        if (std::abs(den) > 1e-9 && std::isfinite(den)) N_start[j] = nj / den;
      }
      N_start[0].z() = nz0;
    }
  }
  return N_start;
}

/// Transfers the late plane's tracks alive now to the reference frame through plane N (into
/// ls->ids and ls->ref). Returns how many could not be carried (the point would lie behind the
/// reference camera or on its horizon), for TrackFilterResult::transfer_failed.
template <class UvOf>
int transferLatePlane(const Tracks& tracks, int now_k, const TrackFrame& now, const Eigen::Vector3d& N, const UvOf& uvOf,
                      LateStart* ls) {
  ls->ids.clear();
  ls->ref.clear();
  for (int id : ls->alive) {
    Eigen::Vector2d ref;
    if (PlaneModel::transferToReference(N, now.beta, now.R, now.t, uvOf(tracks.find(now_k, id)->px), &ref) != MeasureStatus::Ok)
      continue;
    ls->ids.push_back(id);
    ls->ref.push_back(ref);
  }
  return static_cast<int>(ls->alive.size() - ls->ids.size());
}

}  // namespace

TrackFilterResult runTrackFilter(const Tracks& tracks, const std::vector<int>& labels, const TrackFilterOptions& o,
                                 const std::function<void(int, int)>& progress) {
  const int F = tracks.numFrames();
  if (F < 2) throw std::invalid_argument("tracks: need at least 2 frames");
  if (tracks.image.width <= 0 || tracks.image.height <= 0) throw std::invalid_argument("tracks: no image size");
  if (static_cast<int>(labels.size()) < tracks.idBound())
    throw std::invalid_argument("labels: fewer labels than tracks");
  const double beta_sd0 = o.beta_sd0.value_or(TrackFilterOptions::kGuessBetaSd0);
  const double normal_sd0 = o.normal_sd0.value_or(TrackFilterOptions::kFrontalNormalSd0);
  if (!(o.sigma_px > 0) || !(beta_sd0 >= 0) || !(normal_sd0 > 0) || !std::isfinite(o.focal_px) || !(o.depth0 > 0))
    throw std::invalid_argument("estimate: options out of range (sigma, beta sd, normal sd, focal)");
  TrackFilterResult res;
  const double s = o.scale_px > 0 ? o.scale_px : std::max(tracks.image.width, tracks.image.height) / 2.0;
  res.scale_px = s;
  const double cx = tracks.image.cx, cy = tracks.image.cy;
  auto uvOf = [&](const Eigen::Vector2d& px) { return Eigen::Vector2d((px.x() - cx) / s, (px.y() - cy) / s); };
  const auto spans = trackSpans(tracks);
  const bool known_focal = o.focal_px > 0;
  const double f0 = known_focal ? o.focal_px : (o.focal0_px > 0 ? o.focal0_px : std::max(tracks.image.width, tracks.image.height));
  const double beta0 = s / f0;
  FilterOptions fo = o.filter;
  fo.sigma_uv = o.sigma_px / s;

  auto usable = [&](int id, int plane_limit) {
    const int l = labels[id];
    return l >= 0 && l < plane_limit && spans[id].length() >= o.min_track_frames;
  };

  // The motion's process noise. Translations are relative to the main plane's starting depth
  // depth0 / beta0, its distance along the optical axis from the A&P origin (on the image plane),
  // which the gauge fixes, whatever depth0. The noise from the data uses the same depth, although
  // D / f0 and the decomposition's |t / d| n_z are relative to the depth from the centre of
  // projection, (depth0 + 1) / beta0: Q0's translation sd is depth0 / (depth0 + 1) of that
  // motion (0.91 at the default depth0 10), which the adaptation then matches. (Scaling it by
  // the centre's depth instead, 2026-12-03, left every determinable row within 0.02 % but moved
  // box.mp4's window at frame 4 from 578 px determined to 594 px not determined: that window's
  // start is a grid-end decomposition, 1920 px, its interior 668-px hypotheses' scoring filters
  // having diverged, and its refinement sits between two optima; docs/regimes.md.)
  const double depth_start = o.depth0 / beta0;
  double trans_sd = o.q_trans_rel > 0 ? o.q_trans_rel * depth_start : 0.0;
  if (o.q_from_data) {
    const int plane_limit = o.model == TrackModel::Plane ? 1 : (1 << 30);  // the tracks that enter the filter
    res.image_motion_px = imageMotionPx(tracks, [&](int id) { return usable(id, plane_limit); });
    const double D = std::max(res.image_motion_px, o.sigma_px);
    res.start_rotation_deg_per_frame = o.start_rotation_deg_per_frame;
    res.start_translation_rel_per_frame = o.start_translation_rel_per_frame;
    const double given_trans_sd = trans_sd;
    trans_sd = std::max(D / f0, o.start_translation_rel_per_frame) * depth_start;
    double w = std::max(D / f0, o.start_rotation_deg_per_frame * M_PI / 180.0);
    if (!(o.start_rotation_deg_per_frame > 0 || o.start_translation_rel_per_frame > 0)) {
      // No start measured the motion (frontal start): the image motion is only a lower bound (a
      // camera turning to keep the scene in view moves it little), so the given values stay the
      // floor of Q0; the adaptation then follows the motion measured.
      w = std::max(w, std::sqrt(o.filter.q_motion[3]));
      trans_sd = std::max(trans_sd, given_trans_sd);
    }
    fo.q_motion[3] = fo.q_motion[4] = fo.q_motion[5] = w * w;
  } else {
    fo.adapt.enabled = false;
  }
  res.q_from_data = o.q_from_data;
  res.q_adapted = fo.adapt.enabled;
  if (trans_sd > 0) {
    fo.q_motion[0] = fo.q_motion[1] = trans_sd * trans_sd;
    fo.q_motion[2] = trans_sd * trans_sd * beta0 * beta0;
  }
  res.q0_omega_sd_deg = std::sqrt(fo.q_motion[3]) * 180.0 / M_PI;
  res.q0_trans_sd_rel = std::sqrt(fo.q_motion[0]) / depth_start;
  if (o.model == TrackModel::Point) {
    std::vector<int> ids;
    for (const auto& p : tracks.frames[0])
      if (usable(p.id, 1 << 30)) ids.push_back(p.id);
    if (static_cast<int>(ids.size()) < PointModel::kMinPoints)
      throw std::invalid_argument("point model: " + std::to_string(ids.size()) +
                                  " usable tracks in the reference frame, needs at least 7");
    // Longest-lived tracks first, at most max_point_tracks (the point filter is O(N^3)).
    std::stable_sort(ids.begin(), ids.end(), [&](int a, int b) { return spans[a].length() > spans[b].length(); });
    if (o.max_point_tracks > 0 && static_cast<int>(ids.size()) > o.max_point_tracks) ids.resize(o.max_point_tracks);
    std::sort(ids.begin(), ids.end());
    const int n = 7 + static_cast<int>(ids.size());
    std::vector<Eigen::Vector2d> ref;
    for (int id : ids) ref.push_back(uvOf(tracks.find(0, id)->px));
    Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
    Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
    std::vector<bool> fixed(n, false);
    x0[idx::kBeta] = beta0;
    P0(idx::kBeta, idx::kBeta) = known_focal ? 0.0 : std::pow(beta_sd0 * beta0, 2);
    fixed[idx::kBeta] = known_focal;
    // Every point starts at the gauge depth (as the plane models' frontal start), or with a
    // homography start (TrackFilterOptions::initial_normals) on its plane's start: the depth
    // where its reference ray meets that plane ([AS99] eq. 12), when in front of the camera.
    std::vector<Eigen::Vector3d> N_start;
    if (!o.initial_normals.empty()) N_start = startPlanes(o, beta0, static_cast<int>(o.initial_normals.size()));
    for (int i = 7; i < n; ++i) {
      x0[i] = o.depth0 / beta0;
      const int l = labels[ids[static_cast<size_t>(i - 7)]];
      Eigen::Vector3d p;
      if (l >= 0 && l < static_cast<int>(N_start.size()) &&
          PlaneModel::point(N_start[static_cast<size_t>(l)], beta0, ref[static_cast<size_t>(i - 7)], &p, nullptr, nullptr) == MeasureStatus::Ok &&
          p.z() > 0 && std::isfinite(p.z()))
        x0[i] = p.z();
      P0(i, i) = std::pow(o.depth_sd0 * x0[i], 2);
    }
    P0(7, 7) = 0.0;
    fixed[7] = true;  // scale gauge: the first point's depth
    RecursiveFilter<PointModel> f(PointModel(ref), Ekf(x0, P0, fixed), fo);
    std::vector<int> pidx(tracks.idBound(), -1);
    for (size_t i = 0; i < ids.size(); ++i) pidx[ids[i]] = static_cast<int>(i);
    res.planes = 0;
    res.plane_tracks = {static_cast<int>(ids.size())};
    res.plane_new_tracks = {0};
    res.transfer_failed = {0};
    std::vector<double> sum2(1, 0.0);
    std::vector<long> cnt(1, 0);
    ResidualSeries series;
    TrackFrame t0;
    t0.frame = tracks.frameNumber(0);
    t0.beta = beta0;
    t0.var_beta = P0(idx::kBeta, idx::kBeta);
    t0.observed = t0.used = static_cast<int>(ids.size());
    res.frames.push_back(t0);
    for (int k = 1; k < F; ++k) {
      std::vector<Observation> obs;
      for (const auto& p : tracks.frames[k])
        if (pidx[p.id] >= 0) obs.push_back({pidx[p.id], uvOf(p.px)});
      const FrameStats& fs = f.step(obs);
      if (k >= kMinFramesBeforeEnd && ranOut(fs, PointModel::kMinPoints)) {
        res.ended = ranOutNote(tracks.frameNumber(k), fs.update.blocks, PointModel::kMinPoints);
        break;
      }
      res.stopped = afterStep(f, fs, tracks.frameNumber(k));
      if (!res.stopped.empty()) break;
      TrackFrame tf = frameOf(f, fs, tracks.frameNumber(k), static_cast<int>(obs.size()), depth_start);
      accumulateResiduals(f, obs, fs, std::vector<int>(obs.size(), 0), s, &sum2, &cnt, &tf.rms_px, &series);
      res.frames.push_back(tf);
      if (progress) progress(k + 1, F);
    }
    res.plane_rms_px = {cnt[0] ? std::sqrt(sum2[0] / cnt[0]) : 0.0};
    calibrateSds(series, o.sigma_px, &res);
    return res;
  }

  // Plane models.
  int m = 1;
  int m_all = 1;  // with the planes that join mid-run
  if (o.model == TrackModel::Planes) {
    m = 0;
    for (int id = 0, nid = tracks.idBound(); id < nid; ++id) m = std::max(m, labels[id] + 1);
    if (m == 0) throw std::invalid_argument("planes model: no track is labelled with a plane");
    m_all = m;
    m -= static_cast<int>(o.late_planes.size());
    for (size_t i = 0; i < o.late_planes.size(); ++i)
      if (o.late_planes[i].label != m + static_cast<int>(i) || o.late_planes[i].first_frame < 0 ||
          o.late_planes[i].init_frame <= o.late_planes[i].first_frame || o.late_planes[i].init_frame >= F)
        throw std::invalid_argument("estimate: late planes must carry the highest labels in order, with first_frame < init_frame < frames");
    if (m < 1) throw std::invalid_argument("planes model: no plane in the reference frame");
    if (!o.late_planes.empty() && o.filter.reference == ReferenceModel::State)
      throw std::invalid_argument("estimate: planes added mid-run cannot be used with the reference positions in the state");
  } else if (!o.late_planes.empty()) {
    throw std::invalid_argument("estimate: planes added mid-run need the planes model");
  }
  std::vector<int> ref_count(m, 0);
  std::vector<int> ids;
  {
    // At most max_tracks_per_plane reference tracks per plane: the longest-lived ones.
    std::vector<int> cand;
    for (const auto& p : tracks.frames[0])
      if (usable(p.id, m)) cand.push_back(p.id);
    std::stable_sort(cand.begin(), cand.end(), [&](int a, int b) { return spans[a].length() > spans[b].length(); });
    for (int id : cand)
      if (o.max_tracks_per_plane <= 0 || ref_count[labels[id]] < o.max_tracks_per_plane) {
        ids.push_back(id);
        ++ref_count[labels[id]];
      }
    std::sort(ids.begin(), ids.end());
  }
  for (int j = 0; j < m; ++j)
    if (ref_count[j] < PlaneModel::kMinPoints)
      throw std::invalid_argument("plane " + std::to_string(j) + ": " + std::to_string(ref_count[j]) +
                                  " tracks in the reference frame, the plane model needs at least 5");
  if (o.passes < 1) throw std::invalid_argument("estimate: passes must be >= 1");
  double beta_start = beta0;
  std::vector<Eigen::Vector3d> N_start = startPlanes(o, beta0, m);
  const double nz0 = N_start[0].z();  // the scale gauge's N_Z (startPlanes)
  ResidualSeries series;
  // The last completed pass and its residuals: a later pass that stops falls back to it.
  TrackFilterResult kept;
  ResidualSeries kept_series;
  for (int pass = 1; pass <= o.passes; ++pass) {
    res.frames.clear();
    res.stopped.clear();
    res.ended.clear();
    const bool last_pass = pass == o.passes;
    const int n = 7 + 3 * m;
    std::vector<Eigen::Vector2d> ref;
    std::vector<int> lab;
    for (int id : ids) {
      ref.push_back(uvOf(tracks.find(0, id)->px));
      lab.push_back(labels[id]);
    }
    Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
    Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
    std::vector<bool> fixed(n, false);
    x0[idx::kBeta] = beta_start;
    P0(idx::kBeta, idx::kBeta) = known_focal ? 0.0 : std::pow(beta_sd0 * beta_start, 2);
    fixed[idx::kBeta] = known_focal;
    for (int j = 0; j < m; ++j) {
      const int b = PlaneModel::planeIndex(j);
      x0.segment<3>(b) = N_start[j];
      const double v = std::pow(normal_sd0 * std::max(N_start[j].norm(), nz0), 2);
      P0(b, b) = P0(b + 1, b + 1) = v;
      P0(b + 2, b + 2) = j == 0 ? 0.0 : v;
    }
    fixed[PlaneModel::planeIndex(0) + 2] = true;  // scale gauge: N_Z of plane 0
    RecursiveFilter<PlaneModel> f(PlaneModel(ref, lab, m), Ekf(x0, P0, fixed), fo);
    std::vector<int> pidx(tracks.idBound(), -1);
    for (size_t i = 0; i < ids.size(); ++i) pidx[ids[i]] = static_cast<int>(i);
    // The state's plane of each label: the reference planes' own, the late planes' once they join.
    std::vector<int> plane_of(m_all, -1);
    for (int j = 0; j < m; ++j) plane_of[j] = j;
    std::vector<int> first_frame(m, 0);
    std::vector<char> late_done(o.late_planes.size(), 0);
    res.plane_tracks = ref_count;
    res.plane_tracks.resize(m_all, 0);
    res.plane_new_tracks.assign(m_all, 0);
    res.transfer_failed.assign(m_all, 0);
    std::vector<double> sum2(m_all, 0.0);
    std::vector<long> cnt(m_all, 0);
    series = ResidualSeries{};  // the last pass's residuals calibrate the sds
    auto recordPlane = [&](TrackFrame* tf, int j) {
      const int b = PlaneModel::planeIndex(j);
      tf->N.push_back(f.ekf().x().segment<3>(b));
      tf->cov_N.push_back(f.ekf().P().block<3, 3>(b, b));
      tf->cov_beta_N.push_back(f.ekf().P().block<1, 3>(idx::kBeta, b).transpose());
      // Its cross-covariances with the planes before it: recorded in plane order, the pairs land
      // in TrackFrame::cov_N_pair's order (planePairIndex).
      for (int a = 0; a < j; ++a) tf->cov_N_pair.push_back(f.ekf().P().block<3, 3>(PlaneModel::planeIndex(a), b));
    };
    auto recordPlanes = [&](TrackFrame* tf) {
      for (int j = 0; j < f.model().numPlanes(); ++j) recordPlane(tf, j);
    };
    // A track that joins plane j after the reference frame, at reference position `ref`, which
    // was transferred through the state's plane and motion so that the model predicts the
    // track's current observation z: h(x, u) = z. With the references conditional on the state
    // (ReferenceModel::Conditional) the reference keeps that dependence, du/dx = -Hu^-1 H_x (the
    // implicit function theorem on the model's own Jacobians, Hu = dh/du), and z's noise reaches
    // it as sigma^2 Hu^-1 Hu^-T; taken as a measurement of its own (sigma^2 I, independent of the
    // state), the state's error at the join would count as information in every later frame
    // (docs/filter.md, "Points that join later").
    Eigen::MatrixXd G_join;
    auto join = [&](int id, const Eigen::Vector2d& ref, int j) {
      pidx[id] = f.mutableModel().addPoint(ref, j);
      Eigen::Matrix2d C;
      if (fo.reference == ReferenceModel::Conditional &&
          f.model().transferredReferenceJacobian(f.ekf().x(), f.rotation(), pidx[id], fo.sigma_uv, &G_join, &C) == MeasureStatus::Ok)
        f.setConditionalReference(pidx[id], G_join, C);
      ++res.plane_tracks[j];
      ++res.plane_new_tracks[j];
    };
    // A track that may enter the filter now: labelled with a plane in the state, long enough.
    auto enters = [&](int id) {
      const int l = labels[id];
      return l >= 0 && l < m_all && plane_of[l] >= 0 && spans[id].length() >= o.min_track_frames;
    };
    TrackFrame t0;
    t0.frame = tracks.frameNumber(0);
    t0.beta = f.beta();
    t0.var_beta = f.ekf().P()(idx::kBeta, idx::kBeta);
    recordPlanes(&t0);
    t0.observed = t0.used = static_cast<int>(ids.size());
    res.frames.push_back(t0);
    for (int k = 1; k < F; ++k) {
      std::vector<Observation> obs;
      std::vector<int> grp;
      for (const auto& p : tracks.frames[k])
        if (pidx[p.id] >= 0) {
          obs.push_back({pidx[p.id], uvOf(p.px)});
          grp.push_back(plane_of[labels[p.id]]);
        }
      const FrameStats& fs = f.step(obs);
      if (k >= kMinFramesBeforeEnd && ranOut(fs, PlaneModel::kMinPoints)) {
        res.ended = ranOutNote(tracks.frameNumber(k), fs.update.blocks, PlaneModel::kMinPoints);
        break;
      }
      res.stopped = afterStep(f, fs, tracks.frameNumber(k));
      if (!res.stopped.empty()) break;
      TrackFrame tf = frameOf(f, fs, tracks.frameNumber(k), static_cast<int>(obs.size()), depth_start);
      recordPlanes(&tf);
      accumulateResiduals(f, obs, fs, grp, s, &sum2, &cnt, &tf.rms_px, &series);
      res.frames.push_back(tf);
      // Planes that join mid-run (TrackFilterOptions::late_planes; docs/estimate.md section 3).
      for (size_t i = 0; i < o.late_planes.size(); ++i) {
        const TrackFilterOptions::LatePlane& lp = o.late_planes[i];
        if (late_done[i] || k < lp.init_frame) continue;
        // A ray's direction is known to ~sigma / f rad: a point needs 3 such sds of parallax.
        LateStart ls = startLatePlane(tracks, labels, lp, spans, o.min_track_frames,
                                            res.frames[static_cast<size_t>(lp.first_frame)], k, tf, uvOf,
                                            3.0 * o.sigma_px * tf.beta / s);
        if (ls.gone) {
          late_done[i] = 1;  // its tracks ended before it could be triangulated
          continue;
        }
        if (!ls.ok) continue;  // too little parallax yet: tried again next frame
        late_done[i] = 1;
        // A plane in the state seen again (its tracks lost, new ones found on it later): the
        // late plane's points lie on it as well as on their own fit, and the normals agree.
        {
          const double own = medianPlaneResidual(ls.N, ls.X);
          const Eigen::Vector3d n_new = metricPlane(ls.N, tf.beta).n;
          int same = -1;
          double same_residual = 0.0;
          for (int j = 0; j < f.model().numPlanes(); ++j) {  // the closest of those that pass
            const Eigen::Vector3d Nj = f.ekf().x().segment<3>(PlaneModel::planeIndex(j));
            const double cosang = std::abs(metricPlane(Nj, tf.beta).n.dot(n_new));
            const double residual = medianPlaneResidual(Nj, ls.X);
            // The normals agree within kSamePlaneDeg, or within the 95 % disc of their directions'
            // joint sd (the late fit's start covariance, 4 cov_N, and the state's), whichever is
            // wider: a late plane fitted to a few points can be further off than the fixed angle.
            const Eigen::Matrix3d Pj = f.ekf().P().block<3, 3>(PlaneModel::planeIndex(j), PlaneModel::planeIndex(j));
            const double sd_dir = directionSd(ls.N, 4.0 * ls.cov_N) + directionSd(Nj, Pj);
            const double limit = std::max(kSamePlaneDeg * M_PI / 180.0, 2.448 * sd_dir);
            if (cosang > std::cos(limit) && residual <= 2.0 * own + kSamePlaneResidual &&
                (same < 0 || residual < same_residual))
              same = j, same_residual = residual;
          }
          if (same >= 0) {
            res.transfer_failed[same] +=
                transferLatePlane(tracks, k, tf, f.ekf().x().segment<3>(PlaneModel::planeIndex(same)), uvOf, &ls);
            plane_of[lp.label] = same;
            for (size_t q = 0; q < ls.ids.size(); ++q) join(ls.ids[q], ls.ref[q], same);
            continue;
          }
        }
        const int not_carried = transferLatePlane(tracks, k, tf, ls.N, uvOf, &ls);
        if (static_cast<int>(ls.ids.size()) < PlaneModel::kMinPoints) continue;  // its tracks cannot be carried: left out
        if (f.ekf().size() != PlaneModel::planeIndex(f.model().numPlanes()))
          throw std::logic_error("runTrackFilter: a plane can only join a state of motion and planes");
        const int j = f.mutableModel().addPlane();
        res.transfer_failed[j] += not_carried;
        const double sd = TrackFilterOptions::kLatePlaneSd0 * ls.N.norm();
        Eigen::Matrix3d P_new = 4.0 * ls.cov_N;
        P_new.diagonal().array() += sd * sd;
        f.mutableEkf().augment(ls.N, P_new, Eigen::MatrixXd::Zero(3, f.ekf().size()), false);
        plane_of[lp.label] = j;
        first_frame.push_back(k);
        for (size_t q = 0; q < ls.ids.size(); ++q) join(ls.ids[q], ls.ref[q], j);
        recordPlane(&res.frames.back(), j);
      }
      // Tracks born in this frame join their plane, transferred to the reference frame.
      if (o.add_new_tracks) {
        std::vector<int> live(m_all, 0);  // points of each plane observed in this frame
        for (const auto& p : tracks.frames[k])
          if (pidx[p.id] >= 0) ++live[plane_of[labels[p.id]]];
        for (const auto& p : tracks.frames[k]) {
          if (spans[p.id].first != k || pidx[p.id] >= 0 || !enters(p.id)) continue;
          const int j = plane_of[labels[p.id]];
          if (o.max_tracks_per_plane > 0 && live[j] >= o.max_tracks_per_plane) continue;
          ++live[j];
          Eigen::Vector2d uv_ref;
          const MeasureStatus st = PlaneModel::transferToReference(tf.N[j], tf.beta, tf.R, tf.t, uvOf(p.px), &uv_ref);
          if (st != MeasureStatus::Ok) {
            ++res.transfer_failed[j];
            continue;
          }
          join(p.id, uv_ref, j);
        }
      }
      if (progress) progress((pass - 1) * F + k + 1, o.passes * F);
    }
    const int planes_in = f.model().numPlanes();
    res.planes = planes_in;
    res.plane_of_label = plane_of;
    res.plane_first_frame = first_frame;
    res.plane_tracks.resize(planes_in);
    res.plane_new_tracks.resize(planes_in);
    res.transfer_failed.resize(planes_in);
    // Frames before a late plane joined repeat its value there (TrackFilterResult::plane_first_frame).
    for (TrackFrame& fr : res.frames)
      for (int j = static_cast<int>(fr.N.size()); j < planes_in; ++j) {
        const TrackFrame& at = res.frames[static_cast<size_t>(first_frame[j])];
        fr.N.push_back(at.N[j]);
        fr.cov_N.push_back(at.cov_N[j]);
        fr.cov_beta_N.push_back(at.cov_beta_N[j]);
      }
    for (TrackFrame& fr : res.frames) fr.cov_N_pair.resize(static_cast<std::size_t>(planes_in * (planes_in - 1) / 2), Eigen::Matrix3d::Zero());
    res.plane_rms_px.resize(planes_in);
    for (int j = 0; j < planes_in; ++j) res.plane_rms_px[j] = cnt[j] ? std::sqrt(sum2[j] / cnt[j]) : 0.0;
    res.passes = pass;
    if (!res.ok()) {
      // A later pass starts from the last one's end, which can sit where its own start diverges
      // (the ViSP mbt/cube: pass 1 ran every frame from a start at its focal grid's end, pass 2
      // went through infinite focal length at frame 23). The completed pass stands, and says so.
      if (pass > 1) {
        const std::string why = fmt::format("pass {} stopped at {}; the result is pass {}'s", pass, res.stopped, pass - 1);
        res = std::move(kept);
        series = std::move(kept_series);
        res.pass_stopped = why;
      }
      break;
    }
    const TrackFrame& fin = res.frames.back();
    res.pass_focal_px.push_back(s / fin.beta);
    res.pass_N.push_back(fin.N);
    if (last_pass) break;
    kept = res;
    kept_series = series;
    beta_start = known_focal ? beta0 : fin.beta;
    N_start.assign(fin.N.begin(), fin.N.begin() + m);  // the late planes join again where they did
  }
  calibrateSds(series, o.sigma_px, &res);
  return res;
}

}  // namespace rsfm

namespace rsfm {

MotionWald motionWald(const Eigen::Matrix3d& R, const Eigen::Vector3d& t_state, double beta, const Eigen::Matrix<double, 6, 6>& cov) {
  MotionWald w;
  // The rotation from the reference as a rotation vector, against the omega block.
  const Eigen::AngleAxisd aa(R);
  const Eigen::Vector3d rv = aa.angle() * aa.axis();
  const Eigen::LDLT<Eigen::Matrix3d> lr(cov.bottomRightCorner<3, 3>());
  if (lr.info() == Eigen::Success && lr.vectorD().minCoeff() > 0) w.rotation = rv.dot(lr.solve(rv));
  // The centre of projection (reference frame) as a function of the motion state.
  const Eigen::Vector3d t(t_state.x(), t_state.y(), t_state.z() / beta);
  auto centre = [&](const Eigen::Matrix<double, 6, 1>& d) {
    const Eigen::Matrix3d Rd = incrementalRotation(d.tail<3>()) * R;
    return copCentredPose(Rd, Eigen::Vector3d(t.x() + d[0], t.y() + d[1], t.z() + d[2] / beta), beta).position;
  };
  Eigen::Matrix<double, 3, 6> J;
  for (int c = 0; c < 6; ++c) {
    Eigen::Matrix<double, 6, 1> d = Eigen::Matrix<double, 6, 1>::Zero();
    const double h = 1e-7 * std::max(1.0, c < 3 ? std::abs(t_state[c]) : 1.0);
    d[c] = h;
    const Eigen::Vector3d a = centre(d);
    d[c] = -h;
    J.col(c) = (a - centre(d)) / (2 * h);
  }
  const Eigen::Vector3d ck = centre(Eigen::Matrix<double, 6, 1>::Zero());
  const Eigen::LDLT<Eigen::Matrix3d> lt(J * cov * J.transpose());
  if (lt.info() == Eigen::Success && lt.vectorD().minCoeff() > 0) w.translation = ck.dot(lt.solve(ck));
  return w;
}

FilterDeterminacy filterDeterminacy(const TrackFilterResult& result, bool known_focal) {
  FilterDeterminacy d;
  if (result.frames.empty()) return d;
  const TrackFrame& f = result.frames.back();
  const double s = result.scale_px, sb = std::sqrt(std::max(0.0, f.var_beta));
  const double focal = s / f.beta, focal_sd = s * sb / (f.beta * f.beta);
  std::vector<std::string> why;
  const int moving = static_cast<int>(result.frames.size()) - 1 - result.still_frames;
  const double quantile = chi2Quantile(1.0 - 0.001 / std::max(1, moving), 3.0);
  for (std::size_t k = static_cast<std::size_t>(result.still_frames) + 1; k < result.frames.size(); ++k) {
    const TrackFrame& fk = result.frames[k];
    if (fk.still || fk.cov_motion.isZero(0.0) || !(fk.beta > 0)) continue;
    const MotionWald w = motionWald(fk.R, Eigen::Vector3d(fk.t.x(), fk.t.y(), fk.t.z() * fk.beta), fk.beta, fk.cov_motion);
    d.wald_rotation_chi2 = std::max(d.wald_rotation_chi2, w.rotation);
    d.wald_translation_chi2 = std::max(d.wald_translation_chi2, w.translation);
  }
  d.rotates = known_focal || d.wald_rotation_chi2 > quantile;
  d.translates = d.wald_translation_chi2 > quantile;
  if (!d.rotates)
    why.push_back(fmt::format("the camera does not turn significantly (largest frame rotation Wald chi2 {:.1f}, limit {:.1f}): "
                              "the focal length and the planes' tilts are one null direction",
                              d.wald_rotation_chi2, quantile));
  if (!d.translates)
    why.push_back(fmt::format("the camera only turns (largest frame translation Wald chi2 {:.1f}, limit {:.1f}): no structure",
                              d.wald_translation_chi2, quantile));
  d.focal_determined = known_focal || (d.rotates && f.beta > 0 && focal_sd <= kDeterminedFocalRelSd * focal);
  if (!d.focal_determined && d.rotates) {
    // Its linear interval f +- 1.96 sd is where the filter stopped, not what the data support
    // (box-translate: 168-306 px, the truth 520): without the refinement's profile, no interval.
    const double lo = s / (f.beta + 1.96 * sb), hi = f.beta - 1.96 * sb > 0 ? s / (f.beta - 1.96 * sb) : INFINITY;
    why.push_back(fmt::format("focal length sd {:.1f} % (limit {:.0f} %; the filter's own sd, no refinement; its linear "
                              "interval {:.0f}-{:.0f} px is not a supported one without the refinement's profile)",
                              100 * focal_sd / focal, 100 * kDeterminedFocalRelSd, lo, hi));
  }
  for (std::size_t j = 0; j < f.N.size() && j < f.cov_N.size(); ++j) {
    const double sd = metricPlane(f.N[j], f.beta, covBetaN(f, static_cast<int>(j))).sd_angle_deg;
    // A plane's tilt follows the focal length: with the focal length not determined, a normal's
    // sd at the filter's one linearization point says nothing (the refinement adds the normal's
    // turn over the supported focal lengths; the filter has no such profile).
    d.plane_determined.push_back(d.translates && d.focal_determined && sd <= kDeterminedNormalSdDeg);
    if (!d.plane_determined.back() && d.translates)
      why.push_back(d.focal_determined ? fmt::format("plane {} normal sd {:.1f} deg (limit {:.0f} deg; the filter's own sd, no "
                                                     "refinement)",
                                                     j, sd, kDeterminedNormalSdDeg)
                                       : fmt::format("plane {}: its tilt follows the undetermined focal length", j));
  }
  for (std::size_t i = 0; i < why.size(); ++i) d.why += (i ? "; " : "") + why[i];
  return d;
}

Eigen::Matrix4d covBetaN(const TrackFrame& f, int j) {
  Eigen::Matrix4d c = Eigen::Matrix4d::Zero();
  c(0, 0) = f.var_beta;
  if (j >= 0 && j < static_cast<int>(f.cov_N.size())) {
    c.bottomRightCorner<3, 3>() = f.cov_N[static_cast<std::size_t>(j)];
    c.block<1, 3>(0, 1) = f.cov_beta_N[static_cast<std::size_t>(j)].transpose();
    c.block<3, 1>(1, 0) = f.cov_beta_N[static_cast<std::size_t>(j)];
  }
  return c;
}

PlaneAngle planeAngle(const TrackFrame& f, int a, int b) {
  PlaneAngle p;
  p.a = a;
  p.b = b;
  const int m = static_cast<int>(f.N.size());
  if (a < 0 || b <= a || b >= m) return p;
  const Eigen::Vector3d& Na = f.N[static_cast<std::size_t>(a)];
  const Eigen::Vector3d& Nb = f.N[static_cast<std::size_t>(b)];
  Eigen::Matrix<double, 1, 6> g;
  const double theta = normalAngle(Na, Nb, &g);
  p.angle_deg = theta * kRadToDeg;
  p.hi_deg = 90.0;
  const int k = planePairIndex(a, b);
  if (static_cast<int>(f.cov_N.size()) < m || static_cast<int>(f.cov_N_pair.size()) <= k) return p;
  Eigen::Matrix<double, 6, 6> C;
  C << f.cov_N[static_cast<std::size_t>(a)], f.cov_N_pair[static_cast<std::size_t>(k)],
      f.cov_N_pair[static_cast<std::size_t>(k)].transpose(), f.cov_N[static_cast<std::size_t>(b)];
  if (!C.allFinite()) return p;
  p.has_sd = true;
  p.sd_deg = std::sqrt(std::max(0.0, (g * C * g.transpose())(0, 0))) * kRadToDeg;
  // The normals' relative error on the tangent plane: n_b' - n_a' with b's sign following a's
  // (the lines' angle), d n = (I - n n^T) dN / |N|.
  const Eigen::Vector3d na = Na.normalized(), nb = Nb.normalized();
  const double sign = na.dot(nb) < 0 ? -1.0 : 1.0;
  Eigen::Matrix<double, 3, 6> D;
  D.leftCols<3>() = -unitDirectionJacobian(Na);
  D.rightCols<3>() = sign * unitDirectionJacobian(Nb);
  const double sd_rel = std::sqrt(std::max(0.0, (D * C * D.transpose()).trace())) * kRadToDeg;
  constexpr double kDisc95 = 2.4477;  // sqrt(chi2_2(0.95))
  if (p.angle_deg <= kDisc95 * sd_rel) {
    p.lo_deg = 0.0;
    p.hi_deg = std::min(90.0, p.angle_deg + kDisc95 * sd_rel);
  } else {
    p.lo_deg = std::max(0.0, p.angle_deg - 1.96 * p.sd_deg);
    p.hi_deg = std::min(90.0, p.angle_deg + 1.96 * p.sd_deg);
  }
  return p;
}

MetricPlane metricPlane(const Eigen::Vector3d& N, double beta, const Eigen::Matrix4d& cov, Eigen::Matrix4d* J) {
  MetricPlane p;
  const double r = N.norm();
  p.n = N / r;
  p.d = (1.0 + N.z() / beta) / r;
  // Jacobians with respect to (beta, N).
  Eigen::Matrix<double, 3, 4> Jn = Eigen::Matrix<double, 3, 4>::Zero();
  Jn.rightCols<3>() = unitDirectionJacobian(N);
  Eigen::Matrix<double, 1, 4> Jd;
  Jd(0) = -N.z() / (beta * beta * r);
  Jd.rightCols<3>() = Eigen::RowVector3d(0, 0, 1.0 / (beta * r)) - p.d * N.transpose() / (r * r);
  const Eigen::Matrix3d cn = Jn * cov * Jn.transpose();
  p.sd_angle_deg = std::sqrt(std::max(0.0, cn.trace())) * 180.0 / M_PI;
  p.sd_d = std::sqrt(std::max(0.0, (Jd * cov * Jd.transpose())(0, 0)));
  const double sign = p.d < 0 ? -1.0 : 1.0;
  if (J) {
    J->topRows<3>() = sign * Jn;
    J->row(3) = sign * Jd;
  }
  p.n *= sign;
  p.d *= sign;
  return p;
}

}  // namespace rsfm
