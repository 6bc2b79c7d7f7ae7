#include "rsfm/models/independent_planes_model.hpp"

#include <stdexcept>

#include "rsfm/models/plane_model.hpp"

namespace rsfm {

IndependentPlanesModel::IndependentPlanesModel(std::vector<Eigen::Vector2d> ref_uv, std::vector<int> labels,
                                               int num_planes)
    : ref_(std::move(ref_uv)), labels_(std::move(labels)), planes_(num_planes) {
  if (labels_.size() != ref_.size()) throw std::invalid_argument("IndependentPlanesModel: one label per point");
  for (int l : labels_)
    if (l < 0 || l >= planes_) throw std::invalid_argument("IndependentPlanesModel: plane label out of range");
}

MotionContext IndependentPlanesModel::motion(const Eigen::VectorXd& x, int plane, const Eigen::Matrix3d& Rg) {
  Eigen::VectorXd m(7);
  m << x.segment<6>(motionIndex(plane)), x[betaIndex()];
  return MotionContext::fromState(m, Rg);
}

MeasureStatus IndependentPlanesModel::measure(const Eigen::VectorXd& x, const std::vector<Eigen::Matrix3d>& Rgs,
                                              int i, Eigen::Vector2d* h, Eigen::MatrixXd* H,
                                              Eigen::Matrix2d* Hu) const {
  if (i < 0 || i >= numPoints()) return MeasureStatus::UnknownFeature;
  const int l = labels_[i];
  const MotionContext m = motion(x, l, Rgs[l]);
  const Eigen::Vector3d N = x.segment<3>(planeIndex(l));
  Eigen::Vector3d p, dpb;
  Eigen::Matrix3d dpN;
  Eigen::Matrix<double, 3, 2> dpu;
  MeasureStatus s = PlaneModel::point(N, m.beta, ref_[i], &p, &dpb, &dpN, Hu ? &dpu : nullptr);
  if (s != MeasureStatus::Ok) return s;
  Eigen::Matrix<double, 2, 7> Hm;
  Eigen::Matrix<double, 2, 3> dhdp;
  s = projectWithJacobian(m, p, dpb, h, H ? &Hm : nullptr, (H || Hu) ? &dhdp : nullptr);
  if (s != MeasureStatus::Ok) return s;
  if (Hu) *Hu = dhdp * dpu;
  if (!H) return s;
  H->setZero(2, x.size());
  H->col(betaIndex()) = Hm.col(6);
  H->block<2, 6>(0, motionIndex(l)) = Hm.leftCols<6>();
  H->block<2, 3>(0, planeIndex(l)) = dhdp * dpN;
  return s;
}

void IndependentPlanesModel::linearize(const Eigen::VectorXd& x, const std::vector<Eigen::Matrix3d>& Rgs,
                                       const std::vector<Observation>& obs, double sigma, MeasurementBatch* batch,
                                       int* invalid, MeasureStatus* first_problem,
                                       const std::vector<Eigen::Matrix2d>* ref_cov, std::vector<int>* used) const {
  batch->resize(static_cast<int>(obs.size()), static_cast<int>(x.size()), 2);
  *invalid = 0;
  *first_problem = MeasureStatus::Ok;
  if (used) used->clear();
  int b = 0;
  for (int k = 0; k < static_cast<int>(obs.size()); ++k) {
    const Observation& o = obs[k];
    Eigen::Vector2d h;
    Eigen::MatrixXd H;
    Eigen::Matrix2d Hu;
    const MeasureStatus s = measure(x, Rgs, o.id, &h, &H, ref_cov ? &Hu : nullptr);
    if (s != MeasureStatus::Ok || !o.uv.allFinite()) {
      if (*invalid == 0) *first_problem = s == MeasureStatus::Ok ? MeasureStatus::NonFinite : s;
      ++*invalid;
      continue;
    }
    batch->residual.segment<2>(2 * b) = o.uv - h;
    batch->H.middleRows<2>(2 * b) = H;
    Eigen::Matrix2d R = Eigen::Matrix2d::Identity() * sigma * sigma;
    if (ref_cov) R += Hu * (*ref_cov)[o.id] * Hu.transpose();
    batch->R.block<2, 2>(2 * b, 0) = R;
    if (used) used->push_back(k);
    ++b;
  }
  batch->residual.conservativeResize(2 * b);
  batch->H.conservativeResize(2 * b, Eigen::NoChange);
  batch->R.conservativeResize(2 * b, Eigen::NoChange);
}

}  // namespace rsfm
