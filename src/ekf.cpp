#include "rsfm/ekf.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "rsfm/chi2.hpp"

namespace rsfm {

void MeasurementBatch::resize(int nblocks, int n, int bd) {
  block_dim = bd;
  residual = Eigen::VectorXd::Zero(nblocks * bd);
  H = Eigen::MatrixXd::Zero(nblocks * bd, n);
  R = Eigen::MatrixXd::Zero(nblocks * bd, bd);
}

std::string describeHealth(std::uint32_t f) {
  if (f == kHealthy) return "healthy";
  std::string s;
  auto add = [&](std::uint32_t bit, const char* name) {
    if (f & bit) s += (s.empty() ? "" : ", ") + std::string(name);
  };
  add(kNonFiniteInput, "non-finite measurement input");
  add(kNonFiniteState, "non-finite state after update");
  add(kCovarianceNotPD, "covariance not positive semi-definite");
  add(kSolveFailed, "linear solve failed");
  add(kTooFewMeasurements, "too few measurements");
  add(kBadMeasurementCovariance, "measurement covariance not positive definite");
  add(kInvalidRotation, "incremental rotation out of range (|omega| >= 2)");
  return s;
}

Ekf::Ekf(Eigen::VectorXd x0, Eigen::MatrixXd P0, std::vector<bool> fixed)
    : x_(std::move(x0)), P_(std::move(P0)), fixed_(std::move(fixed)) {
  const int n = static_cast<int>(x_.size());
  if (P_.rows() != n || P_.cols() != n || static_cast<int>(fixed_.size()) != n)
    throw std::invalid_argument("Ekf: state, covariance and fixed mask sizes differ");
  P_ = 0.5 * (P_ + P_.transpose()).eval();
  for (int i = 0; i < n; ++i)
    if (fixed_[i]) {
      P_.row(i).setZero();
      P_.col(i).setZero();
    }
}

std::vector<int> Ekf::freeIndices() const {
  std::vector<int> f;
  f.reserve(x_.size());
  for (int i = 0; i < size(); ++i)
    if (!fixed_[i]) f.push_back(i);
  return f;
}

void Ekf::predict(const Eigen::VectorXd& q_diag) {
  for (int i = 0; i < size(); ++i)
    if (!fixed_[i]) P_(i, i) += q_diag[i];
}

void Ekf::predict(const Eigen::MatrixXd& F, const Eigen::MatrixXd& Q) {
  const auto f = freeIndices();
  Eigen::MatrixXd Ff = F(f, f), Pf = P_(f, f), Qf = Q(f, f);
  Eigen::MatrixXd Pn = Ff * Pf * Ff.transpose() + Qf;
  P_(f, f) = 0.5 * (Pn + Pn.transpose());
}

std::uint32_t Ekf::health() const {
  std::uint32_t h = kHealthy;
  if (!x_.allFinite() || !P_.allFinite()) return kNonFiniteState;
  for (int i = 0; i < size(); ++i)
    if (P_(i, i) < 0.0) h |= kCovarianceNotPD;
  const double scale = std::max(1.0, P_.cwiseAbs().maxCoeff());
  if (size() > 0 && (P_ - P_.transpose()).cwiseAbs().maxCoeff() > 1e-9 * scale) h |= kCovarianceNotPD;
  return h;
}

void Ekf::augment(const Eigen::VectorXd& x_new, const Eigen::MatrixXd& P_new,
                  const Eigen::MatrixXd& P_cross, bool fixed) {
  const int n = size(), k = static_cast<int>(x_new.size());
  Eigen::VectorXd x(n + k);
  x << x_, x_new;
  Eigen::MatrixXd P = Eigen::MatrixXd::Zero(n + k, n + k);
  P.topLeftCorner(n, n) = P_;
  P.bottomRightCorner(k, k) = P_new;
  if (!fixed) {
    P.bottomLeftCorner(k, n) = P_cross;
    P.topRightCorner(n, k) = P_cross.transpose();
  } else {
    P.bottomRightCorner(k, k).setZero();
  }
  x_ = std::move(x);
  P_ = std::move(P);
  for (int i = 0; i < k; ++i) fixed_.push_back(fixed);
}

bool Ekf::projectLowerBound(int i, double lower) {
  if (!(x_[i] < lower) || !(P_(i, i) > 0.0)) return false;
  const Eigen::VectorXd col = P_.col(i);
  x_ += col * ((lower - x_[i]) / col[i]);
  return true;
}

void Ekf::setFixed(int i, bool fixed) {
  fixed_[i] = fixed;
  if (fixed) {
    P_.row(i).setZero();
    P_.col(i).setZero();
  }
}

void Ekf::remove(const std::vector<int>& indices) {
  std::vector<bool> drop(size(), false);
  for (int i : indices) drop.at(i) = true;
  std::vector<int> keep;
  for (int i = 0; i < size(); ++i)
    if (!drop[i]) keep.push_back(i);
  Eigen::VectorXd x = x_(keep);
  Eigen::MatrixXd P = P_(keep, keep);
  std::vector<bool> fx;
  for (int i : keep) fx.push_back(fixed_[i]);
  x_ = std::move(x);
  P_ = std::move(P);
  fixed_ = std::move(fx);
}

void Ekf::reorder(const std::vector<int>& order) {
  if (static_cast<int>(order.size()) != size()) throw std::invalid_argument("Ekf::reorder: not a permutation of the state");
  std::vector<bool> seen(size(), false), fx;
  for (int i : order) {
    if (i < 0 || i >= size() || seen[i]) throw std::invalid_argument("Ekf::reorder: not a permutation of the state");
    seen[i] = true;
    fx.push_back(fixed_[i]);
  }
  Eigen::VectorXd x = x_(order);
  Eigen::MatrixXd P = P_(order, order);
  x_ = std::move(x);
  P_ = std::move(P);
  fixed_ = std::move(fx);
}

UpdateStats Ekf::update(const MeasurementBatch& batch, const UpdateOptions& opt) {
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

int iteratedUpdate(Ekf* ekf, int iterations, double tol, int halvings, const Eigen::VectorXd& x_prior,
                   const Eigen::MatrixXd& P_prior, const std::function<bool(const Eigen::VectorXd&, double*)>& measurement_cost,
                   const std::function<bool(const Eigen::VectorXd&)>& gauss_newton_point) {
  const std::vector<int> f = ekf->freeIndices();
  Eigen::MatrixXd Pf = P_prior(f, f);
  Pf.diagonal().array() += 1e-12 * std::max(1e-300, Pf.diagonal().maxCoeff());
  const Eigen::LDLT<Eigen::MatrixXd> prior(Pf);
  auto cost = [&](const Eigen::VectorXd& x, double* out) {
    double c = 0.0;
    if (!measurement_cost(x, &c)) return false;
    const Eigen::VectorXd dx = (x - x_prior)(f);
    c += dx.dot(prior.solve(dx));
    *out = c;
    return std::isfinite(c);
  };
  Eigen::VectorXd x_lin = x_prior;
  double c_lin = 0.0;
  if (!cost(x_lin, &c_lin)) return 0;
  Eigen::VectorXd x_gn = ekf->x();
  Eigen::MatrixXd P_gn = ekf->P();
  for (int it = 0; it < iterations; ++it) {
    const Eigen::VectorXd d = x_gn - x_lin;
    bool ok = false;
    Eigen::VectorXd x_acc;
    double c_acc = 0.0, alpha = 1.0;
    for (int ls = 0; ls < halvings && !ok; ++ls, alpha *= 0.5) {
      const Eigen::VectorXd xt = x_lin + alpha * d;
      double c = 0.0;
      if (cost(xt, &c) && c < c_lin) ok = true, x_acc = xt, c_acc = c;
    }
    ekf->mutableP() = P_gn;
    if (!ok) {  // no step decreases J: stay at the current iterate
      ekf->mutableX() = x_lin;
      return it + 1;
    }
    ekf->mutableX() = x_acc;
    const double step = (x_acc - x_lin).cwiseAbs().maxCoeff();
    x_lin = x_acc;
    c_lin = c_acc;
    if (!(step > tol) || it + 1 >= iterations) return it + 1;
    if (!gauss_newton_point(x_lin)) {
      ekf->mutableX() = x_lin;
      ekf->mutableP() = P_gn;
      return it + 1;
    }
    x_gn = ekf->x();
    P_gn = ekf->P();
    ekf->mutableX() = x_lin;  // until the line search accepts a point
  }
  return iterations;
}

}  // namespace rsfm
