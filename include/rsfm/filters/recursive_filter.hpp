#pragma once
// Frame-by-frame driver shared by the point and plane models (docs/conventions.md, docs/filter.md).
// One step = predict (identity dynamics, P += Q) -> linearize all observations -> EKF update ->
// fold the incremental rotation into the global rotation R_g (and zero omega in the reset reading).
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string_view>
#include <vector>

#include "rsfm/camera.hpp"
#include "rsfm/ekf.hpp"
#include "rsfm/filters/conditional_kernels.hpp"
#include "rsfm/models/linearize.hpp"
#include "rsfm/models/projection.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {

/// How the first-frame (reference) image positions of the points are treated. The A&P and
/// Alon-Sclaroff models take them as exact ([AS99] §2: "a known weakness ... biases the
/// results"); with real tracks they carry the same noise as every other measurement.
enum class ReferenceModel {
  /// As published: reference positions exact, R = sigma^2 I.
  Exact,
  /// Each point's R is inflated by its reference noise transferred to the current frame:
  /// R_i = sigma^2 I + J_i C_i J_i^T, J_i = dh_i/d(u, v)^1, C_i = reference_sigma^2 I.
  Inflate,
  /// As Inflate, and after each update every accepted observation also refines its point's
  /// reference position by a per-point information-form step with the state at its posterior:
  /// S = sigma^2 I + H_i P+ H_i^T, C_i^-1 <- C_i^-1 + J^T S^-1 J, uv_i <- uv_i + C_i J^T S^-1 (z - h).
  /// This removes the errors-in-variables bias of noisy references over time. O(N) per frame for
  /// the plane models. Approximate: each observation informs both the state and its reference,
  /// and the cross-covariance is not kept (Beardsley et al.'s per-point remedy, [BZM97], in spirit).
  Refine,
  /// The reference positions join the state: x = [model state | u_1, v_1, ..., u_N, v_N], each
  /// starting at its measured position with variance reference_sigma^2, and every observation's
  /// Jacobian gets its dh_i/d(u, v)^1 block there (R = sigma^2 I). Exact to first order, as the
  /// batch's joint estimate; the price is a 2N-larger state, O(N^3) per frame. The points must
  /// all exist when the filter is built (the appended block follows the model's state).
  State,
  /// As State to first order, at O(N) per frame: each reference is kept *conditional on the
  /// state*, u_i | x ~ N(u_i + G_i (x - x^), C_i) (x^ the state's mean), the joint Gaussian of
  /// the state and the references factored as p(x) prod_i p(u_i | x). The references are
  /// conditionally independent given the state exactly as long as the state has no process
  /// noise (each observation involves the state and one reference), so then this *is* State's
  /// estimate (first order) without its 2N x 2N covariance. Per frame (docs/filter.md):
  ///  - the observation's Jacobian on the state is the total one, A_i = H_i + Hu_i G_i, and its
  ///    noise sigma^2 I + Hu_i C_i Hu_i^T (the reference marginalized given x, as Inflate);
  ///  - after the update, with K_i = C_i Hu_i^T D_i^-1 (D_i that noise) and the innovation
  ///    nu_i = z_i - h(x^-, u_i): u_i <- u_i + K_i nu_i + (G_i - K_i A_i)(x^+ - x^-),
  ///    G_i <- G_i - K_i A_i, C_i <- C_i - K_i Hu_i C_i (the conditional of u_i given x and z_i);
  ///  - the process noise x' = x + w: u_i | x' has gain G_i J, J = P (P + Q)^-1, and the rest,
  ///    G_i (P - J P) G_i^T, shared through the old state, is added to C_i as if independent
  ///    (the one approximation; G_i spans every state column: kept on the point's own columns
  ///    only, the planes model's references lost their dependence on the other planes and
  ///    box-1deg's online focal length came out -8.9 % instead of -0.7 %);
  ///  - a point not observed in a frame leaves the conditional form: C_i <- C_i + G_i P G_i^T,
  ///    G_i <- 0.
  /// Unlike Refine, the state's own error is not copied into every reference (issue 15 item 2).
  Conditional,
};
inline std::string_view toString(ReferenceModel r) {
  switch (r) {
    case ReferenceModel::Exact: return "exact";
    case ReferenceModel::Inflate: return "inflate";
    case ReferenceModel::Refine: return "refine";
    case ReferenceModel::State: return "state";
    case ReferenceModel::Conditional: return "conditional";
  }
  return "?";
}
inline bool parseReferenceModel(std::string_view s, ReferenceModel* out) {
  if (s == "exact") *out = ReferenceModel::Exact;
  else if (s == "inflate") *out = ReferenceModel::Inflate;
  else if (s == "refine") *out = ReferenceModel::Refine;
  else if (s == "state") *out = ReferenceModel::State;
  else if (s == "conditional") *out = ReferenceModel::Conditional;
  else return false;
  return true;
}

/// Filter tuning. Units: normalized image units and scene units of the state (docs/conventions.md).
struct FilterOptions {
  RotationReading reading = RotationReading::Reset;  ///< see rotation.hpp
  /// Measurement standard deviation (normalized units): R = sigma^2 I per point.
  double sigma_uv = 2.0 / 256.0;
  /// Per-frame process variances of (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z, beta).
  /// Identity dynamics: they must cover one frame's motion (here ~0.017 units and ~0.01 rad
  /// standard deviation, the Table 1 scene's per-frame motion; docs/filter.md).
  Eigen::Matrix<double, 7, 1> q_motion =
      (Eigen::Matrix<double, 7, 1>() << 3e-4, 3e-4, 3e-4, 1e-4, 1e-4, 1e-4, 0.0).finished();
  /// Per-frame process variance of every free structure component (0: static structure).
  double q_structure = 0.0;
  UpdateOptions update;  ///< gating, update form, minimum points (set from the model)
  /// Treatment of the reference positions (see ReferenceModel).
  ReferenceModel reference = ReferenceModel::Exact;
  /// Standard deviation of a reference position (normalized units); < 0: sigma_uv.
  double reference_sigma = -1.0;
  /// Iterated EKF: maximum Gauss-Newton iterations of the measurement update (1 = plain EKF).
  /// Each iteration relinearizes h at the latest iterate x_i; its Gauss-Newton point
  /// x^- + K_i (z - h(x_i) - H_i (x^- - x_i)) is approached with backtracking on the MAP cost
  /// (see iterate()); P from the last linearization.
  int iterations = 1;
  /// Stop iterating when the step |x_{i+1} - x_i| (infinity norm, state units) falls below this.
  double iteration_tol = 1e-9;
  /// Warm-up (the filter's first frames, where the prior is far from the truth and one frame of
  /// many points can collapse P around a poor linearization): the first `warmup_frames` steps use
  /// max(iterations, warmup_iterations) update iterations (iterated EKF, see above), later steps
  /// `iterations`. 0 = no warm-up (the published filter).
  int warmup_frames = 0;
  int warmup_iterations = 5;
  /// Delayed iteration: steps 1..iterate_after_frames that are not warm-up steps use the plain
  /// EKF update even when iterations > 1. In the A&P models the motion is relative to the
  /// reference frame, so in the first frames it is a fraction of a degree and beta enters the
  /// measurements only through its product with that motion: the one-frame MAP the iterations
  /// converge to then fits the noise in beta, and P, linearized there, locks it in (seed 3 of
  /// `experiment planes`, trial 13 at 2 px: beta 0.5 -> 0.30 in frame 1, 0.12 in frame 2, then
  /// the planes flip). The plain update leaves beta at its prior until the motion has grown
  /// (dh/dbeta = 0 at zero motion). 0 = iterate from the first frame (the textbook IEKF).
  int iterate_after_frames = 0;
  /// Lower bound on beta = 1/f (0: none). beta <= 0 has no camera meaning (the centre of
  /// projection at or beyond infinity) and t_Z = (t_Z beta) / beta passes through a pole there.
  /// An update that leaves beta below the bound is projected onto beta = beta_min along the
  /// posterior covariance (estimate projection: x <- x + P e_beta (beta_min - beta) / P_beta,
  /// the minimum-P^-1-distance point on the constraint); P is kept.
  double beta_min = 0.0;
  /// Model mismatch: a step whose update is refused because the gate rejected all but a few
  /// observations, or that gates more than half of them, is taken again from the previous
  /// posterior with the motion's process noise multiplied by mismatch_factor, up to
  /// mismatch_retries times (factor, factor^2, ...): the state was further than its covariance
  /// said (a fast or sudden motion), and the observations, not the stale prior, must decide. The
  /// factor used is reported (FrameStats::q_scale); a step taken again uses the iterated update
  /// (at least 5 iterations). 0 retries: the published filter.
  int mismatch_retries = 0;
  double mismatch_factor = 10.0;
  /// Process noise adapted to the motion the filter measures (issue 14 item 4; docs/filter.md,
  /// "Process noise from the data"). The model's dynamics are the identity (a random walk on the
  /// pose), so the prediction error of one frame is that frame's whole motion delta = x+ - x-
  /// (t_X, t_Y, t_Z beta, omega): the matched process noise is its second moment E[delta delta^T]
  /// (covariance matching, [MS99]). q_motion is taken as the *shape* Q0 of each block (translation,
  /// rotation) and each block's scale s is matched to the motion it measured:
  ///   z = sum_i delta_i^2 / Q0_i over the block's 3 components (z = 1 for a motion of one
  ///       Q0 sd along one axis),
  ///   m <- (1 - a) m + a z, a = 2 / (window + 1) (an exponential window of ~`window` frames),
  ///   Q_block = Q0_block clamp(inflation m, floor, ceiling).
  /// Summing the 3 components makes each component's variance cover the whole motion (a rotation
  /// about one axis is not under-covered by isotropic noise). The first step uses Q0 itself (the
  /// motion the start measured); m starts at 1 (that motion), so the next steps' scale starts
  /// near `inflation`. (Starting at inflation x Q0 instead changed the start chosen on box.mp4's
  /// window at frame 4 and on webcam-object, both for the worse: docs/regimes.md.) Only steps
  /// whose update was applied and healthy feed m. A step taken again on a model mismatch uses
  /// max(s, 1) x mismatch_factor^attempt per block, so a still stretch's small s does not leave
  /// the retries below Q0. Off: q_motion as given every frame (the published filter).
  struct Adaptation {
    bool enabled = false;
    int window = 10;         ///< frames of the exponential window (a = 2 / (window + 1))
    double floor = 1e-2;     ///< smallest scale of Q0 (sd >= 10 % of Q0's: a still stretch)
    double ceiling = 1e4;    ///< largest scale of Q0 (sd <= 100 x Q0's)
    double inflation = 1.0;  ///< the matched second moment's multiplier (the pipeline: 4, an sd twice the motion)
  } adapt;
};

/// One reference position's refinement (ReferenceModel::Refine), information form:
/// S = s2 I + H P+ H^T (given as `HPHt`), C^-1 <- C^-1 + Hu^T S^-1 Hu,
/// uv <- uv + C Hu^T S^-1 r with r = z - h. Leaves `uv` and `C` unchanged and returns false
/// when the result is not finite.
inline bool refineReference(const Eigen::Matrix2d& HPHt, double s2, const Eigen::Matrix2d& Hu,
                            const Eigen::Vector2d& r, Eigen::Vector2d* uv, Eigen::Matrix2d* C) {
  // The back-transferred observation is uncertain through the pixel noise and the state.
  const Eigen::Matrix2d Si = (s2 * Eigen::Matrix2d::Identity() + HPHt).inverse();
  const Eigen::Matrix2d Cn = (C->inverse() + Hu.transpose() * Si * Hu).inverse();
  const Eigen::Vector2d step = Cn * (Hu.transpose() * Si * r);
  if (!Cn.allFinite() || !step.allFinite()) return false;
  *uv += step;
  *C = 0.5 * (Cn + Cn.transpose());
  return true;
}

/// ReferenceModel::Refine after an applied update, for any filter: every accepted observation
/// (`used[b]` not gated) refines its point's reference position with refineReference at the
/// posterior. `measure(id, &h, &HPHt, &Hu)` predicts observation `id` at the posterior with
/// H P+ H^T (2 x 2, H its state Jacobian) and dh/d(u, v)^1 (Hu); false skips it.
template <class Model, class Measure>
void refineReferencesAt(Model& model, const std::vector<Observation>& obs, const std::vector<int>& used,
                        const std::vector<std::uint8_t>& gated, double s2, std::vector<Eigen::Matrix2d>* ref_cov,
                        const Measure& measure) {
  for (size_t b = 0; b < used.size(); ++b) {
    if (b < gated.size() && gated[b]) continue;
    const Observation& o = obs[used[b]];
    Eigen::Vector2d h;
    Eigen::Matrix2d HPHt, Hu;
    if (!measure(o.id, &h, &HPHt, &Hu)) continue;
    Eigen::Vector2d uv = model.reference(o.id);
    if (refineReference(HPHt, s2, Hu, o.uv - h, &uv, &(*ref_cov)[o.id])) model.setReference(o.id, uv);
  }
}

/// What one frame did.
struct FrameStats {
  UpdateStats update;
  int iterations = 0;  ///< measurement linearizations used (1 for the plain EKF)
  int invalid = 0;  ///< observations whose prediction failed (see MeasureStatus), not used
  MeasureStatus first_problem = MeasureStatus::Ok;
  bool beta_projected = false;  ///< the update left beta < FilterOptions::beta_min (projected)
  std::uint32_t health = kHealthy;  ///< EKF health after the step (HealthFlag bits)
  double q_scale = 1.0;  ///< the motion process noise's multiplier this step (FilterOptions::mismatch_retries)
  /// Multipliers of q_motion's translation and rotation blocks used this step (adaptation and
  /// mismatch retries together; without adaptation both equal q_scale).
  double q_translation_scale = 1.0, q_rotation_scale = 1.0;
  /// Observation index (into step()'s argument) of each measurement block; update.gated_mask
  /// is aligned with it.
  std::vector<int> used;
  bool ok() const { return health == kHealthy && update.applied; }
};

template <class Model>
class RecursiveFilter {
 public:
  RecursiveFilter(Model model, Ekf ekf, FilterOptions options)
      : model_(std::move(model)), ekf_(std::move(ekf)), opt_(options) {
    opt_.update.min_blocks = std::max(opt_.update.min_blocks, Model::kMinPoints);
    if (opt_.reference == ReferenceModel::State) {
      const int N = model_.numPoints();
      ref_index_ = ekf_.size();
      Eigen::VectorXd r(2 * N);
      for (int i = 0; i < N; ++i) r.template segment<2>(2 * i) = model_.reference(i);
      const double s2 = referenceSigma() * referenceSigma();
      ekf_.augment(r, Eigen::MatrixXd::Identity(2 * N, 2 * N) * s2, Eigen::MatrixXd::Zero(2 * N, ref_index_));
    }
  }

  /// One frame. The statistics live in the filter until the next step (no allocation per frame
  /// once the filter has seen its largest frame, with the plain update: issue 15).
  const FrameStats& step(const std::vector<Observation>& obs) {
    ensureReferenceCovariances();
    const std::vector<Eigen::Matrix2d>* rc =
        opt_.reference == ReferenceModel::Exact || opt_.reference == ReferenceModel::State ? nullptr : &ref_cov_;
    ++steps_;
    const bool warm = steps_ <= opt_.warmup_frames;
    const int iterations = warm                                  ? std::max(opt_.iterations, opt_.warmup_iterations)
                           : steps_ <= opt_.iterate_after_frames ? 1
                                                                 : opt_.iterations;
    if (ref_index_ >= 0 && 2 * model_.numPoints() != ekf_.size() - ref_index_)
      throw std::logic_error("reference positions in the state: points cannot be added after the filter is built");
    FrameStats& fs = fs_;
    // The previous posterior, for a step taken again on a model mismatch.
    if (opt_.mismatch_retries > 0) {
      x_post_ = ekf_.x();
      P_post_ = ekf_.P();
    }
    double q_scale = 1.0;
    const Eigen::Matrix<double, 6, 1> motion_before = ekf_.x().template head<6>();
    if (opt_.reference == ReferenceModel::Conditional) {
      // The references conditional on the predicted state (a retry's larger noise is not
      // followed here: its prior is the same mean, only wider).
      fillProcessNoise(0, 1.0, &fs);
      conditionalPredict();
      cond_center_ = ekf_.x();
    }
    for (int attempt = 0;; ++attempt) {
      fs.iterations = 1;
      fs.invalid = 0;
      fs.first_problem = MeasureStatus::Ok;
      fs.beta_projected = false;
      fs.health = kHealthy;
      fs.q_scale = q_scale;
      fillProcessNoise(attempt, q_scale, &fs);
      ekf_.predict(q_);
      linearize(ekf_.x(), obs, rc, &batch_, &fs.invalid, &fs.first_problem, &fs.used);
      x_prior_ = ekf_.x();
      P_prior_ = ekf_.P();
      ekf_.update(batch_, opt_.update, &fs.update);
      // A step taken again is iterated (the prior is far from the data's optimum: one
      // linearization at the prior overshoots).
      const int it = attempt > 0 ? std::max({iterations, opt_.warmup_iterations, 5}) : iterations;
      if (it > 1 && fs.update.applied) iterate(it, obs, rc, &fs);
      const UpdateStats& u = fs.update;
      const bool refused_by_gate = !u.applied && (u.health & kTooFewMeasurements) && u.gated > 0 &&
                                   u.blocks >= opt_.update.min_blocks;
      const bool mostly_gated = u.applied && 2 * u.gated > u.blocks;
      if (attempt >= opt_.mismatch_retries || !(refused_by_gate || mostly_gated)) break;
      ekf_.mutableX() = x_post_;
      ekf_.mutableP() = P_post_;
      q_scale *= opt_.mismatch_factor;
    }
    fs.health = ekf_.health() | (fs.update.health & ~kTooFewMeasurements);
    if (opt_.beta_min > 0.0 && fs.update.applied) fs.beta_projected = ekf_.projectLowerBound(idx::kBeta, opt_.beta_min);
    const Eigen::Vector3d omega = ekf_.x().template segment<3>(idx::kWx);
    if (!incrementalRotationValid(omega)) {
      // The update moved omega out of dq's domain (|omega| >= 2): roll it back and report.
      ekf_.mutableX() = x_prior_;
      ekf_.mutableP() = P_prior_;
      syncReferences(x_prior_);
      fs.update.applied = false;
      fs.health |= kInvalidRotation;
      return fs;
    }
    if (opt_.adapt.enabled && fs.update.applied && fs.health == kHealthy) adaptProcessNoise(motion_before);
    if (opt_.reference == ReferenceModel::Refine && fs.update.applied && fs.health == kHealthy)
      refineReferences(obs, fs.used, fs.update.gated_mask);
    if (opt_.reference == ReferenceModel::Conditional && fs.update.applied && fs.health == kHealthy)
      conditionalUpdate(obs, rc, &fs);
    syncReferences(ekf_.x());
    // R^k = R(dq(omega)) R^{k-1} ([AS99] appendix).
    Rg_ = incrementalRotation(omega) * Rg_;
    if (opt_.reading == RotationReading::Reset) ekf_.mutableX().template segment<3>(idx::kWx).setZero();
    return fs;
  }

  /// ReferenceModel::Conditional: point `id`'s reference is a function of the current state, not
  /// a measurement of its own (a point that joins after the reference frame, its reference
  /// transferred through the state's plane and motion): u_id | x ~ N(u_id + G (x - x^), C), G
  /// 2 x n (n the state's size now), C its spread given the state. The point then takes part in
  /// the conditionals from the next step as one the last update saw (conditionalPredict carries G
  /// through the process noise; a frame that does not observe it marginalizes it, C += G P G^T).
  /// Other reference models: nothing is done. docs/filter.md, "Points that join later".
  void setConditionalReference(int id, const Eigen::Ref<const Eigen::MatrixXd>& G, const Eigen::Matrix2d& C) {
    if (opt_.reference != ReferenceModel::Conditional) return;
    if (id < 0 || id >= model_.numPoints() || G.rows() != 2 || G.cols() != ekf_.size())
      throw std::invalid_argument("RecursiveFilter::setConditionalReference: point or G's size does not match");
    ensureReferenceCovariances();
    ensureConditional();
    // G is taken at the current state, which is where the next step centres the conditionals
    // (step: cond_center_ = x after the prediction; the reset reading's omega fold and a plane
    // added since the last update change x's parametrization, not the estimate).
    cond_G_.template middleRows<2>(2 * id) = G;
    ref_cov_[static_cast<std::size_t>(id)] = C;
    if (std::find(cond_active_.begin(), cond_active_.end(), id) == cond_active_.end()) cond_active_.push_back(id);
  }

  /// Starts again from state (x, P) with global rotation Rg (the steps count from 0 again), keeping
  /// the model and the work space: a second pass over the same frames, or a benchmark's repeated
  /// frame, allocates nothing.
  void restart(const Eigen::VectorXd& x, const Eigen::MatrixXd& P, const Eigen::Matrix3d& Rg) {
    if (x.size() != ekf_.size() || P.rows() != ekf_.size() || P.cols() != ekf_.size())
      throw std::invalid_argument("RecursiveFilter::restart: state size differs from the filter's");
    ekf_.mutableX() = x;
    ekf_.mutableP() = P;
    Rg_ = Rg;
    steps_ = 0;
    // ReferenceModel::Conditional: the references' dependence on the old state is dropped.
    for (int id : cond_active_) cond_G_.template middleRows<2>(2 * id).setZero();
    cond_active_.clear();
    adapt_mean_.setOnes();
    adapt_scale_.setOnes();
    syncReferences(ekf_.x());
  }

  const Model& model() const { return model_; }
  Model& mutableModel() { return model_; }
  const Ekf& ekf() const { return ekf_; }
  Ekf& mutableEkf() { return ekf_; }
  const FilterOptions& options() const { return opt_; }
  /// R^k: reference frame -> current camera (after the last step).
  const Eigen::Matrix3d& rotation() const { return Rg_; }
  /// (t_X, t_Y, t_Z) in scene units (t_Z = state[2] / beta).
  Eigen::Vector3d translation() const {
    const auto& x = ekf_.x();
    return {x[idx::kTx], x[idx::kTy], x[idx::kTzB] / x[idx::kBeta]};
  }
  double beta() const { return ekf_.x()[idx::kBeta]; }
  /// Covariance of each point's reference position (normalized units^2).
  const std::vector<Eigen::Matrix2d>& referenceCovariances() const { return ref_cov_; }

 private:
  double referenceSigma() const {
    return opt_.reference_sigma >= 0.0 ? opt_.reference_sigma : opt_.sigma_uv;
  }
  /// ReferenceModel::State: the model's reference positions from the state x.
  void syncReferences(const Eigen::VectorXd& x) {
    if (ref_index_ < 0) return;
    for (int i = 0; i < model_.numPoints(); ++i) model_.setReference(i, x.template segment<2>(ref_index_ + 2 * i));
  }
  /// The model's linearization at x; with the references in the state, at x's references, with
  /// each block's dh/d(u, v)^1 in their columns.
  void linearize(const Eigen::VectorXd& x, const std::vector<Observation>& obs, const std::vector<Eigen::Matrix2d>* rc,
                 BlockBatch* batch, int* invalid, MeasureStatus* problem, std::vector<int>* used) {
    syncReferences(x);
    if (opt_.reference != ReferenceModel::Conditional) {
      model_.linearize(x, Rg_, obs, opt_.sigma_uv, rc, batch, invalid, problem, used, ref_index_);
      return;
    }
    // ReferenceModel::Conditional: the references at x (u_i + G_i (x - x^)), each block's
    // Jacobian the total one H_i + Hu_i G_i (every state column: through G_i a point's reference
    // depends on the whole state), Hu_i kept for the update of the references.
    ensureConditional();
    const int n = ekf_.size();
    const bool shifted = x.size() == cond_center_.size() && x != cond_center_;
    if (shifted) {
      cond_saved_.resize(model_.numPoints());
      cond_d_ = x - cond_center_;
      for (int id : cond_active_) {
        cond_saved_[id] = model_.reference(id);
        model_.setReference(id, cond_saved_[id] + cond_G_.template middleRows<2>(2 * id) * cond_d_);
      }
    }
    if (cond_hu_.size() < obs.size()) {
      cond_hu_.resize(obs.size());
      cond_ids_.resize(obs.size());
    }
    linearizeObservations(model_, x, Rg_, obs, opt_.sigma_uv, rc, &cond_compact_, invalid, problem, used, -1, CondHook{this});
    if (shifted)
      for (int id : cond_active_) model_.setReference(id, cond_saved_[id]);
    batch->reserve(cond_compact_.blocks, 2, n, 0);
    if (n == kOnePlaneWidth) conditionalAssemble<kOnePlaneWidth>(batch);
    else conditionalAssemble<Eigen::Dynamic>(batch);
  }
  // ReferenceModel::Conditional's per-point loops, with the state's width W known at compile time
  // for the one-plane model (10) and dynamic otherwise.
  static constexpr int kOnePlaneWidth = detail::kConditionalKernelWidth;  // 7 + 3 (the vector kernels' width)
  template <int W>
  using CondRows = Eigen::Map<Eigen::Matrix<double, 2, W, Eigen::RowMajor>, 0, Eigen::OuterStride<>>;
  /// A point's gain G_i (rows 2i, 2i + 1 of cond_G_, whose rows are n = cond_G_.cols() long, so
  /// the two rows are 2n contiguous numbers); with W fixed (n == W) a map of a fixed 2 x W block,
  /// whose products Eigen unrolls into packets (the strided map's went coefficient by
  /// coefficient: 718 -> 650 us per frame at N = 3000 in BM_SideBySide_rsfm/3000/3).
  template <int W>
  using CondGain = std::conditional_t<W == Eigen::Dynamic, CondRows<W>, Eigen::Map<Eigen::Matrix<double, 2, W, Eigen::RowMajor>>>;
  template <int W>
  CondGain<W> condGain(int id) {
    const Eigen::Index n = cond_G_.cols();
    if constexpr (W == Eigen::Dynamic) return CondRows<W>(cond_G_.data() + 2 * id * n, 2, n, Eigen::OuterStride<>(n));
    else return CondGain<W>(cond_G_.data() + 2 * id * n);
  }
  template <int W>
  CondRows<W> batchRows(BlockBatch* batch, int b) {
    const Eigen::Index n = batch->width(), stride = batch->J.cols();
    return CondRows<W>(batch->J.data() + 2 * b * stride, 2, n, Eigen::OuterStride<>(stride));
  }
  /// The dense batch of total Jacobians H_i + Hu_i G_i from the compact one.
  template <int W>
  void conditionalAssemble(BlockBatch* batch) {
    constexpr int S = Model::kStructurePerPoint;
    const BlockBatch& c = cond_compact_;
    bool vector_kernel = false;
    if constexpr (W == kOnePlaneWidth && S == 3) vector_kernel = detail::conditionalKernelsEnabled();
    for (int b = 0; b < c.blocks; ++b) {
      if (vector_kernel && c.cols(b, 0) == 7 && c.cols(b, 1) == 8 && c.cols(b, 2) == 9) {
        // The compact row is then the dense one's H (structure in the state's columns 7-9).
        double* j0 = batch->J.data() + 2 * static_cast<Eigen::Index>(b) * batch->J.cols();
        const double* h0 = c.J.data() + 2 * static_cast<Eigen::Index>(b) * c.J.cols();
        detail::conditionalAssemble10(j0, j0 + batch->J.cols(), h0, h0 + c.J.cols(), cond_hu_[b].data(),
                                      condGain<W>(cond_ids_[b]).data());
      } else {
        CondRows<W> J = batchRows<W>(batch, b);
        J.noalias() = cond_hu_[b] * condGain<W>(cond_ids_[b]);
        J.template leftCols<7>() += c.J.template block<2, 7>(2 * b, 0);
        for (int j = 0; j < S; ++j) J.col(c.cols(b, j)) += c.J.col(7 + j).template segment<2>(2 * b);
      }
      batch->residual.template segment<2>(2 * b) = c.residual.template segment<2>(2 * b);
      batch->R.template block<2, 2>(2 * b, 0) = c.R.template block<2, 2>(2 * b, 0);
    }
    batch->blocks = c.blocks;
  }
  /// The process noise's step on every conditional (motion-only noise).
  template <int W>
  void conditionalPredictMotion() {
    if constexpr (W == kOnePlaneWidth) {
      if (detail::conditionalKernelsEnabled()) {
        detail::conditionalPredict10(cond_G_.data(), ref_cov_.data(), cond_active_.data(), static_cast<int>(cond_active_.size()),
                                     cond_M_.data(), cond_Sig_.data());
        return;
      }
    }
    const Eigen::Matrix<double, 6, 6> Sig = cond_Sig_;
    const Eigen::Map<const Eigen::Matrix<double, 6, W>> M(cond_M_.data(), 6, cond_M_.cols());  // nq = 6 rows
    for (int id : cond_active_) {
      CondGain<W> G = condGain<W>(id);
      const Eigen::Matrix<double, 2, 6> Gq = G.template leftCols<6>();
      G.noalias() -= Gq * M;
      const Eigen::Matrix<double, 2, 6> GS = Gq * Sig;
      ref_cov_[id].noalias() += GS * Gq.transpose();
    }
  }
  /// The conditionals' update over the blocks of the last linearization (batch_), d = x+ - x^.
  template <int W>
  void conditionalUpdateBlocks(const std::vector<Observation>& obs) {
    bool vector_kernel = false;
    if constexpr (W == kOnePlaneWidth) vector_kernel = detail::conditionalKernelsEnabled();
    const Eigen::Map<const Eigen::Matrix<double, W, 1>> d(cond_d_.data(), cond_d_.size());
    for (size_t b = 0; b < cond_used_.size(); ++b) {
      const int k = cond_used_[b];
      const int id = obs[k].id;
      cond_seen_[id] = 1;
      CondGain<W> G = condGain<W>(id);
      if (!cond_accepted_[k]) {  // gated: only carried to the new mean
        model_.setReference(id, model_.reference(id) + G * d);
        continue;
      }
      const Eigen::Matrix2d& Hu = cond_hu_[b];
      const Eigen::Matrix2d D = batch_.R.template block<2, 2>(2 * b, 0);
      Eigen::Matrix2d& C = ref_cov_[id];
      // K = C Hu^T D^-1 (D = sigma^2 I + Hu C Hu^T is positive definite).
      const Eigen::Matrix2d K = (D.inverse() * Hu * C).transpose();
      const Eigen::Matrix2d Cn = C - K * Hu * C;
      if (!std::isfinite(K.sum() + Cn.sum())) continue;  // one test for any NaN or Inf in either
      Eigen::Vector2d gd;  // G d after G's update
      if (vector_kernel) {
        const double* a0 = batch_.J.data() + 2 * static_cast<Eigen::Index>(b) * batch_.J.cols();
        detail::conditionalGainUpdate10(G.data(), a0, a0 + batch_.J.cols(), K.data(), cond_d_.data(), gd.data());
      } else {
        if constexpr (W != Eigen::Dynamic) {
          const Eigen::Matrix<double, 2, W, Eigen::RowMajor> A = batchRows<W>(&batch_, static_cast<int>(b));
          G.noalias() -= K * A;
        } else {
          G.noalias() -= K * batchRows<W>(&batch_, static_cast<int>(b));
        }
        gd.noalias() = G * d;
      }
      model_.setReference(id, model_.reference(id) + K * batch_.residual.template segment<2>(2 * b) + gd);
      C = 0.5 * (Cn + Cn.transpose());
    }
  }
  /// FilterOptions::Adaptation after an applied step: the frame's motion delta (t_X, t_Y, t_Z beta,
  /// omega; the prior was `before`, identity dynamics) in units of Q0, per block, into the
  /// exponential window's mean; the next step's scales follow.
  void adaptProcessNoise(const Eigen::Matrix<double, 6, 1>& before) {
    const Eigen::Matrix<double, 6, 1> d = ekf_.x().template head<6>() - before;
    const double a = 2.0 / (std::max(opt_.adapt.window, 1) + 1.0);
    for (int b = 0; b < 2; ++b) {
      double z = 0.0;
      bool any = false;
      for (int i = 3 * b; i < 3 * b + 3; ++i)
        if (opt_.q_motion[i] > 0.0) {
          z += d[i] * d[i] / opt_.q_motion[i];
          any = true;
        }
      if (!any || !std::isfinite(z)) continue;
      adapt_mean_[b] = (1.0 - a) * adapt_mean_[b] + a * z;
      adapt_scale_[b] = std::clamp(opt_.adapt.inflation * adapt_mean_[b], opt_.adapt.floor, opt_.adapt.ceiling);
    }
  }
  void ensureReferenceCovariances() {
    const double s2 = referenceSigma() * referenceSigma();
    while (static_cast<int>(ref_cov_.size()) < model_.numPoints())
      ref_cov_.push_back(Eigen::Matrix2d::Identity() * s2);
  }
  /// The process noise of one attempt of a step into q_ (and its scales into fs).
  void fillProcessNoise(int attempt, double q_scale, FrameStats* fs) {
    q_.setConstant(ekf_.size(), opt_.q_structure);
    if (opt_.adapt.enabled) {
      // FilterOptions::Adaptation: each block at its matched scale; a retry at least Q0 x factor^attempt.
      fs->q_translation_scale = attempt == 0 ? adapt_scale_[0] : std::max(adapt_scale_[0], 1.0) * q_scale;
      fs->q_rotation_scale = attempt == 0 ? adapt_scale_[1] : std::max(adapt_scale_[1], 1.0) * q_scale;
      q_.template head<3>() = opt_.q_motion.template head<3>() * fs->q_translation_scale;
      q_.template segment<3>(3) = opt_.q_motion.template segment<3>(3) * fs->q_rotation_scale;
      q_[6] = opt_.q_motion[6] * q_scale;
    } else {
      fs->q_translation_scale = fs->q_rotation_scale = q_scale;
      q_.template head<7>() = opt_.q_motion * q_scale;
    }
  }

  // ReferenceModel::Conditional ---------------------------------------------------------------
  /// linearizeObservations' hook: keeps Hu_i and the point of each block.
  struct CondHook {
    RecursiveFilter* f;
    static constexpr bool kNeedsHu = true;
    void operator()(int b, int id, const Eigen::Matrix2d& Hu, BlockBatch*) const {
      f->cond_hu_[b] = Hu;
      f->cond_ids_[b] = id;
    }
  };
  /// G's layout follows the state (a plane added: zero columns) and the points (new: zero rows;
  /// room doubles, so adding points allocates rarely).
  void ensureConditional() {
    const int n = ekf_.size(), rows = 2 * model_.numPoints();
    const int old_rows = static_cast<int>(cond_G_.rows()), old_cols = static_cast<int>(cond_G_.cols());
    if (old_cols == n && old_rows >= rows) return;
    const int new_rows = old_rows >= rows ? old_rows : std::max(rows, 2 * old_rows);
    cond_G_.conservativeResize(new_rows, n);
    if (n > old_cols) cond_G_.rightCols(n - old_cols).setZero();
    if (new_rows > old_rows) cond_G_.bottomRows(new_rows - old_rows).setZero();
  }
  /// The identity dynamics' process noise x' = x + w (w ~ N(0, Q), q_ on the free components)
  /// carried into the references' conditionals: E[x | x'] = x^ + J (x' - x^), J = P (P + Q)^-1
  /// = I - Q (P + Q)^-1, so G_i <- G_i - G_i Q (P + Q)^-1 (only the noisy components' columns
  /// of G_i enter); the rest of x's spread given x', P - J P = P (P + Q)^-1 Q (supported on the
  /// noisy components), reaches u_i through G_i and is added to C_i as if independent between
  /// points (the one approximation).
  void conditionalPredict() {
    ensureConditional();
    if (cond_active_.empty()) return;
    const Eigen::MatrixXd& P = ekf_.P();
    const int n = ekf_.size();
    const auto& fixed = ekf_.fixed();
    cond_free_.clear();
    cond_q_.clear();
    for (int i = 0; i < n; ++i) {
      if (i < static_cast<int>(fixed.size()) && fixed[i]) continue;
      if (P(i, i) + q_[i] > 0.0) cond_free_.push_back(i);
      if (q_[i] > 0.0) cond_q_.push_back(i);
    }
    const int nf = static_cast<int>(cond_free_.size()), nq = static_cast<int>(cond_q_.size());
    if (nq == 0) return;
    cond_W_.resize(nf, nf);
    for (int a = 0; a < nf; ++a)
      for (int b = 0; b < nf; ++b) cond_W_(a, b) = P(cond_free_[a], cond_free_[b]) + (a == b ? q_[cond_free_[a]] : 0.0);
    cond_ldlt_.compute(cond_W_);
    if (cond_ldlt_.info() != Eigen::Success) return;
    // Columns of the noisy components: E = W^-1 Q e_q (nf x nq).
    cond_E_.setZero(nf, nq);
    for (int a = 0, c = 0; a < nf && c < nq; ++a)
      if (cond_free_[a] == cond_q_[c]) {  // both lists ascend, and every noisy component is free
        cond_E_(a, c) = q_[cond_q_[c]];
        ++c;
      }
    cond_ldlt_.solveInPlace(cond_E_);
    // M = (Q W^-1) rows q (nq x n, zero on the other columns), Sig = P W^-1 Q at (q, q).
    cond_M_.setZero(nq, n);
    for (int a = 0; a < nf; ++a)
      for (int c = 0; c < nq; ++c) cond_M_(c, cond_free_[a]) = cond_E_(a, c);
    cond_Sig_.setZero(nq, nq);
    for (int c = 0; c < nq; ++c)
      for (int d = 0; d < nq; ++d) {
        double v = 0.0;
        for (int a = 0; a < nf; ++a) v += P(cond_q_[c], cond_free_[a]) * cond_E_(a, d);
        cond_Sig_(c, d) = v;
      }
    for (int c = 0; c < nq; ++c)  // symmetric in exact arithmetic
      for (int d = 0; d < c; ++d) cond_Sig_(c, d) = cond_Sig_(d, c) = 0.5 * (cond_Sig_(c, d) + cond_Sig_(d, c));
    bool motion_only = nq == 6;  // the usual case: noise on the 6 motion components alone
    for (int c = 0; motion_only && c < 6; ++c) motion_only = cond_q_[c] == c;
    if (motion_only) {
      if (n == kOnePlaneWidth) conditionalPredictMotion<kOnePlaneWidth>();
      else conditionalPredictMotion<Eigen::Dynamic>();
      return;
    }
    cond_Gq_.resize(2, nq);
    for (int id : cond_active_) {
      auto G = cond_G_.template middleRows<2>(2 * id);
      for (int c = 0; c < nq; ++c) cond_Gq_.col(c) = G.col(cond_q_[c]);
      G.noalias() -= cond_Gq_ * cond_M_;
      cond_GS_.noalias() = cond_Gq_ * cond_Sig_;
      ref_cov_[id].noalias() += cond_GS_ * cond_Gq_.transpose();
    }
  }
  /// After an applied update: each observed point's reference conditional on the state given its
  /// observation (ReferenceModel::Conditional), gated ones carried to the new mean, and points
  /// not observed leave the conditional form.
  void conditionalUpdate(const std::vector<Observation>& obs, const std::vector<Eigen::Matrix2d>* rc, FrameStats* fs) {
    const Eigen::VectorXd& x = ekf_.x();
    const Eigen::MatrixXd& P = ekf_.P();
    const int np = model_.numPoints();
    cond_seen_.assign(np, 0);
    // Accepted observations (by observation index) of the update.
    cond_accepted_.assign(obs.size(), 0);
    for (size_t b = 0; b < fs->used.size(); ++b)
      if (b >= fs->update.gated_mask.size() || !fs->update.gated_mask[b]) cond_accepted_[fs->used[b]] = 1;
    if (fs->iterations > 1) {
      // The iterated update's last linearization is not batch_: carry every reference to the
      // posterior and linearize there (the innovations are then the posterior residuals).
      cond_d_ = x - cond_center_;
      for (int id : cond_active_)
        model_.setReference(id, model_.reference(id) + cond_G_.template middleRows<2>(2 * id) * cond_d_);
      cond_center_ = x;
      int invalid = 0;
      MeasureStatus problem = MeasureStatus::Ok;
      linearize(x, obs, rc, &batch_, &invalid, &problem, &cond_used_);
    } else {
      cond_used_ = fs->used;
    }
    cond_d_ = x - cond_center_;
    const Eigen::VectorXd& d = cond_d_;
    if (x.size() == kOnePlaneWidth) conditionalUpdateBlocks<kOnePlaneWidth>(obs);
    else conditionalUpdateBlocks<Eigen::Dynamic>(obs);
    // Points of the last frame not observed in this one: marginalized over the state.
    for (int id : cond_active_) {
      if (id < np && cond_seen_[id]) continue;
      auto G = cond_G_.template middleRows<2>(2 * id);
      if (fs->iterations <= 1) model_.setReference(id, model_.reference(id) + G * d);
      cond_GP_.noalias() = G * P;
      ref_cov_[id].noalias() += cond_GP_ * G.transpose();
      G.setZero();
    }
    cond_active_.clear();
    for (size_t b = 0; b < cond_used_.size(); ++b) cond_active_.push_back(obs[cond_used_[b]].id);
    cond_center_ = x;
  }
  /// Iterated EKF with backtracking (FilterOptions::iterations > 1). Gauss-Newton on the MAP cost
  ///   J(x) = sum_b r_b(x)^T R_b^-1 r_b(x) + (x - x^-)^T P^-^-1 (x - x^-)
  /// over the observations accepted by the first update (rsfm::iteratedUpdate, 4 step sizes): each
  /// GN point comes from an update of the prior linearized at the current iterate (residual
  /// shifted by H_i (x_i - x^-)); the step towards it is halved (up to 3 times) until J decreases,
  /// so the first step is a damped EKF step. Stops on a step below iteration_tol, or when no step
  /// decreases J (the iterate is kept). The covariance is the one from the last linearization.
  void iterate(int iterations, const std::vector<Observation>& obs, const std::vector<Eigen::Matrix2d>* rc,
               FrameStats* fs) {
    const Eigen::VectorXd& x_prior = x_prior_;
    const Eigen::MatrixXd& P_prior = P_prior_;
    std::vector<int>* used = &fs->used;
    std::vector<char> accepted(obs.size(), 0);
    for (size_t b = 0; b < used->size(); ++b)
      if (b >= fs->update.gated_mask.size() || !fs->update.gated_mask[b]) accepted[(*used)[b]] = 1;
    const int invalid0 = fs->invalid;
    BlockBatch work;
    std::vector<int> u;
    auto cost = [&](const Eigen::VectorXd& x, double* out) {
      int inv = 0;
      MeasureStatus pr = MeasureStatus::Ok;
      linearize(x, obs, rc, &work, &inv, &pr, &u);
      if (inv > invalid0 || !work.residual.head(work.rows()).allFinite()) return false;
      double c = 0.0;
      for (size_t k = 0; k < u.size(); ++k) {
        if (!accepted[u[k]]) continue;
        const Eigen::Vector2d r = work.residual.template segment<2>(2 * k);
        const Eigen::Matrix2d R = work.R.template block<2, 2>(2 * k, 0);
        c += r.dot(R.ldlt().solve(r));
      }
      *out = c;
      return true;
    };
    // The statistics and blocks of the latest Gauss-Newton point (reported with its P).
    UpdateStats st_gn = fs->update;
    std::vector<int> used_gn = *used;
    UpdateStats st;
    auto gaussNewtonPoint = [&](const Eigen::VectorXd& x_lin) {
      int invalid = 0;
      MeasureStatus problem = MeasureStatus::Ok;
      linearize(x_lin, obs, rc, &work, &invalid, &problem, &u);
      if (invalid > invalid0) return false;
      work.shiftResidual(x_lin - x_prior);
      ekf_.mutableX() = x_prior;
      ekf_.mutableP() = P_prior;
      ekf_.update(work, opt_.update, &st);
      if (!st.applied) return false;
      st_gn = st;
      used_gn = u;
      return true;
    };
    const int n = iteratedUpdate(&ekf_, iterations, opt_.iteration_tol, 4, x_prior, P_prior, cost, gaussNewtonPoint);
    if (n == 0) return;  // keep the plain EKF update
    fs->update = st_gn;
    *used = used_gn;
    fs->iterations = n;
  }

  /// ReferenceModel::Refine: H P+ H^T from the compact Jacobian (the motion block and the
  /// point's structure columns), no dense row per observation.
  void refineReferences(const std::vector<Observation>& obs, const std::vector<int>& used,
                        const std::vector<std::uint8_t>& gated) {
    constexpr int S = Model::kStructurePerPoint;
    const MotionContext m = MotionContext::fromState(ekf_.x(), Rg_);
    const Eigen::MatrixXd& P = ekf_.P();
    refineReferencesAt(model_, obs, used, gated, opt_.sigma_uv * opt_.sigma_uv, &ref_cov_,
                       [&](int id, Eigen::Vector2d* h, Eigen::Matrix2d* HPHt, Eigen::Matrix2d* Hu) {
                         Eigen::Matrix<double, 2, 7> Hm;
                         Eigen::Matrix<double, 2, S> Hs;
                         if (model_.measure(m, ekf_.x(), id, h, &Hm, &Hs, Hu) != MeasureStatus::Ok) return false;
                         const int si = model_.structureIndex(id);
                         const Eigen::Matrix<double, 7, 2> PmH =
                             P.template topLeftCorner<7, 7>() * Hm.transpose() + P.template block<7, S>(0, si) * Hs.transpose();
                         const Eigen::Matrix<double, S, 2> PsH =
                             P.template block<S, 7>(si, 0) * Hm.transpose() + P.template block<S, S>(si, si) * Hs.transpose();
                         *HPHt = Hm * PmH + Hs * PsH;
                         return true;
                       });
  }

  Model model_;
  Ekf ekf_;
  FilterOptions opt_;
  Eigen::Matrix3d Rg_ = Eigen::Matrix3d::Identity();
  std::vector<Eigen::Matrix2d> ref_cov_;
  int ref_index_ = -1;  ///< ReferenceModel::State: first reference column (-1: not in the state)
  int steps_ = 0;  ///< steps taken (warm-up)
  /// FilterOptions::Adaptation: the window's mean of z per block (translation, rotation) and the
  /// scales it gives (both 1 at the start: Q = Q0).
  Eigen::Vector2d adapt_mean_ = Eigen::Vector2d::Ones(), adapt_scale_ = Eigen::Vector2d::Ones();
  // ReferenceModel::Conditional: each point's gain on the state (rows 2i, 2i + 1; every state
  // column), the points in the conditional form (observed in the last frame), the state mean
  // they are centred on, and per-step work space.
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> cond_G_;
  std::vector<int> cond_active_, cond_used_, cond_ids_, cond_free_, cond_q_;
  std::vector<std::uint8_t> cond_seen_, cond_accepted_;
  std::vector<Eigen::Matrix2d> cond_hu_;
  std::vector<Eigen::Vector2d> cond_saved_;
  Eigen::VectorXd cond_center_, cond_d_;
  Eigen::MatrixXd cond_M_, cond_Sig_, cond_W_, cond_E_, cond_Gq_, cond_GS_, cond_GP_;
  Eigen::LDLT<Eigen::MatrixXd> cond_ldlt_;
  BlockBatch cond_compact_;
  // Per-step work space, kept so that a step allocates nothing once warm (issue 15).
  FrameStats fs_;
  BlockBatch batch_;
  Eigen::VectorXd q_, x_post_, x_prior_;
  Eigen::MatrixXd P_post_, P_prior_;
};

}  // namespace rsfm
