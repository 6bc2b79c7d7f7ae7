#include "rsfm/models/plane_model.hpp"

#include "rsfm/models/linearize.hpp"

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include <cmath>
#include <stdexcept>

namespace rsfm {

PlaneModel::PlaneModel(std::vector<Eigen::Vector2d> ref_uv, std::vector<int> labels,
                       int num_planes)
    : ref_(std::move(ref_uv)), labels_(std::move(labels)), planes_(num_planes) {
  if (labels_.size() != ref_.size())
    throw std::invalid_argument("PlaneModel: one label per point is required");
  for (int l : labels_)
    if (l < 0 || l >= planes_) throw std::invalid_argument("PlaneModel: plane label out of range");
}

int PlaneModel::addPoint(const Eigen::Vector2d& ref_uv, int plane) {
  if (plane < 0 || plane >= planes_) throw std::invalid_argument("PlaneModel: bad plane label");
  ref_.push_back(ref_uv);
  labels_.push_back(plane);
  return numPoints() - 1;
}

MeasureStatus PlaneModel::checkRay(const Eigen::Vector3d& N, double beta,
                                   const Eigen::Vector2d& uv) {
  if (!N.allFinite() || !std::isfinite(beta) || !uv.allFinite()) return MeasureStatus::NonFinite;
  // Compared squared (no square root per point: this runs for every observation of every frame).
  const double n2 = N.squaredNorm();
  if (!(n2 < kMaxPlaneNorm * kMaxPlaneNorm)) return MeasureStatus::PlaneThroughOrigin;
  const double den = beta * (N.x() * uv.x() + N.y() * uv.y()) + N.z();  // N . d = 1 / eta
  const double nd2 = n2 * (beta * beta * uv.squaredNorm() + 1.0);        // (|N| |d|)^2
  if (!(den * den > kMinGrazingSine * kMinGrazingSine * nd2)) return MeasureStatus::HorizonSingular;
  return MeasureStatus::Ok;
}

MeasureStatus PlaneModel::point(const Eigen::Vector3d& N, double beta, const Eigen::Vector2d& uv,
                                Eigen::Vector3d* p, Eigen::Vector3d* dp_dbeta,
                                Eigen::Matrix3d* dp_dN, Eigen::Matrix<double, 3, 2>* dp_duv,
                                Eigen::Vector3d* dp_dN_coeff) {
  const MeasureStatus s = checkRay(N, beta, uv);
  if (s != MeasureStatus::Ok) return s;
  const double u = uv.x(), v = uv.y();
  const double a = N.x() * u + N.y() * v;  // N_X u + N_Y v
  const double g = 1.0 - a;
  const double eta = 1.0 / (beta * a + N.z());
  const double nb = N.z() + beta;
  const Eigen::Vector3d pt(eta * nb * u, eta * nb * v, eta * g);
  if (!(1.0 + beta * pt.z() > 1e-12)) return MeasureStatus::BehindCamera;
  if (p) *p = pt;
  const double e2 = eta * eta;
  if (dp_dbeta) *dp_dbeta = e2 * g * Eigen::Vector3d(N.z() * u, N.z() * v, -a);
  const Eigen::Vector3d c(-e2 * u * nb, -e2 * v * nb, -e2 * g);  // dp/dN = ray c^T
  if (dp_dN_coeff) *dp_dN_coeff = c;
  if (dp_dN) *dp_dN = Eigen::Vector3d(u * beta, v * beta, 1.0) * c.transpose();
  if (dp_duv) {
    // d eta/du = -beta N_X eta^2, d eta/dv = -beta N_Y eta^2.
    const double deu = -beta * N.x() * e2, dev = -beta * N.y() * e2;
    dp_duv->col(0) << nb * (eta + u * deu), nb * v * deu, -N.x() * eta + g * deu;
    dp_duv->col(1) << nb * u * dev, nb * (eta + v * dev), -N.y() * eta + g * dev;
  }
  return MeasureStatus::Ok;
}

MeasureStatus PlaneModel::measure(const MotionContext& m, const Eigen::VectorXd& x, int i,
                                  Eigen::Vector2d* h, Eigen::Matrix<double, 2, 7>* Hm,
                                  Eigen::Matrix<double, 2, 3>* Hn, Eigen::Matrix2d* Hu) const {
  const Eigen::Vector3d N = x.segment<3>(planeIndex(labels_[i]));
  Eigen::Vector3d p, dpb, dpN_coeff;
  Eigen::Matrix<double, 3, 2> dpu;
  MeasureStatus s = point(N, m.beta, ref_[i], &p, &dpb, nullptr, Hu ? &dpu : nullptr, &dpN_coeff);
  if (s != MeasureStatus::Ok) return s;
  Eigen::Matrix<double, 2, 3> dhdp;
  s = projectWithJacobian(m, p, dpb, h, Hm, (Hn || Hu) ? &dhdp : nullptr);
  if (s != MeasureStatus::Ok) return s;
  // dp/dN = ray c^T (point()), so dh/dN = (dh/dp ray) c^T: a 2x1 times 1x3 product.
  if (Hn) *Hn = (dhdp * Eigen::Vector3d(m.beta * ref_[i].x(), m.beta * ref_[i].y(), 1.0)) * dpN_coeff.transpose();
  if (Hu) *Hu = dhdp * dpu;
  return s;
}

MeasureStatus PlaneModel::measure(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i,
                                  Eigen::Vector2d* h, Eigen::MatrixXd* H) const {
  if (i < 0 || i >= numPoints()) return MeasureStatus::UnknownFeature;
  const MotionContext m = MotionContext::fromState(x, Rg);
  Eigen::Matrix<double, 2, 7> Hm;
  Eigen::Matrix<double, 2, 3> Hn;
  const MeasureStatus s = measure(m, x, i, h, H ? &Hm : nullptr, H ? &Hn : nullptr);
  if (s == MeasureStatus::Ok && H) {
    H->setZero(2, x.size());
    H->leftCols<7>() = Hm;
    H->block<2, 3>(0, planeIndex(labels_[i])) = Hn;
  }
  return s;
}

MeasureStatus PlaneModel::transferredReferenceJacobian(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i,
                                                       double sigma, Eigen::MatrixXd* G, Eigen::Matrix2d* cov) const {
  if (i < 0 || i >= numPoints()) return MeasureStatus::UnknownFeature;
  const MotionContext m = MotionContext::fromState(x, Rg);
  if (m.status != MeasureStatus::Ok) return m.status;
  Eigen::Vector2d h;
  Eigen::Matrix<double, 2, 7> Hm;
  Eigen::Matrix<double, 2, 3> Hn;
  Eigen::Matrix2d Hu;
  const MeasureStatus s = measure(m, x, i, &h, &Hm, &Hn, &Hu);
  if (s != MeasureStatus::Ok) return s;
  // Hu's smaller singular value against its larger: below kMinGrazingSine the transfer is as
  // ill-conditioned as transferToReference's grazing limit.
  const Eigen::JacobiSVD<Eigen::Matrix2d> svd(Hu);
  const Eigen::Vector2d sv = svd.singularValues();
  if (!(sv[1] > kMinGrazingSine * sv[0])) return MeasureStatus::HorizonSingular;
  const Eigen::Matrix2d Hi = Hu.inverse();
  G->setZero(2, x.size());
  G->leftCols<7>() = -Hi * Hm;
  G->block<2, 3>(0, planeIndex(labels_[i])) = -Hi * Hn;
  if (cov) *cov = sigma * sigma * Hi * Hi.transpose();
  return G->allFinite() ? MeasureStatus::Ok : MeasureStatus::NonFinite;
}

void PlaneModel::linearize(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg,
                           const std::vector<Observation>& obs, double sigma,
                           const std::vector<Eigen::Matrix2d>* ref_cov, BlockBatch* batch,
                           int* invalid, MeasureStatus* first_problem,
                           std::vector<int>* used, int reference_index) const {
  linearizeObservations(*this, x, Rg, obs, sigma, ref_cov, batch, invalid, first_problem, used, reference_index);
}

}  // namespace rsfm

namespace rsfm {

MeasureStatus PlaneModel::transferToReference(const Eigen::Vector3d& N, double beta, const Eigen::Matrix3d& R,
                                              const Eigen::Vector3d& t, const Eigen::Vector2d& uv,
                                              Eigen::Vector2d* uv_ref) {
  if (!N.allFinite() || !std::isfinite(beta) || !R.allFinite() || !t.allFinite() || !uv.allFinite())
    return MeasureStatus::NonFinite;
  if (N.norm() > kMaxPlaneNorm) return MeasureStatus::PlaneThroughOrigin;
  const Eigen::Vector3d m = R * N;
  const Eigen::Vector3d d(beta * uv.x(), beta * uv.y(), 1.0);  // ray direction in camera k
  const double den = m.dot(d);
  if (std::abs(den) < kMinGrazingSine * m.norm() * d.norm()) return MeasureStatus::HorizonSingular;
  const double l = (1.0 + m.dot(t) - m.x() * uv.x() - m.y() * uv.y()) / den;
  if (!(1.0 + beta * l > 0.0)) return MeasureStatus::BehindCamera;
  const Eigen::Vector3d Xc(uv.x() * (1.0 + beta * l), uv.y() * (1.0 + beta * l), l);
  const Eigen::Vector3d X = R.transpose() * (Xc - t);
  const double w = 1.0 + beta * X.z();
  if (!(w > 0.0)) return MeasureStatus::BehindCamera;
  *uv_ref = X.head<2>() / w;
  return uv_ref->allFinite() ? MeasureStatus::Ok : MeasureStatus::NonFinite;
}

}  // namespace rsfm

namespace rsfm {

MeasureStatus PlaneModel::twoViewPoint(double beta, const Eigen::Matrix3d& Ra, const Eigen::Vector3d& ta,
                                       const Eigen::Vector2d& uv_a, const Eigen::Matrix3d& Rb, const Eigen::Vector3d& tb,
                                       const Eigen::Vector2d& uv_b, double min_parallax_rad, Eigen::Vector3d* X,
                                       double* parallax_rad) {
  if (!std::isfinite(beta) || !Ra.allFinite() || !ta.allFinite() || !uv_a.allFinite() || !Rb.allFinite() ||
      !tb.allFinite() || !uv_b.allFinite())
    return MeasureStatus::NonFinite;
  // Each ray in the reference frame: origin R^T ((u, v, 0) - t), direction R^T (beta u, beta v, 1).
  const Eigen::Vector3d oa = Ra.transpose() * (Eigen::Vector3d(uv_a.x(), uv_a.y(), 0.0) - ta);
  const Eigen::Vector3d ob = Rb.transpose() * (Eigen::Vector3d(uv_b.x(), uv_b.y(), 0.0) - tb);
  const Eigen::Vector3d da = Ra.transpose() * Eigen::Vector3d(beta * uv_a.x(), beta * uv_a.y(), 1.0);
  const Eigen::Vector3d db = Rb.transpose() * Eigen::Vector3d(beta * uv_b.x(), beta * uv_b.y(), 1.0);
  const double angle = std::atan2(da.cross(db).norm(), da.dot(db));
  if (parallax_rad) *parallax_rad = angle;
  if (!(angle >= min_parallax_rad)) return MeasureStatus::HorizonSingular;
  // Closest approach of oa + la da and ob + lb db.
  const Eigen::Vector3d w = oa - ob;
  const double a = da.dot(da), b = da.dot(db), c = db.dot(db), d = da.dot(w), e = db.dot(w);
  const double den = a * c - b * b;
  if (!(den > 0.0)) return MeasureStatus::HorizonSingular;
  const double la = (b * e - c * d) / den, lb = (a * e - b * d) / den;
  if (!(1.0 + beta * la > 0.0) || !(1.0 + beta * lb > 0.0)) return MeasureStatus::BehindCamera;
  *X = 0.5 * (oa + la * da + ob + lb * db);
  return X->allFinite() ? MeasureStatus::Ok : MeasureStatus::NonFinite;
}

}  // namespace rsfm
