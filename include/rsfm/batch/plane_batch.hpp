#pragma once
// Batch reference for the plane models (rigid, one or more planes): bundle adjustment over all
// frames with the filter's parameterization, solved with Ceres (issue 3; docs/planes.md,
// docs/table1.md).
//
// Parameters: per frame k >= 1 the motion (t_X, t_Y, t_Z beta, omega) where omega is a
// left perturbation of a fixed base rotation (R_k = R(dq(omega_k)) Rbase_k, [AS99] eqs. 2-3; the
// base is the filter's estimate, so omega starts at 0); beta; one N per plane (N . X = 1, [AS99]
// eq. 9) with the scale gauge held constant (one component of one plane, as in the filter); and,
// optionally, every point's reference-frame position (u, v)^1 with its own frame-0 residual: the
// maximum-likelihood problem, which also estimates what the A&P models take as exact.
// Frame 0 is the reference: identity motion, not a parameter.
// Residuals: (h(x) - z) / sigma per observation, h the filter's own measurement function
// (PlaneModel::point + projectWithJacobian) with its analytic Jacobians, optionally seen through
// the image-side camera (models/radial_camera.hpp: principal point offset and radial distortion,
// each component estimated or held) and under a robust loss (the final refinement,
// pipeline/refine.hpp). A point's reference position needs no frame-0 observation: a track born
// later is anchored by its own observations.
// The covariance at the optimum (inverse of J^T J in the free parameters) is the Cramer-Rao
// bound for beta and the planes under Gaussian noise of standard deviation sigma.
#include <Eigen/Core>
#include <array>
#include <functional>
#include <string>
#include <vector>

#include "rsfm/models/projection.hpp"

namespace rsfm {

struct PlaneBatchOptions {
  bool estimate_references = true;  ///< ML: reference positions are parameters (frame-0 residuals)
  /// Robust loss on each observation's whitened residual (Ceres' HuberLoss / CauchyLoss with
  /// scale `loss_scale`, in units of sigma): none, the plain least squares.
  enum class Loss { None, Huber, Cauchy };
  Loss loss = Loss::None;
  double loss_scale = 3.0;
  /// The image-side camera (dc_x, dc_y, k1, k2; models/radial_camera.hpp): which components are
  /// estimated. None estimated and the state's camera zero: the plain A&P projection (the
  /// experiments' problem, bit for bit).
  std::array<bool, 4> camera_free{false, false, false, false};
  /// Gaussian priors on the free camera components, centred on zero (the nominal principal
  /// point, no distortion): sd in the components' units (normalized for dc, none for k); 0: none.
  std::array<double, 4> camera_prior_sd{0, 0, 0, 0};
  bool hold_beta = false;  ///< beta held at its start value (a known focal length)
  /// A rolling shutter's readout (PlaneBatchState::readout, PlaneBatchData::readout_shift) is a
  /// parameter, with a Gaussian prior about zero of sd `readout_prior_sd` frame intervals (0:
  /// none). Needs readout_shift.
  bool readout_free = false;
  double readout_prior_sd = 0.0;
  /// Eliminate the per-frame motions first (Ceres' Schur ordering; DENSE_SCHUR on what remains:
  /// references, beta, planes, camera). Fast when there are many frames and a few hundred points
  /// (the refinement); false: Ceres' own SPARSE_SCHUR ordering (the experiments).
  bool eliminate_motions_first = false;
  /// With eliminate_motions_first: the reference positions of this many consecutive points form
  /// one parameter block (the same problem and optimum; fewer, larger cells in Ceres' Schur
  /// elimination: docs/performance.md, "The refinement"). 1: a block per point.
  int reference_group = 4;
  /// The degenerate alternative for model selection: every frame a pure rotation about the
  /// centre of projection (planeBatchRotationResidual); translations and planes are not
  /// parameters (the result keeps them as started).
  bool rotation_only = false;
  /// The other degenerate alternative: no rotation in any frame (each frame's omega held at zero;
  /// the caller starts every R at the identity).
  bool translation_only = false;
  /// Trust-region strategy of Ceres: Levenberg-Marquardt (the experiments) or Powell's dogleg
  /// (the refinement: the same optimum in fewer and cheaper iterations on its long, nearly
  /// degenerate camera directions; docs/performance.md, "The refinement").
  enum class TrustRegion { LevenbergMarquardt, Dogleg };
  TrustRegion trust_region = TrustRegion::LevenbergMarquardt;
  int max_iterations = 200;         ///< trust-region iterations
  double function_tolerance = 1e-12;
  double parameter_tolerance = 1e-12;
  bool compute_covariance = true;   ///< covariance of beta and the planes at the optimum
  /// Checked after every successful iteration on that iteration's beta, planes (3 x m, one column
  /// per plane) and references (2 x P): true stops the solve there, the state where it stopped
  /// (PlaneBatchResult::stopped_early). Empty: never. The refinement stops its first solve when
  /// a plane turns edge-on to the reference camera, instead of crawling after it to the
  /// iteration limit (pipeline/refine.cpp; docs/estimate.md section 4).
  using StopWhen =
      std::function<bool(double beta, const Eigen::Ref<const Eigen::Matrix3Xd>& N, const Eigen::Ref<const Eigen::Matrix2Xd>& ref)>;
  StopWhen stop_when;
  /// Called after every iteration with Ceres's iteration number (0: the start) and the cost
  /// then (PlaneBatchResult::final_cost's units): progress for a long solve. Empty: none.
  std::function<void(int iteration, double cost)> on_iteration;
};

/// Observations and model structure. frames[0] are the reference-frame observations.
struct PlaneBatchData {
  std::vector<std::vector<Observation>> frames;  ///< frames 0..F, normalized coordinates
  std::vector<int> labels;                       ///< plane of each point
  int num_planes = 1;
  double sigma_uv = 2.0 / 256.0;                 ///< measurement standard deviation (normalized)
  int gauge_plane = 0;                           ///< plane whose component is held fixed
  int gauge_component = 2;                       ///< 0: N_X, 1: N_Y, 2: N_Z
  /// Names for messages only: the input frame number of each of frames 0..F and the track id of
  /// each point (empty: their indices here). A caller that left frames out (a still stretch) or
  /// kept only some tracks passes them, so that a message names what the user gave.
  std::vector<int> frame_numbers, point_ids;
  /// A rolling shutter (docs/estimate.md section 6): per frame, parallel to frames[k], what the
  /// observation moves per frame interval of readout ((y - mid) / height times its track's
  /// velocity, normalized coordinates; rollingShutterShift). Every prediction is moved by
  /// PlaneBatchState::readout times it. Empty: a global shutter (no readout parameter).
  std::vector<std::vector<Eigen::Vector2d>> readout_shift;
  bool hasReadout() const { return !readout_shift.empty(); }
  /// readout_shift empty, or one shift per observation of every frame.
  bool readoutShiftMatches() const {
    if (readout_shift.empty()) return true;
    if (readout_shift.size() != frames.size()) return false;
    for (std::size_t k = 0; k < frames.size(); ++k)
      if (readout_shift[k].size() != frames[k].size()) return false;
    return true;
  }
  /// The shift of frames[k][j] (zero without readout_shift).
  Eigen::Vector2d shift(int k, std::size_t j) const {
    return readout_shift.empty() ? Eigen::Vector2d::Zero() : readout_shift[k][j];
  }
  int frameName(int k) const { return k >= 0 && k < static_cast<int>(frame_numbers.size()) ? frame_numbers[k] : k; }
  int pointName(int i) const { return i >= 0 && i < static_cast<int>(point_ids.size()) ? point_ids[i] : i; }
};

/// A state of the whole sequence (the start, e.g. the filter's per-frame estimates, or the result).
struct PlaneBatchState {
  std::vector<Eigen::Matrix3d> R;   ///< frames 0..F: reference -> camera k (R[0] = I)
  std::vector<Eigen::Vector3d> t;   ///< frames 0..F: (t_X, t_Y, t_Z beta) (t[0] = 0)
  double beta = 1.0;
  std::vector<Eigen::Vector3d> N;   ///< per plane
  std::vector<Eigen::Vector2d> ref;  ///< per point: reference-frame position (normalized, undistorted)
  Eigen::Vector4d camera = Eigen::Vector4d::Zero();  ///< (dc_x, dc_y, k1, k2), models/radial_camera.hpp
  /// A rolling shutter's readout, frame intervals (first row to last; PlaneBatchData::readout_shift).
  double readout = 0.0;
};

/// One iteration of a solve, as PlaneBatchResult::stalled reads it (from Ceres's summary).
struct SolveStep {
  bool successful = false;
  double cost = 0.0;         ///< after a successful step; a step that could not be evaluated: not finite or ~1.8e308
  double cost_change = 0.0;  ///< cost before - cost after (successful steps)
};
/// True when the steps after the last successful one include one that could not be evaluated
/// and that last successful step still decreased the cost by more than `function_tolerance`
/// (relative): a solve that stopped on its parameter tolerance only because such steps shrank
/// its trust region (PlaneBatchResult::stalled). `steps` excludes the start (Ceres's iteration 0).
bool stalledAfterInvalidSteps(const std::vector<SolveStep>& steps, double function_tolerance);

struct PlaneBatchResult {
  PlaneBatchState state;
  bool converged = false;       ///< Ceres reported a usable solution
  /// Usable, but the solver stopped at max_iterations with the cost still falling (Ceres's
  /// NO_CONVERGENCE): the state is where it stopped, not an optimum.
  bool at_iteration_limit = false;
  /// Usable by Ceres's account (it stopped on its parameter tolerance), but only because the trust
  /// region shrank to nothing under steps it could not evaluate (a point carried behind a camera
  /// or past its plane's horizon), the cost still falling by more than the function tolerance at
  /// its last step: the state is where it stopped, not an optimum.
  bool stalled = false;
  /// Usable, stopped by PlaneBatchOptions::stop_when: the state is where it stopped.
  bool stopped_early = false;
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
/// With `camera` (nullptr: none), the prediction goes through RadialCamera and J_camera (2x4)
/// is its Jacobian.
MeasureStatus planeBatchResidual(const Eigen::Vector3d& t, const Eigen::Vector3d& omega,
                                 const Eigen::Matrix3d& R_base, double beta,
                                 const Eigen::Vector3d& N, const Eigen::Vector2d& ref,
                                 const Eigen::Vector2d& z, double sigma, Eigen::Vector2d* r,
                                 Eigen::Matrix<double, 2, 6>* J_motion, Eigen::Vector2d* J_beta,
                                 Eigen::Matrix<double, 2, 3>* J_N, Eigen::Matrix2d* J_ref,
                                 const Eigen::Vector4d* camera = nullptr,
                                 Eigen::Matrix<double, 2, 4>* J_camera = nullptr);
/// Pure rotation about the centre of projection: the reference ray d = (beta u, beta v, 1) of
/// `ref` turned by R = R(dq(omega)) R_base, h = (w_x, w_y) / (beta w_z) with w = R d, through the
/// camera (nullptr: none); Jacobians with respect to omega (2x3), beta, ref (2x2), camera (2x4).
MeasureStatus planeBatchRotationResidual(const Eigen::Vector3d& omega, const Eigen::Matrix3d& R_base, double beta,
                                         const Eigen::Vector2d& ref, const Eigen::Vector2d& z, double sigma,
                                         const Eigen::Vector4d* camera, Eigen::Vector2d* r,
                                         Eigen::Matrix<double, 2, 3>* J_omega, Eigen::Vector2d* J_beta,
                                         Eigen::Matrix2d* J_ref, Eigen::Matrix<double, 2, 4>* J_camera);
/// The frame-0 residual of a point's reference position through the camera: (RadialCamera(ref)
/// - z) / sigma with its Jacobians (reference 2x2, beta 2x1, camera 2x4).
void planeBatchReferenceResidual(const Eigen::Vector2d& ref, double beta, const Eigen::Vector4d& camera,
                                 const Eigen::Vector2d& z, double sigma, Eigen::Vector2d* r, Eigen::Matrix2d* J_ref,
                                 Eigen::Vector2d* J_beta, Eigen::Matrix<double, 2, 4>* J_camera);

/// The Cramer-Rao bound of the batch problem at a state (with references estimated), accounting
/// for parameters the data do not determine: the Fisher information J^T J of every observation
/// (frame 0 as reference residuals) with the gauge component removed, the per-frame motions
/// eliminated by Schur complement (each frame needs >= 4 observations: otherwise ok = false), and
/// its null space found by eigen-decomposition. A quantity is estimable when its gradient is
/// orthogonal to that null space (rounding-level eigenvalues); its bound is the pseudo-inverse's
/// quadratic form plus the share of the weak directions (eigenvalues between rounding and 1e-10
/// of the largest; the first widened by the tracks' own check, the second as the model gives it),
/// and the callers' sd limits judge it.
/// Pure rotation leaves the planes in the null space; pure translation leaves beta and the
/// planes' tilt (the affine ambiguity).
struct PlaneBatchBoundOptions {
  /// Camera components (dc_x, dc_y, k1, k2) that are parameters of the bound (the state's camera
  /// enters the residuals whenever it is non-zero or a component is free).
  std::array<bool, 4> camera_free{false, false, false, false};
  std::array<double, 4> camera_prior_sd{0, 0, 0, 0};  ///< as PlaneBatchOptions'
  /// The readout is a parameter of the bound (a camera parameter: widened with the camera's
  /// block, not by the spatial clusters), with PlaneBatchOptions' prior. Needs readout_shift.
  bool readout_free = false;
  double readout_prior_sd = 0.0;
  bool motion_covariance = false;  ///< also each frame's 6x6 motion covariance (back-substitution)
  /// Frames whose motion the observations do not determine (fewer than 4, or a singular block)
  /// are left out and listed in skipped_frames; false: such a frame makes the bound fail.
  bool skip_undetermined_frames = false;
  bool hold_beta = false;  ///< beta known: not a parameter (beta_estimable false, var_beta 0)
  /// Widen the bound of beta, the planes and the camera where the tracks' scores say it is too
  /// narrow: the track-clustered ("sandwich") covariance V = S+ (G/(G-1) sum_t g_t g_t^T) S+, G the
  /// tracks with a non-zero score
  /// ([W80] for the estimator; clustered by track as in [CGM11]), g_t = sum over track t's
  /// observations of J~^T r (J~ the observation's Jacobian with the frame's motion eliminated,
  /// r the whitened residual at `at`, which must be the optimum). It holds whatever the errors'
  /// correlation along a track (a tracker's drift) and their spread, since each track's errors
  /// enter through its own score. Those parameters' block of cov becomes the smallest that
  /// covers both in every direction: C' = C^1/2 max(I, C^-1/2 V C^-1/2) C^1/2 (the generalized
  /// eigenvalues of (V, C) clamped at 1 from below, on C's range), so no functional's variance is
  /// narrowed and each is at least the sandwich's. The sd factors sqrt(C'_ii / C_ii) are in
  /// PlaneBatchBound's clustered_* fields. The motions' covariances take the widened block
  /// through the back-substitution (motion_covariance), and are widened with it.
  bool track_clustered = false;
  /// With track_clustered: also cluster the tracks by where they are - per plane, a
  /// spatial_grid x spatial_grid grid over its tracks' reference positions - and widen beta's and
  /// the planes' block (not the camera's) the same way to that sandwich (0: tracks only). Errors
  /// shared by neighbouring tracks (a radial bias, an unmodelled distortion, a texture's pull on
  /// the tracker) are independent between regions, not between tracks.
  int spatial_grid = 0;
};
struct PlaneBatchBound {
  bool ok = false;
  std::string message;
  int parameters = 0;   ///< references, beta, the planes and the free camera components (motions eliminated)
  /// Eigenvalues of the scaled information up to 1e-10 of the largest: the null space proper
  /// (up to 1e-14: rounding) and `weak_dim` directions the data see, however weakly, whose
  /// variance is in cov (plane_batch_bound.cpp).
  int null_dim = 0;
  int weak_dim = 0;
  bool beta_estimable = false;
  double var_beta = 0;                      ///< when estimable
  std::vector<bool> normal_estimable;       ///< per plane: the normal's direction (2 tangent functionals)
  std::vector<Eigen::Matrix3d> cov_N;       ///< per plane (gauge row/column zero; meaningful when estimable)
  std::vector<Eigen::Vector3d> cov_beta_N;  ///< per plane: cov(beta, N)
  /// cov(N_a, N_b) for each pair a < b, in TrackFrame::cov_N_pair's order (planePairIndex); the
  /// widening by the clustered checks and the jackknife included (it acts on rows and columns).
  std::vector<Eigen::Matrix3d> cov_N_pair;
  std::array<bool, 4> camera_estimable{false, false, false, false};
  Eigen::Matrix4d cov_camera = Eigen::Matrix4d::Zero();  ///< free components only (others zero)
  bool readout_estimable = false;  ///< with readout_free
  double var_readout = 0.0;        ///< frame intervals^2
  Eigen::Vector4d cov_readout_camera = Eigen::Vector4d::Zero();  ///< cov(readout, camera), free components
  std::vector<Eigen::Matrix<double, 6, 6>> cov_motion;   ///< frames 0..F (frame 0 and skipped frames zero)
  std::vector<int> skipped_frames;
  /// With track_clustered: the factor sqrt(max(1, V_ii / cov_ii)) applied to beta's sd, the
  /// largest applied to a plane's N components, and per camera component (1: not widened).
  double clustered_beta = 1.0;
  double clustered_beta_ratio = 0.0;  ///< V / cov for beta before widening (0: not computed)
  std::vector<double> clustered_N;
  std::array<double, 4> clustered_camera{1, 1, 1, 1};
  double clustered_readout = 1.0;
  /// With track_clustered, per plane: the further sd factor on its N components from the
  /// delete-one-track jackknife (plane_batch_bound.cpp, planeJackknife), which sees the leverage
  /// the sandwich misses (a track that alone decides a direction: the fit follows it, so its
  /// score is small). jackknife_ratio_N is the jackknife's largest variance over the sandwich's
  /// with the motions held (0: not computed); the sandwich's variance ratio on the plane times it,
  /// where above clustered_N^2, widens the plane's rows and columns of cov by jackknife_N (1: not
  /// widened). Infinite (both) when one track alone decides a direction of the plane, the motions
  /// held (a leverage of 1: e.g. a plane of three tracks); cov is then not widened for it and the
  /// plane's normal must not be called determined.
  std::vector<double> jackknife_N, jackknife_ratio_N;
  /// Whether a functional of (beta, N..., camera) is estimable: `g_beta`, per plane `g_N` (3) and
  /// `g_camera` (4) and `g_readout` its gradient. It is when orthogonal to the null space proper;
  /// its variance g^T cov g includes the weak directions' share, and the caller's limit (e.g.
  /// kDeterminedNormalSdDeg) judges whether it is small enough.
  bool estimable(double g_beta, const std::vector<Eigen::Vector3d>& g_N, const Eigen::Vector4d& g_camera,
                 double g_readout = 0.0) const;
  // Internal: the kept parameters' covariance (the pseudo-inverse, widened, plus the weak
  // directions' variance), scaling, null space and weak directions (scaled) with their eigenvalues.
  Eigen::MatrixXd cov, null_scaled, weak_scaled;
  Eigen::VectorXd scale, weak_lambda;
  int beta_index = -1;               ///< -1: beta held
  std::vector<int> N_index;          ///< 3 per plane, -1 for the gauge component
  std::array<int, 4> camera_index{-1, -1, -1, -1};
  int readout_index = -1;            ///< -1: not a parameter
};
PlaneBatchBound planeBatchBound(const PlaneBatchData& data, const PlaneBatchState& at,
                                const PlaneBatchBoundOptions& options = {});

/// Solves the batch problem from `start`. Never throws on numerical trouble: converged = false
/// and message say what happened.
PlaneBatchResult solvePlaneBatch(const PlaneBatchData& data, const PlaneBatchState& start,
                                 const PlaneBatchOptions& options = {});

}  // namespace rsfm
