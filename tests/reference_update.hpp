#pragma once
// The EKF update as it was before issue 15 (commit 0d28b21, src/ekf.cpp, dynamic-size per-block
// algebra), kept verbatim as the reference the allocation-free update is compared with (to 1e-10).
// Test only.
#include <Eigen/Cholesky>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "rsfm/chi2.hpp"
#include "rsfm/ekf.hpp"

namespace rsfm::testing {

inline UpdateStats referenceUpdate(Eigen::VectorXd& x_, Eigen::MatrixXd& P_, const std::vector<bool>& fixed_,
                                   const MeasurementBatch& batch, const UpdateOptions& opt) {
  auto size = [&] { return static_cast<int>(x_.size()); };
  auto freeIndices = [&] {
    std::vector<int> f;
    for (int i = 0; i < size(); ++i)
      if (!fixed_[i]) f.push_back(i);
    return f;
  };
  UpdateStats st;
  const int bd = batch.block_dim;
  const int nb = batch.blocks();
  st.blocks = nb;
  st.gated_mask.assign(nb, 0);
  if (bd <= 0 || batch.residual.size() != nb * bd || batch.H.rows() != nb * bd ||
      batch.H.cols() != size() || batch.R.rows() != nb * bd || batch.R.cols() != bd)
    throw std::invalid_argument("Ekf::update: measurement batch has inconsistent sizes");
  if (!batch.residual.allFinite() || !batch.H.allFinite() || !batch.R.allFinite()) {
    st.health |= kNonFiniteInput;
    return st;
  }
  const auto f = freeIndices();
  const int nf = static_cast<int>(f.size());
  const Eigen::MatrixXd Pf = P_(f, f);
  const Eigen::MatrixXd Hf = batch.H(Eigen::all, f);

  // Per-block gating: S_b = H_b P H_b^T + R_b.
  const bool gating = opt.gate_probability > 0.0 && opt.gate_probability < 1.0;
  const double gate = gating ? chi2Quantile(opt.gate_probability, bd) : 0.0;
  const Eigen::MatrixXd PHt = Pf * Hf.transpose();  // nf x m
  std::vector<int> used;
  used.reserve(nb);
  for (int b = 0; b < nb; ++b) {
    const Eigen::MatrixXd Rb = batch.R.middleRows(b * bd, bd);
    Eigen::LDLT<Eigen::MatrixXd> rl(Rb);
    if (rl.info() != Eigen::Success || !rl.isPositive() || rl.vectorD().minCoeff() <= 0.0) {
      st.health |= kBadMeasurementCovariance;
      return st;
    }
    if (gating) {
      const Eigen::MatrixXd Sb = Hf.middleRows(b * bd, bd) * PHt.middleCols(b * bd, bd) + Rb;
      Eigen::LDLT<Eigen::MatrixXd> sl(Sb);
      const Eigen::VectorXd rb = batch.residual.segment(b * bd, bd);
      const double d2 = sl.info() == Eigen::Success ? rb.dot(sl.solve(rb)) : HUGE_VAL;
      if (!(d2 <= gate)) {
        st.gated_mask[b] = 1;
        ++st.gated;
        continue;
      }
    }
    used.push_back(b);
  }
  st.used = static_cast<int>(used.size());
  st.nis_dof = st.used * bd;
  if (st.used < std::max(1, opt.min_blocks)) {
    st.health |= kTooFewMeasurements;
    return st;
  }
  const int m = st.used * bd;
  {
    double ss = 0.0;
    for (int b : used) ss += batch.residual.segment(b * bd, bd).squaredNorm();
    st.innovation_rms = std::sqrt(ss / m);
  }

  UpdateForm form = opt.form;
  if (form == UpdateForm::Auto) form = m > nf ? UpdateForm::Information : UpdateForm::Covariance;
  st.form_used = form;

  // The prior must be symmetric positive semi-definite (up to round-off); both forms use its
  // pivoted LDLT: the information form as the factor G, the covariance form only as this check.
  Eigen::LDLT<Eigen::MatrixXd> pl(Pf);
  {
    const Eigen::VectorXd D = pl.vectorD();
    const double dmax = std::max(D.cwiseAbs().maxCoeff(), 1e-300);
    const double scale = std::max(1e-300, Pf.cwiseAbs().maxCoeff());
    if (pl.info() != Eigen::Success || D.minCoeff() < -1e-9 * dmax ||
        (Pf - Pf.transpose()).cwiseAbs().maxCoeff() > 1e-9 * scale) {
      st.health |= kCovarianceNotPD;
      return st;
    }
  }

  Eigen::VectorXd dx;
  Eigen::MatrixXd Pn;
  if (form == UpdateForm::Covariance) {
    Eigen::MatrixXd Hu(m, nf), Ru = Eigen::MatrixXd::Zero(m, m);
    Eigen::VectorXd ru(m);
    for (int k = 0; k < st.used; ++k) {
      const int b = used[k];
      Hu.middleRows(k * bd, bd) = Hf.middleRows(b * bd, bd);
      ru.segment(k * bd, bd) = batch.residual.segment(b * bd, bd);
      Ru.block(k * bd, k * bd, bd, bd) = batch.R.middleRows(b * bd, bd);
    }
    const Eigen::MatrixXd PH = Pf * Hu.transpose();  // nf x m
    Eigen::MatrixXd S = Hu * PH + Ru;
    S = 0.5 * (S + S.transpose()).eval();
    Eigen::LDLT<Eigen::MatrixXd> sl(S);
    if (sl.info() != Eigen::Success || !sl.isPositive()) {
      st.health |= kSolveFailed;
      return st;
    }
    const Eigen::MatrixXd K = sl.solve(PH.transpose()).transpose();  // nf x m
    dx = K * ru;
    st.nis = ru.dot(sl.solve(ru));
    const Eigen::MatrixXd IKH = Eigen::MatrixXd::Identity(nf, nf) - K * Hu;
    Pn = IKH * Pf * IKH.transpose() + K * Ru * K.transpose();
  } else {
    // Information form accumulated block by block: O(m n^2).
    Eigen::MatrixXd J = Eigen::MatrixXd::Zero(nf, nf);
    Eigen::VectorXd g = Eigen::VectorXd::Zero(nf);
    double c = 0.0;
    for (int b : used) {
      const Eigen::MatrixXd Rb = batch.R.middleRows(b * bd, bd);
      Eigen::LDLT<Eigen::MatrixXd> rl(Rb);
      const auto Hb = Hf.middleRows(b * bd, bd);
      const Eigen::VectorXd rb = batch.residual.segment(b * bd, bd);
      const Eigen::MatrixXd RiH = rl.solve(Hb);  // bd x nf
      J.noalias() += Hb.transpose() * RiH;
      const Eigen::VectorXd Rir = rl.solve(rb);
      g.noalias() += Hb.transpose() * Rir;
      c += rb.dot(Rir);
    }
    // P = G G^T from the pivoted LDLT (zero-variance directions allowed; pivots within
    // round-off of zero were accepted above and are taken as zero).
    const Eigen::VectorXd D = pl.vectorD().cwiseMax(0.0);
    Eigen::MatrixXd L = pl.matrixL();
    Eigen::MatrixXd G = pl.transpositionsP().transpose() * (L * D.cwiseSqrt().asDiagonal());
    Eigen::MatrixXd M = Eigen::MatrixXd::Identity(nf, nf) + G.transpose() * J * G;
    M = 0.5 * (M + M.transpose()).eval();
    Eigen::LDLT<Eigen::MatrixXd> ml(M);
    if (ml.info() != Eigen::Success || !ml.isPositive()) {
      st.health |= kSolveFailed;
      return st;
    }
    Pn = G * ml.solve(G.transpose());
    dx = Pn * g;
    st.nis = c - g.dot(dx);
  }
  Pn = 0.5 * (Pn + Pn.transpose()).eval();
  if (!dx.allFinite() || !Pn.allFinite()) {
    st.health |= kNonFiniteState;
    return st;  // prior kept
  }
  x_(f) += dx;
  P_(f, f) = Pn;
  st.applied = true;
  return st;
}

}  // namespace rsfm::testing
