#include "rsfm/pipeline/estimate.hpp"
#include "rsfm/chi2.hpp"
#include "rsfm/clock.hpp"
#include "rsfm/models/plane_model.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace rsfm {

const char* const kFocalGridEndWarning =
    "the start's focal length is at the end of its grid (0.3-3 x max(width, height)): the homographies do not "
    "determine it; consider --focal-px or --focal0-px";

namespace {
std::string rf_message(const EstimateResult& er) {
  return er.refined.message.empty() ? std::string("no message") : er.refined.message.substr(0, er.refined.message.find(';'));
}

/// Puts the still frames back into a run on the frames `kept` (indices into `input`): every input frame from the first up to the run's last gets a
/// record, a left-out one a copy of the record of the kept frame before it (the reference's
/// before the reference frame) with its own frame number, no observations and `still` set.
/// `cov` (per kept frame, may be empty) is filled the same way, zero before the reference.
using MotionCov = Eigen::Matrix<double, 6, 6>;
void fillStill(TrackFilterResult* r, std::vector<MotionCov>* cov, const std::vector<int>& kept, const Tracks& input) {
  // (An input frame left out because it has no observation at all is marked unobserved: its
  // record is a copy too, but its pose is not known.)
  if (r->frames.empty()) return;
  const int last = kept[r->frames.size() - 1];
  std::vector<TrackFrame> frames;
  std::vector<MotionCov> covs;
  frames.reserve(static_cast<size_t>(last + 1));
  size_t i = 0;  // the kept frame at or before k
  for (int k = 0; k <= last; ++k) {
    while (i + 1 < r->frames.size() && kept[i + 1] <= k) ++i;
    const bool is_kept = kept[i] == k;
    TrackFrame f = r->frames[i];
    if (!is_kept) {
      f.frame = input.frameNumber(k);
      f.observed = f.used = f.gated = 0;
      f.nis_per_dof = f.rms_px = 0.0;
      f.q_scale = 1.0;
      f.q_omega_sd_deg = f.q_trans_sd_rel = 0.0;
      f.still = true;
      f.unobserved = k > kept[0] && input.frames[static_cast<size_t>(k)].empty();  // EstimateResult::unobserved_frames
    }
    frames.push_back(std::move(f));
    if (cov && !cov->empty()) covs.push_back(k < kept[0] ? MotionCov::Zero() : (*cov)[i]);
  }
  r->frames = std::move(frames);
  r->still_frames = kept[0];
  if (cov && !cov->empty()) *cov = std::move(covs);
}

/// Labels sized for every id of `input`; a track with no observation in `used` (the frames the
/// stages ran on: it lived only before the reference frame or within held frames) is -2.
void coverIds(std::vector<int>* labels, const Tracks& input, const Tracks& used) {
  const std::size_t n = static_cast<std::size_t>(input.idBound());
  if (labels->size() < n) labels->resize(n, -2);
  std::vector<char> seen(n, 0);
  for (const auto& f : used.frames)
    for (const TrackPoint& p : f)
      if (static_cast<std::size_t>(p.id) < n) seen[static_cast<std::size_t>(p.id)] = 1;
  for (std::size_t id = 0; id < n; ++id)
    if (!seen[id]) (*labels)[id] = -2;
}
}  // namespace

// Documented in pipeline/estimate.hpp.
TrackFilterOptions startOptions(const TrackFilterOptions& base, const vision::StartHypothesis& h, int m) {
  TrackFilterOptions o = base;
  if (h.frontal) return o;
  if (o.focal_px <= 0 && o.focal0_px <= 0) o.focal0_px = h.focal_px;
  if (!o.normal_sd0) o.normal_sd0 = 0.1;
  // A focal length at an end of the grid is not determined by the homographies (no minimum of
  // their disagreement was found): it keeps the width of a guess, not a start's 0.1. With 0.1
  // the filter started from box.mp4@4's 1920 px (3.3x the focal length) held it at 1660-2440 px
  // and the refinement from there ended not determined; with the guess's 0.3 it reaches the
  // other windows' optimum (578 px, faces 88.8 deg). docs/estimate.md, "Start".
  if (!o.beta_sd0) o.beta_sd0 = h.at_grid_end ? TrackFilterOptions::kGuessBetaSd0 : 0.1;
  o.initial_normals.assign(h.normals.begin(), h.normals.begin() + m);
  o.initial_distance_ratios.assign(h.distance_ratios.begin(), h.distance_ratios.begin() + m);
  o.start_rotation_deg_per_frame = h.rotation_deg_per_frame;
  o.start_translation_rel_per_frame = h.translation_rel_per_frame;
  return o;
}

namespace {

/// OnlineAccuracy of a successful refinement (pipeline/refine.hpp).
OnlineAccuracy onlineAccuracy(const TrackFilterResult& online, const RefineResult& refined) {
  OnlineAccuracy a;
  a.checked = true;
  const TrackFrame& o = online.frames.back();
  const TrackFrame& f = refined.state.frames.back();
  const double s = refined.state.scale_px;
  a.focal_determined = refined.focal_determined;
  if (a.focal_determined) {
    const double sd_r = s * std::sqrt(std::max(0.0, f.var_beta)) / (f.beta * f.beta);
    a.focal_sd_px = std::hypot(online.scale_px / o.beta - s / f.beta, sd_r);
  }
  if (o.N.empty()) return a;  // the point model: no planes online
  for (std::size_t j = 0; j < f.N.size(); ++j) {
    const bool det = j < refined.plane_determined.size() && refined.plane_determined[j] && j < o.N.size();
    a.plane_determined.push_back(det);
    if (!det) {
      a.normal_sd_deg.push_back(0.0);
      a.distance_sd.push_back(0.0);
      continue;
    }
    const MetricPlane pr = metricPlane(f.N[j], f.beta, covBetaN(f, static_cast<int>(j))), po = metricPlane(o.N[j], o.beta);
    const double angle = std::acos(std::clamp(pr.n.dot(po.n), -1.0, 1.0)) * 180.0 / M_PI;
    a.normal_sd_deg.push_back(std::hypot(angle, pr.sd_angle_deg));
    a.distance_sd.push_back(std::hypot(po.d - pr.d, pr.sd_d));
  }
  return a;
}

}  // namespace

// Issue 14 item 3; documented in pipeline/estimate.hpp.
void scoreStartHypotheses(const Tracks& tracks, const std::vector<int>& labels, const TrackFilterOptions& base, int m,
                          vision::PlaneStart* start) {
  const double cap = chi2Quantile(base.filter.update.gate_probability, 2.0);
  double best = std::numeric_limits<double>::infinity();
  start->chosen = 0;
  for (size_t i = 0; i < start->hypotheses.size(); ++i) {
    vision::StartHypothesis& h = start->hypotheses[i];
    TrackFilterOptions o = startOptions(base, h, m);
    o.passes = 1;
    h.score = std::numeric_limits<double>::infinity();
    TrackFilterResult run;
    try {
      run = runTrackFilter(tracks, labels, o);
    } catch (const std::invalid_argument& e) {
      h.stopped = e.what();
      continue;
    }
    if (!run.ok()) {
      h.stopped = run.stopped;
      continue;
    }
    const int n = static_cast<int>(run.frames.size());
    const int from = std::max(1, n / 2);
    double sum = 0.0;
    long offered = 0;
    for (int k = from; k < n; ++k) {
      const TrackFrame& f = run.frames[k];
      sum += f.nis_per_dof * 2.0 * f.used + cap * (f.observed - f.used);
      offered += f.observed;
    }
    if (offered == 0) continue;
    h.score = sum / offered;
    if (start->scored_from < 0 && n > from) {
      start->scored_from = run.frames[from].frame;
      start->scored_to = run.frames.back().frame;
    }
    if (h.score < best) {
      best = h.score;
      start->chosen = static_cast<int>(i);
    }
  }
}

// Documented in pipeline/estimate.hpp.
std::vector<TrackFilterOptions::LatePlane> findLatePlanes(const Tracks& tracks, vision::PlaneFinding* pf,
                                                         const vision::PlaneFinderOptions& options) {
  std::vector<TrackFilterOptions::LatePlane> late;
  const int F = tracks.numFrames();
  std::vector<int>& labels = pf->labels;
  if (labels.size() < static_cast<size_t>(tracks.idBound())) labels.resize(static_cast<size_t>(tracks.idBound()), -2);
  std::vector<int>& cut = pf->cut_after;  // the tracks that left their plane (the searches' cuts join them)
  if (cut.size() < labels.size()) cut.resize(labels.size(), -1);
  constexpr int kMinSearchFrames = 3;  // a search's reference frame is this far before its last pair frame
  int next_label = pf->numPlanes();
  int after = 1;  // the first search considers the tracks born after the reference frame
  const std::vector<TrackSpan> spans = trackSpans(tracks);
  auto liveAt = [&](int k) {
    int live = 0;
    for (const TrackPoint& p : tracks.frames[static_cast<size_t>(k)]) {
      const auto id = static_cast<size_t>(p.id);
      live += labels[id] >= 0 && (id >= cut.size() || cut[id] < 0 || k <= cut[id]);
    }
    return live;
  };
  for (int round = 0; round < 16; ++round) {
    // The planes in hand are tracked up to K_end: the frame before their tracks first number too
    // few, fewer than two homography tests' worth (16) or, for planes with fewer tracks, than half
    // of theirs at the search's start, but at least twice what the filter needs (10).
    const int enough = std::min(2 * vision::kHomographyTestTracks, std::max(2 * PlaneModel::kMinPoints, liveAt(after) / 2));
    int K_end = F - 1;
    for (int k = after + 1; k < F; ++k) {
      if (liveAt(k) < enough) {
        K_end = k - 1;
        break;
      }
    }
    if (K_end >= F - 1 || K_end - kMinSearchFrames <= after) break;
    // The tracks a search considers: those no plane holds that were born after the previous
    // search's reference frame (the reference frame's own were judged by the first search).
    auto eligible = [&](int id) { return labels[static_cast<size_t>(id)] < 0 && spans[static_cast<size_t>(id)].first >= after; };
    // Its reference frame: the earliest frame before K_end (the most parallax) where at least half
    // as many of them are alive there and at K_end as at the best frame.
    std::vector<int> both(static_cast<size_t>(K_end + 1), 0);
    int best = 0;
    for (int k = after; k <= K_end - kMinSearchFrames; ++k) {
      for (const TrackPoint& p : tracks.frames[static_cast<size_t>(k)])
        both[static_cast<size_t>(k)] += eligible(p.id) && tracks.find(K_end, p.id) != nullptr;
      best = std::max(best, both[static_cast<size_t>(k)]);
    }
    int K = -1;
    for (int k = after; k <= K_end - kMinSearchFrames && K < 0; ++k)
      if (both[static_cast<size_t>(k)] >= std::max(options.min_plane_tracks, (best + 1) / 2)) K = k;
    if (K < 0) break;
    Tracks sub;
    sub.image = tracks.image;
    sub.source = tracks.source;
    sub.first_frame = tracks.frameNumber(K);
    for (int k = K; k < F; ++k) {
      std::vector<TrackPoint> pts;
      for (const TrackPoint& p : tracks.frames[static_cast<size_t>(k)])
        if (eligible(p.id)) pts.push_back(p);
      sub.frames.push_back(std::move(pts));
      sub.frame_numbers.push_back(tracks.frameNumber(k));
    }
    vision::PlaneFinderOptions fo = options;
    fo.last_pair_frame = K_end - K;
    fo.rois.clear();
    const vision::PlaneFinding found = vision::findPlanes(sub, fo);
    std::vector<const vision::FoundPlane*> accepted;
    for (const auto& c : found.candidates)
      if (c.verdict == vision::PlaneVerdict::Accepted && c.label >= 0) accepted.push_back(&c);
    std::sort(accepted.begin(), accepted.end(), [](auto* a, auto* b) { return a->label < b->label; });
    for (const vision::FoundPlane* c : accepted) {
      vision::FoundPlane nc = *c;
      nc.label = next_label++;
      nc.first_frame = K;
      nc.pair_frame = K + (c->pair_frame >= 0 ? c->pair_frame : found.pair_frame);
      nc.H.clear();
      nc.support.clear();
      for (size_t id = 0; id < found.labels.size() && id < labels.size(); ++id)
        if (found.labels[id] == c->label) {
          labels[id] = nc.label;
          if (id < found.cut_after.size() && found.cut_after[id] >= 0) cut[id] = K + found.cut_after[id];
        }
      late.push_back({nc.label, K, std::max(K + 1, nc.pair_frame)});
      pf->candidates.push_back(std::move(nc));
    }
    if (accepted.empty()) break;
    after = K + 1;  // the next search starts after this one's reference frame
  }
  return late;  // in label order; the filter places each from its init_frame on
}

std::optional<double> knownReadout(const EstimateOptions& o) {
  const std::optional<double> file = o.camera ? o.camera->rolling_shutter_readout : std::nullopt;
  if (o.rolling_shutter_readout && file && *o.rolling_shutter_readout != *file)
    throw std::invalid_argument(fmt::format("rolling shutter readout {} given and {} in the camera file {}: give it once",
                                            *o.rolling_shutter_readout, *file, o.camera->source));
  const std::optional<double> tau = o.rolling_shutter_readout ? o.rolling_shutter_readout : file;
  if (tau && (!std::isfinite(*tau) || std::abs(*tau) > kMaxRollingShutterReadout))
    throw std::invalid_argument(fmt::format("rolling shutter readout {} frame intervals: outside -{} to {}", *tau,
                                            kMaxRollingShutterReadout, kMaxRollingShutterReadout));
  return tau;
}

namespace {
/// EstimateResult::last_used of `r`, an estimate of `input`. The plane finder's cuts count from
/// the reference frame (after a still start, the frame after the last still one).
std::vector<int> lastFramesUsed(const Tracks& input, const EstimateResult& r) {
  const int frames = input.numFrames();
  std::vector<char> held(static_cast<std::size_t>(frames), 0);
  for (int k : r.still.held)
    if (k < frames) held[static_cast<std::size_t>(k)] = 1;
  int last_k = -1;  // the last estimated frame
  if (!r.online.frames.empty())
    for (int k = frames - 1; k >= 0 && last_k < 0; --k)
      if (input.frameNumber(k) <= r.online.frames.back().frame) last_k = k;
  const std::vector<int>& labels = r.labels();
  std::vector<int> last(static_cast<std::size_t>(input.idBound()), -1);
  for (int k = 0; k <= last_k; ++k) {
    if (held[static_cast<std::size_t>(k)]) continue;
    for (const TrackPoint& p : input.frames[static_cast<std::size_t>(k)]) {
      const auto id = static_cast<std::size_t>(p.id);
      if (id >= labels.size() || labels[id] < 0) continue;
      const int cut = id < r.planes.cut_after.size() && r.planes.cut_after[id] >= 0 ? r.still.still_frames + r.planes.cut_after[id] : frames;
      if (k <= cut) last[id] = k;
    }
  }
  return last;
}
}  // namespace

EstimateResult estimate(const Tracks& given, const EstimateOptions& o,
                        const std::function<void(const std::string&)>& note,
                        const std::function<void(int, int)>& progress) {
  // A readout direction given: the tracks' image says it from here on.
  Tracks redirected;
  if (o.readout_direction && *o.readout_direction != given.image.readout_direction) {
    redirected = given;
    redirected.image.readout_direction = *o.readout_direction;
  }
  const Tracks& input = redirected.frames.empty() ? given : redirected;
  auto say = [&](const std::string& m) {
    if (note) note(m);
  };
  EstimateResult r;
  if (const auto k = static_cast<int>(leadingEmptyFrames(input.frames)); k > 0) {
    throw std::invalid_argument(
        k < input.numFrames()
            ? fmt::format("tracks: frame {}, the first, has no tracks, and the reference frame needs them: they start at frame {} "
                          "(trimLeadingEmptyFrames leaves the frames before it out)",
                          input.frameNumber(0), input.frameNumber(k))
            : std::string("tracks: no frame has a track"));
  }
  // A rolling shutter's known readout: the tracks to a global shutter's first (the row is the
  // sensor's, before any undistortion).
  Tracks rs_corrected;
  const Tracks* raw = &input;
  const std::optional<double> known_readout = knownReadout(o);
  if (known_readout) {
    const double tau = *known_readout;
    if (tau != 0.0) {
      rs_corrected = correctRollingShutter(input, tau);
      raw = &rs_corrected;
      say(fmt::format("rolling shutter: readout {:g} frame intervals, the tracks moved to a global shutter's positions", tau));
    }
  }
  // A known camera: the tracks onto its ideal pinhole, its intrinsics known.
  EstimateOptions known = o;
  if (known_readout) known.refine.estimate_readout = false;  // known: not a parameter
  Tracks undistorted;
  const Tracks* t = raw;
  if (o.camera) {
    if (o.filter.focal_px > 0) throw std::invalid_argument("a calibrated camera and a known focal length exclude each other");
    r.camera = vision::calibrationForTracks(*o.camera, input.image);
    const vision::CameraCalibration& cam = *r.camera;
    if (input.image.readout_direction != ReadoutDirection::Down && cam.width == o.camera->width &&
        cam.height == o.camera->height)  // not turned: calibrationForTracks turns only what changes the size
      say(fmt::format("camera: the tracks' video was turned (readout {}) and the calibration's size is theirs, so it is "
                      "taken as made on the frames as decoded (a 180-degree turn cannot be told from the size)",
                      readoutDirectionName(input.image.readout_direction)));
    undistorted = vision::undistortTracks(*raw, cam);
    t = &undistorted;
    known.filter.focal_px = cam.focal();
    known.refine.estimate_principal_point = false;
    known.refine.estimate_distortion = false;
    say(fmt::format("camera: {} ({}x{}, f {:.1f} px, principal point ({:.1f}, {:.1f}){})", cam.source, cam.width, cam.height,
                    cam.focal(), cam.cx, cam.cy, cam.distorted() ? ", tracks undistorted" : ""));
  }
  if (o.principal_point) {
    const Eigen::Vector2d& pp = *o.principal_point;
    if (!(pp.x() >= 0 && pp.x() <= input.image.width - 1 && pp.y() >= 0 && pp.y() <= input.image.height - 1))
      throw std::invalid_argument(fmt::format("--principal-point ({}, {}) is outside the {}x{} image", pp.x(), pp.y(),
                                              input.image.width, input.image.height));
    if (t != &undistorted) {
      undistorted = *raw;
      t = &undistorted;
    }
    undistorted.image.cx = o.principal_point->x();
    undistorted.image.cy = o.principal_point->y();
    known.refine.estimate_principal_point = false;
  }
  // The still start and the later still stretches (issue 14 item 1): the reference frame is the
  // last frame before the scene moves, and the stages run on the frames from there without the
  // later still frames.
  r.still = vision::findStillStart(*t, o.still_px, vision::kHomographyTestTracks);
  const int still = r.still.still_frames;
  std::vector<int> kept;
  {
    size_t h = 0;
    // The last frame with an observation: empty frames after it are where the tracks ran out
    // (the filter says so and ends there), not a gap to go across.
    int last_seen = t->numFrames() - 1;
    while (last_seen > 0 && t->frames[static_cast<size_t>(last_seen)].empty()) --last_seen;
    for (int k = still; k < t->numFrames(); ++k) {
      while (h < r.still.held.size() && r.still.held[h] < k) ++h;
      const bool held = h < r.still.held.size() && r.still.held[h] == k;
      // A frame without a single observation before the last one with some (a stretch where
      // nothing was tracked; a tracks file with a frame missing) says nothing: left out, and the
      // stages go on across it (the tracks that continue past it join its neighbours).
      const bool empty = k < last_seen && t->frames[static_cast<size_t>(k)].empty();
      if (empty) r.unobserved_frames.push_back(t->frameNumber(k));
      if (!held && !empty) kept.push_back(k);
    }
  }
  Tracks from_motion;
  if (static_cast<int>(kept.size()) < t->numFrames()) {
    from_motion.image = t->image;
    from_motion.source = t->source;
    from_motion.first_frame = t->frameNumber(still);
    for (int k : kept) {
      from_motion.frames.push_back(t->frames[static_cast<size_t>(k)]);
      from_motion.frame_numbers.push_back(t->frameNumber(k));
    }
    if (still > 0)
      say(fmt::format("still: frames {}-{} are still (fewer than {} tracks more than {:.2f} px from frame {}; tracking noise "
                      "{:.2f} px); the reference frame is {}",
                      t->frameNumber(0), t->frameNumber(still - 1), vision::kHomographyTestTracks, r.still.threshold_px,
                      t->frameNumber(0), r.still.noise_px, from_motion.first_frame));
    if (!r.unobserved_frames.empty()) {
      std::string runs;
      for (const auto& [first, last] : consecutiveStretches(r.unobserved_frames))
        runs += fmt::format("{}{}-{}", runs.empty() ? "" : ", ", first, last);
      say(fmt::format("frames {} have no observations (nothing tracked there): left out, the estimate goes on across "
                      "them, and they have no pose in the outputs",
                      runs));
    }
    if (!r.still.held.empty()) {
      std::string runs;
      for (const auto& [first, last] : vision::heldStretches(r.still))
        runs += fmt::format("{}{}-{}", runs.empty() ? "" : ", ", t->frameNumber(first), t->frameNumber(last));
      say(fmt::format("still: frames {} are still after the motion started (held: they carry the pose of the frame before)",
                      runs));
    }
    t = &from_motion;
  }
  // The stages' tracks: the plane finder's cuts (tracks that left their plane) are applied to them.
  Tracks on_planes = *t;
  const Tracks& tracks = on_planes;
  r.image = tracks.image;
  double t_stage = steadySeconds();
  auto stageDone = [&](double* seconds) {
    const double t = steadySeconds();
    *seconds = t - t_stage;
    t_stage = t;
  };
  {
    vision::PlaneFinderOptions fo = o.finder;
    if (o.filter.model == TrackModel::Plane && fo.rois.empty()) fo.max_planes = 1;  // the dominant plane only
    r.planes = vision::findPlanes(tracks, fo);
  }
  r.observations_cut = dropObservationsAfter(&on_planes, r.planes.cut_after);
  stageDone(&r.seconds.plane_finding);
  const vision::PlaneFinding& pf = r.planes;
  if (pf.numPlanes() == 0) {
    // Nothing moved at all: every candidate is static, and fewer reference tracks than a plane
    // needs ever move more than the noise does (PlaneTolerances::still_px, at least static_px)
    // from where they were in frame 0.
    const double still_px = pf.tolerances.still_px;
    int moving = 0, total = 0;
    for (const TrackPoint& p0 : tracks.frames.empty() ? std::vector<TrackPoint>{} : tracks.frames[0]) {
      double m = 0;
      for (int k = 1; k < tracks.numFrames(); ++k)
        if (const TrackPoint* pk = tracks.find(k, p0.id)) m = std::max(m, (pk->px - p0.px).norm());
      moving += m > still_px;
      ++total;
    }
    const bool all_static = !pf.candidates.empty() &&
                            std::all_of(pf.candidates.begin(), pf.candidates.end(),
                                        [](const vision::FoundPlane& c) { return c.verdict == vision::PlaneVerdict::Static; });
    if (all_static && moving < o.finder.min_plane_tracks)
      throw NoPlaneFound(fmt::format("nothing moves: {} of the {} tracks of frame {} ever move more than {:.1f} px in {} frames "
                                     "(a still camera before a still scene determines neither motion nor structure); use a "
                                     "stretch where the camera or the object moves (--first, --last)",
                                     moving, total, tracks.first_frame, still_px, tracks.numFrames()));
    std::string cands;
    std::size_t still = 0;
    for (const auto& c : pf.candidates) {
      cands += fmt::format("{}{} {} tracks", cands.empty() ? "" : ", ", vision::toString(c.verdict), c.members.size());
      if (c.verdict == vision::PlaneVerdict::Static) still += c.members.size();
    }
    // Most of the scene still (a still camera) and what moves is no plane: people walking before
    // a fixed camera (opencv-doc vtest.avi: 273 of 330 tracks still), leaves in the wind.
    if (2 * still >= static_cast<std::size_t>(total))
      throw NoPlaneFound(fmt::format("no moving plane: {} of the {} tracks of frame {} are still (a still camera), and the {} "
                                     "that move form no plane of {} tracks (candidates: {}); a moving object needs that many "
                                     "tracks on one of its planes: try --plane-roi around it or --min-plane-tracks",
                                     still, total, tracks.first_frame, moving, o.finder.min_plane_tracks, cands));
    throw NoPlaneFound(fmt::format("no plane with at least {} tracks found in the reference frame (tracks: {}; candidates: {}; "
                                   "try --min-plane-tracks, --ransac-px or --plane-roi)",
                                   o.finder.min_plane_tracks, tracks.frames.empty() ? 0 : tracks.frames[0].size(),
                                   cands.empty() ? "none" : cands));
  }
  {
    std::string tried;
    for (const auto& tr : pf.pair_frame_tries)
      tried += fmt::format("{}{}: {}/{}{}", tried.empty() ? "" : ", ", tracks.frameNumber(tr.frame), tr.planes, tr.tracks_in_planes,
                           tr.loses_plane ? " (loses a plane)" : "");
    const vision::PlaneTolerances& tol = pf.tolerances;
    std::string line = fmt::format("planes: {} accepted (pair frame {}; planes/tracks at the frames tried: {}; tracking noise {} px: "
                                   "tolerances RANSAC {:.2f}, stray {:.2f}, static {:.2f} px{}):",
                                   pf.numPlanes(), tracks.frameNumber(pf.pair_frame), tried.empty() ? "none" : tried,
                                   tol.noise_px > 0 ? fmt::format("{:.3f}", tol.noise_px) : std::string("not measured"),
                                   tol.ransac_px, tol.verify_px, tol.static_px,
                                   pf.widened ? ", widened: the options' found fewer planes or half the tracks" : "");
    for (const auto& c : pf.candidates)
      line += fmt::format(" [{} {} tracks, motion {:.1f} px{}]", vision::toString(c.verdict), c.members.size(),
                          c.median_motion_px,
                          c.same_motion_fraction >= 0 ? fmt::format(", same-motion {:.2f}", c.same_motion_fraction) : "");
    const int cut = pf.tracksCut();
    say(line + fmt::format("; outliers {}", pf.count(-1)) +
        (cut > 0 ? fmt::format("; {} tracks used up to where they left their plane ({} observations after that left out)", cut,
                               r.observations_cut)
                 : std::string()));
  }
  TrackFilterOptions fopt = known.filter;
  // The filter's measurement noise (issue 14 item 5; docs/estimate.md section 3): the option is a
  // floor, raised to the tracking noise the finder measured from the tracks' second differences
  // (or was given, PlaneFinderOptions::noise_px). With tracks noisier than the floor every
  // update would weigh them as if they were exact: on box-orbit's geometry with 1 / 2 px of noise
  // the normalized innovations were 3.9 / 15.5 per degree of freedom with the floor 0.5 px, 1.0
  // with the measured noise, and the online focal length's error 71 / 22 sds instead of 18 / 6
  // (test Adaptive.TheFiltersMeasurementNoiseFollowsTheMeasuredTrackingNoise).
  // Cleaner tracks keep the floor: a model error (distortion, a principal point held at the
  // centre) is not white noise, and a smaller sd would make the filter surer than it is.
  if (pf.tolerances.noise_px > fopt.sigma_px) {
    say(fmt::format("filter: measurement noise {:.3f} px per axis, the measured tracking noise (the floor --sigma-px is {:.2f} px)",
                    pf.tolerances.noise_px, fopt.sigma_px));
    fopt.sigma_px = pf.tolerances.noise_px;
  }
  // The start's focal length at an end of its grid: warned about unless the refinement then
  // determines the focal length from the whole sequence (box.mp4's windows @8, @16).
  bool start_at_grid_end = false;
  if (o.homography_start) {
    r.start_tried = true;
    r.start = vision::planeStart(tracks, pf, fopt.focal_px);
    vision::PlaneStart& start = r.start;
    const int m = fopt.model == TrackModel::Plane ? 1 : pf.numPlanes();
    if (!start.ok) say("start: " + start.note + "; planes start frontal");
    else if (start.hypotheses.size() > 1) {
      // The point model starts its depths on the chosen hypothesis's planes; the hypotheses are
      // scored by the planes model's filter (they are hypotheses about planes).
      TrackFilterOptions scoring = fopt;
      if (scoring.model == TrackModel::Point) scoring.model = TrackModel::Planes;
      // Scored on the tracks that stay on their planes: a cut track's last frames before its cut
      // may already be sliding (within the noise's quantile), and on lowtex-orbit the 39 cut
      // ones turned the scores over (frontal 3.9 -> 8.2 against 5.0 for a 325 px start 38 deg
      // off).
      std::vector<int> whole = pf.labels;
      for (size_t id = 0; id < pf.cut_after.size() && id < whole.size(); ++id)
        if (pf.cut_after[id] >= 0) whole[id] = -1;
      scoreStartHypotheses(tracks, whole, scoring, m, &start);
    }
    const vision::StartHypothesis& h = start.used();
    fopt = startOptions(fopt, h, m);
    if (start.hypotheses.size() > 1) {
      std::string line =
          start.scored_from < 0
              ? fmt::format("start: {} hypotheses, every scoring filter stopped:", start.hypotheses.size())
              : fmt::format("start: {} hypotheses scored on frames {}-{} (chi-square per observation):", start.hypotheses.size(),
                            start.scored_from, start.scored_to);
      for (size_t i = 0; i < start.hypotheses.size(); ++i) {
        const vision::StartHypothesis& c = start.hypotheses[i];
        line += c.frontal ? " [frontal" : fmt::format(" [{:.0f} px branch {} disagreement {:.1f} deg", c.focal_px, c.branch, c.disagreement_deg);
        line += std::isfinite(c.score) ? fmt::format(": {:.3f}", c.score) : std::string(": stopped");
        line += static_cast<int>(i) == start.chosen ? ", chosen]" : "]";
      }
      say(line);
    }
    if (h.frontal) {
      if (start.ok) say("start: every plane frontal at the focal guess (the best-scored start)");
    } else {
      std::string line = fmt::format("start: focal {:.0f} px from the homographies (disagreement {:.2f} deg), normals",
                                     h.focal_px, h.disagreement_deg);
      for (const auto& n : h.normals) line += fmt::format(" ({:.2f}, {:.2f}, {:.2f})", n.x(), n.y(), n.z());
      say(line);
      start_at_grid_end = h.at_grid_end;
    }
  }
  if (o.late_planes && fopt.model == TrackModel::Planes && o.finder.rois.empty()) {
    const int cut_before = pf.tracksCut();
    fopt.late_planes = findLatePlanes(tracks, &r.planes, o.finder);
    const std::size_t late_observations_cut = dropObservationsAfter(&on_planes, r.planes.cut_after);
    r.observations_cut += late_observations_cut;
    if (!fopt.late_planes.empty()) {
      std::string line = fmt::format("planes: {} more came into view later:", fopt.late_planes.size());
      for (const auto& lp : fopt.late_planes)
        line += fmt::format(" [plane {}: {} tracks from frame {}, placed from frame {} on]", lp.label, pf.count(lp.label),
                            tracks.frameNumber(lp.first_frame), tracks.frameNumber(lp.init_frame));
      if (pf.tracksCut() > cut_before)
        line += fmt::format("; {} of their tracks used up to where they left their plane ({} observations after that left out)",
                            pf.tracksCut() - cut_before, late_observations_cut);
      say(line);
    }
  }
  stageDone(&r.seconds.start);
  r.filter_used = fopt;
  r.online = runTrackFilter(tracks, pf.labels, fopt, progress);
  if (!fopt.late_planes.empty() && !r.online.plane_of_label.empty()) {
    // The state's planes in the order they joined; a late plane that never could be placed: outliers.
    std::vector<int>& labels = r.planes.labels;
    for (int& l : labels)
      if (l >= 0 && l < static_cast<int>(r.online.plane_of_label.size())) l = r.online.plane_of_label[static_cast<size_t>(l)];
    std::vector<char> taken(r.online.plane_of_label.size(), 0);
    for (auto& c : r.planes.candidates) {
      if (c.label < 0 || c.label >= static_cast<int>(r.online.plane_of_label.size())) continue;
      c.label = r.online.plane_of_label[static_cast<size_t>(c.label)];
      if (c.label < 0) {
        c.verdict = vision::PlaneVerdict::NotTriangulated;
        say(fmt::format("planes: a plane of {} tracks from frame {} never had the parallax to be placed: its tracks are left out",
                        c.members.size(), tracks.frameNumber(c.first_frame)));
      } else if (taken[static_cast<size_t>(c.label)]) {
        c.verdict = vision::PlaneVerdict::Rejoined;
        say(fmt::format("planes: the {} tracks of frame {} on are plane {} seen again: they joined it", c.members.size(),
                        tracks.frameNumber(c.first_frame), c.label));
      } else {
        taken[static_cast<size_t>(c.label)] = 1;
      }
    }
  }
  stageDone(&r.seconds.filter);
  if (!r.online.ended.empty()) say("warning: " + r.online.ended);
  if (!r.online.pass_stopped.empty()) say("warning: the filter's " + r.online.pass_stopped);
  if (o.refine.enabled && r.online.ok()) {
    // The refinement covers the frames the filter estimated.
    Tracks covered;
    const Tracks* rt = &tracks;
    if (static_cast<int>(r.online.frames.size()) < tracks.numFrames()) {
      covered = tracks;
      covered.frames.resize(r.online.frames.size());
      if (!covered.frame_numbers.empty()) covered.frame_numbers.resize(r.online.frames.size());
      rt = &covered;
    }
    // The point model has no planes in its state, but its tracks are on the finder's planes: the
    // refinement (the plane model's bundle adjustment, docs/estimate.md section 4) starts from the
    // planes model's filter run on the same tracks from the same start (without planes that come
    // into view later), so that the point model's final result is the planes model's; the point
    // filter's figures are the online ones.
    // (Started from the point filter's own motions, the ViSP cube's refinement ended in a local
    // optimum at 236 px with a residual sd of 3.7 px.)
    TrackFilterResult planes_start;
    const TrackFilterResult* from = &r.online;
    if (fopt.model == TrackModel::Point) {
      TrackFilterOptions po = fopt;
      po.model = TrackModel::Planes;
      planes_start = runTrackFilter(*rt, pf.labels, po);
      from = &planes_start;
      if (planes_start.ok() && planes_start.frames.size() < r.online.frames.size())
        planes_start.stopped = "it ended before the point filter (" + planes_start.ended + ")";
    }
    if (from->ok()) {
      r.refined = refine(*rt, pf.labels, *from, fopt, known.refine, note);
    } else {
      r.refined = RefineResult{};
      r.refined.message = "the planes model's filter, the refinement's start, stopped: " + from->stopped;
    }
    stageDone(&r.seconds.refinement);
    if (r.refined.ok) {
      say(fmt::format("refine: focal {:.1f} px, {} in {:.2f} s", r.refined.state.scale_px / r.refined.state.frames.back().beta,
                      r.refined.message, r.refined.seconds));
      if (!r.refined.why.empty()) say("refine: not determined: " + r.refined.why);
      r.refined.online_accuracy = onlineAccuracy(r.online, r.refined);
    } else {
      say("warning: refinement: " + r.refined.message + "; the online estimate stands");
    }
  }
  if (start_at_grid_end && !(r.refined.ok && r.refined.focal_determined)) say(std::string("warning: ") + kFocalGridEndWarning);
  if (t == &from_motion) {
    // The still frames carry the pose of the frame before them: every input frame has a record.
    fillStill(&r.online, nullptr, kept, input);
    coverIds(&r.planes.labels, input, from_motion);
    r.planes.pair_frame = kept[static_cast<size_t>(r.planes.pair_frame)] - still;  // from the reference frame
    for (int& k : r.planes.cut_after)
      if (k >= 0) k = kept[static_cast<size_t>(k)] - still;
    for (auto& c : r.planes.candidates) {
      if (c.pair_frame >= 0) c.pair_frame = kept[static_cast<size_t>(c.pair_frame)] - still;
      c.first_frame = kept[static_cast<size_t>(c.first_frame)] - still;
    }
    for (int& k : r.online.plane_first_frame)
      if (k > 0) k = kept[static_cast<size_t>(k)];  // an index of the filled frames (the reference frame's planes: 0, every frame)
    if (r.refined.ok) r.refined.state.plane_first_frame = r.online.plane_first_frame;
    for (auto& tr : r.planes.pair_frame_tries) tr.frame = kept[static_cast<size_t>(tr.frame)] - still;
    if (r.refined.ok) {
      fillStill(&r.refined.state, &r.refined.cov_motion, kept, input);
      for (int& k : r.refined.undetermined_frames) k = kept[static_cast<size_t>(k)];
      coverIds(&r.refined.labels, input, from_motion);
    }
  }
  r.last_used = lastFramesUsed(input, r);
  return r;
}

PatchEstimateResult estimatePatches(const PatchTracks& tracks, const PatchEstimateOptions& o,
                                    const std::function<void(const std::string&)>& note,
                                    const std::function<void(int, int)>& progress) {
  PatchEstimateResult r;
  PatchPipelineOptions po = o.patch;
  // The patch centres as point tracks: the focal start and the motion check work on them.
  Tracks centres;
  centres.image = tracks.image;
  centres.first_frame = tracks.first_frame;
  for (const auto& f : tracks.frames) {
    std::vector<TrackPoint> pts;
    for (const auto& p : f) pts.push_back({p.id, p.px});
    centres.frames.push_back(std::move(pts));
  }
  if (o.motion_check) {
    // Does the camera translate, does it rotate? The plane pipeline's refinement answers with
    // likelihood ratios against a pure rotation and a pure translation (pipeline/refine.hpp);
    // a still sequence is refused here as there ("nothing moves").
    PatchMotionCheck& m = r.motion;
    EstimateOptions eo;
    eo.filter.model = TrackModel::Planes;
    eo.filter.focal_px = po.focal_px;
    eo.finder = o.finder;
    eo.still_px = po.still_px;
    eo.finder.min_plane_tracks = std::min(eo.finder.min_plane_tracks, vision::kHomographyTestTracks);
    try {
      const EstimateResult er = estimate(centres, eo);
      if (er.refined.ok) {
        const RefineResult& rf = er.refined;
        m.checked = true;
        m.translates = rf.translation_significant;
        m.focal_determined = rf.focal_determined;
        const TrackFrame& last = rf.state.frames.back();
        m.focal_px = rf.state.scale_px / last.beta;
        m.focal_sd_px = rf.state.scale_px * std::sqrt(std::max(0.0, last.var_beta)) / (last.beta * last.beta);
        m.focal_interval_px = rf.focal_interval_px;
        m.rotation_lr = rf.rotation_lr;
        m.translation_lr = rf.translation_lr;
        if (!m.translates || !m.focal_determined) m.why = rf.why;
      } else {
        m.note = "not conclusive: the check's refinement failed (" + rf_message(er) + ")";
      }
    } catch (const NoPlaneFound& ex) {
      if (std::string(ex.what()).rfind("nothing moves", 0) == 0) throw;
      m.note = std::string("not run: ") + ex.what();
    } catch (const std::invalid_argument& ex) {
      m.note = std::string("not run: ") + ex.what();
    }
    if (note && !m.checked) note("motion check: " + m.note);  // a verdict is said once, with the estimate
  }
  if (o.homography_start && po.focal_px <= 0 && po.focal0_px <= 0) {
    // Focal start as for the plane models: homographies of the patch centres (as point tracks)
    // decomposed over a focal grid (vision/plane_init.hpp). Only the focal length is taken: every
    // patch still starts fronto-parallel, so its normal is the filter's own estimate.
    r.start_tried = true;
    vision::PlaneStart& start = r.start;
    try {
      vision::PlaneFinderOptions fo = o.finder;
      fo.min_plane_tracks = std::min(fo.min_plane_tracks, vision::kHomographyTestTracks);
      const vision::PlaneFinding pf = vision::findPlanes(centres, fo);
      if (pf.numPlanes() > 0)
        start = vision::planeStart(centres, pf, 0.0);
      else
        start.note = "no plane among the patch centres";
    } catch (const std::exception& ex) {
      start.note = ex.what();
    }
    if (start.ok) {
      po.focal0_px = start.used().focal_px;
      if (!po.beta_sd0) po.beta_sd0 = 0.1;
    }
    if (note)
      note(fmt::format("start: {}",
                       start.ok ? fmt::format("focal {:.0f} px from homographies of the patch centres{}", start.used().focal_px,
                                              start.used().at_grid_end ? fmt::format("\nwarning: {}", kFocalGridEndWarning) : "")
                                : start.note + "; focal starts at max(width, height)"));
  }
  r.patch_used = po;
  r.run = runPatchTracks(tracks, po, progress);
  return r;
}

}  // namespace rsfm
