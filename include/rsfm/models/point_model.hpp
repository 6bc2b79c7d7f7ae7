#pragma once
// The pointwise structure model of Azarbayejani & Pentland ([AP95] as summarized in
// [AS99] §2, eqs. 1-7; equation numbers are [AS99]'s; keys: docs/bibliography.md).
// State x = (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z, beta, alpha_1..alpha_N): 7 + N.
// Point i is on the first-frame ray through its reference image position (u_i, v_i):
//   p_i = (u_i (1 + alpha_i beta), v_i (1 + alpha_i beta), alpha_i)   (eq. 5, origin on image plane)
// alpha_i is its depth Z in the reference frame. Scale gauge: one alpha fixed (zero variance).
#include <Eigen/Core>
#include <vector>

#include "rsfm/ekf.hpp"
#include "rsfm/models/projection.hpp"

namespace rsfm {

class PointModel {
 public:
  /// A&P need at least 7 points for the state to be observable ([AS99] §3.1).
  static constexpr int kMinPoints = 7;
  /// Structure columns one point's measurement depends on (its alpha).
  static constexpr int kStructurePerPoint = 1;

  PointModel() = default;
  /// `ref_uv`: first-frame normalized image positions, one per point (state index 7 + i).
  explicit PointModel(std::vector<Eigen::Vector2d> ref_uv) : ref_(std::move(ref_uv)) {}

  int numPoints() const { return static_cast<int>(ref_.size()); }
  int stateDim() const { return 7 + numPoints(); }
  const Eigen::Vector2d& reference(int i) const { return ref_[i]; }
  static int alphaIndex(int i) { return 7 + i; }
  int structureIndex(int i) const { return alphaIndex(i); }

  /// Reference-frame 3-D point of [AS99] eq. 5.
  static Eigen::Vector3d point(const Eigen::Vector2d& uv1, double alpha, double beta);

  /// Predicted measurement of point i and its Jacobian with respect to the whole state (2 x n).
  /// Rg is the global rotation kept outside the state.
  MeasureStatus measure(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i,
                        Eigen::Vector2d* h, Eigen::MatrixXd* H) const;

  /// Fast form used by the filter: motion context computed once per frame; writes the 2 x 7
  /// motion block, the 2 x 1 alpha column and dh/d(u, v)^1 (2 x 2, the reference Jacobian).
  MeasureStatus measure(const MotionContext& m, const Eigen::VectorXd& x, int i,
                        Eigen::Vector2d* h, Eigen::Matrix<double, 2, 7>* Hm,
                        Eigen::Vector2d* Ha, Eigen::Matrix2d* Hu = nullptr) const;

  /// Replaces point i's reference position (reference refinement, see recursive_filter.hpp).
  void setReference(int i, const Eigen::Vector2d& uv) { ref_[i] = uv; }

  /// Linearizes every observation (residual, Jacobian, R). R = sigma^2 I, plus
  /// Hu C_i Hu^T when `ref_cov` gives the covariance C_i of each reference position.
  /// Observations whose prediction fails are left out and counted in *invalid (never silently).
  /// `used` (optional) receives the observation index of each batch block.
  void linearize(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg,
                 const std::vector<Observation>& obs, double sigma,
                 const std::vector<Eigen::Matrix2d>* ref_cov, BlockBatch* batch,
                 int* invalid, MeasureStatus* first_problem, std::vector<int>* used = nullptr,
                 int reference_index = -1) const;

 private:
  std::vector<Eigen::Vector2d> ref_;
};

}  // namespace rsfm
