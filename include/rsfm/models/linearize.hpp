#pragma once
// Linearization of a frame's observations shared by the point-based models. A model provides
//   static constexpr int kStructurePerPoint;     // structure columns one point depends on
//   int structureIndex(int i) const;              // first such column
//   MeasureStatus measure(const MotionContext&, const Eigen::VectorXd& x, int i, Eigen::Vector2d* h,
//                         Eigen::Matrix<double, 2, 7>* Hm,
//                         Eigen::Matrix<double, 2, kStructurePerPoint>* Hs, Eigen::Matrix2d* Hu) const;
// Cost O(N) in the number of observations.
#include <Eigen/Core>
#include <vector>

#include "rsfm/ekf.hpp"
#include "rsfm/models/projection.hpp"

namespace rsfm {

/// Fills `batch` (compact Jacobians, ekf.hpp's BlockBatch) with residual z - h(x), Jacobian and R = sigma^2 I (+ Hu C_i Hu^T with
/// `ref_cov`, C_i the covariance of point i's reference position). With `reference_index` >= 0
/// the reference positions are part of x (ReferenceModel::State): point i's Hu = dh/d(u, v)^1
/// goes to columns reference_index + 2i. Observations whose prediction fails are left out and
/// counted in *invalid (the first reason in *first_problem); `used` (optional) receives the
/// observation index of each block. `hook` (optional) is called as hook(b, point, Hu, batch)
/// once block b's rows are written (ReferenceModel::Conditional adds Hu G_i to them there).
struct NoBlockHook {
  void operator()(int, int, const Eigen::Matrix2d&, BlockBatch*) const {}
  static constexpr bool kNeedsHu = false;
};
template <class Model, class Hook = NoBlockHook>
void linearizeObservations(const Model& model, const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg,
                           const std::vector<Observation>& obs, double sigma,
                           const std::vector<Eigen::Matrix2d>* ref_cov, BlockBatch* batch,
                           int* invalid, MeasureStatus* first_problem, std::vector<int>* used,
                           int reference_index = -1, const Hook& hook = Hook()) {
  constexpr int S = Model::kStructurePerPoint;
  const MotionContext m = MotionContext::fromState(x, Rg);
  // Compact layout (ekf.hpp): the 7 motion columns shared, then the point's S structure columns
  // (and with the references in the state its 2 reference columns).
  const int own = S + (reference_index >= 0 ? 2 : 0);
  batch->reserve(static_cast<int>(obs.size()), 2, 7, own);
  if (used) used->clear();
  *invalid = 0;
  *first_problem = MeasureStatus::Ok;
  const bool need_hu = ref_cov || reference_index >= 0 || Hook::kNeedsHu;
  const Eigen::Matrix2d R0 = Eigen::Matrix2d::Identity() * sigma * sigma;
  int b = 0;
  for (int k = 0; k < static_cast<int>(obs.size()); ++k) {
    const Observation& o = obs[k];
    Eigen::Vector2d h;
    Eigen::Matrix<double, 2, 7> Hm;
    Eigen::Matrix<double, 2, S> Hs;
    Eigen::Matrix2d Hu;
    const MeasureStatus s = o.id < 0 || o.id >= model.numPoints()
                                ? MeasureStatus::UnknownFeature
                                : model.measure(m, x, o.id, &h, &Hm, &Hs, need_hu ? &Hu : nullptr);
    if (s != MeasureStatus::Ok || !o.uv.allFinite()) {
      if (*invalid == 0) *first_problem = s == MeasureStatus::Ok ? MeasureStatus::NonFinite : s;
      ++*invalid;
      continue;
    }
    batch->residual.template segment<2>(2 * b) = o.uv - h;
    batch->J.template block<2, 7>(2 * b, 0) = Hm;
    batch->J.template block<2, S>(2 * b, 7) = Hs;
    const int si = model.structureIndex(o.id);
    for (int j = 0; j < S; ++j) batch->cols(b, j) = si + j;
    if (reference_index >= 0) {
      batch->J.template block<2, 2>(2 * b, 7 + S) = Hu;
      batch->cols(b, S) = reference_index + 2 * o.id;
      batch->cols(b, S + 1) = reference_index + 2 * o.id + 1;
    }
    if (ref_cov)
      batch->R.template block<2, 2>(2 * b, 0) = R0 + Hu * (*ref_cov)[o.id] * Hu.transpose();
    else
      batch->R.template block<2, 2>(2 * b, 0) = R0;
    hook(b, o.id, Hu, batch);
    if (used) used->push_back(k);
    ++b;
  }
  batch->blocks = b;
}

}  // namespace rsfm
