#pragma once
// A generic extended Kalman filter over a dynamic-size state (docs/filter.md).
//
// - Prediction is the identity plus additive noise (P <- P + Q) unless the caller supplies a
//   transition Jacobian F (P <- F P F^T + Q; the caller propagates x).
// - Updates take a batch of measurement blocks (2 rows per tracked point, 6 per affine patch),
//   already linearized at the current state: residual r = z - h(x), Jacobian H, and a
//   block-diagonal measurement covariance R.
// - The update factors the prior's free part, P = G G^T (Cholesky; the pivoted LDLT when P is
//   only semi-definite), and works in whitened units: block b's rows become A_b = L_b^-1 H_b G
//   and e_b = L_b^-1 r_b with L_b L_b^T = R_b, so its innovation covariance is A_b A_b^T + I.
//   Two algebraically equivalent forms follow:
//     Information form: M = I + sum_b A_b^T A_b (= I + G^T J G, J = sum_b H_b^T R_b^-1 H_b; one
//       symmetric rank-m update), M = L L^T, dx = G M^-1 A^T e, P+ = G M^-1 G^T = T^T T with
//       T = L^-1 G^T (Woodbury: (P^-1 + J)^-1). Cost O(m n^2) for the blocks, O(n^3) once: this
//       is what makes the plane models O(N) per frame. P+ is positive semi-definite by
//       construction (the role Joseph plays in the other form).
//     Covariance form: S = A A^T + I, K' = A^T S^-1, dx = G K' e, and the Joseph form in factor
//       coordinates P+ = G [(I - K'A)(I - K'A)^T + K'K'^T] G^T. Cost O(m^3).
//   The models' Jacobians are compact (BlockBatch: the 7 motion columns shared by all blocks,
//   then each block's own structure columns), so A = H G costs O(m n) per frame, not O(m n^2).
//   Once the filter has seen its largest frame, an information-form update allocates nothing
//   (the work space lives in the Ekf; issue 15, tests/test_allocations.cpp).
// - Both forms check the prior (free part) first: a negative LDLT pivot beyond round-off skips
//   the update with kCovarianceNotPD (never clamped silently).
// - Components marked fixed (the scale gauge: zero variance, zero process noise) are excluded
//   from every update and prediction, so they never move and keep zero variance.
// - Each block is chi-square gated on its own innovation (d^2 = r_b^T S_b^-1 r_b against the
//   gate_probability quantile of chi2(block_dim)), computed from the same whitened A_b:
//   S_b = A_b A_b^T + I in whitened units; gated blocks do not enter the update.
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace rsfm {

/// A batch of measurement blocks linearized at the current state.
struct MeasurementBatch {
  int block_dim = 2;          ///< rows per block
  Eigen::VectorXd residual;   ///< z - h(x), stacked, size m = blocks * block_dim
  Eigen::MatrixXd H;          ///< m x n Jacobian of h with respect to the whole state
  Eigen::MatrixXd R;          ///< m x block_dim: block b's covariance is rows [b*bd, (b+1)*bd)
  int blocks() const { return block_dim > 0 ? static_cast<int>(residual.size()) / block_dim : 0; }
  /// Allocates for `nblocks` blocks over a state of size n (zero-filled).
  void resize(int nblocks, int n, int bd);
};

using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using RowMatrixXi = Eigen::Matrix<int, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// A batch of measurement blocks with compact Jacobians: the form the point-based models fill
/// (a point's rows depend on the 7 motion columns and on its own structure columns only), and the
/// one the update works on. Block b has rows [b bd, (b+1) bd) of `residual`, `J` and `R`; its
/// Jacobian with respect to the state is zero except for
///   columns 0 .. shared-1             = J(rows, 0 .. shared-1)          (common to every block),
///   column cols(b, j), j < own        = J(rows, shared + j)             (the block's own columns).
/// A dense batch is the case shared = n, own = 0. The storage only grows (reserve()), so a filter
/// that keeps one BlockBatch allocates nothing once it has seen its largest frame (issue 15).
struct BlockBatch {
  int block_dim = 2;  ///< rows per block
  int shared = 0;     ///< leading state columns every block depends on
  int own = 0;        ///< further columns per block (cols)
  int blocks = 0;     ///< blocks in use
  Eigen::VectorXd residual;  ///< z - h(x); entries [0, rows()) in use
  RowMatrixXd J;             ///< rows() x (shared + own) in use
  RowMatrixXi cols;          ///< blocks x own in use: the state column of each own Jacobian column
  RowMatrixXd R;             ///< rows() x block_dim in use: block b's covariance
  int rows() const { return blocks * block_dim; }
  int width() const { return shared + own; }
  /// Makes room for `max_blocks` blocks of this layout and sets blocks = 0. Storage never shrinks.
  void reserve(int max_blocks, int bd, int shared_cols, int own_cols);
  /// residual += (dh/dx) dx over the blocks in use (the iterated update's shift of a relinearized
  /// batch, recursive_filter.hpp).
  void shiftResidual(const Eigen::VectorXd& dx);
  /// The same blocks with a dense m x n Jacobian (tests, dense callers).
  MeasurementBatch dense(int n) const;
  /// A dense batch in this layout (shared = n, own = 0).
  static BlockBatch fromDense(const MeasurementBatch& b);
};

enum class UpdateForm {
  Auto,         ///< Information form when the measurement count exceeds the free state size
  Covariance,   ///< Joseph form with S solved by LDLT
  Information,  ///< factored information form (P = G G^T, Woodbury), O(m) in the measurement count
};

/// Options of one update (defaults documented inline).
struct UpdateOptions {
  UpdateForm form = UpdateForm::Auto;
  /// Per-block chi-square gate probability; a block whose innovation distance exceeds the
  /// quantile is rejected. <= 0 or >= 1 disables gating. Default 0.999 (13.8 for 2-D blocks).
  double gate_probability = 0.999;
  /// Minimum number of accepted blocks to apply the update (A&P needs 7 points, the plane model 5:
  /// [AS99] §3.1). Below it the update is skipped and kTooFewMeasurements is reported.
  int min_blocks = 1;
};

/// Numerical-health flags of an update (bitwise OR).
enum HealthFlag : std::uint32_t {
  kHealthy = 0,
  kNonFiniteInput = 1u << 0,       ///< residual, H or R has NaN/Inf: update skipped
  kNonFiniteState = 1u << 1,       ///< the update produced NaN/Inf: update rolled back
  kCovarianceNotPD = 1u << 2,      ///< P (free part) not symmetric PSD: update skipped
  kSolveFailed = 1u << 3,          ///< S or (I + G^T J G) could not be factorized: update skipped
  kTooFewMeasurements = 1u << 4,   ///< fewer accepted blocks than min_blocks: update skipped
  kBadMeasurementCovariance = 1u << 5,  ///< some R_b is not positive definite: update skipped
  kInvalidRotation = 1u << 6,      ///< the update left |omega| >= 2: rolled back (filter driver)
};
std::string describeHealth(std::uint32_t flags);

/// Statistics of one update.
struct UpdateStats {
  int blocks = 0;                ///< blocks offered
  int used = 0;                  ///< blocks accepted (not gated)
  int gated = 0;                 ///< blocks rejected by the chi-square gate
  double innovation_rms = 0.0;   ///< RMS of the accepted residual components (measurement units)
  double nis = 0.0;              ///< r^T S^-1 r of the accepted blocks (joint)
  int nis_dof = 0;               ///< its degrees of freedom (used * block_dim)
  std::uint32_t health = kHealthy;
  bool applied = false;          ///< the state and covariance were changed
  UpdateForm form_used = UpdateForm::Covariance;
  std::vector<std::uint8_t> gated_mask;  ///< per block: 1 = gated
  /// Back to the defaults with `blocks` blocks, none gated (gated_mask keeps its storage).
  void reset(int blocks);
};

class Ekf {
 public:
  Ekf() = default;
  /// `fixed[i]` marks gauge components: their rows/columns of P0 are forced to zero.
  Ekf(Eigen::VectorXd x0, Eigen::MatrixXd P0, std::vector<bool> fixed);

  const Eigen::VectorXd& x() const { return x_; }
  const Eigen::MatrixXd& P() const { return P_; }
  /// Direct access for the caller's bookkeeping (e.g. folding a rotation). Keep P symmetric.
  Eigen::VectorXd& mutableX() { return x_; }
  Eigen::MatrixXd& mutableP() { return P_; }
  const std::vector<bool>& fixed() const { return fixed_; }
  int size() const { return static_cast<int>(x_.size()); }
  std::vector<int> freeIndices() const;

  /// Identity dynamics: P <- P + diag(q) on the free components.
  void predict(const Eigen::VectorXd& q_diag);
  /// General linearized prediction: P <- F P F^T + Q on the free components (x already moved).
  void predict(const Eigen::MatrixXd& F, const Eigen::MatrixXd& Q);

  UpdateStats update(const MeasurementBatch& batch, const UpdateOptions& options = {});
  /// The update itself (both forms): no heap allocation once the filter has seen its largest
  /// frame (the work space is kept in the Ekf), except in the covariance form (m <= free states).
  void update(const BlockBatch& batch, const UpdateOptions& options, UpdateStats* stats);

  /// Appends components (new structure) with the given mean, covariance block and cross-covariance
  /// with the existing state (rows: new components).
  void augment(const Eigen::VectorXd& x_new, const Eigen::MatrixXd& P_new,
               const Eigen::MatrixXd& P_cross, bool fixed = false);
  /// Estimate projection onto the bound x_i >= lower: when x_i < lower and P_ii > 0, moves x along
  /// P's column i to x_i = lower (the minimum-P^-1-distance point on the constraint; P kept).
  /// Returns true when it projected.
  bool projectLowerBound(int i, double lower);
  /// Marks component i as fixed (its row and column of P are zeroed) or free.
  void setFixed(int i, bool fixed);
  /// Removes the listed components (e.g. lost features).
  void remove(const std::vector<int>& indices);
  /// Permutes the state: new component i is old component order[i] (order is a permutation).
  void reorder(const std::vector<int>& order);

  /// Current numerical health of x and P: non-finite values (kNonFiniteState), negative
  /// variance or asymmetry beyond round-off (kCovarianceNotPD).
  std::uint32_t health() const;

  /// The fused one-plane update (issue 15) has an AVX2/FMA kernel chosen at run time when the
  /// CPU has both (the build itself targets the x86-64 baseline); its results equal the portable
  /// kernel's up to rounding (fused multiply-adds, summation order). True when this CPU has it.
  static bool vectorKernelAvailable();
  /// Allows (true, the default) or forbids the AVX2/FMA kernel for the whole process, for tests
  /// and benchmarks that compare the two kernels; returns the previous setting.
  static bool useVectorKernel(bool enable);
  /// The vector kernels may run: this CPU has them and useVectorKernel has not forbidden them
  /// (also read by the conditional references' kernels, filters/conditional_kernels.hpp).
  static bool vectorKernelEnabled();

 private:
  /// Factors the free part of P (P_f = G G^T) into the work space; false (stats->health set) when
  /// P_f is not symmetric positive semi-definite.
  bool factorPrior(UpdateStats* stats);
  template <int BD>
  bool gateAndWhiten(const BlockBatch& batch, const UpdateOptions& opt, UpdateStats* stats);
  /// The fused two-row path (issue 15): blocks that all depend on the same W free columns, which
  /// are the free components in order, under a lower-triangular G (Cholesky). Whitening, gate and
  /// the information-form sums in one pass over the blocks with W-sized fixed types, and, when the
  /// information form applies, the update itself (w_.fused set). `pos` maps the W free columns to
  /// the batch's Jacobian columns, `skip` lists the nskip fixed columns between them (checked for
  /// finiteness only); `iso` > 0 is the common R_b = iso I.
  template <int W>
  bool fusedTwoRow(const BlockBatch& batch, const UpdateOptions& opt, UpdateStats* stats, const int* pos,
                   const int* skip, int nskip, double iso);

  Eigen::VectorXd x_;
  Eigen::MatrixXd P_;
  std::vector<bool> fixed_;
  /// Update work space (sizes follow the state and the largest batch seen; never shrinks). It is
  /// not part of the filter's value: a copied or moved Ekf starts with an empty one (copying an
  /// Eigen factorization that never ran reads its uninitialized status, which UBSan reports).
  struct Work {
    Work() = default;
    Work(const Work&) {}
    Work(Work&&) noexcept {}
    Work& operator=(const Work&) { return *this; }
    Work& operator=(Work&&) noexcept { return *this; }
    std::vector<int> free;       ///< free component indices
    Eigen::MatrixXd Pf;          ///< P's free part
    Eigen::LLT<Eigen::MatrixXd> llt;
    Eigen::LDLT<Eigen::MatrixXd> ldlt;  ///< fallback when Pf is only semi-definite
    Eigen::MatrixXd G;           ///< Pf = G G^T (nf x nf)
    RowMatrixXd Gx;              ///< G with a zero row for each fixed component (n x nf)
    RowMatrixXd Gc;              ///< Gx's rows of the batch's columns (blocks with the same columns)
    RowMatrixXd A;               ///< per block: L_b^-1 H_b G (whitened; accepted blocks first)
    Eigen::VectorXd e;           ///< per block: L_b^-1 r_b (accepted blocks first)
    Eigen::MatrixXd M;           ///< I + A^T A (information form)
    Eigen::LLT<Eigen::MatrixXd> mllt;
    Eigen::VectorXd g, y, dx;
    bool G_lower = false;        ///< G is lower triangular (the Cholesky factor, not the LDLT's)
    bool fused = false;          ///< fusedTwoRow has left dx and Pn (information form)
    Eigen::MatrixXd T, Pn;
    double gate = 0.0, gate_probability = -1.0;  ///< chi-square gate, cached per (probability, block size)
    int gate_dim = 0;
  } w_;
};

/// Iterated EKF update with backtracking, shared by the filters' `iterations` option: Gauss-Newton
/// on the MAP cost J(x) = measurement_cost(x) + (x - x^-)^T P^-^-1 (x - x^-) (free components).
/// `ekf` holds the plain update of the prior (x^-, P^-) on entry; that update is the first
/// Gauss-Newton point. Each step towards the current point is halved (up to `halvings` tries in
/// all) until J decreases; without a decrease the current iterate stays. After an accepted step
/// larger than `tol` (infinity norm) the next point comes from `gauss_newton_point(x_i)`, which
/// must leave in `ekf` the update of the prior linearized at x_i (residual shifted by
/// H_i (x_i - x^-)) and return false when it could not. On return `ekf` holds the last accepted
/// iterate with the covariance of the last Gauss-Newton point. Returns the iterations used
/// (0 when J cannot be evaluated at x^-: the plain update is kept).
int iteratedUpdate(Ekf* ekf, int iterations, double tol, int halvings, const Eigen::VectorXd& x_prior,
                   const Eigen::MatrixXd& P_prior, const std::function<bool(const Eigen::VectorXd&, double*)>& measurement_cost,
                   const std::function<bool(const Eigen::VectorXd&)>& gauss_newton_point);

}  // namespace rsfm
