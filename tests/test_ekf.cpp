// The generic EKF: both update forms agree with the closed-form linear-Gaussian posterior,
// the gauge never moves, gating and health reporting work.
#include <gtest/gtest.h>

#include <Eigen/LU>
#include <random>

#include "rsfm/ekf.hpp"

namespace rsfm {
namespace {

struct LinearProblem {
  Eigen::VectorXd x0;
  Eigen::MatrixXd P0;
  MeasurementBatch batch;
};

LinearProblem makeProblem(int n, int blocks, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> N01;
  LinearProblem p;
  p.x0 = Eigen::VectorXd::NullaryExpr(n, [&](Eigen::Index) { return N01(rng); });
  Eigen::MatrixXd A = Eigen::MatrixXd::NullaryExpr(n, n, [&](Eigen::Index, Eigen::Index) { return N01(rng); });
  p.P0 = A * A.transpose() / n + 0.1 * Eigen::MatrixXd::Identity(n, n);
  p.batch.resize(blocks, n, 2);
  for (int b = 0; b < blocks; ++b) {
    for (int r = 0; r < 2; ++r) {
      for (int c = 0; c < n; ++c) p.batch.H(2 * b + r, c) = N01(rng);
      p.batch.residual(2 * b + r) = 0.3 * N01(rng);
    }
    Eigen::Matrix2d Rb;
    Rb << 0.05, 0.01, 0.01, 0.04;
    p.batch.R.block<2, 2>(2 * b, 0) = Rb;
  }
  return p;
}

/// Closed-form posterior (information form with explicit inverses, test only).
void closedForm(const LinearProblem& p, Eigen::VectorXd* x, Eigen::MatrixXd* P) {
  const int m = static_cast<int>(p.batch.residual.size());
  Eigen::MatrixXd R = Eigen::MatrixXd::Zero(m, m);
  for (int b = 0; b < m / 2; ++b) R.block<2, 2>(2 * b, 2 * b) = p.batch.R.block<2, 2>(2 * b, 0);
  const Eigen::MatrixXd Ri = R.inverse();
  *P = (p.P0.inverse() + p.batch.H.transpose() * Ri * p.batch.H).inverse();
  *x = p.x0 + *P * p.batch.H.transpose() * Ri * p.batch.residual;
}

TEST(Ekf, CovarianceAndInformationFormsMatchClosedForm) {
  const LinearProblem p = makeProblem(6, 40, 7);
  Eigen::VectorXd xr;
  Eigen::MatrixXd Pr;
  closedForm(p, &xr, &Pr);
  for (UpdateForm form : {UpdateForm::Covariance, UpdateForm::Information}) {
    Ekf ekf(p.x0, p.P0, std::vector<bool>(6, false));
    UpdateOptions o;
    o.form = form;
    o.gate_probability = 0.0;
    const UpdateStats st = ekf.update(p.batch, o);
    ASSERT_TRUE(st.applied);
    EXPECT_EQ(st.form_used, form);
    EXPECT_LT((ekf.x() - xr).norm(), 1e-9);
    EXPECT_LT((ekf.P() - Pr).norm(), 1e-9);
    EXPECT_EQ(ekf.P(), ekf.P().transpose());
    EXPECT_EQ(st.used, 40);
    EXPECT_EQ(st.nis_dof, 80);
  }
}

TEST(Ekf, NisIsTheSameInBothForms) {
  const LinearProblem p = makeProblem(5, 12, 3);
  double nis[2];
  int k = 0;
  for (UpdateForm form : {UpdateForm::Covariance, UpdateForm::Information}) {
    Ekf ekf(p.x0, p.P0, std::vector<bool>(5, false));
    UpdateOptions o;
    o.form = form;
    o.gate_probability = 0.0;
    nis[k++] = ekf.update(p.batch, o).nis;
  }
  EXPECT_NEAR(nis[0], nis[1], 1e-9 * std::max(1.0, nis[0]));
}

TEST(Ekf, GaugeComponentNeverMoves) {
  LinearProblem p = makeProblem(6, 30, 11);
  std::vector<bool> fixed(6, false);
  fixed[4] = true;
  for (UpdateForm form : {UpdateForm::Covariance, UpdateForm::Information}) {
    Ekf ekf(p.x0, p.P0, fixed);
    EXPECT_EQ(ekf.P().row(4).norm(), 0.0);
    UpdateOptions o;
    o.form = form;
    for (int k = 0; k < 5; ++k) {
      ekf.predict(Eigen::VectorXd::Constant(6, 0.01));
      ASSERT_TRUE(ekf.update(p.batch, o).applied);
    }
    EXPECT_EQ(ekf.x()[4], p.x0[4]);  // exactly
    EXPECT_EQ(ekf.P().row(4).norm(), 0.0);
    EXPECT_EQ(ekf.P().col(4).norm(), 0.0);
  }
}

TEST(Ekf, InformationFormAcceptsZeroVarianceDirections) {
  // Motion starts with zero variance in the paper's experiment: the information form must cope.
  LinearProblem p = makeProblem(4, 10, 5);
  p.P0.row(1).setZero();
  p.P0.col(1).setZero();
  Ekf ekf(p.x0, p.P0, std::vector<bool>(4, false));
  UpdateOptions o;
  o.form = UpdateForm::Information;
  const UpdateStats st = ekf.update(p.batch, o);
  ASSERT_TRUE(st.applied) << describeHealth(st.health);
  EXPECT_NEAR(ekf.x()[1], p.x0[1], 1e-12);
  EXPECT_NEAR(ekf.P()(1, 1), 0.0, 1e-12);
  Ekf ekf2(p.x0, p.P0, std::vector<bool>(4, false));
  o.form = UpdateForm::Covariance;
  ASSERT_TRUE(ekf2.update(p.batch, o).applied);
  EXPECT_LT((ekf.x() - ekf2.x()).norm(), 1e-9);
  EXPECT_LT((ekf.P() - ekf2.P()).norm(), 1e-9);
}

TEST(Ekf, GatingRejectsAnOutlierBlock) {
  LinearProblem p = makeProblem(4, 20, 9);
  p.batch.residual.segment<2>(2 * 7) += Eigen::Vector2d(30.0, -25.0);
  Ekf ekf(p.x0, p.P0, std::vector<bool>(4, false));
  const UpdateStats st = ekf.update(p.batch, UpdateOptions{});
  EXPECT_EQ(st.gated, 1);
  EXPECT_EQ(st.gated_mask[7], 1);
  EXPECT_EQ(st.used, 19);
  // With gating disabled the outlier is used.
  Ekf ekf2(p.x0, p.P0, std::vector<bool>(4, false));
  UpdateOptions o;
  o.gate_probability = 0.0;
  EXPECT_EQ(ekf2.update(p.batch, o).gated, 0);
}

TEST(Ekf, NonFiniteInputIsReportedAndStateKept) {
  LinearProblem p = makeProblem(4, 5, 2);
  p.batch.residual[3] = std::numeric_limits<double>::quiet_NaN();
  Ekf ekf(p.x0, p.P0, std::vector<bool>(4, false));
  const UpdateStats st = ekf.update(p.batch, UpdateOptions{});
  EXPECT_FALSE(st.applied);
  EXPECT_TRUE(st.health & kNonFiniteInput);
  EXPECT_EQ(ekf.x(), p.x0);
  EXPECT_NE(describeHealth(st.health).find("non-finite"), std::string::npos);
}

TEST(Ekf, TooFewMeasurementsAndBadR) {
  LinearProblem p = makeProblem(4, 3, 4);
  Ekf ekf(p.x0, p.P0, std::vector<bool>(4, false));
  UpdateOptions o;
  o.min_blocks = 5;
  UpdateStats st = ekf.update(p.batch, o);
  EXPECT_FALSE(st.applied);
  EXPECT_TRUE(st.health & kTooFewMeasurements);
  p.batch.R.block<2, 2>(2, 0) = -Eigen::Matrix2d::Identity();
  st = ekf.update(p.batch, UpdateOptions{});
  EXPECT_TRUE(st.health & kBadMeasurementCovariance);
  EXPECT_FALSE(st.applied);
}

TEST(Ekf, NegativeCovarianceIsFlagged) {
  LinearProblem p = makeProblem(3, 10, 8);
  Ekf ekf(p.x0, p.P0, std::vector<bool>(3, false));
  ekf.mutableP()(0, 0) = -1.0;
  EXPECT_TRUE(ekf.health() & kCovarianceNotPD);
  UpdateOptions o;
  o.form = UpdateForm::Information;
  EXPECT_TRUE(ekf.update(p.batch, o).health & kCovarianceNotPD);
}

TEST(Ekf, AugmentAndRemove) {
  Ekf ekf(Eigen::Vector2d(1, 2), Eigen::Matrix2d::Identity(), {false, false});
  ekf.augment(Eigen::Vector2d(3, 4), 2 * Eigen::Matrix2d::Identity(), Eigen::Matrix2d::Constant(0.1));
  ASSERT_EQ(ekf.size(), 4);
  EXPECT_DOUBLE_EQ(ekf.P()(2, 0), 0.1);
  EXPECT_DOUBLE_EQ(ekf.P()(0, 2), 0.1);
  ekf.remove({1, 2});
  ASSERT_EQ(ekf.size(), 2);
  EXPECT_DOUBLE_EQ(ekf.x()[1], 4.0);
  EXPECT_DOUBLE_EQ(ekf.P()(1, 1), 2.0);
}

}  // namespace
}  // namespace rsfm
