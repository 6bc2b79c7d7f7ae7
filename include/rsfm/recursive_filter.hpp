#pragma once
// Frame-by-frame driver shared by the point and plane models (DESIGN.md §1, §3).
// One step = predict (identity dynamics, P += Q) -> linearize all observations -> EKF update ->
// fold the incremental rotation into the global rotation R_g (and zero omega in the reset reading).
#include <Eigen/Core>
#include <Eigen/LU>
#include <cstdint>
#include <string_view>
#include <vector>

#include "rsfm/camera.hpp"
#include "rsfm/ekf.hpp"
#include "rsfm/models/projection.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {

/// How the first-frame (reference) image positions of the points are treated. The A&P and
/// Alon-Sclaroff models take them as exact (seed 000 §2: "a known weakness ... biases the
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
  /// and the cross-covariance is not kept (Beardsley et al.'s per-point remedy, seed ref. [2], in spirit).
  Refine,
};
inline std::string_view toString(ReferenceModel r) {
  return r == ReferenceModel::Exact ? "exact" : r == ReferenceModel::Inflate ? "inflate" : "refine";
}
inline bool parseReferenceModel(std::string_view s, ReferenceModel* out) {
  if (s == "exact") *out = ReferenceModel::Exact;
  else if (s == "inflate") *out = ReferenceModel::Inflate;
  else if (s == "refine") *out = ReferenceModel::Refine;
  else return false;
  return true;
}

/// Filter tuning. Units: normalized image units and scene units of the state (DESIGN.md §1).
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
  /// Each iteration relinearizes h at the latest iterate x_i and applies
  /// x_{i+1} = x^- + K_i (z - h(x_i) - H_i (x^- - x_i)); P from the last linearization.
  int iterations = 1;
  /// Stop iterating when the step |x_{i+1} - x_i| (infinity norm, state units) falls below this.
  double iteration_tol = 1e-9;
};

/// What one frame did.
struct FrameStats {
  UpdateStats update;
  int iterations = 0;  ///< measurement linearizations used (1 for the plain EKF)
  int invalid = 0;  ///< observations whose prediction failed (see MeasureStatus), not used
  MeasureStatus first_problem = MeasureStatus::Ok;
  std::uint32_t health = kHealthy;  ///< EKF health after the step (HealthFlag bits)
  bool ok() const { return health == kHealthy && update.applied; }
};

template <class Model>
class RecursiveFilter {
 public:
  RecursiveFilter(Model model, Ekf ekf, FilterOptions options)
      : model_(std::move(model)), ekf_(std::move(ekf)), opt_(options) {
    opt_.update.min_blocks = std::max(opt_.update.min_blocks, Model::kMinPoints);
  }

  FrameStats step(const std::vector<Observation>& obs) {
    FrameStats fs;
    Eigen::VectorXd q = Eigen::VectorXd::Constant(ekf_.size(), opt_.q_structure);
    q.head<7>() = opt_.q_motion;
    ekf_.predict(q);
    ensureReferenceCovariances();
    const std::vector<Eigen::Matrix2d>* rc =
        opt_.reference == ReferenceModel::Exact ? nullptr : &ref_cov_;
    MeasurementBatch batch;
    std::vector<int> used;
    model_.linearize(ekf_.x(), Rg_, obs, opt_.sigma_uv, rc, &batch, &fs.invalid,
                     &fs.first_problem, &used);
    const Eigen::VectorXd x_prior = ekf_.x();
    const Eigen::MatrixXd P_prior = ekf_.P();
    fs.iterations = 1;
    fs.update = ekf_.update(batch, opt_.update);
    if (opt_.iterations > 1 && fs.update.applied) {
      // Iterated EKF (Gauss-Newton on the measurement): each iteration restores the prior
      // (x^-, P^-) and applies an update linearized at the latest iterate x_i, with the residual
      // shifted by H_i (x_i - x^-). An iteration that fails (leaves the valid region, is not
      // applied) is discarded and the last good iterate is kept.
      Eigen::VectorXd xi = ekf_.x();
      double step = (xi - x_prior).cwiseAbs().maxCoeff();
      for (int it = 1; it < opt_.iterations && step > opt_.iteration_tol; ++it) {
        int invalid = 0;
        MeasureStatus problem = MeasureStatus::Ok;
        MeasurementBatch relin;
        std::vector<int> used_i;
        model_.linearize(xi, Rg_, obs, opt_.sigma_uv, rc, &relin, &invalid, &problem, &used_i);
        if (invalid > fs.invalid) break;  // the iterate left the valid region
        relin.residual += relin.H * (xi - x_prior);
        const Eigen::VectorXd x_good = ekf_.x();
        const Eigen::MatrixXd P_good = ekf_.P();
        ekf_.mutableX() = x_prior;
        ekf_.mutableP() = P_prior;
        UpdateStats st = ekf_.update(relin, opt_.update);
        if (!st.applied) {
          ekf_.mutableX() = x_good;
          ekf_.mutableP() = P_good;
          break;
        }
        fs.update = std::move(st);
        fs.invalid = invalid;
        fs.first_problem = problem;
        used = std::move(used_i);
        fs.iterations = it + 1;
        step = (ekf_.x() - xi).cwiseAbs().maxCoeff();
        xi = ekf_.x();
      }
    }
    fs.health = ekf_.health() | (fs.update.health & ~kTooFewMeasurements);
    const Eigen::Vector3d omega = ekf_.x().template segment<3>(idx::kWx);
    if (!incrementalRotationValid(omega)) {
      // The update moved omega out of dq's domain (|omega| >= 2): roll it back and report.
      ekf_.mutableX() = x_prior;
      ekf_.mutableP() = P_prior;
      fs.update.applied = false;
      fs.health |= kInvalidRotation;
      return fs;
    }
    if (opt_.reference == ReferenceModel::Refine && fs.update.applied && fs.health == kHealthy)
      refineReferences(obs, used, fs.update.gated_mask);
    // R^k = R(dq(omega)) R^{k-1} (seed appendix).
    Rg_ = incrementalRotation(omega) * Rg_;
    if (opt_.reading == RotationReading::Reset) ekf_.mutableX().template segment<3>(idx::kWx).setZero();
    return fs;
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
  void ensureReferenceCovariances() {
    const double s2 = referenceSigma() * referenceSigma();
    while (static_cast<int>(ref_cov_.size()) < model_.numPoints())
      ref_cov_.push_back(Eigen::Matrix2d::Identity() * s2);
  }
  void refineReferences(const std::vector<Observation>& obs, const std::vector<int>& used,
                        const std::vector<std::uint8_t>& gated) {
    const MotionContext m = MotionContext::fromState(ekf_.x(), Rg_);
    const double s2 = opt_.sigma_uv * opt_.sigma_uv;
    const Eigen::MatrixXd& P = ekf_.P();
    for (size_t b = 0; b < used.size(); ++b) {
      if (b < gated.size() && gated[b]) continue;
      const Observation& o = obs[used[b]];
      Eigen::Vector2d h;
      Eigen::Matrix2d Hu;
      Eigen::MatrixXd H;
      if (model_.measure(m, ekf_.x(), o.id, &h, nullptr, nullptr, &Hu) != MeasureStatus::Ok) continue;
      if (model_.measure(ekf_.x(), Rg_, o.id, nullptr, &H) != MeasureStatus::Ok) continue;
      // The back-transferred observation is uncertain through the pixel noise and the state.
      const Eigen::Matrix2d S = s2 * Eigen::Matrix2d::Identity() + H * P * H.transpose();
      const Eigen::Matrix2d Si = S.inverse();
      Eigen::Matrix2d& C = ref_cov_[o.id];
      const Eigen::Matrix2d info = C.inverse() + Hu.transpose() * Si * Hu;
      const Eigen::Matrix2d Cn = info.inverse();
      const Eigen::Vector2d step = Cn * (Hu.transpose() * Si * (o.uv - h));
      if (!Cn.allFinite() || !step.allFinite()) continue;
      model_.setReference(o.id, model_.reference(o.id) + step);
      C = 0.5 * (Cn + Cn.transpose());
    }
  }

  Model model_;
  Ekf ekf_;
  FilterOptions opt_;
  Eigen::Matrix3d Rg_ = Eigen::Matrix3d::Identity();
  std::vector<Eigen::Matrix2d> ref_cov_;
};

}  // namespace rsfm
