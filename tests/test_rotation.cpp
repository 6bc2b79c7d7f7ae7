// Rotation utilities, readings, camera conventions and the chi-square helpers.
#include <gtest/gtest.h>

#include "rsfm/camera.hpp"
#include "rsfm/chi2.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {
namespace {

TEST(Rotation, IncrementalQuaternionIsUnitAndMatchesAxisAngle) {
  const Eigen::Vector3d w(0.02, -0.01, 0.015);
  const Eigen::Quaterniond q = incrementalQuaternion(w);
  EXPECT_NEAR(q.norm(), 1.0, 1e-15);
  // dq = (cos(a/2), sin(a/2) axis) with sin(a/2) = |w|/2: angle a = 2 asin(|w|/2) ~ |w|.
  const Eigen::AngleAxisd aa(q);
  EXPECT_NEAR(aa.angle(), 2.0 * std::asin(w.norm() / 2.0), 1e-12);
  EXPECT_LT((aa.axis() - w.normalized()).norm(), 1e-12);
  EXPECT_NEAR(incrementalEpsilon(w), w.squaredNorm() / 4.0, 1e-18);
}

TEST(Rotation, ValidityAndZero) {
  EXPECT_TRUE(incrementalRotationValid(Eigen::Vector3d::Zero()));
  EXPECT_TRUE((incrementalRotation(Eigen::Vector3d::Zero()) - Eigen::Matrix3d::Identity()).norm() < 1e-15);
  EXPECT_FALSE(incrementalRotationValid(Eigen::Vector3d(2.0, 0.0, 0.0)));
  EXPECT_FALSE(incrementalRotationValid(Eigen::Vector3d(NAN, 0.0, 0.0)));
}

TEST(Rotation, HamiltonConvention) {
  // A quarter turn about z maps x to y under the Hamilton convention used throughout.
  const Eigen::Vector3d w(0.0, 0.0, 2.0 * std::sin(M_PI / 4.0));
  const Eigen::Vector3d y = incrementalRotation(w) * Eigen::Vector3d::UnitX();
  EXPECT_LT((y - Eigen::Vector3d::UnitY()).norm(), 1e-12);
}

TEST(Rotation, ReadingsParseAndPrint) {
  RotationReading r;
  ASSERT_TRUE(parseRotationReading("rate", &r));
  EXPECT_EQ(r, RotationReading::Rate);
  ASSERT_TRUE(parseRotationReading("reset", &r));
  EXPECT_EQ(r, RotationReading::Reset);
  EXPECT_FALSE(parseRotationReading("Rate", &r));
  EXPECT_EQ(toString(RotationReading::Rate), "rate");
}

TEST(Rotation, CanonicalAndAngle) {
  const Eigen::Quaterniond q(-0.8, 0.36, 0.0, -0.48);
  const Eigen::Quaterniond c = canonical(q.normalized());
  EXPECT_GE(c.w(), 0.0);
  EXPECT_LT((c.toRotationMatrix() - q.normalized().toRotationMatrix()).norm(), 1e-12);
  const Eigen::Matrix3d A = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY()).toRotationMatrix();
  EXPECT_NEAR(rotationAngle(A, Eigen::Matrix3d::Identity()), 0.3, 1e-12);
}

TEST(Camera, ApProjectionEqualsPinholeAboutTheCop) {
  // A&P: origin on the image plane, COP at (0,0,-1/beta). Pinhole with f = 1/beta about the COP
  // must give the same image point.
  const double beta = 0.7;
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.2, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(0.1, -0.2, 0.3), X(0.4, 0.5, 1.2);
  const Eigen::Vector2d uv = apProject(apTransform(X, R, Eigen::Vector3d(t.x(), t.y(), t.z() * beta), beta));
  // COP-centred: Y = X + e/beta; camera: Yc = R Y + t', t' = t + (I - R) e / beta.
  const CameraPose pose = copCentredPose(R, t, beta);
  const Eigen::Matrix3d Rcw = pose.orientation.toRotationMatrix().transpose();
  const Eigen::Vector3d Yc = Rcw * (X + Eigen::Vector3d(0, 0, 1 / beta) - pose.position);
  const Eigen::Vector2d pin = Yc.head<2>() / Yc.z() / beta;
  EXPECT_LT((uv - pin).norm(), 1e-12);
}

TEST(Camera, PixelConversionRoundTrip) {
  ImageGeometry g{512.0, 320.0, 240.0};
  const Eigen::Vector2d px(100.5, 400.25);
  EXPECT_LT((g.toPixels(g.toNormalized(px)) - px).norm(), 1e-12);
}

TEST(Chi2, KnownQuantiles) {
  EXPECT_NEAR(chi2Quantile(0.999, 2), 13.815510557964274, 1e-8);  // -2 ln(0.001)
  EXPECT_NEAR(chi2Quantile(0.95, 3), 7.814727903251178, 1e-8);
  EXPECT_NEAR(chi2Quantile(0.025, 100), 74.22192747492, 1e-6);
  EXPECT_NEAR(chi2Cdf(chi2Quantile(0.3, 7), 7), 0.3, 1e-10);
}

}  // namespace
}  // namespace rsfm
