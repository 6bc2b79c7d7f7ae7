// The Cramer-Rao bound of the plane batch problem with its null space (plane_batch.hpp).
#include <fmt/format.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

#include "rsfm/geometry.hpp"
#include "rsfm/batch/plane_batch.hpp"

namespace rsfm {

bool PlaneBatchBound::estimable(double g_beta, const std::vector<Eigen::Vector3d>& g_N, const Eigen::Vector4d& g_camera,
                                double g_readout) const {
  if (!ok) return false;
  const int n = static_cast<int>(scale.size());
  Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
  if (beta_index >= 0)
    g[beta_index] = g_beta;
  else if (g_beta != 0)
    return false;  // beta is held
  for (std::size_t j = 0; j < g_N.size(); ++j)
    for (int a = 0; a < 3; ++a)
      if (N_index[3 * j + a] >= 0) g[N_index[3 * j + a]] = g_N[j][a];
  for (int c = 0; c < 4; ++c) {
    if (camera_index[c] >= 0)
      g[camera_index[c]] = g_camera[c];
    else if (g_camera[c] != 0)
      return false;  // a held component is not a parameter
  }
  if (readout_index >= 0)
    g[readout_index] = g_readout;
  else if (g_readout != 0)
    return false;
  if (g.norm() == 0) return true;
  const Eigen::VectorXd gs = scale.cwiseProduct(g);
  // Orthogonal to the null space proper (eigenvalues at rounding level). The weak directions'
  // share of its variance, sum_i (u_i^T g_s)^2 / lambda_i, is in cov: whether that variance is
  // small enough is the caller's limit to judge (docs/estimate.md, "Null, weak and seen
  // directions").
  return null_scaled.cols() == 0 || (null_scaled.transpose() * gs).norm() <= 1e-6 * gs.norm();
}

namespace {

/// One track's whitened normal equations on its plane's three N components and its own
/// reference (2), with everything else held: the jackknife's (planeJackknife) pieces.
struct TrackPlaneInfo {
  Eigen::Matrix3d Snn = Eigen::Matrix3d::Zero();
  Eigen::Matrix<double, 3, 2> Snu = Eigen::Matrix<double, 3, 2>::Zero();
  Eigen::Matrix2d Suu = Eigen::Matrix2d::Zero();
  Eigen::Vector3d gn = Eigen::Vector3d::Zero();
  Eigen::Vector2d gu = Eigen::Vector2d::Zero();
  int observations = 0;
  void add(const Eigen::Matrix<double, 2, 3>& JN, const Eigen::Matrix2d& Ju, const Eigen::Vector2d& r) {
    Snn.noalias() += JN.transpose() * JN;
    Snu.noalias() += JN.transpose() * Ju;
    Suu.noalias() += Ju.transpose() * Ju;
    gn.noalias() += JN.transpose() * r;
    gu.noalias() += Ju.transpose() * r;
    ++observations;
  }
};

/// The delete-one-track jackknife of each plane's N components (PlaneBatchBoundOptions::
/// track_clustered; [E82] ch. 3 for the jackknife, [MW85] for it as the leverage-robust form of
/// the sandwich, [CGM11] for clusters). The sandwich V = sum_t (S+ g_t)(S+ g_t)^T reads a track
/// that alone decides a direction (high leverage) as if it were one of many: the fit follows it,
/// so its residual and its score are small, and a plane carried by two tracks and a few that
/// barely move was reported well determined (box.mp4 under an FFmpeg contrast swing: 11 tracks,
/// sd 3.1 deg, 30 deg off). Here, with the motions, beta and the other planes held at the
/// optimum, each track t of plane j gives (its own reference eliminated) an information I_t and
/// a score s_t on the plane's kept N components. Dropping it moves them by
/// d_t = (I - I_t)^-1 s_t (I = sum_t I_t; exact for the linearized problem), and
/// V_J = (T-1)/T sum_t (d_t - mean d)(d_t - mean d)^T is the jackknife covariance, against the
/// same problem's sandwich V_0 = sum_t (I^-1 s_t)(I^-1 s_t)^T. With every leverage small the two
/// agree; ratio = lambda_max(V_J) / lambda_max(V_0) (both in I's metric) is what the sandwich
/// misses. The sandwich of the whole problem (`sandwich_N`: its largest variance ratio on the
/// plane's N components against the bound, track or region clusters) corrected for it reads
/// sandwich_N x ratio; where that exceeds what the track-clustered check already gave
/// (clustered_N^2), the plane's rows and columns of `cov` are scaled by
/// a = sqrt(sandwich_N x ratio) / clustered_N (jackknife_N = max(1, a)). A bound the
/// sandwich stays inside is not widened for leverage alone. A track without which a direction
/// is not determined at all (a leverage of 1: I - I_t singular), or scores that vanish while the
/// jackknife's do not, make it infinite; `cov` is then left as it is.
void planeJackknife(const PlaneBatchData& data, const std::vector<int>& iN, const std::vector<TrackPlaneInfo>& tp,
                    const std::vector<double>& sandwich_N, PlaneBatchBound* out) {
  // At most 3 x 3 (a plane's kept components): fixed storage, no heap allocation per track.
  using M3 = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 3, 3>;
  using V3 = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 3, 1>;
  const int m = data.num_planes;
  const int P = static_cast<int>(tp.size());
  out->jackknife_N.assign(m, 1.0);
  out->jackknife_ratio_N.assign(m, 0.0);
  std::vector<M3> It;
  std::vector<V3> st, d, w;
  It.reserve(P);
  st.reserve(P);
  d.reserve(P);
  w.reserve(P);
  for (int j = 0; j < m; ++j) {
    int kept[3], k = 0;
    for (int e = 0; e < 3; ++e)
      if (iN[3 * j + e] >= 0) kept[k++] = e;
    if (k == 0) continue;
    // Per track: I_t and s_t on the kept components, its reference eliminated.
    It.clear();
    st.clear();
    d.clear();
    M3 I = M3::Zero(k, k);
    for (int t = 0; t < P; ++t) {
      if (data.labels[t] != j || tp[t].observations < 2) continue;
      const Eigen::LDLT<Eigen::Matrix2d> lu(tp[t].Suu);
      if (lu.info() != Eigen::Success || !(lu.vectorD().minCoeff() > 0)) continue;
      const Eigen::Matrix3d Ifull = tp[t].Snn - tp[t].Snu * lu.solve(tp[t].Snu.transpose());
      const Eigen::Vector3d sfull = tp[t].gn - tp[t].Snu * lu.solve(tp[t].gu);
      M3 Ik(k, k);
      V3 sk(k);
      for (int a = 0; a < k; ++a) {
        sk[a] = sfull[kept[a]];
        for (int b = 0; b < k; ++b) Ik(a, b) = Ifull(kept[a], kept[b]);
      }
      It.push_back(Ik);
      st.push_back(sk);
      I += Ik;
    }
    const int T = static_cast<int>(It.size());
    if (T < 2) continue;
    // Whitened by I's Cholesky factor (I = L L^T): the bound is the identity there.
    const Eigen::LLT<M3> llt(I);
    if (llt.info() != Eigen::Success) continue;
    const M3 L = llt.matrixL();
    bool decisive = false;
    Eigen::SelfAdjointEigenSolver<M3> eh(k);
    w.clear();
    for (int t = 0; t < T; ++t) {
      // The track's leverages: the eigenvalues of H = L^-1 I_t L^-T, in [0, 1]; 1 is a direction
      // that this track alone determines.
      const M3 Lt = L.triangularView<Eigen::Lower>().solve(It[t]);
      const M3 H = L.triangularView<Eigen::Lower>().solve(Lt.transpose());
      eh.compute(0.5 * (H + H.transpose()));
      if (eh.info() != Eigen::Success || eh.eigenvalues().maxCoeff() > 1.0 - 1e-9) {
        decisive = true;
        break;
      }
      // d_t, whitened: L^T (I - I_t)^-1 s_t = (1 - H)^-1 w_t, w_t = L^-1 s_t.
      w.push_back(L.triangularView<Eigen::Lower>().solve(st[t]));
      const M3 IH = M3::Identity(k, k) - H;
      d.push_back(Eigen::LDLT<M3>(IH).solve(w.back()));
    }
    if (decisive) {
      out->jackknife_N[j] = out->jackknife_ratio_N[j] = INFINITY;
      continue;
    }
    V3 mean = V3::Zero(k);
    for (const auto& x : d) mean += x;
    mean /= T;
    M3 V = M3::Zero(k, k), V0 = M3::Zero(k, k);
    for (const auto& x : d) V.noalias() += (x - mean) * (x - mean).transpose();
    V *= static_cast<double>(T - 1) / T;
    // The sandwich in the same held-motions problem, V_0 = sum_t (I^-1 s_t)(I^-1 s_t)^T (whitened:
    // the w_t): the jackknife's excess over it is the leverage the sandwich misses.
    for (const auto& x : w) V0.noalias() += x * x.transpose();
    Eigen::SelfAdjointEigenSolver<M3> ev(V, Eigen::EigenvaluesOnly), e0(V0, Eigen::EigenvaluesOnly);
    if (ev.info() != Eigen::Success || e0.info() != Eigen::Success) continue;
    const double vj = std::max(0.0, ev.eigenvalues().maxCoeff()), v0 = std::max(0.0, e0.eigenvalues().maxCoeff());
    const double ratio = v0 > 0 ? vj / v0 : vj > 0 ? INFINITY : 1.0;
    if (!std::isfinite(ratio)) {
      out->jackknife_N[j] = out->jackknife_ratio_N[j] = INFINITY;
      continue;
    }
    out->jackknife_ratio_N[j] = ratio;
    // The sandwich corrected for the leverage it misses, against what the plane's sd already has.
    const double clustered = out->clustered_N[j];
    const double target = std::sqrt(std::max(1.0, sandwich_N[j] * ratio));
    out->jackknife_N[j] = std::max(1.0, target / clustered);
    if (!(target > clustered)) continue;
    const double a = target / clustered;  // the plane's rows and columns: its variances x a^2, PSD kept
    for (int e = 0; e < k; ++e) {
      const int i = iN[3 * j + kept[e]];
      out->cov.row(i) *= a;
      out->cov.col(i) *= a;
    }
  }
}

}  // namespace

PlaneBatchBound planeBatchBound(const PlaneBatchData& data, const PlaneBatchState& at, const PlaneBatchBoundOptions& opt) {
  PlaneBatchBound out;
  const int F = static_cast<int>(data.frames.size()) - 1;
  const int P = static_cast<int>(data.labels.size());
  const int m = data.num_planes;
  if (F < 1 || static_cast<int>(at.R.size()) != F + 1 || static_cast<int>(at.t.size()) != F + 1 ||
      static_cast<int>(at.N.size()) != m || static_cast<int>(at.ref.size()) != P || data.gauge_plane < 0 ||
      data.gauge_plane >= m || data.gauge_component < 0 || data.gauge_component > 2) {
    out.message = "bound: inconsistent problem sizes";
    return out;
  }
  if (!data.readoutShiftMatches()) {
    out.message = "bound: readout_shift does not match the observations";
    return out;
  }
  // A rolling shutter's readout moves each prediction by readout x shift (plane_batch.hpp); as a
  // parameter it is one more column, shift / sigma.
  const bool use_readout = data.hasReadout() && (opt.readout_free || at.readout != 0.0);
  const bool use_camera = std::any_of(opt.camera_free.begin(), opt.camera_free.end(), [](bool b) { return b; }) ||
                          !at.camera.isZero(0.0) || use_readout;
  const Eigen::Vector4d* cam = use_camera ? &at.camera : nullptr;
  // Kept parameters: refs (2P), beta (1), the planes (3m minus the gauge component), the free
  // camera components.
  const int iBeta = opt.hold_beta ? -1 : 2 * P;
  out.beta_index = iBeta;
  out.N_index.assign(3 * m, -1);
  int n = 2 * P + (opt.hold_beta ? 0 : 1);
  for (int j = 0; j < m; ++j)
    for (int c = 0; c < 3; ++c)
      if (!(j == data.gauge_plane && c == data.gauge_component)) out.N_index[3 * j + c] = n++;
  for (int c = 0; c < 4; ++c)
    if (opt.camera_free[c]) out.camera_index[c] = n++;
  if (use_readout && opt.readout_free) out.readout_index = n++;
  const int iR = out.readout_index;
  const std::vector<int>& iN = out.N_index;
  const std::array<int, 4>& iC = out.camera_index;
  out.parameters = n;
  Eigen::MatrixXd S = Eigen::MatrixXd::Zero(n, n);
  // Priors on the free camera components.
  for (int c = 0; c < 4; ++c)
    if (iC[c] >= 0 && opt.camera_prior_sd[c] > 0) S(iC[c], iC[c]) += 1.0 / (opt.camera_prior_sd[c] * opt.camera_prior_sd[c]);
  if (iR >= 0 && opt.readout_prior_sd > 0) S(iR, iR) += 1.0 / (opt.readout_prior_sd * opt.readout_prior_sd);
  // Frame 0: reference residuals (RadialCamera(ref) + readout shift - z) / sigma. `gidx`
  // receives the kept columns of the observation's Jacobian `J` (q of them).
  auto referenceRow = [&](const Observation& o, const Eigen::Vector2d& shift, Eigen::Vector2d* r, int* gidx,
                          Eigen::Matrix<double, 2, 8>* J) {
    Eigen::Vector2d Jb;
    Eigen::Matrix2d Ju;
    Eigen::Matrix<double, 2, 4> Jc;
    planeBatchReferenceResidual(at.ref[o.id], at.beta, at.camera, o.uv, data.sigma_uv, r, &Ju, &Jb, &Jc);
    if (use_readout) *r += at.readout / data.sigma_uv * shift;
    int q = 0;
    for (int a = 0; a < 2; ++a) {
      gidx[q] = 2 * o.id + a;
      J->col(q++) = Ju.col(a);
    }
    if (use_camera) {
      if (iBeta >= 0) {
        gidx[q] = iBeta;
        J->col(q++) = Jb;
      }
      for (int c = 0; c < 4; ++c)
        if (iC[c] >= 0) {
          gidx[q] = iC[c];
          J->col(q++) = Jc.col(c);
        }
      if (iR >= 0) {
        gidx[q] = iR;
        J->col(q++) = shift / data.sigma_uv;
      }
    }
    return q;
  };
  for (std::size_t j = 0; j < data.frames[0].size(); ++j) {
    const Observation& o = data.frames[0][j];
    if (o.id < 0 || o.id >= P) continue;
    Eigen::Vector2d r;
    int idx[8];
    Eigen::Matrix<double, 2, 8> J;
    const int q = referenceRow(o, data.shift(0, j), &r, idx, &J);
    // At most 8 x 8: fixed storage, no heap allocation per observation.
    const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 8, 8> JtJ = J.leftCols(q).transpose() * J.leftCols(q);
    for (int a = 0; a < q; ++a)
      for (int b = 0; b < q; ++b) S(idx[a], idx[b]) += JtJ(a, b);
  }
  // One observation at frame k >= 1: its whitened residual, motion Jacobian and the Jacobian of
  // its kept columns (`gidx`, q of them); false when it cannot be projected.
  auto frameRow = [&](int k, const Observation& o, const Eigen::Vector2d& shift, Eigen::Vector2d* r,
                      Eigen::Matrix<double, 2, 6>* Jm, int* gidx, Eigen::Matrix<double, 2, 11>* Jc, int* q) {
    const int l = data.labels[o.id];
    Eigen::Vector2d Jb;
    Eigen::Matrix<double, 2, 3> JN;
    Eigen::Matrix2d Ju;
    Eigen::Matrix<double, 2, 4> Jcam;
    if (planeBatchResidual(at.t[k], Eigen::Vector3d::Zero(), at.R[k], at.beta, at.N[l], at.ref[o.id], o.uv,
                           data.sigma_uv, r, Jm, &Jb, &JN, &Ju, cam, cam ? &Jcam : nullptr) != MeasureStatus::Ok)
      return false;
    if (use_readout) *r += at.readout / data.sigma_uv * shift;
    *q = 0;
    if (iBeta >= 0) {
      gidx[*q] = iBeta;
      Jc->col((*q)++) = Jb;
    }
    for (int a = 0; a < 3; ++a)
      if (iN[3 * l + a] >= 0) {
        gidx[*q] = iN[3 * l + a];
        Jc->col((*q)++) = JN.col(a);
      }
    for (int a = 0; a < 2; ++a) {
      gidx[*q] = 2 * o.id + a;
      Jc->col((*q)++) = Ju.col(a);
    }
    for (int a = 0; a < 4; ++a)
      if (iC[a] >= 0) {
        gidx[*q] = iC[a];
        Jc->col((*q)++) = Jcam.col(a);
      }
    if (iR >= 0) {
      gidx[*q] = iR;
      Jc->col((*q)++) = shift / data.sigma_uv;
    }
    return true;
  };
  // Frames k >= 1: accumulate the frame's block [motion (6) | kept columns it touches], then
  // eliminate its motion (Schur complement) into S.
  struct FrameBlock {
    std::vector<int> cols;
    Eigen::MatrixXd Hmc;
    Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt;
  };
  std::vector<FrameBlock> blocks(opt.motion_covariance || opt.track_clustered ? F + 1 : 0);
  std::vector<int> cols;
  for (int k = 1; k <= F; ++k) {
    const auto& obs = data.frames[k];
    auto skip = [&](const std::string& why) {
      if (!opt.skip_undetermined_frames) {
        out.message = fmt::format("bound: frame {} {}", data.frameName(k), why);
        return false;
      }
      out.skipped_frames.push_back(k);
      return true;
    };
    if (obs.size() < 4) {
      if (!skip(fmt::format("has {} observations (its motion needs >= 4)", obs.size()))) return out;
      continue;
    }
    // Columns of this frame: beta, its planes' kept components, its points' refs, the camera.
    cols.clear();
    if (iBeta >= 0) cols.push_back(iBeta);
    std::vector<char> plane_in(m, 0);
    for (const Observation& o : obs) plane_in[data.labels[o.id]] = 1;
    for (int j = 0; j < m; ++j)
      if (plane_in[j])
        for (int c = 0; c < 3; ++c)
          if (iN[3 * j + c] >= 0) cols.push_back(iN[3 * j + c]);
    for (const Observation& o : obs) {
      cols.push_back(2 * o.id);
      cols.push_back(2 * o.id + 1);
    }
    for (int c = 0; c < 4; ++c)
      if (iC[c] >= 0) cols.push_back(iC[c]);
    if (iR >= 0) cols.push_back(iR);
    std::sort(cols.begin(), cols.end());
    cols.erase(std::unique(cols.begin(), cols.end()), cols.end());
    const int c = static_cast<int>(cols.size());
    auto local = [&](int global) { return static_cast<int>(std::lower_bound(cols.begin(), cols.end(), global) - cols.begin()); };
    Eigen::Matrix<double, 6, 6> Hmm = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::MatrixXd Hmc = Eigen::MatrixXd::Zero(6, c), Hcc = Eigen::MatrixXd::Zero(c, c);
    for (std::size_t j = 0; j < obs.size(); ++j) {
      const Observation& o = obs[j];
      if (o.id < 0 || o.id >= P) continue;
      Eigen::Vector2d r;
      Eigen::Matrix<double, 2, 6> Jm;
      // The observation's kept columns (local indices) and their Jacobian.
      int idx[11];
      Eigen::Matrix<double, 2, 11> Jc;
      int q = 0;
      if (!frameRow(k, o, data.shift(k, j), &r, &Jm, idx, &Jc, &q)) {
        out.message = fmt::format("bound: track {} cannot be projected at frame {}", data.pointName(o.id), data.frameName(k));
        return out;
      }
      for (int a = 0; a < q; ++a) idx[a] = local(idx[a]);
      Hmm += Jm.transpose() * Jm;
      // At most 6 x 11 and 11 x 11: fixed storage, no heap allocation per observation.
      const Eigen::Matrix<double, 6, Eigen::Dynamic, 0, 6, 11> JmtJc = Jm.transpose() * Jc.leftCols(q);
      const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 11, 11> JctJc = Jc.leftCols(q).transpose() * Jc.leftCols(q);
      for (int a = 0; a < q; ++a) {
        Hmc.col(idx[a]) += JmtJc.col(a);
        for (int b = 0; b < q; ++b) Hcc(idx[a], idx[b]) += JctJc(a, b);
      }
    }
    Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt(Hmm);
    if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 1e-12 * ldlt.vectorD().maxCoeff())) {
      if (!skip("has a motion its observations do not determine")) return out;
      continue;
    }
    const Eigen::MatrixXd red = Hcc - Hmc.transpose() * ldlt.solve(Hmc);
    for (int b = 0; b < c; ++b)  // column by column (both are column-major)
      for (int a = 0; a < c; ++a) S(cols[a], cols[b]) += red(a, b);
    if (opt.motion_covariance || opt.track_clustered) blocks[k] = {cols, Hmc, ldlt};
  }
  // Null space and pseudo-inverse, on the matrix scaled to unit diagonal (parameters differ in
  // units). A parameter whose information is negligible against the largest (a plane under pure
  // rotation: only rounding) keeps the largest's scale, so that it shows in the null space.
  // Eigenvalues up to kRoundingEigen of the largest are rounding (the exact nulls measured here
  // are ~1e-16; the assembly's relative error is ~sqrt(observations) eps): the null space. Those
  // up to kWeakEigen are the data's, however weak (an edge-on plane: 1e-13..1e-11; a translation
  // whose perspective barely shows the affine ambiguity: 1e-11..1e-9): they are left out of the
  // pseudo-inverse, which the clustered widening below works on, and their variance is added to
  // cov after it, unwidened; the sd limits judge what they leave.
  const double dmax = std::max(1e-300, S.diagonal().maxCoeff());
  Eigen::VectorXd d(n);
  for (int i = 0; i < n; ++i) d[i] = 1.0 / std::sqrt(S(i, i) > 1e-12 * dmax ? S(i, i) : dmax);
  const Eigen::MatrixXd Ss = d.asDiagonal() * S * d.asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(Ss);
  if (es.info() != Eigen::Success) {
    out.message = "bound: eigen-decomposition failed";
    return out;
  }
  const Eigen::VectorXd& lam = es.eigenvalues();
  constexpr double kRoundingEigen = 1e-14, kWeakEigen = 1e-10;
  const double lmax = std::max(1e-300, lam.maxCoeff()), tol = kWeakEigen * lmax;
  // S+ = U diag(1/lam) U^T over the kept eigenvectors, as one product (Us = U diag(lam^-1/2)).
  std::vector<int> null_cols, weak_cols, kept;
  for (int i = 0; i < n; ++i) (lam[i] <= kRoundingEigen * lmax ? null_cols : lam[i] <= tol ? weak_cols : kept).push_back(i);
  Eigen::MatrixXd Us(n, static_cast<Eigen::Index>(kept.size()));
  for (size_t j = 0; j < kept.size(); ++j) Us.col(static_cast<Eigen::Index>(j)) = es.eigenvectors().col(kept[j]) / std::sqrt(lam[kept[j]]);
  Eigen::MatrixXd pinv(n, n);
  pinv.noalias() = Us * Us.transpose();
  out.weak_dim = static_cast<int>(weak_cols.size());
  out.null_dim = static_cast<int>(null_cols.size()) + out.weak_dim;
  out.null_scaled.resize(n, static_cast<Eigen::Index>(null_cols.size()));
  for (std::size_t i = 0; i < null_cols.size(); ++i) out.null_scaled.col(static_cast<Eigen::Index>(i)) = es.eigenvectors().col(null_cols[i]);
  out.weak_scaled.resize(n, out.weak_dim);
  out.weak_lambda.resize(out.weak_dim);
  for (int i = 0; i < out.weak_dim; ++i) {
    out.weak_scaled.col(i) = es.eigenvectors().col(weak_cols[i]);
    out.weak_lambda[i] = lam[weak_cols[i]];
  }
  out.scale = d;
  out.cov = d.asDiagonal() * pinv * d.asDiagonal();  // back to the original units
  out.ok = true;
  out.clustered_N.assign(m, 1.0);
  if (opt.track_clustered) {
    // The track-clustered covariance of the global parameters (PlaneBatchBoundOptions), as
    // V = sum_t (A g_t) (A g_t)^T with A = their rows of S+: only q x P numbers are kept.
    std::vector<int> glob;
    if (iBeta >= 0) glob.push_back(iBeta);
    for (int i : iN)
      if (i >= 0) glob.push_back(i);
    for (int i : iC)
      if (i >= 0) glob.push_back(i);
    if (iR >= 0) glob.push_back(iR);
    const int q = static_cast<int>(glob.size());
    Eigen::MatrixXd A(q, n);
    for (int a = 0; a < q; ++a) A.row(a) = out.cov.row(glob[a]);
    Eigen::MatrixXd g = Eigen::MatrixXd::Zero(q, P);  // A g_t, one column per track
    // The plane's jackknife over its tracks (below): per track, its information and score on
    // its plane's N components and its reference, with the motions and beta held.
    std::vector<TrackPlaneInfo> tp(static_cast<std::size_t>(P));
    for (std::size_t j = 0; j < data.frames[0].size(); ++j) {
      const Observation& o = data.frames[0][j];
      if (o.id < 0 || o.id >= P) continue;
      Eigen::Vector2d r;
      int idx[8];
      Eigen::Matrix<double, 2, 8> J;
      const int nq = referenceRow(o, data.shift(0, j), &r, idx, &J);
      const Eigen::Matrix<double, 8, 1> v = J.transpose() * r;
      for (int a = 0; a < nq; ++a) g.col(o.id) += A.col(idx[a]) * v[a];
      tp[o.id].add(Eigen::Matrix<double, 2, 3>::Zero(), J.leftCols<2>(), r);  // columns 0-1: the reference
    }
    for (int k = 1; k <= F; ++k) {
      const FrameBlock& b = blocks[k];
      if (b.cols.empty()) continue;  // a frame left out of the bound
      // The frame's motion eliminated: an observation's reduced score is
      // Jc^T r - Hmc^T Hmm^-1 Jm^T r, so A times it is A_c Jc^T r - W Jm^T r, W = A_c (Hmm^-1 Hmc)^T.
      const int c = static_cast<int>(b.cols.size());
      Eigen::MatrixXd Ac(q, c);
      for (int a = 0; a < c; ++a) Ac.col(a) = A.col(b.cols[a]);
      const Eigen::MatrixXd W = Ac * b.ldlt.solve(b.Hmc).transpose();  // q x 6
      for (std::size_t j = 0; j < data.frames[k].size(); ++j) {
        const Observation& o = data.frames[k][j];
        if (o.id < 0 || o.id >= P) continue;
        Eigen::Vector2d r;
        Eigen::Matrix<double, 2, 6> Jm;
        int idx[11];
        Eigen::Matrix<double, 2, 11> Jc;
        int nq = 0;
        if (!frameRow(k, o, data.shift(k, j), &r, &Jm, idx, &Jc, &nq)) continue;  // cannot happen: the first pass projected it
        const Eigen::Matrix<double, 11, 1> v = Jc.transpose() * r;
        for (int a = 0; a < nq; ++a) g.col(o.id) += A.col(idx[a]) * v[a];
        g.col(o.id).noalias() -= W * (Jm.transpose() * r);
        // This observation's columns on its plane's N components and its reference.
        const int l = data.labels[o.id];
        Eigen::Matrix<double, 2, 3> JN = Eigen::Matrix<double, 2, 3>::Zero();
        Eigen::Matrix2d Ju = Eigen::Matrix2d::Zero();
        for (int a = 0; a < nq; ++a) {
          for (int e = 0; e < 3; ++e)
            if (iN[3 * l + e] >= 0 && idx[a] == iN[3 * l + e]) JN.col(e) = Jc.col(a);
          for (int e = 0; e < 2; ++e)
            if (idx[a] == 2 * o.id + e) Ju.col(e) = Jc.col(a);
        }
        tp[o.id].add(JN, Ju, r);
      }
    }
    int tracks = 0;
    for (int t = 0; t < P; ++t) tracks += !g.col(t).isZero(0.0);
    // Per plane: the sandwiches' largest variance ratio (track or region clusters) on its N
    // components against the bound, before widening (0: not computed).
    std::vector<double> sandwich_N(m, 0.0);
    // The spatial clusters' scores (spatial_grid): the tracks' scores summed per cell.
    Eigen::MatrixXd gs;
    int cells = 0;
    if (opt.spatial_grid > 0) {
      const int G = opt.spatial_grid;
      std::vector<Eigen::Vector2d> lo(m, Eigen::Vector2d::Constant(1e300)), hi(m, Eigen::Vector2d::Constant(-1e300));
      for (int t = 0; t < P && t < static_cast<int>(at.ref.size()); ++t) {
        const int j = data.labels[t];
        if (j < 0 || j >= m || g.col(t).isZero(0.0)) continue;
        lo[j] = lo[j].cwiseMin(at.ref[t]);
        hi[j] = hi[j].cwiseMax(at.ref[t]);
      }
      gs = Eigen::MatrixXd::Zero(q, m * G * G);
      for (int t = 0; t < P && t < static_cast<int>(at.ref.size()); ++t) {
        const int j = data.labels[t];
        if (j < 0 || j >= m || g.col(t).isZero(0.0)) continue;
        const Eigen::Vector2d span = (hi[j] - lo[j]).cwiseMax(1e-12);
        const int ix = std::clamp(static_cast<int>(G * (at.ref[t].x() - lo[j].x()) / span.x()), 0, G - 1);
        const int iy = std::clamp(static_cast<int>(G * (at.ref[t].y() - lo[j].y()) / span.y()), 0, G - 1);
        gs.col((j * G + iy) * G + ix) += g.col(t);
      }
      for (int c = 0; c < gs.cols(); ++c) cells += !gs.col(c).isZero(0.0);
    }
    if (tracks > 1) {
      Eigen::VectorXd c0(q);
      for (int a = 0; a < q; ++a) c0[a] = out.cov(glob[a], glob[a]);
      // Widens the bound of the globals `sel` to cover the sandwich V in every direction, never
      // narrowing any: C' = C^1/2 max(I, C^-1/2 V C^-1/2) C^1/2 on C's range (the generalized
      // eigenvalues of (V, C) clamped at 1 from below), so C' >= C and C' >= V in the Loewner
      // order and every functional's variance, a frame's motion's through the back-substitution
      // included, is at least the bound's and the sandwich's. Invariant to the parameters' units
      // (computed on the correlation matrix).
      auto widen = [&](const Eigen::MatrixXd& V, const std::vector<int>& sel) {
        const int r = static_cast<int>(sel.size());
        Eigen::MatrixXd C(r, r), Vr(r, r);
        Eigen::VectorXd d(r);
        for (int a = 0; a < r; ++a) d[a] = std::sqrt(std::max(out.cov(glob[sel[a]], glob[sel[a]]), 0.0));
        for (int a = 0; a < r; ++a)
          for (int e = 0; e < r; ++e) {
            const double n = d[a] > 0 && d[e] > 0 ? d[a] * d[e] : 0.0;
            C(a, e) = n > 0 ? out.cov(glob[sel[a]], glob[sel[e]]) / n : 0.0;
            Vr(a, e) = n > 0 && std::isfinite(V(sel[a], sel[e])) ? V(sel[a], sel[e]) / n : 0.0;
          }
        const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> ec(C);
        if (ec.info() != Eigen::Success) return;
        const double tol = 1e-10 * std::max(1.0, ec.eigenvalues().maxCoeff());
        std::vector<int> keep;
        for (int a = 0; a < r; ++a)
          if (ec.eigenvalues()[a] > tol) keep.push_back(a);
        const int k = static_cast<int>(keep.size());
        if (k == 0) return;
        Eigen::MatrixXd S(r, k), W(r, k);  // C^1/2 and C^-1/2 on the range
        for (int i = 0; i < k; ++i) {
          const double l = ec.eigenvalues()[keep[i]];
          S.col(i) = ec.eigenvectors().col(keep[i]) * std::sqrt(l);
          W.col(i) = ec.eigenvectors().col(keep[i]) / std::sqrt(l);
        }
        const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> em(W.transpose() * Vr * W);
        if (em.info() != Eigen::Success) return;
        const Eigen::VectorXd lift = (em.eigenvalues().array() - 1.0).cwiseMax(0.0);
        const Eigen::MatrixXd D = S * em.eigenvectors() * lift.asDiagonal() * em.eigenvectors().transpose() * S.transpose();
        for (int a = 0; a < r; ++a)
          for (int e = 0; e < r; ++e) out.cov(glob[sel[a]], glob[sel[e]]) += D(a, e) * d[a] * d[e];
      };
      std::vector<int> all(q), no_camera;
      for (int a = 0; a < q; ++a) {
        all[a] = a;
        if (std::find(iC.begin(), iC.end(), glob[a]) == iC.end() && glob[a] != iR) no_camera.push_back(a);
      }
      const Eigen::MatrixXd V = g * g.transpose() * (static_cast<double>(tracks) / (tracks - 1));
      widen(V, all);
      // The spatial clusters widen beta and the planes only: the camera's bound decides whether
      // the principal point and the distortion are held (RefineResult), and a region's shared
      // error is what a free camera absorbs.
      Eigen::MatrixXd Vs;
      if (cells > 1 && !no_camera.empty()) {
        Vs = gs * gs.transpose() * (static_cast<double>(cells) / (cells - 1));
        widen(Vs, no_camera);
      }
      Eigen::VectorXd f = Eigen::VectorXd::Ones(q), ratio = Eigen::VectorXd::Zero(q);
      for (int a = 0; a < q; ++a)
        if (c0[a] > 0) {
          ratio[a] = std::isfinite(V(a, a)) ? V(a, a) / c0[a] : 0.0;
          f[a] = std::sqrt(std::max(1.0, out.cov(glob[a], glob[a]) / c0[a]));
        }
      for (int a = 0; a < q; ++a) {
        if (glob[a] == iBeta) {
          out.clustered_beta = f[a];
          out.clustered_beta_ratio = ratio[a];
        }
        // The region sandwich's ratio (0 without regions), for the planes' jackknife.
        const double ratio_s = c0[a] > 0 && Vs.size() && std::isfinite(Vs(a, a)) ? Vs(a, a) / c0[a] : 0.0;
        for (int j = 0; j < m; ++j)
          for (int e = 0; e < 3; ++e)
            if (iN[3 * j + e] == glob[a]) {
              out.clustered_N[j] = std::max(out.clustered_N[j], f[a]);
              sandwich_N[j] = std::max({sandwich_N[j], ratio[a], ratio_s});
            }
        for (int e = 0; e < 4; ++e)
          if (iC[e] == glob[a]) out.clustered_camera[e] = f[a];
        if (glob[a] == iR) out.clustered_readout = f[a];
      }
    }
    planeJackknife(data, iN, tp, sandwich_N, &out);
  }
  if (out.weak_dim > 0) {
    // The weak directions' variance (above), in the original units, as the model gives it: not
    // widened by the tracks' own check, which sees only the pseudo-inverse's directions. Widened
    // by each parameter's factor instead (tried on 2026-12-07), a 1200-frame orbit's focal
    // length read 8.7 % (its error -4.5 %) and its planes 1.0-1.7 deg (errors 0.5-0.6 deg):
    // two to three times too wide; unwidened, 3.6 % and 0.5-0.8 deg (docs/estimate.md, "Null,
    // weak and seen directions").
    Eigen::MatrixXd Ws = d.asDiagonal() * out.weak_scaled;
    for (int i = 0; i < out.weak_dim; ++i) Ws.col(i) /= std::sqrt(out.weak_lambda[i]);
    out.cov.noalias() += Ws * Ws.transpose();
  }
  const Eigen::MatrixXd& cov = out.cov;
  out.beta_estimable = iBeta >= 0 && out.estimable(1.0, {}, Eigen::Vector4d::Zero());
  out.var_beta = iBeta >= 0 ? cov(iBeta, iBeta) : 0.0;
  for (int j = 0; j < m; ++j) {
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    Eigen::Vector3d cb = Eigen::Vector3d::Zero();
    for (int a = 0; a < 3; ++a) {
      if (iN[3 * j + a] < 0) continue;
      if (iBeta >= 0) cb[a] = cov(iBeta, iN[3 * j + a]);
      for (int b = 0; b < 3; ++b)
        if (iN[3 * j + b] >= 0) C(a, b) = cov(iN[3 * j + a], iN[3 * j + b]);
    }
    out.cov_N.push_back(C);
    out.cov_beta_N.push_back(cb);
    // The direction's tangent functionals: rows of (I - n n^T) / |N|.
    const Eigen::Matrix3d J = unitDirectionJacobian(at.N[j]);
    bool ok = true;
    for (int row = 0; row < 3 && ok; ++row) {
      std::vector<Eigen::Vector3d> g(m, Eigen::Vector3d::Zero());
      g[j] = J.row(row).transpose();
      ok = out.estimable(0.0, g, Eigen::Vector4d::Zero());
    }
    out.normal_estimable.push_back(ok);
    // Its cross-covariances with the planes before it: the pairs (a, j), a < j, in the order of
    // TrackFrame::cov_N_pair.
    for (int a = 0; a < j; ++a) {
      Eigen::Matrix3d X = Eigen::Matrix3d::Zero();
      for (int e = 0; e < 3; ++e)
        for (int c = 0; c < 3; ++c)
          if (iN[3 * a + e] >= 0 && iN[3 * j + c] >= 0) X(e, c) = cov(iN[3 * a + e], iN[3 * j + c]);
      out.cov_N_pair.push_back(X);
    }
  }
  for (int c = 0; c < 4; ++c) {
    if (iC[c] < 0) continue;
    Eigen::Vector4d g = Eigen::Vector4d::Zero();
    g[c] = 1;
    out.camera_estimable[c] = out.estimable(0.0, {}, g);
    for (int b = 0; b < 4; ++b)
      if (iC[b] >= 0) out.cov_camera(c, b) = cov(iC[c], iC[b]);
  }
  if (iR >= 0) {
    out.readout_estimable = out.estimable(0.0, {}, Eigen::Vector4d::Zero(), 1.0);
    out.var_readout = cov(iR, iR);
    for (int c = 0; c < 4; ++c)
      if (iC[c] >= 0) out.cov_readout_camera[c] = cov(iR, iC[c]);
  }
  if (opt.motion_covariance) {
    // cov(m_k) = H_kk^-1 + H_kk^-1 H_kc cov_c H_ck H_kk^-1 (the eliminated block's marginal).
    out.cov_motion.assign(F + 1, Eigen::Matrix<double, 6, 6>::Zero());
    for (int k = 1; k <= F; ++k) {
      const FrameBlock& b = blocks[k];
      if (b.cols.empty()) continue;
      const int c = static_cast<int>(b.cols.size());
      Eigen::MatrixXd Cc(c, c);
      for (int e = 0; e < c; ++e)  // column by column (both are column-major)
        for (int a = 0; a < c; ++a) Cc(a, e) = cov(b.cols[a], b.cols[e]);
      const Eigen::Matrix<double, 6, 6> Hinv = b.ldlt.solve(Eigen::Matrix<double, 6, 6>::Identity());
      const Eigen::MatrixXd G = Hinv * b.Hmc;  // 6 x c
      out.cov_motion[k] = Hinv + G * Cc * G.transpose();
    }
  }
  out.message = fmt::format("bound: {} parameters after eliminating {} motions{}, null space of dimension {}", n,
                            F - static_cast<int>(out.skipped_frames.size()),
                            out.skipped_frames.empty() ? "" : fmt::format(" ({} frames left out)", out.skipped_frames.size()),
                            out.null_dim);
  return out;
}

}  // namespace rsfm
