#pragma once
// The one shared central-difference Jacobian checker used for every model (measurement and
// transition). Step per component: h_j = step * max(1, |x_j|). Error per entry:
// |J_analytic - J_numeric| / max(1, |J_numeric|), i.e. absolute for small entries and relative
// for large ones; the check passes when the largest error is below `tol`.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <functional>
#include <string>

namespace rsfm::test {

struct JacobianCheck {
  double max_error = 0.0;
  int row = -1, col = -1;
  Eigen::MatrixXd numeric;
};

/// f: R^n -> R^m; returns false if f could not be evaluated at a perturbed point.
using VectorFunction = std::function<bool(const Eigen::VectorXd&, Eigen::VectorXd*)>;

inline JacobianCheck centralDifference(const VectorFunction& f, const Eigen::VectorXd& x,
                                       const Eigen::MatrixXd& J, double step = 1e-6,
                                       const std::vector<bool>* skip_cols = nullptr) {
  JacobianCheck r;
  Eigen::VectorXd f0;
  EXPECT_TRUE(f(x, &f0)) << "function fails at the linearization point";
  r.numeric = Eigen::MatrixXd::Zero(f0.size(), x.size());
  for (int j = 0; j < x.size(); ++j) {
    if (skip_cols && (*skip_cols)[j]) continue;
    const double h = step * std::max(1.0, std::abs(x[j]));
    Eigen::VectorXd xp = x, xm = x, fp, fm;
    xp[j] += h;
    xm[j] -= h;
    EXPECT_TRUE(f(xp, &fp) && f(xm, &fm)) << "function fails near the point, column " << j;
    r.numeric.col(j) = (fp - fm) / (2 * h);
  }
  for (int i = 0; i < J.rows(); ++i)
    for (int j = 0; j < J.cols(); ++j) {
      const double e = std::abs(J(i, j) - r.numeric(i, j)) / std::max(1.0, std::abs(r.numeric(i, j)));
      if (e > r.max_error) r.max_error = e, r.row = i, r.col = j;
    }
  return r;
}

/// Asserts the analytic Jacobian J of f at x against central differences.
inline void expectJacobian(const VectorFunction& f, const Eigen::VectorXd& x,
                           const Eigen::MatrixXd& J, double tol, const std::string& what,
                           double step = 1e-6) {
  ASSERT_EQ(J.cols(), x.size()) << what;
  const JacobianCheck r = centralDifference(f, x, J, step);
  ASSERT_EQ(J.rows(), r.numeric.rows()) << what;
  EXPECT_LT(r.max_error, tol) << what << ": worst entry (" << r.row << ", " << r.col
                              << ") analytic " << (r.row >= 0 ? J(r.row, r.col) : 0.0)
                              << " numeric " << (r.row >= 0 ? r.numeric(r.row, r.col) : 0.0);
}

}  // namespace rsfm::test
