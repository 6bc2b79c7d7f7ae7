#include "rsfm/ekf.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <stdexcept>

#include "rsfm/chi2.hpp"

#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#endif

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

void UpdateStats::reset(int nblocks) {
  blocks = nblocks;
  used = gated = 0;
  innovation_rms = nis = 0.0;
  nis_dof = 0;
  health = kHealthy;
  applied = false;
  form_used = UpdateForm::Covariance;
  gated_mask.assign(nblocks, 0);
}

namespace {
/// Storage growth of the work space: 25 % headroom, so a slowly growing frame does not
/// reallocate every time.
Eigen::Index grown(Eigen::Index need, Eigen::Index have) { return need <= have ? have : need + need / 4; }
constexpr int kMaxBlockDim = 6;  // the patch model's 6-row blocks are the largest
// Free state sizes of the fused two-row path (Ekf::fusedTwoRow): one plane (7 motion + 3 plane
// components, the gauge and a known focal length fixed or not) and a little room.
constexpr int kFusedMin = 7, kFusedMax = 12;

/// In-place Cholesky A = L L^T of a small symmetric matrix from its lower half (plain loops: at
/// these sizes Eigen's LLT spends most of its time in set-up). The strict upper half is zeroed.
/// False when a pivot is not positive (Eigen's LLT criterion): A is then left partly overwritten.
template <class Mat>
bool smallCholesky(Mat& A) {
  const int n = static_cast<int>(A.rows());
  for (int j = 0; j < n; ++j) {
    double d = A(j, j);
    for (int k = 0; k < j; ++k) d -= A(j, k) * A(j, k);
    if (!(d > 0.0)) return false;
    const double ljj = std::sqrt(d), inv = 1.0 / ljj;
    A(j, j) = ljj;
    for (int i = j + 1; i < n; ++i) {
      double v = A(i, j);
      for (int k = 0; k < j; ++k) v -= A(i, k) * A(j, k);
      A(i, j) = v * inv;
    }
    for (int i = 0; i < j; ++i) A(i, j) = 0.0;
  }
  return true;
}

/// A two-row block's noise factor L_b (L_b L_b^T = R_b, lower) from R_b's lower half; false when
/// R_b is not positive definite. Shared by gateAndWhiten's two-row branch and fusedTwoRow
/// (always inlined: GCC's budget left these calls out of fusedTwoRow's loop, 79 -> 86 ns per point
/// in BM_PlaneUpdate/3000).
struct Chol2 {
  double l00, l10, l11;
};
[[gnu::always_inline]] inline bool cholesky2(double r00, double r10, double r11, Chol2* l) {
  const double l00 = std::sqrt(r00), l10 = r10 / l00, d11 = r11 - l10 * l10;
  if (!(r00 > 0.0) || !(d11 > 0.0)) return false;
  *l = {l00, l10, std::sqrt(d11)};
  return true;
}
/// The chi-square gate distance e^T S^-1 e of a whitened two-row block, S = [s00 s01; s01 s11].
[[gnu::always_inline]] inline double gateDistance2(double s00, double s01, double s11, double e0, double e1) {
  return (s11 * e0 * e0 - 2.0 * s01 * e0 * e1 + s00 * e1 * e1) / (s00 * s11 - s01 * s01);
}
}  // namespace

void BlockBatch::reserve(int max_blocks, int bd, int shared_cols, int own_cols) {
  block_dim = bd;
  shared = shared_cols;
  own = own_cols;
  blocks = 0;
  const Eigen::Index rows = static_cast<Eigen::Index>(max_blocks) * bd, w = shared_cols + own_cols;
  if (residual.size() < rows) residual.resize(grown(rows, residual.size()));
  if (J.rows() < rows || J.cols() != w) J.resize(grown(rows, J.rows()), w);
  if (cols.rows() < max_blocks || cols.cols() != own_cols) cols.resize(grown(max_blocks, cols.rows()), own_cols);
  if (R.rows() < rows || R.cols() != bd) R.resize(grown(rows, R.rows()), bd);
}

void BlockBatch::shiftResidual(const Eigen::VectorXd& dx) {
  for (int b = 0; b < blocks; ++b) {
    auto rb = residual.segment(b * block_dim, block_dim);
    rb.noalias() += J.block(b * block_dim, 0, block_dim, shared) * dx.head(shared);
    for (int j = 0; j < own; ++j) rb += J.block(b * block_dim, shared + j, block_dim, 1) * dx[cols(b, j)];
  }
}

MeasurementBatch BlockBatch::dense(int n) const {
  MeasurementBatch d;
  d.resize(blocks, n, block_dim);
  const int m = rows();
  d.residual = residual.head(m);
  d.R = R.topRows(m);
  d.H.leftCols(shared) = J.topLeftCorner(m, shared);
  for (int b = 0; b < blocks; ++b)
    for (int j = 0; j < own; ++j)
      d.H.block(b * block_dim, cols(b, j), block_dim, 1) += J.block(b * block_dim, shared + j, block_dim, 1);
  return d;
}

BlockBatch BlockBatch::fromDense(const MeasurementBatch& d) {
  BlockBatch b;
  b.block_dim = d.block_dim;
  b.shared = static_cast<int>(d.H.cols());
  b.own = 0;
  b.blocks = d.blocks();
  b.residual = d.residual;
  b.J = d.H;
  b.cols.resize(b.blocks, 0);
  b.R = d.R;
  return b;
}

UpdateStats Ekf::update(const MeasurementBatch& batch, const UpdateOptions& opt) {
  const int bd = batch.block_dim;
  const int nb = batch.blocks();
  if (bd <= 0 || batch.residual.size() != nb * bd || batch.H.rows() != nb * bd ||
      batch.H.cols() != size() || batch.R.rows() != nb * bd || batch.R.cols() != bd)
    throw std::invalid_argument("Ekf::update: measurement batch has inconsistent sizes");
  UpdateStats st;
  update(BlockBatch::fromDense(batch), opt, &st);
  return st;
}

bool Ekf::factorPrior(UpdateStats* st) {
  const int n = size();
  Work& w = w_;
  w.free.clear();
  for (int i = 0; i < n; ++i)
    if (!fixed_[i]) w.free.push_back(i);
  const int nf = static_cast<int>(w.free.size());
  const bool all_free = nf == n;
  // (Explicit loops: an indexed view would copy the index vector, a heap allocation.)
  if (all_free) {
    w.Pf = P_;
  } else {
    w.Pf.resize(nf, nf);
    for (int j = 0; j < nf; ++j)
      for (int i = 0; i < nf; ++i) w.Pf(i, j) = P_(w.free[i], w.free[j]);
  }
  // The prior must be symmetric positive semi-definite up to round-off.
  const double scale = std::max(1e-300, nf > 0 ? w.Pf.cwiseAbs().maxCoeff() : 0.0);
  if (nf > 0 && (w.Pf - w.Pf.transpose()).cwiseAbs().maxCoeff() > 1e-9 * scale) {
    st->health |= kCovarianceNotPD;
    return false;
  }
  // P_f = G G^T: Cholesky when P_f is positive definite (the usual case), else the pivoted LDLT,
  // whose pivots within round-off of zero are taken as zero (zero-variance directions allowed).
  bool llt_ok;
  if (nf <= kFusedMax) {
    w.G = w.Pf;
    llt_ok = smallCholesky(w.G);
  } else {
    w.llt.compute(w.Pf);
    llt_ok = w.llt.info() == Eigen::Success;
    if (llt_ok) w.G = w.llt.matrixL();
  }
  if (llt_ok) {
    w.G_lower = true;
  } else {
    w.ldlt.compute(w.Pf);
    const Eigen::VectorXd D = w.ldlt.vectorD();
    const double dmax = std::max(D.cwiseAbs().maxCoeff(), 1e-300);
    if (w.ldlt.info() != Eigen::Success || D.minCoeff() < -1e-9 * dmax) {
      st->health |= kCovarianceNotPD;
      return false;
    }
    const Eigen::MatrixXd L = w.ldlt.matrixL();
    w.G = w.ldlt.transpositionsP().transpose() * (L * D.cwiseMax(0.0).cwiseSqrt().asDiagonal());
    w.G_lower = false;
  }
  if (all_free) {
    w.Gx = w.G;
  } else {
    w.Gx.setZero(n, nf);
    for (int k = 0; k < nf; ++k) w.Gx.row(w.free[k]) = w.G.row(k);
  }
  return true;
}

namespace {
/// A non-finite residual, Jacobian or R: the update is skipped (statistics as if nothing was tried).
bool nonFinite(UpdateStats* st) {
  st->reset(st->blocks);
  st->health |= kNonFiniteInput;
  return false;
}
}  // namespace

namespace {
/// The fused pass's inputs (Ekf::fusedTwoRow): the batch, its W free columns' places `pos` in J,
/// the `nskip` fixed columns `skip` between them (checked for finiteness only), the common
/// R_b = iso I (iso > 0, folded into Gs with inv_s = iso^-1/2) or 0, the gate, how many rows of
/// the accepted blocks' A and e to keep for the covariance form, and the statistics.
struct FusedPass {
  const BlockBatch* batch;
  const int* pos;
  const int* skip;
  int nskip;
  double iso, inv_s;
  bool gating;
  double gate;
  int keep_rows;
  RowMatrixXd* A;
  Eigen::VectorXd* e;
  UpdateStats* st;
};
/// What the pass leaves: M = I + sum_b A_b^T A_b (lower half), g = sum_b A_b^T e_b, e^T e
/// (whitened), the raw residuals' sum of squares (pixels^2) and the number of accepted blocks.
template <int W>
struct FusedSums {
  Eigen::Matrix<double, W, W> M;
  Eigen::Matrix<double, W, 1> g;
  double ee = 0.0, ss = 0.0;
  int k = 0;
};

/// The portable pass (x86-64 baseline, SSE2: one 2-vector holds a block's two rows). False with
/// the statistics' health set on a non-finite input or a bad R_b.
template <int W>
bool fusedSumsPortable(const FusedPass& in, const Eigen::Matrix<double, W, W>& Gs, FusedSums<W>* out) {
  using Mat2W = Eigen::Matrix<double, 2, W>;
  const BlockBatch& batch = *in.batch;
  UpdateStats* st = in.st;
  const int nb = batch.blocks;
  Eigen::Matrix<double, 2, W*(W + 1) / 2> Mp = Eigen::Matrix<double, 2, W*(W + 1) / 2>::Zero();
  Mat2W gp = Mat2W::Zero();
  double ee = 0.0, ss = 0.0;
  int k = 0;
  for (int b = 0; b < nb; ++b) {
    const int r = 2 * b;
    const double r00 = batch.R(r, 0), r01 = batch.R(r, 1), r10 = batch.R(r + 1, 0), r11 = batch.R(r + 1, 1);
    const double e0r = batch.residual[r], e1r = batch.residual[r + 1];
    if (!std::isfinite(r00 + r01 + r10 + r11 + e0r + e1r)) return nonFinite(st);
    for (int q = 0; q < in.nskip; ++q)
      if (!std::isfinite(batch.J(r, in.skip[q]) + batch.J(r + 1, in.skip[q]))) return nonFinite(st);
    // Column j of Hb holds both rows' entries (one SSE2 packet); so do A_b's columns.
    Mat2W Hb;
    for (int j = 0; j < W; ++j) Hb.col(j) << batch.J(r, in.pos[j]), batch.J(r + 1, in.pos[j]);
    Eigen::Vector2d eb;
    if (in.iso > 0.0) {
      eb << e0r * in.inv_s, e1r * in.inv_s;
    } else {  // whiten H_b's rows and r_b with L_b^-1 (L_b L_b^T = R_b), before the product
      Chol2 l;
      if (!cholesky2(r00, r10, r11, &l)) {
        st->health |= kBadMeasurementCovariance;
        return false;
      }
      Hb.row(0) *= 1.0 / l.l00;
      Hb.row(1) = (Hb.row(1) - l.l10 * Hb.row(0)) * (1.0 / l.l11);
      eb[0] = e0r / l.l00;
      eb[1] = (e1r - l.l10 * eb[0]) / l.l11;
    }
    Mat2W Ab;
#pragma GCC unroll 16
    for (int c = 0; c < W; ++c) {
      Eigen::Vector2d acc = Hb.col(c) * Gs(c, c);
#pragma GCC unroll 16
      for (int j = c + 1; j < W; ++j) acc += Hb.col(j) * Gs(j, c);
      Ab.col(c) = acc;
    }
    // S_b - I = A_b A_b^T: its diagonal as one packet sum, the off-diagonal as a dot product.
    Eigen::Vector2d sd = Ab.col(0).cwiseAbs2();
    double s01 = Ab(0, 0) * Ab(1, 0);
    for (int c = 1; c < W; ++c) sd += Ab.col(c).cwiseAbs2(), s01 += Ab(0, c) * Ab(1, c);
    const double s00 = 1.0 + sd[0], s11 = 1.0 + sd[1];
    if (!std::isfinite(s00 + s11)) return nonFinite(st);  // a non-finite Jacobian entry
    if (in.gating) {
      if (!(gateDistance2(s00, s01, s11, eb[0], eb[1]) <= in.gate)) {
        st->gated_mask[b] = 1;
        ++st->gated;
        continue;
      }
    }
    if (2 * k + 2 <= in.keep_rows) {
      in.A->block(2 * k, 0, 2, W) = Ab;
      in.e->template segment<2>(2 * k) = eb;
    }
    // M and g accumulated per row lane: Mp(:, t) += A_b(:, i) .* A_b(:, c) for t = (i, c), i >= c,
    // and gp(:, c) += A_b(:, c) .* e_b; the two lanes are added once after the loop.
#pragma GCC unroll 16
    for (int c = 0, t = 0; c < W; ++c) {
      const Eigen::Vector2d ac = Ab.col(c);
#pragma GCC unroll 16
      for (int i = c; i < W; ++i, ++t) Mp.col(t) += Ab.col(i).cwiseProduct(ac);
      gp.col(c) += ac.cwiseProduct(eb);
    }
    ee += eb.squaredNorm();
    ss += e0r * e0r + e1r * e1r;
    ++k;
  }
  for (int c = 0, t = 0; c < W; ++c)
    for (int i = c; i < W; ++i, ++t) out->M(i, c) = Mp(0, t) + Mp(1, t) + (i == c ? 1.0 : 0.0);
  out->g = gp.colwise().sum().transpose();
  out->ee = ee, out->ss = ss, out->k = k;
  return true;
}

#if defined(__GNUC__) && defined(__x86_64__)
#define RSFM_AVX2_KERNEL 1
/// The same pass with AVX2 and FMA (chosen at run time when the CPU has them; the build targets
/// the x86-64 baseline): two blocks at a time, one 4-vector holding both blocks' two rows
/// (lanes b.0, b.1, b+1.0, b+1.1), so A_b = H_b G and the sums M, g take one fused multiply-add
/// per entry for two blocks instead of a multiply and an add per block. The results differ from
/// the portable pass's by rounding only (FMA, the lanes' summation order). False, with nothing
/// but gated_mask and gated touched, on any non-finite input or bad R_b: the caller then runs the
/// portable pass, which reports the failure exactly as before.
template <int W>
[[gnu::target("avx2,fma")]] bool fusedSumsAvx2(const FusedPass& in, const Eigen::Matrix<double, W, W>& Gs,
                                               FusedSums<W>* out) {
  constexpr int kTri = W * (W + 1) / 2;
  const BlockBatch& batch = *in.batch;
  UpdateStats* st = in.st;
  const int nb = batch.blocks;
  const double* J = batch.J.data();
  const Eigen::Index js = batch.J.outerStride();  // row-major: one row is contiguous
  __m256d Mp[kTri], gp[W], H[W], A[W];
  for (int t = 0; t < kTri; ++t) Mp[t] = _mm256_setzero_pd();
  for (int c = 0; c < W; ++c) gp[c] = _mm256_setzero_pd();
  double ee = 0.0, ss = 0.0;
  int k = 0;
  for (int b = 0; b < nb; b += 2) {
    const int nq = std::min(2, nb - b);
    // Per lane: the whitened residual, the raw one, and L_b^-1 as h0' = h0 * s0,
    // h1' = (h1 - l10 h0') * s1 (lanes beyond the last block stay zero).
    alignas(32) double e[4] = {0.0, 0.0, 0.0, 0.0}, raw[4] = {0.0, 0.0, 0.0, 0.0};
    alignas(32) double ws0[4] = {1.0, 1.0, 1.0, 1.0}, wl[4] = {0.0, 0.0, 0.0, 0.0}, ws1[4] = {1.0, 1.0, 1.0, 1.0};
    for (int q = 0; q < nq; ++q) {
      const int r = 2 * (b + q);
      const double r00 = batch.R(r, 0), r01 = batch.R(r, 1), r10 = batch.R(r + 1, 0), r11 = batch.R(r + 1, 1);
      const double e0r = batch.residual[r], e1r = batch.residual[r + 1];
      if (!std::isfinite(r00 + r01 + r10 + r11 + e0r + e1r)) return false;
      for (int s = 0; s < in.nskip; ++s)
        if (!std::isfinite(J[r * js + in.skip[s]] + J[(r + 1) * js + in.skip[s]])) return false;
      raw[2 * q] = e0r, raw[2 * q + 1] = e1r;
      if (in.iso > 0.0) {
        e[2 * q] = e0r * in.inv_s, e[2 * q + 1] = e1r * in.inv_s;
      } else {
        Chol2 l;
        if (!cholesky2(r00, r10, r11, &l)) return false;
        ws0[2 * q] = 1.0 / l.l00, wl[2 * q + 1] = l.l10, ws1[2 * q + 1] = 1.0 / l.l11;
        e[2 * q] = e0r / l.l00;
        e[2 * q + 1] = (e1r - l.l10 * e[2 * q]) / l.l11;
      }
    }
    const double* j0 = J + 2 * b * js;
#pragma GCC unroll 16
    for (int j = 0; j < W; ++j) {
      const double* c = j0 + in.pos[j];
      H[j] = nq == 2 ? _mm256_set_pd(c[3 * js], c[2 * js], c[js], c[0]) : _mm256_set_pd(0.0, 0.0, c[js], c[0]);
    }
    if (!(in.iso > 0.0)) {
      const __m256d s0 = _mm256_load_pd(ws0), l10 = _mm256_load_pd(wl), s1 = _mm256_load_pd(ws1);
#pragma GCC unroll 16
      for (int j = 0; j < W; ++j) {
        const __m256d h = _mm256_mul_pd(H[j], s0);  // row 0 whitened, row 1 as it was
        H[j] = _mm256_mul_pd(_mm256_fnmadd_pd(l10, _mm256_permute_pd(h, 0b0101), h), s1);
      }
    }
    // A_b(:, c) = sum_{j >= c} H_b(:, j) G(j, c) (G lower triangular), both blocks at once.
#pragma GCC unroll 16
    for (int c = 0; c < W; ++c) {
      __m256d acc = _mm256_mul_pd(H[c], _mm256_set1_pd(Gs(c, c)));
#pragma GCC unroll 16
      for (int j = c + 1; j < W; ++j) acc = _mm256_fmadd_pd(H[j], _mm256_set1_pd(Gs(j, c)), acc);
      A[c] = acc;
    }
    // S_b - I = A_b A_b^T: the diagonals in sd's lanes, the off-diagonals in so's lanes 0 and 2
    // (each row times its block's other row: the in-pair swap).
    __m256d sd = _mm256_mul_pd(A[0], A[0]), so = _mm256_mul_pd(A[0], _mm256_permute_pd(A[0], 0b0101));
#pragma GCC unroll 16
    for (int c = 1; c < W; ++c) {
      sd = _mm256_fmadd_pd(A[c], A[c], sd);
      so = _mm256_fmadd_pd(A[c], _mm256_permute_pd(A[c], 0b0101), so);
    }
    alignas(32) double sdv[4], sov[4], mask[4] = {0.0, 0.0, 0.0, 0.0};
    _mm256_store_pd(sdv, sd);
    _mm256_store_pd(sov, so);
    int accepted = 0;
    for (int q = 0; q < nq; ++q) {
      const double s00 = 1.0 + sdv[2 * q], s11 = 1.0 + sdv[2 * q + 1];
      if (!std::isfinite(s00 + s11)) return false;  // a non-finite Jacobian entry
      const double e0 = e[2 * q], e1 = e[2 * q + 1];
      if (in.gating && !(gateDistance2(s00, sov[2 * q], s11, e0, e1) <= in.gate)) {
        st->gated_mask[b + q] = 1;
        ++st->gated;
        continue;
      }
      mask[2 * q] = mask[2 * q + 1] = 1.0;
      ++accepted;
      if (2 * k + 2 <= in.keep_rows) {
        alignas(32) double col[4];
        for (int c = 0; c < W; ++c) {
          _mm256_store_pd(col, A[c]);
          (*in.A)(2 * k, c) = col[2 * q], (*in.A)(2 * k + 1, c) = col[2 * q + 1];
        }
        (*in.e)[2 * k] = e0, (*in.e)[2 * k + 1] = e1;
      }
      ee += e0 * e0 + e1 * e1;
      ss += raw[2 * q] * raw[2 * q] + raw[2 * q + 1] * raw[2 * q + 1];
      ++k;
    }
    if (accepted == 0) continue;
    __m256d ev = _mm256_load_pd(e);
    if (accepted < 2) {  // one block of the pair gated (or the last, single block): zero its lanes
      const __m256d m = _mm256_load_pd(mask);
      ev = _mm256_mul_pd(ev, m);
#pragma GCC unroll 16
      for (int c = 0; c < W; ++c) A[c] = _mm256_mul_pd(A[c], m);
    }
#pragma GCC unroll 16
    for (int c = 0, t = 0; c < W; ++c) {
#pragma GCC unroll 16
      for (int i = c; i < W; ++i, ++t) Mp[t] = _mm256_fmadd_pd(A[i], A[c], Mp[t]);
      gp[c] = _mm256_fmadd_pd(A[c], ev, gp[c]);
    }
  }
  alignas(32) double v[4];
  for (int c = 0, t = 0; c < W; ++c) {
    for (int i = c; i < W; ++i, ++t) {
      _mm256_store_pd(v, Mp[t]);
      out->M(i, c) = (v[0] + v[1]) + (v[2] + v[3]) + (i == c ? 1.0 : 0.0);
    }
    _mm256_store_pd(v, gp[c]);
    out->g[c] = (v[0] + v[1]) + (v[2] + v[3]);
  }
  out->ee = ee, out->ss = ss, out->k = k;
  return true;
}
#endif

std::atomic<bool> g_vector_kernel{true};

bool cpuHasAvx2Fma() {
#ifdef RSFM_AVX2_KERNEL
  static const bool has = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  return has;
#else
  return false;
#endif
}
}  // namespace

bool Ekf::vectorKernelAvailable() { return cpuHasAvx2Fma(); }

bool Ekf::useVectorKernel(bool enable) { return g_vector_kernel.exchange(enable); }

bool Ekf::vectorKernelEnabled() { return cpuHasAvx2Fma() && g_vector_kernel.load(std::memory_order_relaxed); }

// The fused two-row path (issue 15 item 1). The blocks all depend on the same W free columns,
// and these are the free components in order, so with P_f = G G^T (Cholesky, G lower triangular)
// block b's whitened rows are A_b = L_b^-1 H_b G with A_b(:, c) = sum_{j >= c} H_b(:, j) G(j, c):
// half the multiply-adds of a general product. The gate (as in gateAndWhiten), the information
// sums M = I + sum_b A_b^T A_b and g = sum_b A_b^T e_b, and e^T e are accumulated in the same
// pass in W-sized fixed types (fusedSumsPortable, or fusedSumsAvx2 where the CPU has AVX2 and
// FMA), so no m x W matrix is written and read back. When the information form applies, the
// update follows here too in fixed types (dx = G M^-1 g, P+ = T^T T with T = L^-1 G^T,
// nis = e^T e - g^T M^-1 g: the same equations as Ekf::update). Otherwise the accepted blocks'
// rows are kept in A and e for the covariance form, which update() applies.
template <int W>
bool Ekf::fusedTwoRow(const BlockBatch& batch, const UpdateOptions& opt, UpdateStats* st, const int* pos,
                      const int* skip, int nskip, double iso) {
  using MatW = Eigen::Matrix<double, W, W>;
  using VecW = Eigen::Matrix<double, W, 1>;
  Work& w = w_;
  const int nb = batch.blocks;
  const double inv_s = iso > 0.0 ? 1.0 / std::sqrt(iso) : 1.0;
  const MatW G = w.G;
  const MatW Gs = G * inv_s;  // R_b = iso I folded into G (as in gateAndWhiten)
  FusedPass in;
  in.batch = &batch, in.pos = pos, in.skip = skip, in.nskip = nskip, in.iso = iso, in.inv_s = inv_s;
  in.gating = opt.gate_probability > 0.0 && opt.gate_probability < 1.0;
  in.gate = w.gate;
  // Rows of A the covariance form may need: all when it is asked for; with Auto only while the
  // accepted rows could still number no more than W (the covariance form's condition).
  in.keep_rows = opt.form == UpdateForm::Covariance ? 2 * nb : opt.form == UpdateForm::Information ? 0 : W;
  in.A = &w.A, in.e = &w.e, in.st = st;
  FusedSums<W> sums;
  bool done = false;
#ifdef RSFM_AVX2_KERNEL
  if (vectorKernelEnabled()) {
    done = fusedSumsAvx2<W>(in, Gs, &sums);
    if (!done) st->reset(nb);  // the portable pass reports the failure, block by block
  }
#endif
  if (!done && !fusedSumsPortable<W>(in, Gs, &sums)) return false;
  const int k = sums.k;
  const double ee = sums.ee, ss = sums.ss;
  st->used = k;
  st->nis_dof = 2 * k;
  if (k < std::max(1, opt.min_blocks)) {
    st->health |= kTooFewMeasurements;
    return false;
  }
  st->innovation_rms = std::sqrt(ss / (2 * k));
  const UpdateForm form = opt.form != UpdateForm::Auto ? opt.form : 2 * k > W ? UpdateForm::Information : UpdateForm::Covariance;
  if (form != UpdateForm::Information) return true;  // update() applies the covariance form to A, e
  st->form_used = form;
  MatW M = sums.M;  // I + sum_b A_b^T A_b (lower half; LLT reads no other)
  const VecW g = sums.g;
  MatW& L = M;  // M = L L^T in place
  if (!smallCholesky(L)) {
    st->health |= kSolveFailed;
    return false;
  }
  const VecW inv_d = L.diagonal().cwiseInverse();
  VecW y = g;  // y = L^-T L^-1 g
  for (int i = 0; i < W; ++i) {
    for (int k = 0; k < i; ++k) y[i] -= L(i, k) * y[k];
    y[i] *= inv_d[i];
  }
  for (int i = W - 1; i >= 0; --i) {
    for (int k = i + 1; k < W; ++k) y[i] -= L(k, i) * y[k];
    y[i] *= inv_d[i];
  }
  MatW T = G.transpose();  // T = L^-1 G^T, row by row (a column-major axpy per term)
  for (int i = 0; i < W; ++i) {
    for (int k = 0; k < i; ++k) T.row(i) -= L(i, k) * T.row(k);
    T.row(i) *= inv_d[i];
  }
  MatW Pn;  // T^T T, the lower half computed and mirrored (exactly symmetric)
  for (int j = 0; j < W; ++j)
    for (int i = j; i < W; ++i) Pn(j, i) = Pn(i, j) = T.col(i).dot(T.col(j));
  w.dx.resize(W);
  w.dx.noalias() = G * y;
  w.Pn.resize(W, W);
  w.Pn = Pn;
  st->nis = ee - g.dot(y);
  w.fused = true;
  return true;
}

// Gating and whitening, block by block, on the factored prior (P_f = G G^T). With L_b L_b^T = R_b,
// block b's whitened rows are A_b = L_b^-1 H_b G and e_b = L_b^-1 r_b, and its innovation
// covariance in whitened units is S_b = A_b A_b^T + I, so the gate distance is
// d^2 = e_b^T S_b^-1 e_b = r_b^T (H_b P H_b^T + R_b)^-1 r_b (the same as before issue 15). The
// accepted blocks are packed to the front of A and e.
template <int BD>
bool Ekf::gateAndWhiten(const BlockBatch& batch, const UpdateOptions& opt, UpdateStats* st) {
  using Mat = Eigen::Matrix<double, BD, BD, 0, (BD > 0 ? BD : kMaxBlockDim), (BD > 0 ? BD : kMaxBlockDim)>;
  using Vec = Eigen::Matrix<double, BD, 1, 0, (BD > 0 ? BD : kMaxBlockDim), 1>;
  Work& w = w_;
  const int bd = batch.block_dim, nb = batch.blocks, m = batch.rows();
  const int nf = static_cast<int>(w.G.rows());
  if (w.A.rows() < m || w.A.cols() != nf) w.A.resize(grown(m, w.A.rows()), nf);
  if (w.e.size() < m) w.e.resize(grown(m, w.e.size()));
  // A = H G. When every block has the same own columns (one plane), one product with the
  // gathered rows of G; otherwise the shared columns in one product, then each block's own.
  auto Am = w.A.topRows(m);
  bool uniform = true;
  for (int b = 1; b < nb && uniform && batch.own > 0; ++b) uniform = batch.cols.row(b) == batch.cols.row(0);
  // Two-row blocks that all have R_b = s^2 I (the models' R without reference inflation) are
  // whitened by scaling G once: A = H (G / s).
  double iso = 0.0;
  if (BD == 2 && uniform && nb > 0) {
    iso = batch.R(0, 0);
    for (int b = 0; b < nb && iso > 0.0; ++b)
      if (batch.R(2 * b, 0) != iso || batch.R(2 * b + 1, 1) != iso || batch.R(2 * b, 1) != 0.0 || batch.R(2 * b + 1, 0) != 0.0)
        iso = 0.0;
    if (!(iso > 0.0 && std::isfinite(iso))) iso = 0.0;
  }
  const bool gating = opt.gate_probability > 0.0 && opt.gate_probability < 1.0;
  if (gating && (w.gate_probability != opt.gate_probability || w.gate_dim != bd)) {
    w.gate = chi2Quantile(opt.gate_probability, bd);
    w.gate_probability = opt.gate_probability;
    w.gate_dim = bd;
  }
  if constexpr (BD == 2) {
    // The fused path: every block on the same columns, whose free ones are all the free
    // components in order, so A_b = H_b G with G lower triangular (one plane; fusedTwoRow).
    if (uniform && nb > 0 && w.G_lower && nf >= kFusedMin && nf <= kFusedMax) {
      // pos: the free columns' places in J; skip: fixed columns before the last free one, whose
      // Jacobian entries are still checked for finiteness (the general path's A = H Gx would turn
      // an Inf there into NaN; trailing fixed columns are left out by both paths).
      int pos[kFusedMax], skip[kFusedMax];
      int W = 0, nskip = 0, pending = 0;
      bool in_order = true;
      for (int j = 0; j < batch.width() && in_order; ++j) {
        const int c = j < batch.shared ? j : batch.cols(0, j - batch.shared);
        if (fixed_[c]) {
          if (nskip + pending < kFusedMax) skip[nskip + pending] = j;
          ++pending;
          continue;
        }
        if (W >= nf || c != w.free[W] || nskip + pending > kFusedMax) in_order = false;
        else pos[W++] = j, nskip += pending, pending = 0;
      }
      if (in_order && W == nf) {
        switch (W) {
          case 7: return fusedTwoRow<7>(batch, opt, st, pos, skip, nskip, iso);
          case 8: return fusedTwoRow<8>(batch, opt, st, pos, skip, nskip, iso);
          case 9: return fusedTwoRow<9>(batch, opt, st, pos, skip, nskip, iso);
          case 10: return fusedTwoRow<10>(batch, opt, st, pos, skip, nskip, iso);
          case 11: return fusedTwoRow<11>(batch, opt, st, pos, skip, nskip, iso);
          case 12: return fusedTwoRow<12>(batch, opt, st, pos, skip, nskip, iso);
          default: break;
        }
      }
    }
  }
  const double inv_s = iso > 0.0 ? 1.0 / std::sqrt(iso) : 1.0;
  if (uniform && nb > 0) {
    // The block's columns; trailing fixed ones (zero rows of Gx, the gauge) are left out.
    int wz = batch.width();
    auto column = [&](int j) { return j < batch.shared ? j : batch.cols(0, j - batch.shared); };
    while (wz > 0 && fixed_[column(wz - 1)]) --wz;
    w.Gc.resize(wz, nf);
    for (int j = 0; j < wz; ++j) w.Gc.row(j) = w.Gx.row(column(j)) * inv_s;
    Am.noalias() = batch.J.topLeftCorner(m, wz) * w.Gc;
  } else {
    if (batch.shared > 0)
      Am.noalias() = batch.J.topLeftCorner(m, batch.shared) * w.Gx.topRows(batch.shared);
    else
      Am.setZero();
    for (int b = 0; b < nb; ++b)
      for (int r = 0; r < bd; ++r)
        for (int j = 0; j < batch.own; ++j)
          w.A.row(b * bd + r) += batch.J(b * bd + r, batch.shared + j) * w.Gx.row(batch.cols(b, j));
  }
  double ss = 0.0;
  int k = 0;
  for (int b = 0; b < nb; ++b) {
    // Whiten block b in place (rows of A) and into eb; with gating, its distance d2.
    Vec eb(bd);
    double d2 = 0.0;
    if constexpr (BD == 2) {
      // Two rows (the point models): Cholesky of R_b, whitening and the gate written out.
      const double r00 = batch.R(2 * b, 0), r01 = batch.R(2 * b, 1), r10 = batch.R(2 * b + 1, 0),
                   r11 = batch.R(2 * b + 1, 1);
      const double r0 = batch.residual[2 * b], r1 = batch.residual[2 * b + 1];
      if (!std::isfinite(r00 + r01 + r10 + r11 + r0 + r1)) return nonFinite(st);
      auto a0 = w.A.row(2 * b), a1 = w.A.row(2 * b + 1);
      if (iso > 0.0) {  // already whitened through G
        eb << r0 * inv_s, r1 * inv_s;
      } else {
        Chol2 l;
        if (!cholesky2(r00, r10, r11, &l)) {
          st->health |= kBadMeasurementCovariance;
          return false;
        }
        a0 *= 1.0 / l.l00;
        a1 = (a1 - l.l10 * a0) * (1.0 / l.l11);
        eb[0] = r0 / l.l00;
        eb[1] = (r1 - l.l10 * eb[0]) / l.l11;
      }
      // A non-finite Jacobian entry makes its row of A = H G non-finite (Inf * 0 is NaN), so the
      // squared norms check the input (no separate pass over J).
      const double s00 = 1.0 + a0.squaredNorm(), s11 = 1.0 + a1.squaredNorm();
      if (!std::isfinite(s00 + s11)) return nonFinite(st);
      if (gating) d2 = gateDistance2(s00, a0.dot(a1), s11, eb[0], eb[1]);
    } else {
      const Mat Rb = batch.R.block(b * bd, 0, bd, bd);
      if (!Rb.allFinite() || !batch.residual.segment(b * bd, bd).allFinite() || !w.A.middleRows(b * bd, bd).allFinite())
        return nonFinite(st);
      const Eigen::LLT<Mat> rl(Rb);
      if (rl.info() != Eigen::Success) {
        st->health |= kBadMeasurementCovariance;
        return false;
      }
      auto Ab = w.A.middleRows(b * bd, bd);
      rl.matrixL().solveInPlace(Ab);
      eb = rl.matrixL().solve(Vec(batch.residual.segment(b * bd, bd)));
      if (gating) {
        Mat S = Mat::Identity(bd, bd);
        S.noalias() += Ab * Ab.transpose();
        const Eigen::LLT<Mat> sl(S);
        d2 = sl.info() == Eigen::Success ? eb.dot(sl.solve(eb)) : HUGE_VAL;
      }
    }
    if (gating && !(d2 <= w.gate)) {
      st->gated_mask[b] = 1;
      ++st->gated;
      continue;
    }
    if (k != b) w.A.middleRows(k * bd, bd) = w.A.middleRows(b * bd, bd);
    w.e.segment(k * bd, bd) = eb;
    ss += batch.residual.segment(b * bd, bd).squaredNorm();
    ++k;
  }
  st->used = k;
  st->nis_dof = k * bd;
  if (k < std::max(1, opt.min_blocks)) {
    st->health |= kTooFewMeasurements;
    return false;
  }
  st->innovation_rms = std::sqrt(ss / (k * bd));
  return true;
}

void Ekf::update(const BlockBatch& batch, const UpdateOptions& opt, UpdateStats* st) {
  const int bd = batch.block_dim, nb = batch.blocks, m = batch.rows(), n = size();
  st->reset(nb);
  if (bd <= 0 || bd > kMaxBlockDim || nb < 0 || batch.shared < 0 || batch.shared > n || batch.own < 0 ||
      batch.residual.size() < m || batch.J.rows() < m || batch.J.cols() != batch.width() ||
      batch.cols.rows() < (batch.own > 0 ? nb : 0) || batch.cols.cols() != batch.own || batch.R.rows() < m ||
      batch.R.cols() != bd)
    throw std::invalid_argument("Ekf::update: measurement batch has inconsistent sizes");
  for (int b = 0; b < nb; ++b)
    for (int j = 0; j < batch.own; ++j)
      if (batch.cols(b, j) < 0 || batch.cols(b, j) >= n)
        throw std::invalid_argument("Ekf::update: measurement batch has a column outside the state");
  // Non-finite residuals, Jacobians or covariances are detected block by block in gateAndWhiten.
  if (!factorPrior(st)) return;
  w_.fused = false;
  const bool ok = bd == 2 ? gateAndWhiten<2>(batch, opt, st)
                          : bd == 6 ? gateAndWhiten<6>(batch, opt, st) : gateAndWhiten<Eigen::Dynamic>(batch, opt, st);
  if (!ok) return;
  Work& w = w_;
  const int nf = static_cast<int>(w.G.rows());
  const int mu = st->used * bd;
  const auto W = w.A.topRows(mu);
  const auto e = w.e.head(mu);
  UpdateForm form = opt.form;
  if (form == UpdateForm::Auto) form = mu > nf ? UpdateForm::Information : UpdateForm::Covariance;
  st->form_used = form;
  // In whitened units the measurements are e = W z + noise(I) with z = G^-1 (x - x^-) ~ N(0, I).
  if (w.fused) {
    // fusedTwoRow has done the information form (dx, Pn, nis).
  } else if (form == UpdateForm::Information) {
    // M = I + W^T W (= I + G^T J G, J = sum_b H_b^T R_b^-1 H_b), M = L L^T;
    // dx = G M^-1 W^T e; P+ = G M^-1 G^T = T^T T with T = L^-1 G^T (Woodbury: (P^-1 + J)^-1).
    w.M.setIdentity(nf, nf);
    w.M.selfadjointView<Eigen::Lower>().rankUpdate(W.transpose());
    w.mllt.compute(w.M);
    if (w.mllt.info() != Eigen::Success) {
      st->health |= kSolveFailed;
      return;
    }
    w.g.noalias() = W.transpose() * e;
    w.y = w.g;
    w.mllt.solveInPlace(w.y);
    w.dx.noalias() = w.G * w.y;
    w.T = w.G.transpose();
    w.mllt.matrixL().solveInPlace(w.T);
    w.Pn.setZero(nf, nf);
    w.Pn.selfadjointView<Eigen::Lower>().rankUpdate(w.T.transpose());
    st->nis = e.squaredNorm() - w.g.dot(w.y);
  } else {
    // Covariance form in whitened units: S = W W^T + I, K' = W^T S^-1, dx = G K' e, and the
    // Joseph form P+ = G [(I - K'W)(I - K'W)^T + K'K'^T] G^T. Cost O(m^3): used when m <= nf.
    const Eigen::MatrixXd S = W * W.transpose() + Eigen::MatrixXd::Identity(mu, mu);
    const Eigen::LDLT<Eigen::MatrixXd> sl(S);
    if (sl.info() != Eigen::Success || !sl.isPositive()) {
      st->health |= kSolveFailed;
      return;
    }
    const Eigen::MatrixXd K = sl.solve(Eigen::MatrixXd(W)).transpose();  // nf x mu
    w.dx = w.G * (K * e);
    st->nis = e.dot(sl.solve(Eigen::VectorXd(e)));
    const Eigen::MatrixXd IKW = Eigen::MatrixXd::Identity(nf, nf) - K * W;
    const Eigen::MatrixXd C = IKW * IKW.transpose() + K * K.transpose();
    w.Pn = w.G * C * w.G.transpose();
    w.Pn = (0.5 * (w.Pn + w.Pn.transpose())).eval();
  }
  if (form == UpdateForm::Information && !w.fused)  // rankUpdate filled the lower half
    for (int j = 0; j < nf; ++j)
      for (int i = 0; i < j; ++i) w.Pn(i, j) = w.Pn(j, i);
  if (!w.dx.allFinite() || !w.Pn.allFinite()) {
    st->health |= kNonFiniteState;
    return;  // prior kept
  }
  if (nf == n) {
    x_ += w.dx;
    P_ = w.Pn;
  } else {
    for (int j = 0; j < nf; ++j) {
      x_[w.free[j]] += w.dx[j];
      for (int i = 0; i < nf; ++i) P_(w.free[i], w.free[j]) = w.Pn(i, j);
    }
  }
  st->applied = true;
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
