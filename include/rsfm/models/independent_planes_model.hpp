#pragma once
// Planes moving independently ([AS99] §3.2, last sentence; docs/planes.md): each plane j has its own
// motion (t^j, omega^j) and its own global rotation R_g^j outside the state; beta is shared.
// State x = (beta, [t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z, N_X, N_Y, N_Z]^j for j = 0..m-1):
// size 1 + 9m. A point labelled j is projected exactly as in the plane model ([AS99] eqs. 6, 7
// and 12) with plane j's motion. Each plane is its own rigid body, so each needs its own scale
// gauge (one component of each N held fixed).
#include <Eigen/Core>
#include <vector>

#include "rsfm/ekf.hpp"
#include "rsfm/models/projection.hpp"

namespace rsfm {

class IndependentPlanesModel {
 public:
  static constexpr int kMinPoints = 5;  ///< per plane ([AS99] §3.1)
  static constexpr int kBlock = 9;      ///< state components per plane

  IndependentPlanesModel() = default;
  IndependentPlanesModel(std::vector<Eigen::Vector2d> ref_uv, std::vector<int> labels, int num_planes);

  int numPoints() const { return static_cast<int>(ref_.size()); }
  int numPlanes() const { return planes_; }
  int stateDim() const { return 1 + kBlock * planes_; }
  static int betaIndex() { return 0; }
  static int motionIndex(int plane) { return 1 + kBlock * plane; }     ///< t_X of the plane
  static int planeIndex(int plane) { return 1 + kBlock * plane + 6; }  ///< N_X of the plane
  int label(int i) const { return labels_[i]; }
  const Eigen::Vector2d& reference(int i) const { return ref_[i]; }

  /// Motion context of plane j: (t^j, omega^j, beta) with its global rotation Rg.
  static MotionContext motion(const Eigen::VectorXd& x, int plane, const Eigen::Matrix3d& Rg);

  /// Predicted measurement of point i and its Jacobian with respect to the whole state (2 x n).
  /// Rgs: the global rotation of every plane.
  /// Hu (optional): dh/d(u, v)^1, the derivative with respect to the point's reference position.
  MeasureStatus measure(const Eigen::VectorXd& x, const std::vector<Eigen::Matrix3d>& Rgs, int i,
                        Eigen::Vector2d* h, Eigen::MatrixXd* H, Eigen::Matrix2d* Hu = nullptr) const;

  /// Linearizes every observation: R = sigma^2 I, plus Hu C_i Hu^T with `ref_cov` (C_i: the
  /// covariance of point i's reference position; ReferenceModel::Inflate / Refine); failed
  /// predictions are left out and counted; `used` (optional) receives each block's observation index.
  void linearize(const Eigen::VectorXd& x, const std::vector<Eigen::Matrix3d>& Rgs,
                 const std::vector<Observation>& obs, double sigma, MeasurementBatch* batch, int* invalid,
                 MeasureStatus* first_problem, const std::vector<Eigen::Matrix2d>* ref_cov = nullptr,
                 std::vector<int>* used = nullptr) const;

  /// Replaces point i's reference position (reference refinement).
  void setReference(int i, const Eigen::Vector2d& uv) { ref_[i] = uv; }

 private:
  std::vector<Eigen::Vector2d> ref_;
  std::vector<int> labels_;
  int planes_ = 0;
};

}  // namespace rsfm
