#pragma once
// A generic extended Kalman filter over a dynamic-size state (DESIGN.md §3).
//
// - Prediction is the identity plus additive noise (P <- P + Q) unless the caller supplies a
//   transition Jacobian F (P <- F P F^T + Q; the caller propagates x).
// - Updates take a batch of measurement blocks (2 rows per tracked point, 6 per affine patch),
//   already linearized at the current state: residual r = z - h(x), Jacobian H, and a
//   block-diagonal measurement covariance R.
// - Two algebraically equivalent update forms:
//     Covariance form: S = H P H^T + R solved by LDLT, K = P H^T S^-1, Joseph-form covariance
//       P+ = (I-KH) P (I-KH)^T + K R K^T, then symmetrized. Cost O(m^3) in the measurement count m.
//     Information form: J = sum_b H_b^T R_b^-1 H_b, g = sum_b H_b^T R_b^-1 r_b accumulated block by
//       block (O(m n^2)), then with a factor P = G G^T (pivoted LDLT of P, so zero-variance
//       directions are allowed) and the Woodbury identity P+ = G (I + G^T J G)^-1 G^T
//       = (P^-1 + J)^-1, dx = P+ g. Cost O(m) for a fixed state size n: this is what makes the
//       plane models O(N) per frame. The factored form keeps P+ positive semi-definite by
//       construction (the role Joseph plays in the other form).
// - Both forms check the prior (free part) first: a negative LDLT pivot beyond round-off skips
//   the update with kCovarianceNotPD (never clamped silently).
// - Components marked fixed (the scale gauge: zero variance, zero process noise) are excluded
//   from every update and prediction, so they never move and keep zero variance.
// - Each block is chi-square gated on its own innovation (d^2 = r_b^T S_b^-1 r_b against the
//   gate_probability quantile of chi2(block_dim)); gated blocks do not enter the update.
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
  /// seed §3.1). Below it the update is skipped and kTooFewMeasurements is reported.
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

 private:
  Eigen::VectorXd x_;
  Eigen::MatrixXd P_;
  std::vector<bool> fixed_;
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
