#pragma once
// Batch reference for the plane models (rigid, one or more planes): bundle adjustment over all
// frames with the filter's parameterization, solved with Ceres (issue 3; DESIGN §2, §4).
//
// Parameters: per frame k >= 1 the motion (t_X, t_Y, t_Z beta, omega) where omega is a
// left perturbation of a fixed base rotation (R_k = R(dq(omega_k)) Rbase_k, seed eqs. 2-3; the
// base is the filter's estimate, so omega starts at 0); beta; one N per plane (N . X = 1, seed
// eq. 9) with the scale gauge held constant (one component of one plane, as in the filter); and,
// optionally, every point's reference-frame position (u, v)^1 with its own frame-0 residual: the
// maximum-likelihood problem, which also estimates what the A&P models take as exact.
// Frame 0 is the reference: identity motion, not a parameter.
// Residuals: (h(x) - z) / sigma per observation, h the filter's own measurement function
// (PlaneModel::point + projectWithJacobian) with its analytic Jacobians.
// The covariance at the optimum (inverse of J^T J in the free parameters) is the Cramer-Rao
// bound for beta and the planes under Gaussian noise of standard deviation sigma.
#include <Eigen/Core>
#include <string>
#include <vector>

#include "rsfm/models/projection.hpp"

namespace rsfm {

struct PlaneBatchOptions {
  bool estimate_references = true;  ///< ML: reference positions are parameters (frame-0 residuals)
  int max_iterations = 200;         ///< Levenberg-Marquardt iterations
  double function_tolerance = 1e-12;
  double parameter_tolerance = 1e-12;
  bool compute_covariance = true;   ///< covariance of beta and the planes at the optimum
};

/// Observations and model structure. frames[0] are the reference-frame observations.
struct PlaneBatchData {
  std::vector<std::vector<Observation>> frames;  ///< frames 0..F, normalized coordinates
  std::vector<int> labels;                       ///< plane of each point
  int num_planes = 1;
  double sigma_uv = 2.0 / 256.0;                 ///< measurement standard deviation (normalized)
  int gauge_plane = 0;                           ///< plane whose component is held fixed
  int gauge_component = 2;                       ///< 0: N_X, 1: N_Y, 2: N_Z
};

/// A state of the whole sequence (the start, e.g. the filter's per-frame estimates, or the result).
struct PlaneBatchState {
  std::vector<Eigen::Matrix3d> R;   ///< frames 0..F: reference -> camera k (R[0] = I)
  std::vector<Eigen::Vector3d> t;   ///< frames 0..F: (t_X, t_Y, t_Z beta) (t[0] = 0)
  double beta = 1.0;
  std::vector<Eigen::Vector3d> N;   ///< per plane
  std::vector<Eigen::Vector2d> ref;  ///< per point: reference-frame position (normalized)
};

struct PlaneBatchResult {
  PlaneBatchState state;
  bool converged = false;       ///< Ceres reported a usable solution
  std::string message;          ///< Ceres's summary line or the failure
  int iterations = 0;
  double initial_cost = 0, final_cost = 0;  ///< 0.5 sum of squared whitened residuals
  int residuals = 0;
  bool covariance_ok = false;
  double var_beta = 0;                          ///< Cramer-Rao bound of beta
  std::vector<Eigen::Matrix3d> cov_N;           ///< per plane (gauge row/column zero)
  std::vector<Eigen::RowVector3d> cov_beta_N;   ///< per plane: cross-covariance of beta with N
};

/// Whitened residual of one observation at frame k >= 1 (2 rows) and its Jacobians with respect to
/// the motion (2x6), beta (2x1), the point's plane (2x3) and its reference (2x2). Exposed for the
/// agreement test with the filter's measurement function. Returns the model's status.
MeasureStatus planeBatchResidual(const Eigen::Vector3d& t, const Eigen::Vector3d& omega,
                                 const Eigen::Matrix3d& R_base, double beta,
                                 const Eigen::Vector3d& N, const Eigen::Vector2d& ref,
                                 const Eigen::Vector2d& z, double sigma, Eigen::Vector2d* r,
                                 Eigen::Matrix<double, 2, 6>* J_motion, Eigen::Vector2d* J_beta,
                                 Eigen::Matrix<double, 2, 3>* J_N, Eigen::Matrix2d* J_ref);

/// The Cramer-Rao bound of the batch problem at a state (with references estimated), accounting
/// for parameters the data do not determine: the Fisher information J^T J of every observation
/// (frame 0 as reference residuals) with the gauge component removed, the per-frame motions
/// eliminated by Schur complement (each frame needs >= 4 observations: otherwise ok = false), and
/// its null space found by eigen-decomposition. A quantity is estimable when its gradient is
/// orthogonal to that null space; its bound is then the pseudo-inverse's quadratic form.
/// Pure rotation leaves the planes in the null space; pure translation leaves beta and the
/// planes' tilt (the affine ambiguity).
struct PlaneBatchBound {
  bool ok = false;
  std::string message;
  int parameters = 0;   ///< references, beta and the planes (the motions eliminated)
  int null_dim = 0;     ///< dimension of the null space
  bool beta_estimable = false;
  double var_beta = 0;                      ///< when estimable
  std::vector<bool> normal_estimable;       ///< per plane: the normal's direction (2 tangent functionals)
  std::vector<Eigen::Matrix3d> cov_N;       ///< per plane (gauge row/column zero; meaningful when estimable)
};
PlaneBatchBound planeBatchBound(const PlaneBatchData& data, const PlaneBatchState& at);

/// Solves the batch problem from `start`. Never throws on numerical trouble: converged = false
/// and message say what happened.
PlaneBatchResult solvePlaneBatch(const PlaneBatchData& data, const PlaneBatchState& start,
                                 const PlaneBatchOptions& options = {});

}  // namespace rsfm
