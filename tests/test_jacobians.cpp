// Every analytic Jacobian against central differences through the shared checker
// (tests/jacobian_checker.hpp), including the near-singular cases.
#include <gtest/gtest.h>

#include <random>

#include "jacobian_checker.hpp"
#include "rsfm/geometry.hpp"
#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/models/point_model.hpp"
#include "rsfm/models/radial_camera.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {
namespace {

using test::expectJacobian;

Eigen::Matrix3d someRotation() {
  return Eigen::AngleAxisd(0.4, Eigen::Vector3d(0.3, -1.0, 0.2).normalized()).toRotationMatrix();
}

// ---- incremental rotation: dR(dq(omega))/d omega ([AS99] appendix) ----
void checkRotationJacobian(const Eigen::Vector3d& w, const std::string& what) {
  auto f = [](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
    if (!incrementalRotationValid(x)) return false;
    const Eigen::Matrix3d R = incrementalRotation(x);
    *y = Eigen::Map<const Eigen::VectorXd>(R.data(), 9);
    return true;
  };
  const auto d = incrementalRotationDerivatives(w);
  Eigen::MatrixXd J(9, 3);
  for (int j = 0; j < 3; ++j) J.col(j) = Eigen::Map<const Eigen::VectorXd>(d[j].data(), 9);
  expectJacobian(f, w, J, 1e-7, what);
}

TEST(RotationJacobian, OmegaZero) { checkRotationJacobian(Eigen::Vector3d::Zero(), "omega = 0"); }
TEST(RotationJacobian, Generic) { checkRotationJacobian({0.05, -0.02, 0.03}, "small omega"); }
TEST(RotationJacobian, LargeOmega) { checkRotationJacobian({1.1, -0.7, 0.9}, "|omega| = 1.58"); }

TEST(RotationJacobian, MatchesSeedAppendixMatrices) {
  // [AS99]'s appendix prints dR/d omega_X explicitly; compare with our chain-rule form.
  const Eigen::Vector3d w(0.3, -0.2, 0.25);
  const double g = std::sqrt(1.0 - w.squaredNorm() / 4.0);
  const double wx = w.x(), wy = w.y(), wz = w.z();
  Eigen::Matrix3d dX;
  dX << 0, (2 * wy * g + wx * wz) / (4 * g), (2 * wz * g - wx * wy) / (4 * g),  //
      (2 * wy * g - wx * wz) / (4 * g), -wx, wx * wx / (4 * g) - g,               //
      (2 * wz * g + wx * wy) / (4 * g), -wx * wx / (4 * g) + g, -wx;
  Eigen::Matrix3d dY;
  dY << -wy, (2 * wx * g + wy * wz) / (4 * g), -wy * wy / (4 * g) + g,  //
      (2 * wx * g - wy * wz) / (4 * g), 0, (2 * wz * g + wx * wy) / (4 * g),  //
      wy * wy / (4 * g) - g, (2 * wz * g - wx * wy) / (4 * g), -wy;
  Eigen::Matrix3d dZ;
  dZ << -wz, wz * wz / (4 * g) - g, (2 * wx * g - wy * wz) / (4 * g),  //
      -wz * wz / (4 * g) + g, -wz, (2 * wy * g + wx * wz) / (4 * g),    //
      (2 * wx * g + wy * wz) / (4 * g), (2 * wy * g - wx * wz) / (4 * g), 0;
  const auto d = incrementalRotationDerivatives(w);
  EXPECT_LT((d[0] - dX).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((d[1] - dY).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((d[2] - dZ).cwiseAbs().maxCoeff(), 1e-12);
}

// ---- measurement models ----
template <class Model>
void checkModel(const Model& model, const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i,
                double tol, const std::string& what, double step = 1e-6) {
  Eigen::Vector2d h;
  Eigen::MatrixXd H;
  ASSERT_EQ(model.measure(x, Rg, i, &h, &H), MeasureStatus::Ok) << what;
  auto f = [&](const Eigen::VectorXd& xx, Eigen::VectorXd* y) {
    Eigen::Vector2d hh;
    if (model.measure(xx, Rg, i, &hh, nullptr) != MeasureStatus::Ok) return false;
    *y = hh;
    return true;
  };
  expectJacobian(f, x, H, tol, what, step);
}

Eigen::VectorXd motion(const Eigen::Vector3d& t, const Eigen::Vector3d& w, double beta, int n) {
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n);
  x.head<3>() = t;
  x.segment<3>(3) = w;
  x[6] = beta;
  return x;
}

PointModel pointModel() {
  return PointModel({{0.1, -0.2}, {-0.35, 0.3}, {0.6, 0.45}, {0.0, 0.0}, {-0.7, -0.6}});
}

TEST(PointModelJacobian, Generic) {
  const PointModel m = pointModel();
  Eigen::VectorXd x = motion({0.05, -0.03, 0.02}, {0.02, -0.04, 0.01}, 0.9, m.stateDim());
  x.tail(5) << 0.6, 0.8, 1.1, 0.5, 0.9;
  for (int i = 0; i < m.numPoints(); ++i)
    checkModel(m, x, someRotation(), i, 1e-6, "point " + std::to_string(i));
}

TEST(PointModelJacobian, OmegaZeroAndIdentityRotation) {
  const PointModel m = pointModel();
  Eigen::VectorXd x = motion({0.0, 0.0, 0.0}, Eigen::Vector3d::Zero(), 1.0, m.stateDim());
  x.tail(5) << 0.6, 0.8, 1.1, 0.5, 0.9;
  for (int i = 0; i < m.numPoints(); ++i)
    checkModel(m, x, Eigen::Matrix3d::Identity(), i, 1e-6, "omega=0 point " + std::to_string(i));
}

TEST(PointModelJacobian, LargeOmega) {
  const PointModel m = pointModel();
  Eigen::VectorXd x = motion({0.1, 0.2, -0.1}, {0.8, -0.9, 0.5}, 1.2, m.stateDim());
  x.tail(5) << 0.6, 0.8, 1.1, 0.5, 0.9;
  int checked = 0;
  for (int i = 0; i < m.numPoints(); ++i) {
    Eigen::Vector2d h;
    if (m.measure(x, someRotation(), i, &h, nullptr) != MeasureStatus::Ok) continue;  // behind
    checkModel(m, x, someRotation(), i, 1e-6, "large omega point " + std::to_string(i));
    ++checked;
  }
  EXPECT_GE(checked, 3);
}

TEST(PointModelJacobian, SmallBeta) {
  // beta -> 0 is the orthographic limit; the model stays smooth.
  const PointModel m = pointModel();
  Eigen::VectorXd x = motion({0.05, -0.03, 1e-5}, {0.02, -0.04, 0.01}, 1e-4, m.stateDim());
  x.tail(5) << 6.0, 8.0, 11.0, 5.0, 9.0;
  for (int i = 0; i < m.numPoints(); ++i)
    checkModel(m, x, someRotation(), i, 1e-6, "small beta point " + std::to_string(i));
}

PlaneModel planeModel() {
  return PlaneModel({{0.1, -0.2}, {-0.35, 0.3}, {0.6, 0.45}, {0.0, 0.0}, {-0.7, -0.6}},
                    std::vector<int>(5, 0), 1);
}

Eigen::VectorXd planeState(const Eigen::Vector3d& t, const Eigen::Vector3d& w, double beta,
                           const Eigen::Vector3d& N) {
  Eigen::VectorXd x = motion(t, w, beta, 10);
  x.tail<3>() = N;
  return x;
}

TEST(PlaneModelJacobian, Generic) {
  const PlaneModel m = planeModel();
  const auto x = planeState({0.05, -0.03, 0.02}, {0.02, -0.04, 0.01}, 0.9, {1.15, 0.1, 2.0});
  for (int i = 0; i < m.numPoints(); ++i)
    checkModel(m, x, someRotation(), i, 1e-6, "plane point " + std::to_string(i));
}

TEST(PlaneModelJacobian, OmegaZero) {
  const PlaneModel m = planeModel();
  const auto x = planeState({0, 0, 0}, Eigen::Vector3d::Zero(), 0.5, {1.5, 0.5, 2.0});
  for (int i = 0; i < m.numPoints(); ++i)
    checkModel(m, x, Eigen::Matrix3d::Identity(), i, 1e-6, "omega=0 point " + std::to_string(i));
}

TEST(PlaneModelJacobian, LargeOmega) {
  const PlaneModel m = planeModel();
  const auto x = planeState({0.1, 0.2, -0.1}, {0.8, -0.9, 0.5}, 1.2, {1.15, 0.1, 2.0});
  int checked = 0;
  for (int i = 0; i < m.numPoints(); ++i) {
    Eigen::Vector2d h;
    if (m.measure(x, someRotation(), i, &h, nullptr) != MeasureStatus::Ok) continue;  // behind
    checkModel(m, x, someRotation(), i, 1e-6, "large omega point " + std::to_string(i));
    ++checked;
  }
  EXPECT_GE(checked, 3);
}

TEST(PlaneModelJacobian, SmallBeta) {
  const PlaneModel m = planeModel();
  const auto x = planeState({0.05, -0.03, 1e-5}, {0.02, -0.04, 0.01}, 1e-4, {0.1, 0.02, 0.2});
  for (int i = 0; i < m.numPoints(); ++i)
    checkModel(m, x, someRotation(), i, 1e-6, "small beta point " + std::to_string(i));
}

TEST(PlaneModelJacobian, NearHorizon) {
  // Point at (0.6, 0.45): choose N so that beta (N_X u + N_Y v) + N_Z = 5e-3: the ray meets the
  // plane at a grazing angle of ~0.1 deg (just above the reported limit), depth ~200. The
  // Jacobian is large but must still match.
  PlaneModel m({{0.6, 0.45}}, {0}, 1);
  const double beta = 1.0, NX = -2.0, NY = 0.0;
  const double NZ = 5e-3 - beta * (NX * 0.6 + NY * 0.45);
  // Keep the point in front of the current camera: small motion only.
  const auto x = planeState({0.0, 0.0, 0.0}, {0.001, 0.0, 0.0}, beta, {NX, NY, NZ});
  Eigen::Vector2d h;
  Eigen::MatrixXd H;
  ASSERT_EQ(m.measure(x, Eigen::Matrix3d::Identity(), 0, &h, &H), MeasureStatus::Ok);
  checkModel(m, x, Eigen::Matrix3d::Identity(), 0, 1e-4, "near horizon", 1e-9);
  // Exactly on the horizon, and just inside the grazing limit: reported, not divided by zero.
  auto xs = x;
  xs[9] = -beta * (NX * 0.6 + NY * 0.45);
  EXPECT_EQ(m.measure(xs, Eigen::Matrix3d::Identity(), 0, &h, &H), MeasureStatus::HorizonSingular);
  xs[9] = 1e-3 - beta * (NX * 0.6 + NY * 0.45);  // sine ~ 1e-3 / (2.2 * 1.25) < 1e-3
  EXPECT_EQ(m.measure(xs, Eigen::Matrix3d::Identity(), 0, &h, &H), MeasureStatus::HorizonSingular);
}

TEST(PlaneModelJacobian, PlaneNearlyThroughOrigin) {
  // |N| = 1e4: the plane passes 1e-4 units from the image-plane origin; still representable.
  const PlaneModel m = planeModel();
  const auto x = planeState({0.05, -0.03, 0.02}, {0.02, -0.04, 0.01}, 0.9, {3e3, -2e3, 1e4});
  for (int i = 0; i < m.numPoints(); ++i) {
    Eigen::Vector2d h;
    Eigen::MatrixXd H;
    const MeasureStatus s = m.measure(x, someRotation(), i, &h, &H);
    if (s != MeasureStatus::Ok) continue;  // some rays may cross behind: that is reported too
    checkModel(m, x, someRotation(), i, 1e-5, "plane near origin point " + std::to_string(i), 1e-7);
  }
  // Through the origin (|N| beyond the representable bound) and N infinite: reported.
  Eigen::Vector2d h;
  auto xo = planeState({0, 0, 0}, {0, 0, 0}, 1.0, {0.0, 0.0, 2e9});
  EXPECT_EQ(m.measure(xo, Eigen::Matrix3d::Identity(), 0, &h, nullptr), MeasureStatus::PlaneThroughOrigin);
  xo[9] = std::numeric_limits<double>::infinity();
  EXPECT_EQ(m.measure(xo, Eigen::Matrix3d::Identity(), 0, &h, nullptr), MeasureStatus::NonFinite);
}

TEST(PlaneModelJacobian, MultiplePlanesTouchOnlyTheirOwnBlock) {
  PlaneModel m({{0.1, 0.2}, {-0.3, 0.1}}, {0, 1}, 2);
  Eigen::VectorXd x = motion({0.05, -0.03, 0.02}, {0.02, -0.04, 0.01}, 0.9, 13);
  x.segment<3>(7) << 1.1, 0.1, 2.0;
  x.segment<3>(10) << -0.5, 1.2, 1.5;
  for (int i = 0; i < 2; ++i) checkModel(m, x, someRotation(), i, 1e-6, "two planes");
  Eigen::Vector2d h;
  Eigen::MatrixXd H;
  ASSERT_EQ(m.measure(x, someRotation(), 1, &h, &H), MeasureStatus::Ok);
  EXPECT_EQ((H.block<2, 3>(0, 7).norm()), 0.0);
}

// dh/d(u, v)^1: the reference Jacobian used to transfer reference noise and refine references.
template <class Model>
void checkReferenceJacobian(Model model, const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i,
                            const std::string& what) {
  const MotionContext m = MotionContext::fromState(x, Rg);
  Eigen::Vector2d h;
  Eigen::Matrix2d Hu;
  if constexpr (std::is_same_v<Model, PlaneModel>) {
    ASSERT_EQ(model.measure(m, x, i, &h, nullptr, nullptr, &Hu), MeasureStatus::Ok) << what;
  } else {
    ASSERT_EQ(model.measure(m, x, i, &h, nullptr, nullptr, &Hu), MeasureStatus::Ok) << what;
  }
  auto f = [&](const Eigen::VectorXd& uv, Eigen::VectorXd* y) {
    Model mm = model;
    mm.setReference(i, uv);
    Eigen::Vector2d hh;
    if (mm.measure(x, Rg, i, &hh, nullptr) != MeasureStatus::Ok) return false;
    *y = hh;
    return true;
  };
  expectJacobian(f, Eigen::VectorXd(model.reference(i)), Hu, 1e-6, what);
}

TEST(ReferenceJacobian, PointAndPlaneModels) {
  const PointModel pm = pointModel();
  Eigen::VectorXd xp = motion({0.05, -0.03, 0.02}, {0.02, -0.04, 0.01}, 0.9, pm.stateDim());
  xp.tail(5) << 0.6, 0.8, 1.1, 0.5, 0.9;
  const PlaneModel lm = planeModel();
  const auto xl = planeState({0.05, -0.03, 0.02}, {0.02, -0.04, 0.01}, 0.9, {1.15, 0.1, 2.0});
  for (int i = 0; i < 5; ++i) {
    checkReferenceJacobian(pm, xp, someRotation(), i, "point model reference " + std::to_string(i));
    checkReferenceJacobian(lm, xl, someRotation(), i, "plane model reference " + std::to_string(i));
  }
  // omega = 0, identity: the plane model's reference Jacobian is the plane-induced homography's.
  const auto x0 = planeState({0, 0, 0}, Eigen::Vector3d::Zero(), 1.0, {1.15, 0.1, 2.0});
  checkReferenceJacobian(lm, x0, Eigen::Matrix3d::Identity(), 2, "plane model reference, no motion");
}

// ---- the image-side camera of the refinement (models/radial_camera.hpp) ----
void checkRadialCamera(const Eigen::Vector4d& cam, double beta, const Eigen::Vector2d& h, const std::string& what) {
  // Variables (h_x, h_y, beta, dc_x, dc_y, k1, k2).
  auto f = [](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
    *y = RadialCamera::apply(x.tail<4>(), x[2], x.head<2>());
    return true;
  };
  Eigen::VectorXd x(7);
  x << h, beta, cam;
  Eigen::Matrix2d Jh;
  Eigen::Vector2d Jb;
  Eigen::Matrix<double, 2, 4> Jc;
  RadialCamera::apply(cam, beta, h, &Jh, &Jb, &Jc);
  Eigen::MatrixXd J(2, 7);
  J << Jh, Jb, Jc;
  expectJacobian(f, x, J, 1e-7, what);
  // The inverse recovers h.
  Eigen::Vector2d back;
  ASSERT_TRUE(RadialCamera::invert(cam, beta, RadialCamera::apply(cam, beta, h), &back)) << what;
  EXPECT_LT((back - h).norm(), 1e-12 * std::max(1.0, h.norm())) << what;
}

// The reference of a point that joins after the reference frame, transferred from its current
// observation z through the state's plane and motion (PlaneModel::transferToReference), as a
// function of the state: du/dx = -Hu^-1 H_x (PlaneModel::transferredReferenceJacobian).
void checkTransferredReference(const PlaneModel& model, const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i,
                               double tol, const std::string& what, double step = 1e-6) {
  Eigen::Vector2d z;
  ASSERT_EQ(model.measure(x, Rg, i, &z, nullptr), MeasureStatus::Ok) << what;
  // u = transfer(state xx, observation zz), the state's motion read as the filter reads it.
  auto transferAt = [&](const Eigen::VectorXd& xx, const Eigen::Vector2d& zz, Eigen::VectorXd* y) {
    if (!incrementalRotationValid(xx.segment<3>(3))) return false;
    const double beta = xx[6];
    const Eigen::Matrix3d R = incrementalRotation(xx.segment<3>(3)) * Rg;
    const Eigen::Vector3d t(xx[0], xx[1], xx[2] / beta);
    Eigen::Vector2d u;
    if (PlaneModel::transferToReference(xx.segment<3>(model.structureIndex(i)), beta, R, t, zz, &u) != MeasureStatus::Ok)
      return false;
    *y = u;
    return true;
  };
  auto transfer = [&](const Eigen::VectorXd& xx, Eigen::VectorXd* y) { return transferAt(xx, z, y); };
  Eigen::VectorXd u0;
  ASSERT_TRUE(transfer(x, &u0)) << what;
  EXPECT_LT((u0 - model.reference(i)).norm(), 1e-9 * std::max(1.0, model.reference(i).norm())) << what << ": the transfer inverts h";
  const double sigma = 0.01;
  Eigen::MatrixXd G;
  Eigen::Matrix2d C;
  ASSERT_EQ(model.transferredReferenceJacobian(x, Rg, i, sigma, &G, &C), MeasureStatus::Ok) << what;
  expectJacobian(transfer, x, G, tol, what, step);
  // z's noise: C = sigma^2 du/dz du/dz^T, du/dz from the same transfer.
  auto transferZ = [&](const Eigen::VectorXd& zz, Eigen::VectorXd* y) { return transferAt(x, zz, y); };
  const test::JacobianCheck dz = test::centralDifference(transferZ, z, Eigen::Matrix2d::Zero(), step);
  const Eigen::Matrix2d C_num = sigma * sigma * dz.numeric * dz.numeric.transpose();
  EXPECT_LT((C - C_num).norm(), tol * std::max(sigma * sigma, C_num.norm())) << what << ": the observation's noise at the reference";
}

TEST(TransferredReferenceJacobian, GenericAndTwoPlanes) {
  const PlaneModel m = planeModel();
  const auto x = planeState({0.05, -0.03, 0.02}, {0.02, -0.04, 0.01}, 0.9, {1.15, 0.1, 2.0});
  for (int i = 0; i < m.numPoints(); ++i) checkTransferredReference(m, x, someRotation(), i, 1e-6, "plane point " + std::to_string(i));
  // Large motion (omega 0.8 rad, the reset reading's omega is 0 but a state may carry one).
  const auto xl = planeState({0.1, 0.2, -0.1}, {0.3, -0.4, 0.2}, 1.2, {1.15, 0.1, 2.0});
  int checked = 0;
  for (int i = 0; i < m.numPoints(); ++i) {
    Eigen::Vector2d h;
    if (m.measure(xl, someRotation(), i, &h, nullptr) != MeasureStatus::Ok) continue;
    checkTransferredReference(m, xl, someRotation(), i, 1e-6, "large motion point " + std::to_string(i));
    ++checked;
  }
  EXPECT_GE(checked, 3);
  // Two planes: a point's reference depends on its own plane's N, not the other's.
  PlaneModel m2({{0.1, 0.2}, {-0.3, 0.1}}, {0, 1}, 2);
  Eigen::VectorXd x2 = motion({0.05, -0.03, 0.02}, {0.02, -0.04, 0.01}, 0.9, 13);
  x2.segment<3>(7) << 1.1, 0.1, 2.0;
  x2.segment<3>(10) << -0.5, 1.2, 1.5;
  for (int i = 0; i < 2; ++i) checkTransferredReference(m2, x2, someRotation(), i, 1e-6, "two planes " + std::to_string(i));
  Eigen::MatrixXd G;
  ASSERT_EQ(m2.transferredReferenceJacobian(x2, someRotation(), 1, 0.01, &G, nullptr), MeasureStatus::Ok);
  EXPECT_EQ((G.block<2, 3>(0, 7).norm()), 0.0);
  EXPECT_GT((G.block<2, 3>(0, 10).norm()), 0.0);
}

TEST(TransferredReferenceJacobian, NearAndOnTheHorizon) {
  // The ray from the current camera grazes the plane (~0.1 deg, as PlaneModelJacobian.NearHorizon):
  // the derivatives are large but must still match; on the horizon the transfer does not
  // determine the reference, and that is reported, not divided by zero.
  PlaneModel m({{0.6, 0.45}}, {0}, 1);
  const double beta = 1.0, NX = -2.0, NY = 0.0;
  const double NZ = 5e-3 - beta * (NX * 0.6 + NY * 0.45);
  const auto x = planeState({0.0, 0.0, 0.0}, {0.001, 0.0, 0.0}, beta, {NX, NY, NZ});
  checkTransferredReference(m, x, Eigen::Matrix3d::Identity(), 0, 1e-4, "near horizon", 1e-9);
  auto xs = x;
  xs[9] = -beta * (NX * 0.6 + NY * 0.45);
  Eigen::MatrixXd G;
  EXPECT_EQ(m.transferredReferenceJacobian(xs, Eigen::Matrix3d::Identity(), 0, 0.01, &G, nullptr), MeasureStatus::HorizonSingular);
  EXPECT_EQ(m.transferredReferenceJacobian(x, Eigen::Matrix3d::Identity(), 3, 0.01, &G, nullptr), MeasureStatus::UnknownFeature);
}

TEST(RadialCameraJacobian, Barrel) { checkRadialCamera({0.01, -0.02, -0.25, 0.05}, 1.3, {0.4, -0.3}, "barrel"); }
TEST(RadialCameraJacobian, Pincushion) { checkRadialCamera({0.0, 0.0, 0.1, 0.05}, 0.8, {-0.6, 0.5}, "pincushion"); }
TEST(RadialCameraJacobian, AtTheCentreAndWithoutDistortion) {
  checkRadialCamera({0.02, 0.01, -0.2, 0.0}, 1.0, {0.0, 0.0}, "principal point");
  checkRadialCamera(Eigen::Vector4d::Zero(), 1.0, {0.3, 0.2}, "no distortion (k derivatives still needed)");
  // Without distortion the prediction is h + dc exactly (the experiments' arithmetic).
  const Eigen::Vector2d h(0.123456789, -0.987654321);
  EXPECT_EQ(RadialCamera::apply(Eigen::Vector4d::Zero(), 0.7, h), h);
}
TEST(RadialCameraJacobian, NearTheFold) {
  // k1 = -0.25: the radial map folds at r = 1.155 (pinhole units); just inside it.
  checkRadialCamera({0.0, 0.0, -0.25, 0.0}, 1.0, {0.8, 0.75}, "near the fold");
}

// ---- the angle between two planes' normals (the sd of summary.json's angles, planeAngle) ----
void checkNormalAngle(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const std::string& what, double step = 1e-6) {
  auto f = [](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
    *y = Eigen::VectorXd::Constant(1, normalAngle(Eigen::Vector3d(x.head<3>()), Eigen::Vector3d(x.tail<3>()), nullptr));
    return true;
  };
  Eigen::Matrix<double, 1, 6> J;
  Eigen::VectorXd x(6);
  x << a, b;
  const double theta = normalAngle(a, b, &J);
  EXPECT_NEAR(theta, normalAngle(a, b), 1e-12) << what;  // the same angle as without the gradient
  expectJacobian(f, x, J, 1e-6, what, step);
  EXPECT_NEAR(J.leftCols<3>().dot(a), 0.0, 1e-9) << what;  // only the directions count
  EXPECT_NEAR(J.rightCols<3>().dot(b), 0.0, 1e-9) << what;
}
TEST(NormalAngleJacobian, Generic) { checkNormalAngle({0.3, -0.2, 1.1}, {1.2, 0.4, 0.7}, "generic, unequal lengths"); }
TEST(NormalAngleJacobian, AntiParallelSide) {
  // The vectors 120 deg apart: the lines' angle is 60 deg, b's sign follows a's.
  checkNormalAngle({1, 0, 0}, {std::cos(2.0944), std::sin(2.0944), 0.0}, "vectors 120 deg apart");
}
TEST(NormalAngleJacobian, NearParallel) {
  // 1e-3 rad apart (a step far below the angle) and 1e-3 rad from anti-parallel.
  checkNormalAngle({0, 0, 2}, {1e-3, 0, 1}, "1e-3 rad", 1e-8);
  checkNormalAngle({0, 0, 2}, {1e-3, 0, -1}, "1e-3 rad from anti-parallel", 1e-8);
}
TEST(NormalAngleJacobian, NearTheFold) {
  // 89.9 deg on either side of the fold at 90 deg (the lines' angle turns back there).
  const double e = 0.1 * M_PI / 180;
  checkNormalAngle({1, 0, 0}, {std::sin(e), std::cos(e), 0.0}, "89.9 deg", 1e-8);
  checkNormalAngle({1, 0, 0}, {-std::sin(e), std::cos(e), 0.0}, "90.1 deg between the vectors", 1e-8);
}
// ---- the unit direction of a plane's N (behind every reported normal sd) ----
void checkUnitDirection(const Eigen::Vector3d& N, const std::string& what) {
  // J's entries are ~1/|N|, and the checker's error is absolute below 1: the direction is scaled
  // by the constant |N| (so J |N| is checked, entries ~1) and the step follows |N| when it is
  // short, so that a far plane (short N) and a near one are held to the same relative bar.
  const double r = N.norm();
  auto f = [r](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
    *y = r * Eigen::Vector3d(x.head<3>()).normalized();
    return true;
  };
  const Eigen::Matrix3d J = unitDirectionJacobian(N);
  expectJacobian(f, Eigen::VectorXd(N), r * J, 1e-7, what, 1e-6 * std::min(1.0, r));
  EXPECT_LT((J * N).norm(), 1e-12) << what;  // the length does not move the direction
  EXPECT_LT((J - J.transpose()).norm(), 1e-15 * J.norm()) << what;
}
TEST(UnitDirectionJacobian, GenericShortAndLong) {
  checkUnitDirection({0.3, -0.2, 1.1}, "generic");
  checkUnitDirection({2e-4, 1e-4, -3e-4}, "a far plane (|N| 4e-4)");
  checkUnitDirection({250.0, -40.0, 900.0}, "a near plane (|N| 935)");
}
TEST(UnitDirectionJacobian, RmsAngleAndDegenerateInput) {
  // Isotropic C = s^2 I on N = r e_z: the direction's two tangent variances are (s / r)^2 each.
  const double s = 0.01, r = 2.0;
  EXPECT_NEAR(directionRmsAngle({0, 0, r}, s * s * Eigen::Matrix3d::Identity()), std::sqrt(2.0) * s / r, 1e-15);
  // Variance along N alone changes the length, not the direction.
  EXPECT_NEAR(directionRmsAngle({0, 0, r}, Eigen::Vector3d(0, 0, 1).asDiagonal()), 0.0, 1e-15);
  EXPECT_TRUE(unitDirectionJacobian(Eigen::Vector3d::Zero()).isZero(0.0));
  EXPECT_TRUE(unitDirectionJacobian({NAN, 0, 1}).isZero(0.0));
  EXPECT_TRUE(std::isinf(directionRmsAngle(Eigen::Vector3d::Zero(), Eigen::Matrix3d::Identity())));
  Eigen::Matrix3d C = Eigen::Matrix3d::Identity();
  C(0, 1) = NAN;
  EXPECT_TRUE(std::isinf(directionRmsAngle({0, 0, 1}, C)));  // not determined, never 0
}
TEST(NormalAngleJacobian, DegenerateInputGivesZero) {
  Eigen::Matrix<double, 1, 6> J;
  EXPECT_EQ(normalAngle({0, 0, 1}, {0, 0, 3}, &J), 0.0);  // parallel: a cone point
  EXPECT_TRUE(J.isZero(0.0));
  EXPECT_EQ(normalAngle({0, 0, 0}, {0, 0, 3}, &J), 0.0);
  EXPECT_TRUE(J.isZero(0.0));
  EXPECT_EQ(normalAngle({NAN, 0, 1}, {0, 0, 3}, &J), 0.0);
  EXPECT_TRUE(J.isZero(0.0));
}

TEST(PlaneAngle, IntervalsFollowTheCovarianceAndStayInRange) {
  TrackFrame f;
  f.N = {{0, 0, 2}, {1, 0, 1}, {0, 1, 1e-3}};  // 45 deg, 90 deg, ~90 deg
  const double v = std::pow(0.5 * M_PI / 180, 2);  // 0.5 deg per tangent direction of a unit normal
  for (const auto& N : f.N) f.cov_N.push_back(v * N.squaredNorm() * Eigen::Matrix3d::Identity());
  EXPECT_FALSE(planeAngle(f, 0, 1).has_sd);  // no cross-covariances: no sd
  f.cov_N_pair.assign(3, Eigen::Matrix3d::Zero());
  const PlaneAngle p01 = planeAngle(f, 0, 1);
  ASSERT_TRUE(p01.has_sd);
  EXPECT_NEAR(p01.angle_deg, 45.0, 1e-9);
  // Independent normals, 0.5 deg along the angle's direction each: sqrt(0.5^2 + 0.5^2).
  EXPECT_NEAR(p01.sd_deg, std::sqrt(0.5), 1e-6);
  EXPECT_NEAR(p01.lo_deg, 45.0 - 1.96 * p01.sd_deg, 1e-9);
  // Errors from one common rotation omega ~ N(0, v I) (dN = omega x N for both: the scene turns
  // as a whole): the angle does not move, to first order.
  auto skew = [](const Eigen::Vector3d& w) {
    Eigen::Matrix3d S;
    S << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
    return S;
  };
  TrackFrame h = f;
  for (int j = 0; j < 3; ++j) h.cov_N[static_cast<std::size_t>(j)] = v * skew(h.N[static_cast<std::size_t>(j)]) * skew(h.N[static_cast<std::size_t>(j)]).transpose();
  for (int b = 1; b < 3; ++b)
    for (int a = 0; a < b; ++a)
      h.cov_N_pair[static_cast<std::size_t>(planePairIndex(a, b))] =
          v * skew(h.N[static_cast<std::size_t>(a)]) * skew(h.N[static_cast<std::size_t>(b)]).transpose();
  EXPECT_LT(planeAngle(h, 0, 1).sd_deg, 1e-9);
  EXPECT_LT(planeAngle(h, 0, 2).sd_deg, 1e-9);
  // Next to the fold: the interval ends at 90.
  const PlaneAngle p02 = planeAngle(f, 0, 2);
  EXPECT_NEAR(p02.angle_deg, 90.0, 0.1);
  EXPECT_EQ(p02.hi_deg, 90.0);
  // Nearly parallel planes (0.2 deg apart, 0.5 deg errors): the interval reaches 0.
  TrackFrame g;
  g.N = {{0, 0, 1}, {std::sin(0.2 * M_PI / 180), 0, std::cos(0.2 * M_PI / 180)}};
  g.cov_N = {v * Eigen::Matrix3d::Identity(), v * Eigen::Matrix3d::Identity()};
  g.cov_N_pair = {Eigen::Matrix3d::Zero()};
  const PlaneAngle pg = planeAngle(g, 0, 1);
  EXPECT_EQ(pg.lo_deg, 0.0);
  EXPECT_GT(pg.hi_deg, 0.2 + 1.96 * pg.sd_deg);  // the relative error's disc, not the linearization's
  EXPECT_EQ(planePairIndex(0, 1), 0);
  EXPECT_EQ(planePairIndex(0, 2), 1);
  EXPECT_EQ(planePairIndex(1, 2), 2);
  EXPECT_EQ(planePairIndex(0, 3), 3);
}

// ---- a plane's unit normal and distance from (beta, N) (metricPlane: behind the reported
// plane_normal_sd_deg and plane_distance_sd) ----
void checkMetricPlane(const Eigen::Vector3d& N, double beta, const std::string& what, double step = 1e-6) {
  auto f = [](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
    const MetricPlane p = metricPlane(Eigen::Vector3d(x.tail<3>()), x[0]);
    *y = Eigen::Vector4d(p.n.x(), p.n.y(), p.n.z(), p.d);
    return std::isfinite(p.d);
  };
  Eigen::Matrix4d J;
  metricPlane(N, beta, Eigen::Matrix4d::Zero(), &J);
  Eigen::VectorXd x(4);
  x << beta, N;
  expectJacobian(f, x, J, 1e-6, what, step);
}
TEST(MetricPlaneJacobian, Generic) { checkMetricPlane({0.3, -0.2, 1.1}, 0.8, "generic"); }
TEST(MetricPlaneJacobian, TheSignFlips) {
  // d = (1 + N_Z / beta) / |N| < 0: n and d change sign, and so does the Jacobian.
  checkMetricPlane({0.3, -0.2, -1.5}, 0.8, "d < 0");
}
TEST(MetricPlaneJacobian, NearlyEdgeOnAndSmallBeta) {
  // A plane through the centre of projection's neighbourhood (d -> 0, edge-on) and a long focal
  // length (beta = 0.05).
  checkMetricPlane({0.2, 0.1, -0.8 + 1e-4}, 0.8, "d near 0", 1e-8);
  checkMetricPlane({0.02, -0.01, 0.5}, 0.05, "beta 0.05");
}
TEST(MetricPlaneJacobian, GivesTheReportedSds) {
  // The sds metricPlane reports are those of J cov J^T.
  const Eigen::Vector3d N(0.3, -0.2, 1.1);
  Eigen::Matrix4d A = Eigen::Matrix4d::Random(), cov = 1e-4 * A * A.transpose(), J;
  const MetricPlane p = metricPlane(N, 0.8, cov, &J);
  const Eigen::Matrix4d C = J * cov * J.transpose();
  EXPECT_NEAR(p.sd_angle_deg, std::sqrt(C.topLeftCorner<3, 3>().trace()) * 180.0 / M_PI, 1e-12);
  EXPECT_NEAR(p.sd_d, std::sqrt(C(3, 3)), 1e-12);
}

TEST(Models, InvalidRotationIsReported) {
  const PlaneModel m = planeModel();
  const auto x = planeState({0, 0, 0}, {2.5, 0, 0}, 1.0, {1.0, 0.0, 2.0});
  Eigen::Vector2d h;
  EXPECT_EQ(m.measure(x, Eigen::Matrix3d::Identity(), 0, &h, nullptr), MeasureStatus::InvalidRotation);
}

TEST(Models, PlanePointLiesOnPlaneAndRay) {
  // [AS99] eq. 12 gives the point on the first-frame ray (eq. 5) that satisfies N . X = 1 (eq. 9).
  const Eigen::Vector3d N(1.15, -0.3, 2.0);
  const double beta = 0.8;
  const Eigen::Vector2d uv(0.3, -0.25);
  Eigen::Vector3d p;
  ASSERT_EQ(PlaneModel::point(N, beta, uv, &p, nullptr, nullptr), MeasureStatus::Ok);
  EXPECT_NEAR(N.dot(p), 1.0, 1e-12);
  const Eigen::Vector3d q = PointModel::point(uv, p.z(), beta);
  EXPECT_LT((q - p).norm(), 1e-12);
}

}  // namespace
}  // namespace rsfm
