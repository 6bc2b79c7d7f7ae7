#pragma once
// Frame-by-frame driver shared by the point and plane models (DESIGN.md §1, §3).
// One step = predict (identity dynamics, P += Q) -> linearize all observations -> EKF update ->
// fold the incremental rotation into the global rotation R_g (and zero omega in the reset reading).
#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "rsfm/camera.hpp"
#include "rsfm/ekf.hpp"
#include "rsfm/models/projection.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {

/// Filter tuning. Units: normalized image units and scene units of the state (DESIGN.md §1).
struct FilterOptions {
  RotationReading reading = RotationReading::Reset;  ///< see rotation.hpp
  /// Measurement standard deviation (normalized units): R = sigma^2 I per point.
  double sigma_uv = 2.0 / 256.0;
  /// Per-frame process variances of (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z, beta).
  Eigen::Matrix<double, 7, 1> q_motion =
      (Eigen::Matrix<double, 7, 1>() << 1e-4, 1e-4, 1e-4, 3e-5, 3e-5, 3e-5, 0.0).finished();
  /// Per-frame process variance of every free structure component (0: static structure).
  double q_structure = 0.0;
  UpdateOptions update;  ///< gating, update form, minimum points (set from the model)
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
    MeasurementBatch batch;
    model_.linearize(ekf_.x(), Rg_, obs, opt_.sigma_uv, &batch, &fs.invalid, &fs.first_problem);
    if (opt_.iterations <= 1) {
      fs.iterations = 1;
      fs.update = ekf_.update(batch, opt_.update);
    } else {
      // Iterated EKF (Gauss-Newton on the measurement): the prior (x^-, P^-) is restored before
      // each relinearized update, whose residual is shifted by H_i (x_i - x^-).
      const Eigen::VectorXd x_prior = ekf_.x();
      const Eigen::MatrixXd P_prior = ekf_.P();
      Eigen::VectorXd xi = x_prior;
      for (int it = 0; it < opt_.iterations; ++it) {
        if (it > 0) {
          int invalid = 0;
          MeasureStatus problem = MeasureStatus::Ok;
          model_.linearize(xi, Rg_, obs, opt_.sigma_uv, &batch, &invalid, &problem);
          if (invalid > fs.invalid) break;  // the iterate left the valid region: keep the last
          batch.residual += batch.H * (xi - x_prior);
          ekf_.mutableX() = x_prior;
          ekf_.mutableP() = P_prior;
        }
        fs.update = ekf_.update(batch, opt_.update);
        fs.iterations = it + 1;
        if (!fs.update.applied) break;
        const double step = (ekf_.x() - xi).cwiseAbs().maxCoeff();
        xi = ekf_.x();
        if (!(step > opt_.iteration_tol)) break;
      }
    }
    fs.health = ekf_.health() | (fs.update.health & ~kTooFewMeasurements);
    const Eigen::Vector3d omega = ekf_.x().template segment<3>(idx::kWx);
    if (!incrementalRotationValid(omega)) {
      fs.health |= kNonFiniteState;
      return fs;
    }
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

 private:
  Model model_;
  Ekf ekf_;
  FilterOptions opt_;
  Eigen::Matrix3d Rg_ = Eigen::Matrix3d::Identity();
};

}  // namespace rsfm
