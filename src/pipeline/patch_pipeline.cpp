#include "rsfm/pipeline/patch_pipeline.hpp"
#include "rsfm/units.hpp"

#include "rsfm/geometry.hpp"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <stdexcept>

namespace rsfm {

namespace {


/// First-order sd (degrees) of the unit normal of structure s with 4x4 covariance of (beta, p1, p2, p4).
double normalSdDeg(const Eigen::Vector3d& s, double beta, const Eigen::Matrix4d& cov) {
  const Eigen::Vector3d m(s[0], s[1], 1.0 - beta * s[2]);
  // dm/d(beta, p1, p2, p4)
  Eigen::Matrix<double, 3, 4> dm = Eigen::Matrix<double, 3, 4>::Zero();
  dm(0, 1) = 1.0;
  dm(1, 2) = 1.0;
  dm(2, 0) = -s[2];
  dm(2, 3) = -beta;
  return directionRmsAngle(m, dm * cov * dm.transpose()) * kRadToDeg;
}

/// Kronecker product of 2x2 matrices (row-major vectorization: vec(X Y Z) = (X (x) Z^T) vec(Y)).
Eigen::Matrix4d kron(const Eigen::Matrix2d& a, const Eigen::Matrix2d& b) {
  Eigen::Matrix4d k;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j) k.block<2, 2>(2 * i, 2 * j) = a(i, j) * b;
  return k;
}

struct FusedMap {
  Eigen::Matrix2d A = Eigen::Matrix2d::Identity();  // first appearance -> current frame
  Eigen::Matrix4d C = Eigen::Matrix4d::Zero();      // covariance of (A11, A12, A21, A22)
};

double median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

NormalAgreement normalAgreement(const PatchRunFrame& f) {
  NormalAgreement a;
  std::vector<Eigen::Vector3d> ref;
  for (const auto& p : f.patches) ref.push_back(f.R.transpose() * p.normal);
  if (ref.empty()) return a;
  std::vector<double> xs, ys, zs;
  for (const auto& n : ref) xs.push_back(n.x()), ys.push_back(n.y()), zs.push_back(n.z());
  a.median = Eigen::Vector3d(median(xs), median(ys), median(zs)).normalized();
  for (size_t i = 0; i < ref.size(); ++i) {
    a.ids.push_back(f.patches[i].id);
    a.angle_deg.push_back(normalAngle(ref[i], a.median) * kRadToDeg);
  }
  std::vector<double> s = a.angle_deg;
  std::sort(s.begin(), s.end());
  a.median_deg = s[s.size() / 2];
  a.p90_deg = s[std::min(s.size() - 1, static_cast<size_t>(0.9 * s.size()))];
  a.max_deg = s.back();
  a.within_5deg = static_cast<int>(std::count_if(s.begin(), s.end(), [](double d) { return d <= 5.0; }));
  return a;
}

PatchRunResult runPatchTracks(const PatchTracks& tracks, const PatchPipelineOptions& o,
                              const std::function<void(int, int)>& progress) {
  if (tracks.numFrames() < 2) throw std::invalid_argument("patch tracks: need at least 2 frames");
  const int W = tracks.image.width, Hh = tracks.image.height;
  const double s = o.scale_px > 0 ? o.scale_px : std::max(W, Hh) / 2.0;
  if (!(o.sigma_px > 0) || !(o.sigma_affine > 0)) throw std::invalid_argument("noise standard deviations must be positive");
  if (!(o.depth0 > 0)) throw std::invalid_argument("depth0 must be positive");
  if (std::isnan(o.still_px)) throw std::invalid_argument("still_px must be a number (<= 0: no still start)");
  const bool maps_in_state = o.centres == PatchCentres::State;
  if (maps_in_state && o.fused_maps) throw std::invalid_argument("fused maps and maps in the state (centres 'state') exclude each other");
  if (maps_in_state && o.measurement != AffineMeasurement::Exact)
    throw std::invalid_argument("maps in the state (centres 'state') need the exact measurement");
  const double focal0 = o.focal_px > 0 ? o.focal_px : o.focal0_px > 0 ? o.focal0_px : std::max(W, Hh);
  const double beta0 = s / focal0;
  const Eigen::Vector2d cpx(tracks.image.cx, tracks.image.cy);
  auto norm = [&](const Eigen::Vector2d& px) -> Eigen::Vector2d { return (px - cpx) / s; };
  // Patches long enough to use.
  std::map<int, int> frames_seen;
  for (const auto& f : tracks.frames)
    for (const auto& p : f) ++frames_seen[p.id];
  auto usable = [&](int id) { return frames_seen[id] >= o.min_patch_frames; };
  std::vector<int> ids;  // state slot -> patch id
  std::vector<Eigen::Vector2d> c0;
  for (const auto& p : tracks.frames[0])
    if (usable(p.id)) ids.push_back(p.id), c0.push_back(norm(p.px));
  const int K = static_cast<int>(ids.size());
  std::map<int, FusedMap> maps;  // per patch id: fused cumulative map (PatchPipelineOptions::fused_maps)
  // Per patch id: the inverse of its map where it enters the filter. Maps in the state start at
  // the identity there; a patch whose template frame lies before the tracks' first frame is
  // measured relative to its entry map.
  std::map<int, Eigen::Matrix2d> entry_inv;
  auto startMap = [&](const PatchObservation& p) {
    entry_inv[p.id] = p.A.inverse();
    FusedMap m;
    m.A = p.A;
    // In its first frame a patch's map is the identity by definition.
    const bool first = (p.px - p.px0).norm() < 1e-9 && (p.A - Eigen::Matrix2d::Identity()).norm() < 1e-12;
    m.C = Eigen::Matrix4d::Identity() * (first ? 0.0 : o.sigma_map * o.sigma_map);
    maps[p.id] = m;
  };
  for (const auto& p : tracks.frames[0])
    if (usable(p.id)) startMap(p);
  if (K < PatchModel::kMinPatches)
    throw std::invalid_argument("only " + std::to_string(K) + " patches (seen in at least " +
                                std::to_string(o.min_patch_frames) + " frames) in the first frame; the patch filter needs " +
                                std::to_string(PatchModel::kMinPatches));
  int gauge = 0;
  for (int k = 1; k < K; ++k)
    if (c0[k].norm() < c0[gauge].norm()) gauge = k;
  const double Z0 = o.depth0 / beta0, g0 = Z0 / (1.0 + beta0 * Z0);
  const int n = 7 + 3 * K;
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
  x0[6] = beta0;
  const double tsd = o.motion_sd0 * Z0;
  P0(0, 0) = P0(1, 1) = tsd * tsd;
  P0(2, 2) = std::pow(o.motion_sd0 * Z0 * beta0, 2);
  for (int j = 3; j < 6; ++j) P0(j, j) = o.motion_sd0 * o.motion_sd0;
  P0(6, 6) = o.focal_px > 0 ? 0.0 : std::pow(o.beta_sd0.value_or(PatchPipelineOptions::kGuessBetaSd0) * beta0, 2);
  const Eigen::Matrix3d Ps0 =
      Eigen::Vector3d(o.normal_sd0 * o.normal_sd0, o.normal_sd0 * o.normal_sd0, std::pow(o.depth_rel_sd0 * g0, 2)).asDiagonal();
  for (int k = 0; k < K; ++k) {
    const int i = PatchModel::structureIndex(k);
    x0.segment<3>(i) << 0.0, 0.0, g0;
    P0.block<3, 3>(i, i) = Ps0;
  }
  std::vector<bool> fixed(n, false);
  if (o.focal_px > 0) fixed[6] = true;
  PatchFilterOptions fo;
  fo.measurement = o.measurement;
  const double sp = o.sigma_px / s;
  fo.measurement_sd << sp, sp, o.sigma_affine, o.sigma_affine, o.sigma_affine, o.sigma_affine;
  fo.centre_sd = sp;
  fo.centres = o.centres;
  const double qt = std::pow(o.q_trans_rel * Z0, 2);
  fo.q_motion << qt, qt, qt * beta0 * beta0, o.q_omega, o.q_omega, o.q_omega, 0.0;
  fo.anneal_frames = o.anneal_frames;
  fo.anneal_factor = o.anneal_factor;
  fo.update.gate_probability = o.gate_probability;
  PatchFilter f(PatchModel(c0), Ekf(x0, P0, fixed), gauge, fo);

  PatchRunResult res;
  res.scale_px = s;
  res.entered = K;
  auto snapshot = [&](int k, const PatchFrameStats* fs) {
    PatchRunFrame fr;
    fr.frame = tracks.first_frame + k;
    fr.R = f.rotation();
    fr.T = f.translation();
    fr.beta = f.beta();
    fr.var_beta = f.ekf().P()(6, 6);
    const Eigen::VectorXd& x = f.ekf().x();
    const Eigen::MatrixXd& P = f.ekf().P();
    for (int p = 0; p < f.numPatches(); ++p) {
      PatchEstimate e;
      e.id = ids[p];
      const Eigen::Vector2d c = f.model().centre(p);
      e.px = c * s + cpx;
      const int i = PatchModel::structureIndex(p);
      e.normal = f.normal(p);
      std::vector<int> cols{6, i, i + 1, i + 2};
      e.normal_sd_deg = normalSdDeg(x.segment<3>(i), x[6], P(cols, cols));
      e.depth = PatchModel::depthAt(x.segment<3>(i), x[6], c);
      fr.patches.push_back(e);
    }
    if (fs) {
      fr.observed = fs->update.blocks;
      fr.used = fs->update.used;
      fr.gated = fs->update.gated;
      fr.nis_per_dof = fs->update.nis_dof > 0 ? fs->update.nis / fs->update.nis_dof : 0.0;
    }
    res.frames.push_back(std::move(fr));
  };
  snapshot(0, nullptr);
  int prev = 0;          // the last frame the filter stepped to (0 while the start is still)
  bool moving = o.still_px <= 0.0;
  for (int k = 1; k < tracks.numFrames(); ++k) {
    // Patches whose track ended leave the state.
    for (int p = f.numPatches() - 1; p >= 0; --p) {
      if (tracks.find(k, ids[p])) continue;
      if (f.numPatches() <= PatchModel::kMinPatches) {
        res.stopped = "frame " + std::to_string(tracks.first_frame + k) + ": fewer than " +
                      std::to_string(PatchModel::kMinPatches) + " patches left";
        return res;
      }
      f.removePatch(p);
      ids.erase(ids.begin() + p);
      ++res.left;
    }
    if (!moving) {
      std::vector<double> disp;
      for (int p = 0; p < f.numPatches(); ++p) {
        const PatchObservation* a = tracks.find(0, ids[p]);
        const PatchObservation* b = tracks.find(k, ids[p]);
        if (a && b) disp.push_back((b->px - a->px).norm());
      }
      moving = disp.empty() || median(std::move(disp)) > o.still_px;
      if (!moving) {
        ++res.still_frames;
        snapshot(k, nullptr);
        if (progress) progress(k + 1, tracks.numFrames());
        continue;
      }
    }
    std::vector<AffineObservation> obs;
    for (int p = 0; p < f.numPatches(); ++p) {
      const PatchObservation* a = tracks.find(prev, ids[p]);
      const PatchObservation* b = tracks.find(k, ids[p]);
      if (!a || !b) continue;
      AffineObservation ob;
      ob.id = p;
      Eigen::Matrix2d Ai;
      if (maps_in_state) {
        Ai = b->A * entry_inv.at(ids[p]);  // cumulative since the patch entered
      } else if (o.fused_maps) {
        // The previous map is the fused one: z_A = A_k Ahat^-1, its uncertainty J C J^T with
        // J = -(z_A (x) Ahat^-T) (row-major vectorization).
        const FusedMap& m = maps.at(ids[p]);
        const Eigen::Matrix2d inv = m.A.inverse();
        Ai = b->A * inv;
        const Eigen::Matrix4d J = -kron(Ai, inv.transpose());
        ob.map_cov = J * m.C * J.transpose();
      } else {
        Ai = b->A * a->A.inverse();
      }
      ob.z << norm(b->px), Ai(0, 0), Ai(0, 1), Ai(1, 0), Ai(1, 1);
      obs.push_back(ob);
    }
    const PatchFrameStats fs = f.step(obs);
    if (o.fused_maps && fs.health == kHealthy && fs.transition == MeasureStatus::Ok) {
      // Each patch's cumulative map: the posterior's inter-frame map M applied to the previous
      // fused map (covariance from both), fused with the tracker's map (sigma_map^2 I); a gated
      // patch restarts from the tracker's map.
      std::vector<char> accepted(f.numPatches(), 0), offered(f.numPatches(), 0);
      for (size_t bi = 0; bi < fs.used.size(); ++bi) {
        const int p = obs[fs.used[bi]].id;
        offered[p] = 1;
        if (bi >= fs.update.gated_mask.size() || !fs.update.gated_mask[bi]) accepted[p] = 1;
      }
      const double s2 = o.sigma_map * o.sigma_map;
      for (int p = 0; p < static_cast<int>(fs.posterior_z.size()); ++p) {
        FusedMap& m = maps.at(ids[p]);
        const PatchObservation* b = tracks.find(k, ids[p]);
        if (b && offered[p] && !accepted[p]) {
          m.A = b->A;
          m.C = Eigen::Matrix4d::Identity() * s2;
          continue;
        }
        const Vector6d& zp = fs.posterior_z[p];
        if (!zp.allFinite()) {
          if (b) m.A = b->A, m.C = Eigen::Matrix4d::Identity() * s2;
          continue;
        }
        Eigen::Matrix2d M;
        M << zp[2], zp[3], zp[4], zp[5];
        const Eigen::Matrix4d JM = kron(Eigen::Matrix2d::Identity(), m.A.transpose());
        const Eigen::Matrix4d JA = kron(M, Eigen::Matrix2d::Identity());
        const Eigen::Matrix4d Cp = JM * fs.posterior_cov[p].bottomRightCorner<4, 4>() * JM.transpose() + JA * m.C * JA.transpose();
        const Eigen::Matrix2d Ap = M * m.A;
        if (!b) {
          m.A = Ap, m.C = Cp;
          continue;
        }
        const Eigen::Matrix4d G = Cp * (Cp + Eigen::Matrix4d::Identity() * s2).inverse();
        Eigen::Vector4d v;
        v << Ap(0, 0), Ap(0, 1), Ap(1, 0), Ap(1, 1);
        const Eigen::Vector4d meas(b->A(0, 0), b->A(0, 1), b->A(1, 0), b->A(1, 1));
        v += G * (meas - v);
        m.A << v[0], v[1], v[2], v[3];
        const Eigen::Matrix4d C = (Eigen::Matrix4d::Identity() - G) * Cp;
        m.C = 0.5 * (C + C.transpose());
      }
    }
    if (fs.health != kHealthy || fs.transition != MeasureStatus::Ok) {
      res.stopped = "frame " + std::to_string(tracks.first_frame + k) + ": " +
                    (fs.transition != MeasureStatus::Ok ? std::string(toString(fs.transition)) : describeHealth(fs.health));
      return res;
    }
    if (!(f.beta() > 0.0)) {
      res.stopped = "frame " + std::to_string(tracks.first_frame + k) + ": beta <= 0 (focal length at infinity)";
      return res;
    }
    // New patches join in the frame where they are first seen.
    // They start at the median depth g of the patches live before any of them joined.
    std::set<int> live(ids.begin(), ids.end());
    double gmed = NAN;
    for (const auto& p : tracks.frames[k]) {
      if (live.count(p.id) || !usable(p.id) || tracks.find(prev, p.id)) continue;
      if (std::isnan(gmed)) {
        std::vector<double> gs;
        for (int q = 0; q < f.numPatches(); ++q)
          gs.push_back(f.structure(q)[2] - f.structure(q).head<2>().dot(f.model().centre(q)));
        gmed = median(std::move(gs));
      }
      Eigen::Matrix3d Pn = Ps0;
      Pn(2, 2) = std::pow(o.depth_rel_sd0 * gmed, 2);
      f.addPatch(norm(p.px), Eigen::Vector3d(0.0, 0.0, gmed), Pn);
      ids.push_back(p.id);
      startMap(p);
      ++res.entered;
      ++res.joined;
    }
    snapshot(k, &fs);
    prev = k;
    // Posterior centre residuals of the accepted patches (pixels).
    double r2 = 0;
    int nr = 0;
    for (size_t b = 0; b < fs.used.size(); ++b) {
      if (b < fs.update.gated_mask.size() && fs.update.gated_mask[b]) continue;
      const AffineObservation& ob = obs[fs.used[b]];
      r2 += (f.model().centre(ob.id) - ob.z.head<2>()).squaredNorm() * s * s;
      nr += 2;
    }
    res.frames.back().rms_px = nr ? std::sqrt(r2 / nr) : 0.0;
    if (progress) progress(k + 1, tracks.numFrames());
  }
  return res;
}

}  // namespace rsfm
