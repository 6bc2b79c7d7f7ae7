#include "rsfm/vision/plane_finder.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <stdexcept>
#include <unordered_set>

namespace rsfm::vision {

const char* toString(PlaneVerdict v) {
  switch (v) {
    case PlaneVerdict::Accepted: return "accepted";
    case PlaneVerdict::Static: return "static";
    case PlaneVerdict::OtherMotion: return "other-motion";
    case PlaneVerdict::TooFew: return "too-few";
    case PlaneVerdict::NotTriangulated: return "not-triangulated";
    case PlaneVerdict::Rejoined: return "rejoined";
  }
  return "?";
}

int PlaneFinding::numPlanes() const {
  int m = 0;
  for (const auto& c : candidates) m += c.verdict == PlaneVerdict::Accepted;
  return m;
}

int PlaneFinding::count(int label) const {
  return static_cast<int>(std::count(labels.begin(), labels.end(), label));
}

int PlaneFinding::tracksCut() const {
  int n = 0;
  for (std::size_t id = 0; id < cut_after.size() && id < labels.size(); ++id) n += cut_after[id] >= 0 && labels[id] >= 0;
  return n;
}

namespace {

cv::Point2d apply(const cv::Matx33d& H, const cv::Point2d& p) {
  const cv::Vec3d q = H * cv::Vec3d(p.x, p.y, 1.0);
  return {q[0] / q[2], q[1] / q[2]};
}

cv::Point2d pt(const TrackPoint& t) { return {t.px.x(), t.px.y()}; }

/// Least-squares homography from correspondences (>= 4), or false: the normalized DLT (Hartley),
/// the smallest eigenvector of A^T A (9 x 9), which is much cheaper than cv::findHomography's
/// iterative refinement and is what the per-frame checks need.
bool fitH(const std::vector<cv::Point2d>& a, const std::vector<cv::Point2d>& b, cv::Matx33d* H) {
  const size_t n = a.size();
  if (n < 4) return false;
  // Hartley's normalization: centroid to the origin, mean distance sqrt(2).
  struct Norm {
    double s, cx, cy;
  };
  auto normalizer = [](const std::vector<cv::Point2d>& p) {
    double cx = 0, cy = 0;
    for (const auto& q : p) {
      cx += q.x;
      cy += q.y;
    }
    cx /= static_cast<double>(p.size());
    cy /= static_cast<double>(p.size());
    double d = 0;
    for (const auto& q : p) d += std::sqrt((q.x - cx) * (q.x - cx) + (q.y - cy) * (q.y - cy));
    d /= static_cast<double>(p.size());
    return Norm{d > 1e-12 ? std::sqrt(2.0) / d : 1.0, cx, cy};
  };
  const Norm na = normalizer(a), nb = normalizer(b);
  const cv::Matx33d Ta(na.s, 0, -na.s * na.cx, 0, na.s, -na.s * na.cy, 0, 0, 1);
  const cv::Matx33d Tb(nb.s, 0, -nb.s * nb.cx, 0, nb.s, -nb.s * nb.cy, 0, 0, 1);
  // A^T A from its structure: with P = (p, 1) and the rows r1 = (P, 0, -q_x P),
  // r2 = (0, P, -q_y P), sum r1 r1^T + r2 r2^T has 3 x 3 blocks S, 0, -Sx / 0, S, -Sy /
  // -Sx, -Sy, Sxy for S = sum P P^T, Sx = sum q_x P P^T, Sy = sum q_y P P^T,
  // Sxy = sum (q_x^2 + q_y^2) P P^T: the six distinct entries of P P^T weighted four ways per
  // point instead of two 9 x 9 outer products.
  double acc[4][6] = {};
  for (size_t i = 0; i < n; ++i) {
    const double px = na.s * (a[i].x - na.cx), py = na.s * (a[i].y - na.cy);
    const double qx = nb.s * (b[i].x - nb.cx), qy = nb.s * (b[i].y - nb.cy);
    const double pp[6] = {px * px, px * py, px, py * py, py, 1.0};
    const double w[4] = {1.0, qx, qy, qx * qx + qy * qy};
    for (int j = 0; j < 4; ++j)
      for (int e = 0; e < 6; ++e) acc[j][e] += w[j] * pp[e];
  }
  auto block = [&](int j) {
    const double* v = acc[j];
    Eigen::Matrix3d B;
    B << v[0], v[1], v[2], v[1], v[3], v[4], v[2], v[4], v[5];
    return B;
  };
  const Eigen::Matrix3d S = block(0), Sx = block(1), Sy = block(2), Sxy = block(3);
  Eigen::Matrix<double, 9, 9> M = Eigen::Matrix<double, 9, 9>::Zero();
  M.block<3, 3>(0, 0) = S;
  M.block<3, 3>(3, 3) = S;
  M.block<3, 3>(0, 6) = -Sx;
  M.block<3, 3>(6, 0) = -Sx;
  M.block<3, 3>(3, 6) = -Sy;
  M.block<3, 3>(6, 3) = -Sy;
  M.block<3, 3>(6, 6) = Sxy;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 9, 9>> es(M);
  if (es.info() != Eigen::Success) return false;
  const Eigen::Matrix<double, 9, 1> h = es.eigenvectors().col(0);
  const cv::Matx33d Hn(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
  cv::Matx33d Hd = Tb.inv() * Hn * Ta;
  if (!std::isfinite(Hd(2, 2)) || std::abs(Hd(2, 2)) < 1e-12) return false;
  *H = Hd * (1.0 / Hd(2, 2));
  return true;
}

/// The points of x -> xp that show parallax against H1 (off H1 x by at least 2 tol_px): H1 x in
/// *a and x' in *b (homogeneous, pixels).
void parallaxPoints(const cv::Matx33d& H1, const std::vector<cv::Point2d>& x, const std::vector<cv::Point2d>& xp,
                    double tol_px, std::vector<cv::Vec3d>* a, std::vector<cv::Vec3d>* b) {
  for (size_t i = 0; i < x.size(); ++i) {
    const cv::Point2d h = apply(H1, x[i]);
    if (std::hypot(h.x - xp[i].x, h.y - xp[i].y) < 2.0 * tol_px) continue;  // no parallax
    a->emplace_back(h.x, h.y, 1.0);
    b->emplace_back(xp[i].x, xp[i].y, 1.0);
  }
}

/// Distance (px) of x' from the epipolar line through e and H1 x.
double epipolarDistance(const cv::Vec3d& e, const cv::Vec3d& a, const cv::Vec3d& b) {
  const cv::Vec3d l = e.cross(a);
  const double nrm = std::hypot(l[0], l[1]);
  return nrm < 1e-12 ? 1e9 : std::abs(l.dot(b)) / nrm;
}

int epipoleInliers(const cv::Vec3d& e, const std::vector<cv::Vec3d>& a, const std::vector<cv::Vec3d>& b, double tol_px) {
  int in = 0;
  for (size_t k = 0; k < a.size(); ++k) in += epipolarDistance(e, a[k], b[k]) < tol_px;
  return in;
}

/// RANSAC over pairs of parallax points for the epipole most of them agree with; its inliers.
int fitEpipole(const std::vector<cv::Vec3d>& a, const std::vector<cv::Vec3d>& b, double tol_px, unsigned seed,
               cv::Vec3d* e_best) {
  const int n = static_cast<int>(a.size());
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  int best = 0;
  for (int it = 0; it < 300; ++it) {
    const int i = pick(rng), j = pick(rng);
    if (i == j) continue;
    const cv::Vec3d e = a[i].cross(b[i]).cross(a[j].cross(b[j]));  // intersection of the two lines
    if (cv::norm(e) < 1e-12) continue;
    const int in = epipoleInliers(e, a, b, tol_px);
    if (in > best) best = in, *e_best = e;
  }
  return best;
}

}  // namespace

double sameMotionFraction(const cv::Matx33d& H1, const std::vector<cv::Point2d>& x, const std::vector<cv::Point2d>& xp,
                          double tol_px, unsigned seed) {
  std::vector<cv::Vec3d> a, b;
  parallaxPoints(H1, x, xp, tol_px, &a, &b);
  if (a.size() < 5) return -1.0;
  cv::Vec3d e;
  return static_cast<double>(fitEpipole(a, b, tol_px, seed, &e)) / a.size();
}

double epipoleAgreement(const cv::Matx33d& H1, const std::vector<cv::Point2d>& by_x, const std::vector<cv::Point2d>& by_xp,
                        const std::vector<cv::Point2d>& x, const std::vector<cv::Point2d>& xp, double tol_px,
                        double min_fraction, unsigned seed) {
  std::vector<cv::Vec3d> ba, bb, a, b;
  parallaxPoints(H1, by_x, by_xp, tol_px, &ba, &bb);
  parallaxPoints(H1, x, xp, tol_px, &a, &b);
  if (ba.size() < 5 || a.size() < 5) return -1.0;
  // Over epipoles from pairs of the two planes' parallax points (either's, or one of each): the
  // most of x's points on the lines of an epipole that `by` accepts (min_fraction of its own).
  std::vector<cv::Vec3d> ua = ba, ub = bb;
  ua.insert(ua.end(), a.begin(), a.end());
  ub.insert(ub.end(), b.begin(), b.end());
  const int n = static_cast<int>(ua.size());
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  int best = -1;
  for (int it = 0; it < 500; ++it) {
    const int i = pick(rng), j = pick(rng);
    if (i == j) continue;
    const cv::Vec3d e = ua[i].cross(ub[i]).cross(ua[j].cross(ub[j]));
    if (cv::norm(e) < 1e-12) continue;
    if (epipoleInliers(e, ba, bb, tol_px) < min_fraction * ba.size()) continue;
    best = std::max(best, epipoleInliers(e, a, b, tol_px));
  }
  return best < 0 ? -1.0 : static_cast<double>(best) / a.size();
}

bool findsPlanesAgain(const std::vector<FoundPlane>& won, const std::vector<FoundPlane>& found,
                      const std::function<bool(int)>& alive, int min_plane_tracks) {
  for (const auto& p : won) {
    if (p.verdict != PlaneVerdict::Accepted) continue;
    std::unordered_set<int> live;
    for (int id : p.members)
      if (alive(id)) live.insert(id);
    if (static_cast<int>(live.size()) < min_plane_tracks) continue;  // cannot be found there
    size_t most = 0;
    for (const auto& q : found) {
      if (q.verdict != PlaneVerdict::Accepted) continue;
      size_t common = 0;
      for (int id : q.members) common += live.count(id);
      most = std::max(most, common);
    }
    if (2 * most <= live.size()) return false;
  }
  return true;
}

double trackNoisePx(const Tracks& tracks) {
  // Second differences a = x(k+1) - 2 x(k) + x(k-1) of every track seen in three consecutive
  // frames: white tracking noise of sd s per axis gives them the variance 6 s^2, while a smooth
  // motion gives them little. What a change of the camera's rotation adds (jitter, a shake) is
  // the small-rotation flow field, quadratic in the image position (u = xy w_x / f - (f + x^2 /
  // f) w_y + y w_z, and v alike), so each frame's least-squares fit of a quadratic in (x, y) per
  // axis is removed first; the rest's per-axis robust sd (1.4826 x the median absolute value) /
  // sqrt 6 is the noise. Tracking error that drifts slowly is not white and does not show here.
  constexpr int kTerms = 6;
  using Basis = Eigen::Matrix<double, kTerms, 1>;
  const int F = tracks.numFrames();
  const double scale = std::max(1.0, 0.5 * std::max(tracks.image.width, tracks.image.height));
  const Eigen::Vector2d centre(tracks.image.cx, tracks.image.cy);
  auto basis = [&](const Eigen::Vector2d& x) {
    const Eigen::Vector2d u = (x - centre) / scale;
    Basis b;
    b << 1.0, u.x(), u.y(), u.x() * u.x(), u.x() * u.y(), u.y() * u.y();
    return b;
  };
  std::vector<double> r;
  std::vector<Eigen::Vector2d> pos, acc;
  for (int k = 1; k + 1 < F; ++k) {
    pos.clear();
    acc.clear();
    for (const TrackPoint& p : tracks.frames[k]) {
      const TrackPoint* a = tracks.find(k - 1, p.id);
      const TrackPoint* b = tracks.find(k + 1, p.id);
      if (!a || !b) continue;
      pos.push_back(p.px);
      acc.push_back(b->px - 2.0 * p.px + a->px);
    }
    const int n = static_cast<int>(pos.size());
    if (n < 4 * kHomographyTestTracks) continue;  // too few to leave the noise after the fit
    // Least squares, then once more over the tracks within 3 robust sds of the first fit (an
    // object moving on its own before the background, a slipped track: not the frame's field).
    std::vector<double> e_abs(static_cast<size_t>(n));
    Eigen::Matrix<double, kTerms, 2> A = Eigen::Matrix<double, kTerms, 2>::Zero();
    double cut = std::numeric_limits<double>::infinity();
    bool fitted = false;
    for (int pass = 0; pass < 2; ++pass) {
      Eigen::Matrix<double, kTerms, kTerms> N = Eigen::Matrix<double, kTerms, kTerms>::Zero();
      Eigen::Matrix<double, kTerms, 2> B = Eigen::Matrix<double, kTerms, 2>::Zero();
      int used = 0;
      for (int i = 0; i < n; ++i) {
        if (pass > 0 && e_abs[static_cast<size_t>(i)] > cut) continue;
        const Basis u = basis(pos[i]);
        N += u * u.transpose();
        B += u * acc[i].transpose();
        ++used;
      }
      if (used < 4 * kHomographyTestTracks) break;
      const Eigen::LDLT<Eigen::Matrix<double, kTerms, kTerms>> ldlt(N);
      if (ldlt.info() != Eigen::Success) break;
      const Eigen::Matrix<double, kTerms, 2> A1 = ldlt.solve(B);
      if (!A1.allFinite()) break;
      A = A1;
      fitted = true;
      for (int i = 0; i < n; ++i) e_abs[static_cast<size_t>(i)] = (acc[i] - A.transpose() * basis(pos[i])).norm();
      std::vector<double> tmp = e_abs;
      std::nth_element(tmp.begin(), tmp.begin() + n / 2, tmp.end());
      cut = 3.0 * 1.4826 * tmp[static_cast<size_t>(n / 2)];  // |e| of 2 axes: a generous cut
    }
    if (!fitted) continue;
    // The tracks within the cut of the last fit: random-walking or slipped tracks (a fifth of
    // them read the noise 1.2x) are not the noise's measure.
    int used = 0;
    for (int i = 0; i < n; ++i) used += e_abs[static_cast<size_t>(i)] <= cut;
    if (used <= kTerms) continue;
    const double keep = std::sqrt(static_cast<double>(used) / (used - kTerms));  // the fit's own share
    for (int i = 0; i < n; ++i) {
      if (e_abs[static_cast<size_t>(i)] > cut) continue;
      const Eigen::Vector2d e = acc[i] - A.transpose() * basis(pos[i]);
      r.push_back(keep * std::abs(e.x()));
      r.push_back(keep * std::abs(e.y()));
    }
  }
  if (r.size() < 100) return -1.0;
  std::nth_element(r.begin(), r.begin() + static_cast<long>(r.size() / 2), r.end());
  return 1.4826 * r[r.size() / 2] / std::sqrt(6.0);
}

PlaneTolerances planeTolerances(const PlaneFinderOptions& o, double noise_px, int frames) {
  PlaneTolerances t;
  t.noise_px = noise_px;
  t.ransac_px = o.ransac_px;
  t.verify_px = o.verify_px;
  t.static_px = o.static_px;
  t.motion_px = o.motion_px;
  t.still_px = o.static_px;
  if (!(noise_px > 0)) return t;
  // A member's residual to its plane's homography carries the noise of its reference position
  // and of its position in the frame: sd s = sqrt 2 x noise per axis, a Rayleigh magnitude.
  const double s = std::sqrt(2.0) * noise_px;
  // At the pair frame (RANSAC, same-motion test): its 99.9 % quantile, s sqrt(-2 ln 0.001).
  const double one = s * std::sqrt(-2.0 * std::log(1e-3));
  // In every frame (the stray test; a track's own motion): the largest of `frames` residuals
  // stays below it with probability 0.99, s sqrt(2 ln(100 frames)).
  const double all = s * std::sqrt(2.0 * std::log(100.0 * std::max(frames, 2)));
  t.ransac_px = std::max(o.ransac_px, one);
  t.motion_px = std::max(o.motion_px, one);
  t.verify_px = std::max(o.verify_px, all);
  t.still_px = std::max(o.static_px, all);
  // A still plane's members move by the noise alone: their median displacement's largest value
  // over the frames stays below the median magnitude's ~2x.
  t.static_px = std::max(o.static_px, 2.0 * s * std::sqrt(2.0 * std::log(2.0)));
  return t;
}

namespace {

/// The search with the pixel tolerances `tol` (findPlanes).
PlaneFinding findPlanesWith(const Tracks& tracks, const PlaneFinderOptions& o, const PlaneTolerances& tol) {
  // A frame's homography tests a track when at least this many members determine it.
  constexpr int kMinSupport = kHomographyTestTracks;
  const int F = tracks.numFrames();
  const int ids = tracks.idBound();
  PlaneFinding res;
  res.labels.assign(ids, -1);
  res.tolerances = tol;
  const auto spans = trackSpans(tracks);
  for (int id = 0; id < ids; ++id)
    if (spans[id].first > 0 && spans[id].length() < o.min_new_track_frames) res.labels[id] = -2;
  std::vector<int> ref_ids;
  for (const auto& p : tracks.frames[0]) ref_ids.push_back(p.id);
  // The reference tracks that can be in any pair: seen in a later frame too. A tracker that
  // loses half of its new tracks at once (lowtex-fast-blur: 229 tracks in frame 0, 107 in
  // frame 1) would otherwise leave no frame with half of them alive, and the pair frame fell
  // back to frame 1, whose 4 px of motion cannot tell the planes apart.
  int n0 = 0;
  for (int id : ref_ids) n0 += spans[id].length() >= 2;
  // Whether each track's own motion reaches the verification tolerance from where it was first
  // seen (issue 14 item 2): a track that never does fits "still" as well as any moving plane, so
  // it cannot test one. Used by the pair frame and by every plane's member test below.
  std::vector<char> moves(ids, 0);
  for (int id = 0; id < ids; ++id) {
    const TrackSpan s = spans[id];
    const TrackPoint* p0 = s.first >= 0 ? tracks.find(s.first, id) : nullptr;
    double moved = 0.0;
    for (int k = s.first + 1; p0 && k <= s.last && moved < tol.verify_px; ++k)
      if (const TrackPoint* pk = tracks.find(k, id)) moved = std::max(moved, (pk->px - p0->px).norm());
    moves[id] = moved >= tol.verify_px;
  }

  // Pair frame: the last frame where half of the reference tracks are alive, and half of those
  // that can test a moving plane: the tracks whose own motion reaches the verification tolerance
  // somewhere in their lives (issue 14 item 2). A still background's tracks outlive an object's;
  // counting only all tracks put the pair frame where the object's tracks were nearly all gone
  // (webcam-object: 14 moving tracks alive at the pair frame, no plane). When fewer tracks move
  // than two planes need, only the first condition holds (nothing moves: the static planes are
  // found, and the run is refused with "nothing moves").
  std::vector<int> movers;
  for (int id : ref_ids)
    if (moves[id]) movers.push_back(id);
  if (static_cast<int>(movers.size()) < 2 * o.min_plane_tracks) movers.clear();
  // Pair frames are chosen up to this frame (PlaneFinderOptions::last_pair_frame).
  const int F_pair = o.last_pair_frame > 0 ? std::min(F, o.last_pair_frame + 1) : F;
  int pair = 1;
  for (int k = 1; k < F_pair; ++k) {
    int alive = 0, alive_movers = 0;
    for (int id : ref_ids) alive += tracks.find(k, id) != nullptr;
    for (int id : movers) alive_movers += tracks.find(k, id) != nullptr;
    if (alive >= std::max(o.min_alive_fraction * n0, 2.0 * o.min_plane_tracks) &&
        alive_movers >= o.min_alive_fraction * static_cast<double>(movers.size()))
      pair = k;
  }
  res.pair_frame = pair;

  // Each track's position in the reference frame: its own for reference tracks, its first
  // position carried back by its plane's homography for a track that joined later (NaN: none).
  std::vector<cv::Point2d> refpos(ids, cv::Point2d(NAN, NAN));
  for (const auto& p : tracks.frames[0]) refpos[p.id] = pt(p);
  // Per-frame least-squares homographies of a member set; drops members that stray. A frame's
  // homography comes from the reference members (`joined` false) while at least kMinSupport of
  // them are in view, else from every member: tracks that joined later extend a plane past its
  // reference tracks' lives but never outvote them.
  std::vector<char> joined(ids, 0);
  const double ransac_px = tol.ransac_px, verify_px = tol.verify_px;
  // The members' points in frame k, in the members' order (nullptr: not in view): one merge of
  // the members' ids (in the order `by_id`, idOrder's, computed once per member set) with the
  // frame's (sorted by id), not a search per member and frame.
  auto idOrder = [](const std::vector<int>& members) {
    std::vector<int> order(members.size());
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int x, int y) { return members[static_cast<size_t>(x)] < members[static_cast<size_t>(y)]; });
    return order;
  };
  auto pointsAt = [&](const std::vector<int>& members, const std::vector<int>& by_id, int k, std::vector<const TrackPoint*>* at) {
    at->assign(members.size(), nullptr);
    const std::vector<TrackPoint>& f = tracks.frames[static_cast<size_t>(k)];
    size_t j = 0;
    for (int m : by_id) {
      const int id = members[static_cast<size_t>(m)];
      while (j < f.size() && f[j].id < id) ++j;
      if (j == f.size()) break;
      if (f[j].id == id) (*at)[static_cast<size_t>(m)] = &f[j];
    }
  };
  std::vector<const TrackPoint*> at;
  // Where a member leaves its plane (an occlusion edge it slides along, a slow slip of the
  // tracker): its observations up to cut_after[id] count, the later ones are left out (-1: its
  // whole life; FoundPlane::cuts). A long sequence's tracks often follow their plane for hundreds
  // of frames and then slide; dropping them whole lost the planes there (a 240-deg orbit of
  // 1200 frames: the estimate ended at frame 273).
  std::vector<int> cut_after(ids, -1);
  // A member's part on the plane ends at its last residual within what the tracking noise gives
  // a member at most (its 99.9 % quantile, as the pair frame's; sd sqrt 2 x noise per axis:
  // planeTolerances), and at most half the stray tolerance: the frames where it was already
  // sliding away stay out. A track that strays and comes back within it is no slide.
  const double clean_px = std::min(
      0.5 * verify_px, tol.noise_px > 0 ? std::sqrt(2.0) * tol.noise_px * std::sqrt(-2.0 * std::log(1e-3)) : verify_px);
  // Cuts are made once the planes are chosen (below): the search, its pair frame and its verdicts
  // judge whole tracks, as a member that strays anywhere is no evidence for a plane there.
  bool allow_cuts = false;
  auto usedAt = [&](int id, int k) { return cut_after[id] < 0 || k <= cut_after[id]; };
  auto fitAllFrames = [&](FoundPlane* c) {
    std::vector<int> members = c->members;
    for (int id : members) cut_after[id] = -1;
    for (const auto& [id, last] : c->cuts) cut_after[id] = last;
    const double verify2 = verify_px * verify_px;
    const double clean2 = clean_px * clean_px;
    // Two rounds in the search (as before the cuts); once cuts are made, a third settles them.
    for (int round = 0; round < (allow_cuts ? 3 : 2); ++round) {
      c->H.assign(F, cv::Matx33d::eye());
      c->support.assign(F, 0);
      c->support[0] = static_cast<int>(members.size());
      // Per member: the first frame where it strays, and the last one before that with a clean residual.
      // And whether it came back to the plane after straying (a noise spike, not a slide).
      std::vector<int> strays(ids, -1), clean_at(ids, -1);
      std::vector<char> back(ids, 0);
      const std::vector<int> by_id = idOrder(members);
      std::vector<cv::Point2d> a, b;
      for (int k = 1; k < F; ++k) {
        pointsAt(members, by_id, k, &at);
        auto collect = [&](bool with_joined) {
          a.clear();
          b.clear();
          for (size_t m = 0; m < members.size(); ++m) {
            const int id = members[m];
            if (std::isfinite(refpos[id].x) && at[m] && usedAt(id, k) && (with_joined || !joined[id])) {
              a.push_back(refpos[id]);
              b.push_back(pt(*at[m]));
            }
          }
        };
        collect(false);
        if (static_cast<int>(a.size()) < kMinSupport) collect(true);
        if (!fitH(a, b, &c->H[k])) {
          c->H[k] = c->H[k - 1];
          continue;
        }
        // Once cuts are made, the frame's fit leaves out the points that stray from it (twice):
        // a few tracks sliding off together drag the least-squares homography, and the plane's
        // other members would be cut for it. (Not in the search: at the 3 px tolerance a noisy
        // sequence's good members stray too, and a fit without them judged the rest more
        // strictly: webcam-object lost a plane.)
        for (int it = 0; allow_cuts && it < 2; ++it) {
          size_t n = 0;
          for (size_t i = 0; i < a.size(); ++i) {
            const cv::Point2d q = apply(c->H[k], a[i]);
            const double dx = q.x - b[i].x, dy = q.y - b[i].y;
            if (dx * dx + dy * dy <= verify2) {
              a[n] = a[i];
              b[n] = b[i];
              ++n;
            }
          }
          if (n == a.size() || static_cast<int>(n) < kMinSupport) break;
          a.resize(n);
          b.resize(n);
          cv::Matx33d H;
          if (!fitH(a, b, &H)) break;
          c->H[k] = H;
        }
        c->support[k] = static_cast<int>(a.size());
        // Every member in view is tested against it.
        for (size_t m = 0; m < members.size(); ++m) {
          const int id = members[m];
          const TrackPoint* pk = at[m];
          if (!pk || !std::isfinite(refpos[id].x) || !usedAt(id, k) || back[id]) continue;
          const cv::Point2d q = apply(c->H[k], refpos[id]);
          const double dx = q.x - pk->px.x(), dy = q.y - pk->px.y();
          const double r2 = dx * dx + dy * dy;
          if (strays[id] >= 0) back[id] = r2 <= clean2;
          else if (r2 > verify2) strays[id] = k;
          else if (r2 <= clean2) clean_at[id] = k;
        }
      }
      // A member that strays and never comes back (it left the plane: a slide, not a spike of
      // noise) keeps its part up to its last clean frame when that part is one a later track
      // would need to join (min_new_track_frames, and its own motion reaching the stray
      // tolerance) and, for a track of the plane's own pair, reaches the pair frame. One that
      // comes back is no member (its error is not the plane's to explain).
      std::vector<int> keep;
      bool changed = false;
      for (int id : members) {
        if (strays[id] < 0) {
          keep.push_back(id);
          continue;
        }
        changed = true;
        const int last = clean_at[id];
        const TrackSpan s = spans[id];
        const int pair_k = c->pair_frame >= 0 ? c->pair_frame : res.pair_frame;  // a manual plane: the run's
        bool ok = !back[id] && last >= 0 && last - s.first + 1 >= o.min_new_track_frames && (joined[id] || last >= pair_k);
        if (ok) {
          // Its own motion on the plane, and while it left it (its last clean frame to the one it
          // strayed in). A point off the plane leaves it in proportion to its own image motion
          // (its parallax grows with the baseline): it needs several times more motion to go from
          // the noise's quantile to the stray tolerance than it made within the quantile. A track
          // that slides off leaves within a little motion. So the part is kept only when the
          // track left with less than half the motion it had made on the plane (ViSP's
          // Castle-simu, a castle's relief: 26 tracks cut otherwise, and its focal length's
          // supported interval lost the truth).
          const TrackPoint* p0 = tracks.find(s.first, id);
          const TrackPoint* pl = tracks.find(last, id);
          const TrackPoint* ps = tracks.find(strays[id], id);
          double moved = 0.0;
          for (int k = s.first + 1; p0 && k <= last; ++k)
            if (const TrackPoint* pk = tracks.find(k, id)) moved = std::max(moved, (pk->px - p0->px).norm());
          ok = moved >= verify_px && pl && ps && 2.0 * (ps->px - pl->px).norm() < moved;
        }
        if (!allow_cuts) ok = false;
        if (ok) {
          cut_after[id] = last;
          keep.push_back(id);
        }
      }
      members.swap(keep);
      if (!changed) break;
    }
    c->members = members;
    // Largest median displacement from the reference over the frames.
    double motion = 0.0;
    const std::vector<int> by_id = idOrder(members);
    for (int k = 1; k < F; k += std::max(1, F / 20)) {
      std::vector<double> d;
      pointsAt(members, by_id, k, &at);
      for (size_t m = 0; m < members.size(); ++m) {
        const int id = members[m];
        const TrackPoint* pk = at[m];
        if (std::isfinite(refpos[id].x) && pk && usedAt(id, k))
          d.push_back(std::hypot(pk->px.x() - refpos[id].x, pk->px.y() - refpos[id].y));
      }
      if (d.size() < 3) continue;
      std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
      motion = std::max(motion, d[d.size() / 2]);
    }
    c->median_motion_px = motion;
    // Issue 14 item 2: on a moving plane, a member whose own motion never reaches the
    // verification tolerance from where it was first seen fits "still" as well as it fits the
    // plane (a point of the still background near where the plane's homography barely moves
    // the image, e.g. the image of its rotation axis): it does not test the plane, and is not
    // a member. The same rule as for a track joining later (below).
    if (motion >= tol.static_px)
      c->members.erase(std::remove_if(c->members.begin(), c->members.end(), [&](int id) { return !moves[id]; }),
                       c->members.end());
    c->cuts.clear();
    for (int id : c->members)
      if (cut_after[id] >= 0) c->cuts.emplace_back(id, cut_after[id]);
  };

  std::vector<FoundPlane> cands;
  if (!o.rois.empty()) {
    for (size_t j = 0; j < o.rois.size(); ++j) cands.emplace_back();
    for (int id : ref_ids) {
      const cv::Point2d p = pt(*tracks.find(0, id));
      for (size_t j = 0; j < o.rois.size(); ++j)
        if (cv::pointPolygonTest(o.rois[j], cv::Point2f(static_cast<float>(p.x), static_cast<float>(p.y)), false) >= 0) {
          cands[j].members.push_back(id);
          break;
        }
    }
    for (auto& c : cands) {
      c.pair_inliers = c.members;  // taken back with cuts once the planes are chosen, as RANSAC's
      fitAllFrames(&c);
      if (static_cast<int>(c.members.size()) < o.min_plane_tracks) c.verdict = PlaneVerdict::TooFew;
    }
  } else {
    // The whole search at one pair frame: the candidates with their verdicts.
    auto searchAt = [&](const int pair) {
    std::vector<FoundPlane> cands;
    // Sequential RANSAC at (reference, pair_k) over the reference tracks `remaining` alive there.
    cv::theRNG().state = o.seed;
    auto sequentialRansac = [&](std::vector<int> remaining, int pair_k) {
      const int pair = pair_k;
      for (int round = 0; round < o.max_planes + 3 && static_cast<int>(remaining.size()) >= o.min_plane_tracks; ++round) {
        std::vector<cv::Point2d> a, b;
        for (int id : remaining) {
          a.push_back(pt(*tracks.find(0, id)));
          b.push_back(pt(*tracks.find(pair, id)));
        }
        std::vector<uchar> mask;
        cv::Mat h = cv::findHomography(a, b, cv::RANSAC, ransac_px, mask, 3000, 0.999);
        if (h.empty()) break;
        cv::Matx33d H(h);
        // Refit on the inliers and re-collect them (twice).
        for (int it = 0; it < 2; ++it) {
          std::vector<cv::Point2d> ia, ib;
          for (size_t i = 0; i < a.size(); ++i)
            if (mask[i]) {
              ia.push_back(a[i]);
              ib.push_back(b[i]);
            }
          if (!fitH(ia, ib, &H)) break;
          for (size_t i = 0; i < a.size(); ++i) {
            const cv::Point2d q = apply(H, a[i]);
            mask[i] = std::hypot(q.x - b[i].x, q.y - b[i].y) < ransac_px;
          }
        }
        FoundPlane c;
        c.pair_frame = pair;
        std::vector<int> rest;
        for (size_t i = 0; i < a.size(); ++i) (mask[i] ? c.members : rest).push_back(remaining[i]);
        if (static_cast<int>(c.members.size()) < o.min_plane_tracks) break;
        remaining.swap(rest);
        c.pair_inliers = c.members;
        fitAllFrames(&c);
        if (static_cast<int>(c.members.size()) < o.min_plane_tracks) c.verdict = PlaneVerdict::TooFew;
        cands.push_back(std::move(c));
      }
    };
    std::vector<int> at_pair, lost;  // reference tracks alive at the pair frame; those lost before it
    for (int id : ref_ids)
      (tracks.find(pair, id) ? at_pair : lost).push_back(id);
    sequentialRansac(at_pair, pair);
    // A plane whose reference tracks are all gone by the pair frame (a face leaving the view while
    // the rest of the scene stays) is looked for among the reference tracks lost before it, at
    // their own pair frame (the same rule: the last frame where half of those seen twice are
    // alive, and a plane's worth). Their tracks otherwise could only join the planes found above.
    int lost_n = 0;
    for (int id : lost) lost_n += spans[id].length() >= 2;
    int pair2 = -1;
    for (int k = 1; k < pair && lost_n >= o.min_plane_tracks; ++k) {
      int alive = 0;
      for (int id : lost) alive += tracks.find(k, id) != nullptr;
      if (alive >= std::max(o.min_alive_fraction * lost_n, 1.0 * o.min_plane_tracks)) pair2 = k;
    }
    if (pair2 > 0) {
      std::vector<int> at_pair2;
      for (int id : lost)
        if (tracks.find(pair2, id)) at_pair2.push_back(id);
      sequentialRansac(at_pair2, pair2);
    }
    // Merge candidates that are one plane split by the RANSAC threshold: their union must keep
    // 90 % of its tracks under the per-frame verification.
    for (bool merged = true; merged;) {
      merged = false;
      for (size_t a = 0; a < cands.size() && !merged; ++a)
        for (size_t b = a + 1; b < cands.size() && !merged; ++b) {
          if (cands[a].verdict != PlaneVerdict::Accepted || cands[b].verdict != PlaneVerdict::Accepted) continue;
          FoundPlane u;
          u.members = cands[a].members;
          u.pair_frame = cands[a].pair_frame;
          u.members.insert(u.members.end(), cands[b].members.begin(), cands[b].members.end());
          u.pair_inliers = cands[a].pair_inliers;
          u.pair_inliers.insert(u.pair_inliers.end(), cands[b].pair_inliers.begin(), cands[b].pair_inliers.end());
          const size_t total = u.members.size();
          fitAllFrames(&u);
          if (u.members.size() >= 0.9 * total) {
            cands[a] = std::move(u);
            cands.erase(cands.begin() + static_cast<long>(b));
            merged = true;
          }
        }
    }
    // The reference -> frame-k positions of the `members` seen in frame k (the same-motion tests).
    auto pairPoints = [&](const std::vector<int>& members, int k, std::vector<cv::Point2d>* a, std::vector<cv::Point2d>* b) {
      for (int id : members)
        if (const TrackPoint* pk = tracks.find(k, id)) {
          a->push_back(pt(*tracks.find(0, id)));
          b->push_back(pt(*pk));
        }
    };
    // Static planes; then the main plane = the largest moving one; others must share its motion.
    int main_plane = -1;
    for (size_t j = 0; j < cands.size(); ++j) {
      auto& c = cands[j];
      if (c.verdict != PlaneVerdict::Accepted) continue;
      if (o.reject_static && c.median_motion_px < tol.static_px) {
        c.verdict = PlaneVerdict::Static;
        continue;
      }
      if (main_plane < 0 || c.members.size() > cands[main_plane].members.size()) main_plane = static_cast<int>(j);
    }
    for (size_t j = 0; j < cands.size(); ++j) {
      auto& c = cands[j];
      if (c.verdict != PlaneVerdict::Accepted || static_cast<int>(j) == main_plane) continue;
      std::vector<cv::Point2d> a, b;
      const int cp = c.pair_frame;  // the main plane's homography is known in every frame
      pairPoints(c.members, cp, &a, &b);
      c.same_motion_fraction = sameMotionFraction(cands[main_plane].H[cp], a, b, tol.motion_px, o.seed + 17u * j);
      if (c.same_motion_fraction >= 0 && c.same_motion_fraction < o.same_motion_fraction)
        c.verdict = PlaneVerdict::OtherMotion;
    }
    // Each plane's test above fits an epipole to its own tracks, which a small group's nearly
    // parallel parallax vectors always allow (a far epipole): opencv-doc box.mp4 at 320 x 240,
    // 13 tracks of the arm that moved 12 px while the box moved 77-96 px passed with 0.67 and,
    // as a third plane, sent the start to its focal grid's end. A rigid scene's planes share one
    // epipole: each smaller plane that passed must have same_motion_fraction of its parallax
    // points on the lines of an epipole that the largest one that passed (after the main one)
    // accepts too, at the smaller one's pair frame (the largest one's tracks alive there; a plane
    // of the tracks lost before the pair frame is found at an earlier frame).
    {
      int second = -1;
      for (size_t j = 0; j < cands.size(); ++j) {
        const auto& c = cands[j];
        if (c.verdict == PlaneVerdict::Accepted && c.same_motion_fraction >= 0 &&
            (second < 0 || c.members.size() > cands[second].members.size()))
          second = static_cast<int>(j);
      }
      for (size_t j = 0; second >= 0 && j < cands.size(); ++j) {
        auto& c = cands[j];
        if (static_cast<int>(j) == second || c.verdict != PlaneVerdict::Accepted || c.same_motion_fraction < 0) continue;
        const int cp = c.pair_frame;
        std::vector<cv::Point2d> sa, sb, a, b;
        pairPoints(cands[second].members, cp, &sa, &sb);
        pairPoints(c.members, cp, &a, &b);
        const double agree = epipoleAgreement(cands[main_plane].H[cp], sa, sb, a, b, tol.motion_px, o.same_motion_fraction,
                                              o.seed + 17u * static_cast<unsigned>(second));
        if (agree < 0) continue;
        c.same_motion_fraction = std::min(c.same_motion_fraction, agree);
        if (c.same_motion_fraction < o.same_motion_fraction) c.verdict = PlaneVerdict::OtherMotion;
      }
    }
    return cands;
    };
    // The pair frame is chosen by what the data show there (issue 14 item 2): the search runs at
    // the share-of-live-tracks frame above and at frames chosen by the moving reference tracks'
    // image motion: the frame where their median displacement from the reference frame is
    // largest (a motion that turns back has its parallax in the middle, not at the end), then the
    // first frames where it reaches three quarters, half and a quarter of that (an object before
    // a still background: the background's tracks outlive the object's, and its planes show
    // between too little parallax and too few tracks). A frame wins only with more accepted
    // planes (each verified on every frame and moving with the main plane, at most max_planes)
    // than every frame before it in that order, which is one of decreasing parallax: on a tie
    // the frame with more image motion stays (the start's homographies are taken at the pair
    // frame too). docs/estimate.md section 1.
    std::vector<int> tries{pair};
    {
      // The moving reference tracks' median displacement from the reference frame, per frame
      // (NaN: fewer than two planes' worth alive): the frame where it is largest, and the first
      // frames where it reaches three quarters, half and a quarter of that.
      const std::vector<int>& who = movers.empty() ? ref_ids : movers;
      std::vector<double> motion(F, NAN), d;
      double most = 0.0;
      int k_most = -1;
      for (int k = 1; k < F_pair; ++k) {
        d.clear();
        for (int id : who)
          if (const TrackPoint* pk = tracks.find(k, id)) d.push_back((pk->px - tracks.find(0, id)->px).norm());
        if (static_cast<int>(d.size()) < 2 * o.min_plane_tracks) continue;
        std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
        motion[k] = d[d.size() / 2];
        if (motion[k] > most) {
          most = motion[k];
          k_most = k;
        }
      }
      if (k_most > 0) tries.push_back(k_most);
      for (const double part : {0.75, 0.5, 0.25})
        for (int k = 1; k < k_most; ++k)
          if (motion[k] >= part * most) {
            tries.push_back(k);
            break;
          }
    }
    // (planes, tracks in them) of a search: its accepted planes, at most max_planes, largest first.
    auto score = [&](const std::vector<FoundPlane>& cs) {
      std::vector<size_t> sizes;
      for (const auto& c : cs)
        if (c.verdict == PlaneVerdict::Accepted) sizes.push_back(c.members.size());
      std::sort(sizes.rbegin(), sizes.rend());
      if (static_cast<int>(sizes.size()) > o.max_planes) sizes.resize(static_cast<size_t>(o.max_planes));
      size_t total = 0;
      for (size_t n : sizes) total += n;
      return PlaneFinding::PairTry{-1, static_cast<int>(sizes.size()), static_cast<int>(total)};
    };
    // A frame with more planes wins only if it finds the winner's planes again: each of them
    // that can be seen there (min_plane_tracks of its tracks alive at that frame) has more than
    // half of those tracks in one accepted plane of the frame's search. Otherwise the frame
    // trades a plane for another (opencv-doc box.mp4 frames 45-194: the frame of a quarter of
    // the largest motion found three planes, the box's second face with 8 tracks of which 3
    // were off it and the 10 on it left out, and a third of 9 background tracks that barely
    // moved; the share-of-live-tracks frame had found both faces, the second with 17).
    auto findsAgain = [&](const std::vector<FoundPlane>& won, const std::vector<FoundPlane>& cs, int k) {
      return findsPlanesAgain(won, cs, [&](int id) { return tracks.find(k, id) != nullptr; }, o.min_plane_tracks);
    };
    cands = searchAt(pair);
    PlaneFinding::PairTry best = score(cands);
    best.frame = pair;
    res.pair_frame_tries.push_back(best);
    // No frame can win once max_planes are accepted: the rest are not tried.
    for (size_t t = 1; t < tries.size() && best.planes < o.max_planes; ++t) {
      if (std::find(tries.begin(), tries.begin() + static_cast<long>(t), tries[t]) != tries.begin() + static_cast<long>(t))
        continue;  // tried already
      std::vector<FoundPlane> cs = searchAt(tries[t]);
      PlaneFinding::PairTry s = score(cs);
      s.frame = tries[t];
      s.loses_plane = s.planes > best.planes && !findsAgain(cands, cs, tries[t]);
      res.pair_frame_tries.push_back(s);
      if (s.planes > best.planes && !s.loses_plane) {
        best = s;
        cands = std::move(cs);
        res.pair_frame = tries[t];
      }
    }
  }
  // Accepted planes, largest first, at most max_planes.
  std::vector<int> order;
  for (size_t j = 0; j < cands.size(); ++j)
    if (cands[j].verdict == PlaneVerdict::Accepted) order.push_back(static_cast<int>(j));
  if (o.rois.empty())
    std::stable_sort(order.begin(), order.end(),
                     [&](int x, int y) { return cands[x].members.size() > cands[y].members.size(); });
  if (static_cast<int>(order.size()) > o.max_planes) {
    for (size_t r = o.max_planes; r < order.size(); ++r) cands[order[r]].verdict = PlaneVerdict::TooFew;
    order.resize(o.max_planes);
  }
  for (size_t r = 0; r < order.size(); ++r) {
    cands[order[r]].label = static_cast<int>(r);
    for (int id : cands[order[r]].members) res.labels[id] = static_cast<int>(r);
  }
  // The chosen planes' pair inliers that strayed later (an occlusion edge a track slid along, a
  // slip) are members up to where they left the plane (fitAllFrames' cuts).
  allow_cuts = true;
  for (size_t r = 0; r < order.size(); ++r) {
    FoundPlane& c = cands[order[r]];
    const size_t before = c.members.size();
    for (int id : c.pair_inliers)
      if (res.labels[id] == -1) c.members.push_back(id);
    if (c.members.size() == before) continue;
    const std::vector<int> was = c.members;
    fitAllFrames(&c);
    // The refit may drop members (its fits differ): those are outliers.
    for (int id : was) res.labels[id] = -1;
    for (int id : c.members) res.labels[id] = static_cast<int>(r);
  }

  // Tracks not yet judged (born later, or reference tracks lost before the pair frame): carried
  // from their first frame b by H(k) H(b)^-1 of exactly one accepted plane. Members of rejected
  // candidates stay outliers. The planes' homographies are then fitted again on every member
  // (joined tracks at their carried-back reference positions) and the test repeated, so a plane
  // stays followed after its reference tracks have died: each round carries it as far as the
  // tracks that joined in the previous one live.
  std::vector<char> judged(ids, 0);
  for (const auto& c : cands)
    for (int id : c.members) judged[id] = 1;
  for (int round = 0; round < 20; ++round) {
    int n_joined = 0;
    for (int id = 0; id < ids; ++id) {
      const TrackSpan s = spans[id];
      if (s.first < 0 || judged[id] || res.labels[id] == -2 || s.length() < 2) continue;
      const TrackPoint* pb = tracks.find(s.first, id);
      if (!pb) continue;
      // Planes it fits over its whole life. No track joins with a part (one that strays in a
      // tested frame joins no plane, as before the cuts): tried on 2026-12-07, a join of a part
      // up to the first tested frame where the track strays moved the late planes' and the focal
      // length's figures one track at a time (Adaptive.PlanesThatComeIntoViewLaterJoinTheFilter's
      // fourth plane by 0.8 deg, Castle-simu's supported focal interval), with or without
      // come-back and departure tests. A joined track that strays in a frame between the tested
      // ones is cut by the refit below.
      int fits = 0, which = -1;
      for (int j : order) {
        const auto& c = cands[j];
        // Only frames whose homography its members determine (kMinSupport of them) test a track.
        if (c.support[s.first] < kMinSupport) continue;
        const cv::Matx33d Hb_inv = c.H[s.first].inv();
        bool ok = true;
        int checked = 0;
        double moved = 0.0;  // the track's own largest displacement from its first position (px)
        const int step = std::max(1, s.length() / 8);
        for (int k = s.first + step; k <= s.last && ok; k += step) {
          const TrackPoint* pk = tracks.find(k, id);
          if (!pk || c.support[k] < kMinSupport) continue;
          const cv::Point2d q = apply(c.H[k] * Hb_inv, pt(*pb));
          ok = std::hypot(q.x - pk->px.x(), q.y - pk->px.y()) < verify_px;  // NaN (a singular H) fails
          moved = std::max(moved, (pk->px - pb->px).norm());
          ++checked;
        }
        // Issue 14 item 2: the track's own motion must test the plane. A track that never moves
        // more than the join tolerance from where it started fits "still" as well as it fits
        // the plane (a still object's track, or the plane's, over a few slow frames): it cannot
        // tell, and joins no moving plane.
        if (ok && checked >= 2 && moved >= verify_px) {
          ++fits;
          which = c.label;
        }
      }
      if (fits == 1) {
        res.labels[id] = which;
        cands[order[which]].members.push_back(id);
        judged[id] = 1;
        joined[id] = 1;
        refpos[id] = apply(cands[order[which]].H[s.first].inv(), pt(*pb));
        ++n_joined;
      }
    }
    if (n_joined == 0) break;
    for (int j : order) {
      const std::vector<int> before = cands[j].members;
      fitAllFrames(&cands[j]);
      // Members the refit drops are outliers again (and judged: they do not come back).
      std::vector<char> kept(ids, 0);
      for (int id : cands[j].members) kept[id] = 1;
      for (int id : before)
        if (!kept[id]) res.labels[id] = -1;
    }
  }
  res.cut_after.assign(ids, -1);
  for (int j : order)
    for (const auto& [id, last] : cands[j].cuts) res.cut_after[id] = last;
  res.candidates = std::move(cands);
  return res;
}

}  // namespace

PlaneFinding findPlanes(const Tracks& tracks, const PlaneFinderOptions& o) {
  if (o.max_planes < 1 || o.min_plane_tracks < 4 || !(o.ransac_px > 0) || !(o.verify_px > 0) ||
      !(o.min_alive_fraction > 0 && o.min_alive_fraction <= 1))
    throw std::invalid_argument("plane finder: options out of range");
  const int F = tracks.numFrames();
  if (F < 2) {
    PlaneFinding res;
    res.labels.assign(tracks.idBound(), -1);
    return res;
  }
  // The options' tolerances first. When the tracking noise needs wider ones (planeTolerances),
  // the search runs with those too, and they are kept when they put more planes on the tracks,
  // or as many planes holding at least twice the tracks: the options' then left most of the
  // planes' tracks off them (docs/estimate.md section 1, "the pixel tolerances"). Otherwise the
  // options' stand: a few more members at the edge of a face change the start, not the planes.
  const double noise = o.noise_px < 0 ? trackNoisePx(tracks) : o.noise_px;
  const PlaneTolerances wide = planeTolerances(o, noise, F);
  PlaneTolerances floors = planeTolerances(o, 0.0, F);
  floors.noise_px = noise;
  PlaneFinding res = findPlanesWith(tracks, o, floors);
  if (!(wide.ransac_px > floors.ransac_px || wide.verify_px > floors.verify_px)) return res;
  PlaneFinding w = findPlanesWith(tracks, o, wide);
  const int on = static_cast<int>(res.labels.size()) - res.count(-1) - res.count(-2);
  const int on_wide = static_cast<int>(w.labels.size()) - w.count(-1) - w.count(-2);
  if (w.numPlanes() > res.numPlanes() || (w.numPlanes() == res.numPlanes() && on_wide >= 2 * on && on_wide > 0)) {
    w.widened = true;
    return w;
  }
  return res;
}

}  // namespace rsfm::vision
