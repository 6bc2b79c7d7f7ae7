// Calway's affine-patch model ([Cal00]; docs/patches.md). Jacobians by the chain rule, one
// parameter at a time (forward mode): for each of the 10 parameters (t_X, t_Y, t_Z beta, omega,
// beta, p1, p2, p4) the derivatives of the intermediate quantities are propagated explicitly.
#include "rsfm/models/patch_model.hpp"

#include <Eigen/Geometry>
#include <array>
#include <cmath>

#include "rsfm/rotation.hpp"

namespace rsfm {

namespace {

constexpr int kTx = 0, kTy = 1, kW = 2, kBeta = 6, kP1 = 7, kP2 = 8, kP4 = 9;

bool finite(const Eigen::Matrix<double, 7, 1>& m, const Eigen::Vector3d& s) {
  return m.allFinite() && s.allFinite();
}

/// Partial derivatives of R(dq(omega)), beta and P = (p1, p2, 1 - beta p4) with respect to
/// parameter j of (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z, beta, p1, p2, p4); dRw are the
/// rotation's derivatives dR/domega.
struct Partials {
  Eigen::Matrix3d dR = Eigen::Matrix3d::Zero();
  double dbeta = 0.0;
  Eigen::Vector3d dP = Eigen::Vector3d::Zero();
};

Partials partials(int j, const std::array<Eigen::Matrix3d, 3>& dRw, double beta, double p4) {
  Partials d;
  if (j >= 3 && j <= 5) d.dR = dRw[j - 3];
  if (j == kBeta) d.dbeta = 1.0, d.dP.z() = -p4;
  if (j == kP1) d.dP.x() = 1.0;
  if (j == kP2) d.dP.y() = 1.0;
  if (j == kP4) d.dP.z() = -beta;
  return d;
}

}  // namespace

MeasureStatus PatchModel::exact(const Eigen::Matrix<double, 7, 1>& m, const Eigen::Vector3d& s,
                                const Eigen::Vector2d& c, Vector6d* z, PatchJacobian<6>* J,
                                Eigen::Matrix<double, 6, 2>* Jc) {
  if (!finite(m, s) || !c.allFinite()) return MeasureStatus::NonFinite;
  const Eigen::Vector3d omega = m.segment<3>(3);
  if (!incrementalRotationValid(omega)) return MeasureStatus::InvalidRotation;
  const double beta = m[kBeta];
  if (!(beta > 0.0)) return MeasureStatus::BehindCamera;
  const double u = c.x(), v = c.y();
  const double p1 = s[0], p2 = s[1], p4 = s[2];
  const double g = p4 - p1 * u - p2 * v;
  if (!(1.0 - beta * g > kMinDepthFactor)) return MeasureStatus::BehindCamera;
  const Eigen::Matrix3d R = incrementalRotation(omega);
  const Eigen::Vector3d e3 = Eigen::Vector3d::UnitZ();
  // a = beta tbar = (beta t_X, beta t_Y, t_Z beta) + (I - R) e3.
  const Eigen::Vector3d a = Eigen::Vector3d(beta * m[kTx], beta * m[kTy], m[kW]) + e3 - R * e3;
  const Eigen::Vector3d P(p1, p2, 1.0 - beta * p4);
  const Eigen::Matrix3d H = R + a * P.transpose();
  const Eigen::Vector3d y(beta * u, beta * v, 1.0);
  const Eigen::Vector3d w = H * y;
  if (!(w.z() > kMinDepthFactor)) return MeasureStatus::BehindCamera;
  const Eigen::Vector2d h = w.head<2>() / (beta * w.z());
  const Eigen::Matrix2d A = (H.topLeftCorner<2, 2>() - beta * h * H.block<1, 2>(2, 0)) / w.z();
  if (z) *z << h, A(0, 0), A(0, 1), A(1, 0), A(1, 1);
  if (Jc) {
    // y = (beta u, beta v, 1): dw/dc_j = beta H e_j, so dh/dc = A and
    // dA/dc_j = -(beta / w3) (A e_j H[2, 0:2] + H[2, j] A).
    for (int j = 0; j < 2; ++j) {
      const Eigen::Matrix2d dA = -(beta / w.z()) * (A.col(j) * H.block<1, 2>(2, 0) + H(2, j) * A);
      Jc->col(j) << A.col(j), dA(0, 0), dA(0, 1), dA(1, 0), dA(1, 1);
    }
  }
  if (!J) return MeasureStatus::Ok;
  const std::array<Eigen::Matrix3d, 3> dRw = incrementalRotationDerivatives(omega);
  for (int j = 0; j < 10; ++j) {
    const auto [dR, db, dP] = partials(j, dRw, beta, p4);
    Eigen::Vector3d da = -dR * e3;
    if (j == kTx) da.x() += beta;
    if (j == kTy) da.y() += beta;
    if (j == kW) da.z() += 1.0;
    if (j == kBeta) da += Eigen::Vector3d(m[kTx], m[kTy], 0.0);
    const Eigen::Matrix3d dH = dR + da * P.transpose() + a * dP.transpose();
    const Eigen::Vector3d dy = j == kBeta ? Eigen::Vector3d(u, v, 0.0) : Eigen::Vector3d::Zero();
    const Eigen::Vector3d dw = dH * y + H * dy;
    // h = w12 / (beta w3)
    const Eigen::Vector2d dh = (dw.head<2>() - h * (beta * dw.z() + w.z() * db)) / (beta * w.z());
    // A = (H2 - beta h H3) / w3
    const Eigen::Matrix2d dA = (dH.topLeftCorner<2, 2>() - (db * h + beta * dh) * H.block<1, 2>(2, 0) -
                                beta * h * dH.block<1, 2>(2, 0)) / w.z() -
                               A * (dw.z() / w.z());
    J->col(j) << dh, dA(0, 0), dA(0, 1), dA(1, 0), dA(1, 1);
  }
  return J->allFinite() ? MeasureStatus::Ok : MeasureStatus::NonFinite;
}

MeasureStatus PatchModel::composeMap(const Eigen::Matrix<double, 7, 1>& m, const Eigen::Vector3d& s, const Vector6d& w,
                                      Vector6d* w_new, PatchJacobian<6>* J, Eigen::Matrix<double, 6, 6>* Jw) {
  if (!w.allFinite()) return MeasureStatus::NonFinite;
  Vector6d z;
  PatchJacobian<6> Jz;
  Eigen::Matrix<double, 6, 2> Jc;
  const MeasureStatus st = exact(m, s, w.head<2>(), &z, J || Jw ? &Jz : nullptr, Jw ? &Jc : nullptr);
  if (st != MeasureStatus::Ok) return st;
  Eigen::Matrix2d B, A;
  B << z[2], z[3], z[4], z[5];
  A << w[2], w[3], w[4], w[5];
  const Eigen::Matrix2d BA = B * A;
  if (w_new) *w_new << z[0], z[1], BA(0, 0), BA(0, 1), BA(1, 0), BA(1, 1);
  // d(B A) = dB A (B's parameters) + B dA (the previous map).
  auto mapColumn = [&](const Vector6d& dz) {
    Eigen::Matrix2d dB;
    dB << dz[2], dz[3], dz[4], dz[5];
    const Eigen::Matrix2d d = dB * A;
    Vector6d out;
    out << dz[0], dz[1], d(0, 0), d(0, 1), d(1, 0), d(1, 1);
    return out;
  };
  if (J)
    for (int j = 0; j < 10; ++j) J->col(j) = mapColumn(Jz.col(j));
  if (Jw) {
    Jw->setZero();
    for (int j = 0; j < 2; ++j) Jw->col(j) = mapColumn(Jc.col(j));
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 2; ++c) {
        Eigen::Matrix2d E = Eigen::Matrix2d::Zero();
        E(r, c) = 1.0;
        const Eigen::Matrix2d d = B * E;
        Jw->block<4, 1>(2, 2 + 2 * r + c) << d(0, 0), d(0, 1), d(1, 0), d(1, 1);
      }
  }
  return MeasureStatus::Ok;
}

MeasureStatus PatchModel::instantaneous(const Eigen::Matrix<double, 7, 1>& m, const Eigen::Vector3d& s,
                                        const Eigen::Vector2d& c, Vector6d* z, PatchJacobian<6>* J) {
  if (!finite(m, s) || !c.allFinite()) return MeasureStatus::NonFinite;
  const double beta = m[kBeta];
  if (!(beta > 0.0)) return MeasureStatus::BehindCamera;
  const double u = c.x(), v = c.y();
  const double p1 = s[0], p2 = s[1], p4 = s[2];
  const double Vx = m[kTx], Vy = m[kTy], W = m[kW];
  const double Ox = m[3], Oy = m[4], Oz = m[5];
  const double g = p4 - p1 * u - p2 * v;
  const double e = 1.0 - beta * g;
  if (!(e > kMinDepthFactor)) return MeasureStatus::BehindCamera;
  // The instantaneous flow formulas of docs/patches.md, first order in (V, Omega).
  const double bu = e * (Vx - u * W) + Oy * (g + beta * u * u) - Oz * v - beta * Ox * u * v;
  const double bv = e * (Vy - v * W) - Ox * (g + beta * v * v) + Oz * u + beta * Oy * u * v;
  const double a11 = beta * p1 * Vx - W * (e + beta * p1 * u) - Oy * (p1 - 2.0 * beta * u) - beta * Ox * v;
  const double a12 = beta * p2 * Vx - beta * p2 * u * W - Oy * p2 - Oz - beta * Ox * u;
  const double a21 = beta * p1 * Vy - beta * p1 * v * W + Ox * p1 + Oz + beta * Oy * v;
  const double a22 = beta * p2 * Vy - W * (e + beta * p2 * v) + Ox * (p2 - 2.0 * beta * v) + beta * Oy * u;
  if (z) *z << u + bu, v + bv, 1.0 + a11, a12, a21, 1.0 + a22;
  if (!J) return MeasureStatus::Ok;
  J->setZero();
  // dg/d(p1, p2, p4) = (-u, -v, 1); de/dbeta = -g; de/dp = -beta dg/dp.
  const Eigen::Vector3d dg(-u, -v, 1.0);
  // b_u
  J->row(0) << e, 0.0, -u * e, -beta * u * v, g + beta * u * u, -v,
      -g * (Vx - u * W) + Oy * u * u - Ox * u * v, 0, 0, 0;
  J->block<1, 3>(0, kP1) = (Oy - beta * (Vx - u * W)) * dg.transpose();
  // b_v
  J->row(1) << 0.0, e, -v * e, -(g + beta * v * v), beta * u * v, u,
      -g * (Vy - v * W) - Ox * v * v + Oy * u * v, 0, 0, 0;
  J->block<1, 3>(1, kP1) = (-beta * (Vy - v * W) - Ox) * dg.transpose();
  // a11
  J->row(2) << beta * p1, 0.0, -(e + beta * p1 * u), -beta * v, -(p1 - 2.0 * beta * u), 0.0,
      p1 * Vx - W * (-g + p1 * u) + 2.0 * Oy * u - Ox * v, beta * Vx - 2.0 * beta * u * W - Oy, -beta * v * W,
      beta * W;
  // a12
  J->row(3) << beta * p2, 0.0, -beta * p2 * u, -beta * u, -p2, -1.0, p2 * Vx - p2 * u * W - Ox * u, 0.0,
      beta * Vx - beta * u * W - Oy, 0.0;
  // a21
  J->row(4) << 0.0, beta * p1, -beta * p1 * v, p1, beta * v, 1.0, p1 * Vy - p1 * v * W + Oy * v,
      beta * Vy - beta * v * W + Ox, 0.0, 0.0;
  // a22
  J->row(5) << 0.0, beta * p2, -(e + beta * p2 * v), p2 - 2.0 * beta * v, beta * u, 0.0,
      p2 * Vy - W * (-g + p2 * v) - 2.0 * Ox * v + Oy * u, -beta * u * W, beta * Vy - 2.0 * beta * v * W + Ox,
      beta * W;
  return MeasureStatus::Ok;
}

MeasureStatus PatchModel::propagate(const Eigen::Matrix<double, 7, 1>& m, const Eigen::Vector3d& s,
                                    Eigen::Vector3d* s_new, PatchJacobian<3>* J) {
  if (!finite(m, s)) return MeasureStatus::NonFinite;
  const Eigen::Vector3d omega = m.segment<3>(3);
  if (!incrementalRotationValid(omega)) return MeasureStatus::InvalidRotation;
  const double beta = m[kBeta];
  if (!(beta > 0.0)) return MeasureStatus::BehindCamera;
  const double p4 = s[2];
  const Eigen::Matrix3d R = incrementalRotation(omega);
  const Eigen::Vector3d P(s[0], s[1], 1.0 - beta * p4);
  const Eigen::Vector3d t(m[kTx], m[kTy], m[kW] / beta);
  const Eigen::Vector3d RP = R * P;
  const double q = RP.dot(t);
  const double sig = RP.z() + beta * (p4 + q);
  if (!(sig > kMinDepthFactor)) return MeasureStatus::BehindCamera;
  const Eigen::Vector3d out(RP.x() / sig, RP.y() / sig, (p4 + q) / sig);
  if (s_new) *s_new = out;
  if (!J) return MeasureStatus::Ok;
  const std::array<Eigen::Matrix3d, 3> dRw = incrementalRotationDerivatives(omega);
  for (int j = 0; j < 10; ++j) {
    const auto [dR, db, dP] = partials(j, dRw, beta, p4);
    const double dp4 = j == kP4 ? 1.0 : 0.0;
    Eigen::Vector3d dt = Eigen::Vector3d::Zero();
    if (j == kTx) dt.x() = 1.0;
    if (j == kTy) dt.y() = 1.0;
    if (j == kW) dt.z() = 1.0 / beta;
    if (j == kBeta) dt.z() = -m[kW] / (beta * beta);
    const Eigen::Vector3d dRP = dR * P + R * dP;
    const double dq = dRP.dot(t) + RP.dot(dt);
    const double ds = dRP.z() + db * (p4 + q) + beta * (dp4 + dq);
    J->col(j) << (dRP.x() - out.x() * ds) / sig, (dRP.y() - out.y() * ds) / sig,
        (dp4 + dq - out.z() * ds) / sig;
  }
  return J->allFinite() ? MeasureStatus::Ok : MeasureStatus::NonFinite;
}

double PatchModel::regauge(const Eigen::VectorXd& x, int gauge, double gauge_value, Eigen::VectorXd* x_new,
                           Eigen::MatrixXd* G) {
  const int n = static_cast<int>(x.size());
  const int K = (n - 7) / 3;
  if (gauge < 0 || gauge >= K || !x.allFinite()) return -1.0;
  const double beta = x[kBeta];
  const int ig = p4Index(gauge);
  const double den = 1.0 - beta * x[ig];
  const double lambda = (1.0 - beta * gauge_value) / den;
  if (!(beta > 0.0) || !(lambda > 0.0) || !std::isfinite(lambda)) return -1.0;
  // dlambda/dbeta and dlambda/dp4_gauge.
  const double dl_db = (x[ig] - gauge_value) / (den * den);
  const double dl_dp4 = (1.0 - beta * gauge_value) * beta / (den * den);
  const Eigen::Vector3d omega = x.segment<3>(3);
  const Eigen::Vector3d e3 = Eigen::Vector3d::UnitZ();
  // u = R e3 - e3, so beta tbar = (beta t_X, beta t_Y, t_Z beta) - u.
  const Eigen::Vector3d uu = incrementalRotation(omega) * e3 - e3;
  const std::array<Eigen::Matrix3d, 3> dRw = incrementalRotationDerivatives(omega);
  Eigen::VectorXd y = x;
  const double il = 1.0 / lambda;
  y[kTx] = x[kTx] * il + uu.x() * (1.0 - il) / beta;
  y[kTy] = x[kTy] * il + uu.y() * (1.0 - il) / beta;
  y[kW] = (x[kW] - uu.z()) * il + uu.z();
  for (int k = 0; k < K; ++k) {
    const int i = structureIndex(k);
    y[i] = lambda * x[i];
    y[i + 1] = lambda * x[i + 1];
    y[i + 2] = (1.0 - lambda * (1.0 - beta * x[i + 2])) / beta;
  }
  y[ig] = gauge_value;  // exact by construction; avoid round-off
  if (x_new) *x_new = y;
  if (G) {
    // x' = phi(x, lambda(x)): G = d phi/dx + d phi/dlambda * dlambda/dx.
    G->setIdentity(n, n);
    Eigen::VectorXd dphi_dl = Eigen::VectorXd::Zero(n);
    const double il2 = il * il;
    (*G)(kTx, kTx) = il;
    (*G)(kTy, kTy) = il;
    (*G)(kW, kW) = il;
    for (int jw = 0; jw < 3; ++jw) {
      const Eigen::Vector3d du = dRw[jw] * e3;
      (*G)(kTx, 3 + jw) = du.x() * (1.0 - il) / beta;
      (*G)(kTy, 3 + jw) = du.y() * (1.0 - il) / beta;
      (*G)(kW, 3 + jw) = du.z() * (1.0 - il);
    }
    (*G)(kTx, kBeta) = -uu.x() * (1.0 - il) / (beta * beta);
    (*G)(kTy, kBeta) = -uu.y() * (1.0 - il) / (beta * beta);
    dphi_dl[kTx] = (uu.x() / beta - x[kTx]) * il2;
    dphi_dl[kTy] = (uu.y() / beta - x[kTy]) * il2;
    dphi_dl[kW] = -(x[kW] - uu.z()) * il2;
    for (int k = 0; k < K; ++k) {
      const int i = structureIndex(k);
      (*G)(i, i) = lambda;
      (*G)(i + 1, i + 1) = lambda;
      (*G)(i + 2, i + 2) = lambda;
      // p4' = 1/beta - lambda/beta + lambda p4: explicit beta derivative (lambda - 1) / beta^2.
      (*G)(i + 2, kBeta) = (lambda - 1.0) / (beta * beta);
      dphi_dl[i] = x[i];
      dphi_dl[i + 1] = x[i + 1];
      dphi_dl[i + 2] = -(1.0 - beta * x[i + 2]) / beta;
    }
    G->col(kBeta) += dphi_dl * dl_db;
    G->col(ig) += dphi_dl * dl_dp4;
    G->row(ig).setZero();  // the gauge patch's p4 is the constant gauge_value
  }
  return lambda;
}

MeasureStatus PatchModel::transition(const Eigen::VectorXd& x, int gauge, double gauge_value,
                                     Eigen::VectorXd* x_new, Eigen::MatrixXd* F, double* lambda) const {
  const int n = static_cast<int>(x.size());
  if (n != stateDim()) return MeasureStatus::UnknownFeature;
  const Eigen::Matrix<double, 7, 1> m = x.head<7>();
  Eigen::VectorXd y = x;
  Eigen::MatrixXd Jp;
  if (F) Jp.setIdentity(n, n);
  for (int k = 0; k < numPatches(); ++k) {
    const int i = structureIndex(k);
    Eigen::Vector3d s_new;
    PatchJacobian<3> J;
    const MeasureStatus st = propagate(m, x.segment<3>(i), &s_new, F ? &J : nullptr);
    if (st != MeasureStatus::Ok) return st;
    y.segment<3>(i) = s_new;
    if (F) {
      Jp.block(i, 0, 3, 7) = J.leftCols<7>();
      Jp.block(i, i, 3, 3) = J.rightCols<3>();
    }
  }
  Eigen::MatrixXd G;
  const double l = regauge(y, gauge, gauge_value, x_new, F ? &G : nullptr);
  if (!(l > 0.0) || !std::isfinite(l)) return MeasureStatus::BehindCamera;
  if (lambda) *lambda = l;
  if (F) *F = G * Jp;
  return MeasureStatus::Ok;
}

Eigen::Vector3d PatchModel::normal(const Eigen::Vector3d& s, double beta) {
  return Eigen::Vector3d(s[0], s[1], 1.0 - beta * s[2]).normalized();
}

double PatchModel::depthAt(const Eigen::Vector3d& s, double beta, const Eigen::Vector2d& c) {
  const double g = s[2] - s[0] * c.x() - s[1] * c.y();
  return g / (1.0 - beta * g);
}

bool PatchModel::structureFromPlane(const Eigen::Vector3d& n, double d, double beta, Eigen::Vector3d* s) {
  const double sig = n.z() + beta * d;
  if (!(sig > 0.0) || !std::isfinite(sig)) return false;
  *s = Eigen::Vector3d(n.x(), n.y(), d) / sig;
  return true;
}

}  // namespace rsfm
