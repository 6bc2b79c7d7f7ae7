#pragma once
// Frame driver for planes moving independently (IndependentPlanesModel): one global rotation per
// plane, folded from that plane's omega after each update (reset reading, docs/conventions.md),
// identity dynamics plus noise for every plane's motion and the shared beta.
#include <Eigen/Core>
#include <Eigen/LU>
#include <cstdint>
#include <vector>

#include "rsfm/ekf.hpp"
#include "rsfm/models/independent_planes_model.hpp"
#include "rsfm/filters/recursive_filter.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {

struct IndependentFilterOptions {
  double sigma_uv = 2.0 / 256.0;  ///< measurement standard deviation (normalized units)
  /// Per-frame process variances of each plane's (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z).
  Eigen::Matrix<double, 6, 1> q_motion =
      (Eigen::Matrix<double, 6, 1>() << 3e-4, 3e-4, 3e-4, 1e-4, 1e-4, 1e-4).finished();
  double q_beta = 0.0;       ///< per-frame variance of the shared beta
  double q_structure = 0.0;  ///< per-frame variance of every free plane component
  /// Treatment of the reference (first-frame) positions, as in RecursiveFilter (ReferenceModel:
  /// exact as published, inflate R through dh/d(u, v)^1, or also refine each reference after
  /// every update; recursive_filter.hpp and docs/filter.md).
  ReferenceModel reference = ReferenceModel::Exact;
  /// Standard deviation of a reference position (normalized units); < 0: sigma_uv.
  double reference_sigma = -1.0;
  UpdateOptions update;      ///< gating, form (min_blocks: at least 5 points)
};

class IndependentPlanesFilter {
 public:
  IndependentPlanesFilter(IndependentPlanesModel model, Ekf ekf, IndependentFilterOptions options)
      : model_(std::move(model)), ekf_(std::move(ekf)), opt_(options),
        Rg_(model_.numPlanes(), Eigen::Matrix3d::Identity()) {
    opt_.update.min_blocks = std::max(opt_.update.min_blocks, IndependentPlanesModel::kMinPoints);
  }

  FrameStats step(const std::vector<Observation>& obs) {
    FrameStats fs;
    Eigen::VectorXd q = Eigen::VectorXd::Constant(ekf_.size(), opt_.q_structure);
    q[IndependentPlanesModel::betaIndex()] = opt_.q_beta;
    for (int j = 0; j < model_.numPlanes(); ++j)
      q.segment<6>(IndependentPlanesModel::motionIndex(j)) = opt_.q_motion;
    ekf_.predict(q);
    const double rs = opt_.reference_sigma >= 0.0 ? opt_.reference_sigma : opt_.sigma_uv;
    while (static_cast<int>(ref_cov_.size()) < model_.numPoints())
      ref_cov_.push_back(Eigen::Matrix2d::Identity() * rs * rs);
    const std::vector<Eigen::Matrix2d>* rc = opt_.reference == ReferenceModel::Exact ? nullptr : &ref_cov_;
    MeasurementBatch batch;
    std::vector<int> used;
    model_.linearize(ekf_.x(), Rg_, obs, opt_.sigma_uv, &batch, &fs.invalid, &fs.first_problem, rc, &used);
    const Eigen::VectorXd x_prior = ekf_.x();
    const Eigen::MatrixXd P_prior = ekf_.P();
    fs.iterations = 1;
    fs.update = ekf_.update(batch, opt_.update);
    fs.health = ekf_.health() | (fs.update.health & ~kTooFewMeasurements);
    for (int j = 0; j < model_.numPlanes(); ++j)
      if (!incrementalRotationValid(ekf_.x().segment<3>(IndependentPlanesModel::motionIndex(j) + 3))) {
        ekf_.mutableX() = x_prior;
        ekf_.mutableP() = P_prior;
        fs.update.applied = false;
        fs.health |= kInvalidRotation;
        return fs;
      }
    if (opt_.reference == ReferenceModel::Refine && fs.update.applied && fs.health == kHealthy)
      refineReferences(obs, used, fs.update.gated_mask);
    for (int j = 0; j < model_.numPlanes(); ++j) {
      auto w = ekf_.mutableX().segment<3>(IndependentPlanesModel::motionIndex(j) + 3);
      Rg_[j] = incrementalRotation(w) * Rg_[j];  // R^k = R(dq(omega)) R^{k-1}, per plane
      w.setZero();
    }
    return fs;
  }

  const IndependentPlanesModel& model() const { return model_; }
  const Ekf& ekf() const { return ekf_; }
  double beta() const { return ekf_.x()[IndependentPlanesModel::betaIndex()]; }
  /// Plane j's rotation reference -> current camera, and its translation (t_X, t_Y, t_Z).
  const Eigen::Matrix3d& rotation(int j) const { return Rg_[j]; }
  Eigen::Vector3d translation(int j) const {
    const auto t = ekf_.x().segment<3>(IndependentPlanesModel::motionIndex(j));
    return {t.x(), t.y(), t.z() / beta()};
  }
  Eigen::Vector3d plane(int j) const { return ekf_.x().segment<3>(IndependentPlanesModel::planeIndex(j)); }

 private:
  /// ReferenceModel::Refine: as RecursiveFilter::refineReferences (refineReference, with the
  /// state at its posterior, before omega is folded).
  void refineReferences(const std::vector<Observation>& obs, const std::vector<int>& used,
                        const std::vector<std::uint8_t>& gated) {
    refineReferencesAt(model_, obs, used, gated, opt_.sigma_uv * opt_.sigma_uv, &ref_cov_,
                       [&](int id, Eigen::Vector2d* h, Eigen::Matrix2d* HPHt, Eigen::Matrix2d* Hu) {
                         Eigen::MatrixXd H;
                         if (model_.measure(ekf_.x(), Rg_, id, h, &H, Hu) != MeasureStatus::Ok) return false;
                         *HPHt = H * ekf_.P() * H.transpose();
                         return true;
                       });
  }

  IndependentPlanesModel model_;
  Ekf ekf_;
  IndependentFilterOptions opt_;
  std::vector<Eigen::Matrix3d> Rg_;
  std::vector<Eigen::Matrix2d> ref_cov_;
};

}  // namespace rsfm
