#pragma once
// Calway's affine-patch filter ([Cal00]; docs/patches.md): an EKF over the state of PatchModel,
// 7 + 3K, with a nonlinear transition. One step, for the measurements of frame k:
//   1. predict the inter-frame motion (identity dynamics: P += Q on the motion and beta; the
//      structure gets q_structure);
//   2. update with each patch's 6 affine parameters (about its centre in frame k-1), chi-square
//      gated per patch (6 dof);
//   3. carry every patch's centre into frame k (PatchCentres) and accumulate the camera pose;
//   4. carry the structure into frame k by the Murray-Shapiro transition followed by the scale
//      gauge (PatchModel::transition): x <- f(x), P <- F P F^T.
// Scale gauge: one patch's p4 is held fixed (zero variance). In every frame the scene is rescaled
// about the centre of projection so that this p4 keeps its value; `scale()` accumulates the
// factors so that poses are reported in the units of the first frame. When the gauge patch is
// removed, the gauge moves to the remaining patch with the smallest p4 variance, by the same
// rescaling with lambda = 1 (values unchanged, covariance transformed by its Jacobian).
#include <Eigen/Core>
#include <cstdint>
#include <string_view>
#include <vector>

#include "rsfm/ekf.hpp"
#include "rsfm/models/patch_model.hpp"

namespace rsfm {

/// Treatment of the patch centres, which are outside the state (7 + 3K) but are the points about
/// which each next measurement is taken (the model leaves this open; docs/patches.md, "Filter").
enum class PatchCentres {
  /// The tracker's measured centre. The previous centre is then a noisy measurement of the same
  /// point: centre_sd^2 A A^T is added to R of the centre coordinates. Each displacement is used as
  /// if independent, so the long-baseline information of the positions is lost (a k-frame
  /// displacement looks k times noisier than it is).
  Measured,
  /// The posterior's predicted centre, h(x+, c_prev). Drifts off the tracked point wherever the
  /// state is wrong: a patch whose structure is off is gated and never re-synchronized (20 px in
  /// 60 frames in the plane scene; docs/patches.md).
  Predicted,
  /// A 2-D Kalman filter per centre, beside the EKF: the predicted centre h(x+, c_prev) with
  /// covariance A C_prev A^T + J P+ J^T (J = dh/dx of the patch) is fused with the measured centre
  /// (centre_sd^2 I); R of the next centre measurement gets A C A^T. A gated patch restarts from its
  /// measured centre. Approximate: the measured centre informs both the state and the centre, and
  /// their cross-covariance is not kept (as ReferenceModel::Refine for points).
  Fused,
  /// Each patch's cumulative map w = (centre, 2x2 A from the patch's template frame) is part of
  /// the state, which becomes 7 + 3K + 6K: [motion, beta | s_1..s_K | w_1..w_K]. Per frame w is
  /// carried forward by the exact inter-frame map (PatchModel::composeMap; Jacobians with respect
  /// to motion, structure and w itself) and the tracker's cumulative map is measured directly
  /// (H = I on w, R = measurement_sd^2). A tracker's error lies in its map against the template,
  /// independent from frame to frame; as inter-frame maps A_k A_{k-1}^-1 the same errors are
  /// differenced, and treating those as independent spends the long-baseline information of the
  /// maps (a k-frame deformation looks sqrt(k/2) times noisier than it is). Observations then hold
  /// cumulative maps, not inter-frame ones. Exact measurement only; no iterated update (the
  /// measurement is linear).
  State,
};
std::string_view toString(PatchCentres c);
bool parsePatchCentres(std::string_view s, PatchCentres* out);

/// Tuning of the patch filter. Units: normalized image units (docs/conventions.md), the gauge's
/// scene units.
struct PatchFilterOptions {
  AffineMeasurement measurement = AffineMeasurement::Exact;
  /// Measurement standard deviations of (h_u, h_v, A_11, A_12, A_21, A_22): the centre in
  /// normalized units (default 0.5 px at s = 256), the entries of the 2x2 map unitless.
  Vector6d measurement_sd = (Vector6d() << 0.5 / 256.0, 0.5 / 256.0, 0.005, 0.005, 0.005, 0.005).finished();
  /// Per-frame process variances of the inter-frame motion (t_X, t_Y, t_Z beta, omega_X,
  /// omega_Y, omega_Z) and beta: identity dynamics (constant velocity), so they must cover the
  /// change of one frame's motion from frame to frame.
  Eigen::Matrix<double, 7, 1> q_motion =
      (Eigen::Matrix<double, 7, 1>() << 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 0.0).finished();
  /// Per-frame process variance of each free structure component (p1, p2, p4).
  double q_structure = 0.0;
  UpdateOptions update;  ///< gating (per patch, 6 dof), form, minimum patches (>= kMinPatches)
  /// Where each patch's centre in the new frame (the linearization point of the next
  /// measurement) comes from; see PatchCentres.
  PatchCentres centres = PatchCentres::Fused;
  /// Standard deviation of a measured centre (normalized units): the tracker's position noise.
  double centre_sd = 0.5 / 256.0;
  /// PatchCentres::State: per-frame process variance of each map component (tracker drift;
  /// normalized units^2 for the centre, unitless for A). 0: the template does not drift.
  double q_map = 0.0;
  double beta_min = 0.0;  ///< lower bound on beta, as FilterOptions::beta_min (0: none)
  /// Iterated EKF: Gauss-Newton relinearizations of the measurement per frame (1 = plain EKF);
  /// stops when the step (infinity norm) falls below iteration_tol.
  int iterations = 1;
  double iteration_tol = 1e-10;
  /// Warm-up: the first warmup_frames frames use max(iterations, warmup_iterations). The first
  /// frames linearize at a motion prior of zero, far from the truth; one plain update there
  /// collapses P around a poor linearization (beta then stays 30-40 % off in the sphere scene).
  int warmup_frames = 0;
  int warmup_iterations = 10;
  /// Annealing: frame k <= anneal_frames uses R multiplied by
  /// 1 + (anneal_factor - 1) (1 - (k - 1) / anneal_frames), so the first frames, linearized far
  /// from the truth (zero motion, fronto-parallel patches, a wrong beta), inform the state softly.
  int anneal_frames = 0;
  double anneal_factor = 1.0;
};

struct PatchFrameStats {
  UpdateStats update;
  int invalid = 0;  ///< observations whose prediction failed (left out)
  MeasureStatus first_problem = MeasureStatus::Ok;
  MeasureStatus transition = MeasureStatus::Ok;  ///< status of the structure transition
  double lambda = 1.0;  ///< scale factor of this frame's gauge rescaling
  std::uint32_t health = kHealthy;
  bool beta_projected = false;
  int iterations = 1;  ///< measurement linearizations used
  std::vector<int> used;  ///< observation index of each measurement block (update.gated_mask is aligned)
  /// Per patch slot (before any removal): the measurement predicted from the posterior state about
  /// the previous centre, and its covariance J P+ J^T (NaN when the prediction failed).
  std::vector<Vector6d> posterior_z;
  std::vector<Eigen::Matrix<double, 6, 6>> posterior_cov;
  bool ok() const { return health == kHealthy && update.applied && transition == MeasureStatus::Ok; }
};

class PatchFilter {
 public:
  /// `ekf` holds the state 7 + 3K in the model's patch order; `gauge` is the patch whose p4 is
  /// fixed (its covariance row must be zero: it is marked fixed here). With PatchCentres::State
  /// the maps are appended here, each patch's starting at (its model centre, I): a patch's map is
  /// the identity in its template frame, by definition.
  PatchFilter(PatchModel model, Ekf ekf, int gauge, PatchFilterOptions options);

  /// One frame. `obs[i].id` is a patch slot; patches without an observation keep their centre
  /// moved by the prediction.
  PatchFrameStats step(const std::vector<AffineObservation>& obs);

  /// Adds a patch centred at `centre` (current frame) with prior structure s0 and covariance P0
  /// (no cross-covariance with the state). Returns its slot.
  int addPatch(const Eigen::Vector2d& centre, const Eigen::Vector3d& s0, const Eigen::Matrix3d& P0);
  /// State index of patch k's cumulative map (PatchCentres::State; 6 entries: centre, A row-major).
  int mapIndex(int k) const { return 7 + 3 * numPatches() + 6 * k; }
  bool mapsInState() const { return opt_.centres == PatchCentres::State; }
  /// Covariance of patch k's centre (normalized units^2; PatchCentres::Fused, else centre_sd^2 I).
  const Eigen::Matrix2d& centreCovariance(int k) const { return centre_cov_[k]; }
  /// Removes a patch (slots above it shift down by one). Moves the gauge first if it is the gauge
  /// patch. Returns false when it is the last patch.
  bool removePatch(int slot);

  const PatchModel& model() const { return model_; }
  const Ekf& ekf() const { return ekf_; }
  Ekf& mutableEkf() { return ekf_; }
  const PatchFilterOptions& options() const { return opt_; }
  int gauge() const { return gauge_; }
  int numPatches() const { return model_.numPatches(); }
  double beta() const { return ekf_.x()[6]; }
  Eigen::Vector3d structure(int k) const { return ekf_.x().segment<3>(PatchModel::structureIndex(k)); }
  /// Unit normal of patch k in the current camera frame.
  Eigen::Vector3d normal(int k) const { return PatchModel::normal(structure(k), beta()); }
  /// One current scene unit in first-frame units (product of the gauge rescalings).
  double scale() const { return scale_; }
  /// Camera pose after the last step, centre-of-projection coordinates in first-frame units:
  /// X_cam = rotation() X_ref + translation() (X in the first camera's COP-centred frame).
  const Eigen::Matrix3d& rotation() const { return R_; }
  const Eigen::Vector3d& translation() const { return T_; }

 private:
  PatchFrameStats stepState(const std::vector<AffineObservation>& obs);
  void predictMotion();
  double annealInflation() const;
  /// After an update: health, the beta bound, the rotation's validity (rolled back to the
  /// prior if invalid). False when the frame must stop here.
  bool checkUpdate(const Eigen::VectorXd& x_prior, const Eigen::MatrixXd& P_prior, const std::vector<int>& used,
                   PatchFrameStats* fs);
  Eigen::Matrix<double, 6, 6> initialMapCovariance() const;
  /// Pose accumulation and the structure's transition into the new frame (maps unchanged).
  bool advance(PatchFrameStats* fs);
  /// Rescaling of the structure part (PatchModel::regauge) applied to the whole state.
  double regaugeState(int gauge, double value, Eigen::VectorXd* y, Eigen::MatrixXd* G) const;
  void linearize(const Eigen::VectorXd& x, const std::vector<AffineObservation>& obs, MeasurementBatch* batch,
                 std::vector<int>* used, PatchFrameStats* fs) const;
  void iterate(int iterations, const std::vector<AffineObservation>& obs, const std::vector<int>& used,
               const Eigen::VectorXd& x_prior, const Eigen::MatrixXd& P_prior, PatchFrameStats* fs);

  PatchModel model_;
  std::vector<Eigen::Matrix2d> centre_cov_;
  int steps_ = 0;
  Ekf ekf_;
  int gauge_ = 0;
  double gauge_value_ = 0.0;
  PatchFilterOptions opt_;
  double scale_ = 1.0;
  Eigen::Matrix3d R_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d T_ = Eigen::Vector3d::Zero();
};

}  // namespace rsfm
