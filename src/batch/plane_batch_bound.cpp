// The Cramer-Rao bound of the plane batch problem with its null space (plane_batch.hpp).
#include <fmt/format.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

#include "rsfm/batch/plane_batch.hpp"

namespace rsfm {

PlaneBatchBound planeBatchBound(const PlaneBatchData& data, const PlaneBatchState& at) {
  PlaneBatchBound out;
  const int F = static_cast<int>(data.frames.size()) - 1;
  const int P = static_cast<int>(data.labels.size());
  const int m = data.num_planes;
  if (F < 1 || static_cast<int>(at.R.size()) != F + 1 || static_cast<int>(at.t.size()) != F + 1 ||
      static_cast<int>(at.N.size()) != m || static_cast<int>(at.ref.size()) != P || data.gauge_plane < 0 ||
      data.gauge_plane >= m || data.gauge_component < 0 || data.gauge_component > 2) {
    out.message = "bound: inconsistent problem sizes";
    return out;
  }
  // Kept parameters: refs (2P), beta (1), the planes (3m minus the gauge component).
  const int iBeta = 2 * P;
  std::vector<int> iN(3 * m, -1);
  int n = iBeta + 1;
  for (int j = 0; j < m; ++j)
    for (int c = 0; c < 3; ++c)
      if (!(j == data.gauge_plane && c == data.gauge_component)) iN[3 * j + c] = n++;
  out.parameters = n;
  Eigen::MatrixXd S = Eigen::MatrixXd::Zero(n, n);
  // Frame 0: reference residuals (ref - z) / sigma.
  const double w2 = 1.0 / (data.sigma_uv * data.sigma_uv);
  for (const Observation& o : data.frames[0])
    if (o.id >= 0 && o.id < P) S.block<2, 2>(2 * o.id, 2 * o.id) += w2 * Eigen::Matrix2d::Identity();
  // Frames k >= 1: accumulate the frame's block [motion (6) | kept columns it touches], then
  // eliminate its motion (Schur complement) into S.
  std::vector<int> cols;
  for (int k = 1; k <= F; ++k) {
    const auto& obs = data.frames[k];
    if (obs.size() < 4) {
      out.message = fmt::format("bound: frame {} has {} observations (its motion needs >= 4)", k, obs.size());
      return out;
    }
    // Columns of this frame: beta, its planes' kept components, its points' refs.
    cols.assign(1, iBeta);
    std::vector<char> plane_in(m, 0);
    for (const Observation& o : obs) plane_in[data.labels[o.id]] = 1;
    for (int j = 0; j < m; ++j)
      if (plane_in[j])
        for (int c = 0; c < 3; ++c)
          if (iN[3 * j + c] >= 0) cols.push_back(iN[3 * j + c]);
    for (const Observation& o : obs) {
      cols.push_back(2 * o.id);
      cols.push_back(2 * o.id + 1);
    }
    std::sort(cols.begin(), cols.end());
    cols.erase(std::unique(cols.begin(), cols.end()), cols.end());
    const int c = static_cast<int>(cols.size());
    auto local = [&](int global) { return static_cast<int>(std::lower_bound(cols.begin(), cols.end(), global) - cols.begin()); };
    Eigen::Matrix<double, 6, 6> Hmm = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::MatrixXd Hmc = Eigen::MatrixXd::Zero(6, c), Hcc = Eigen::MatrixXd::Zero(c, c);
    for (const Observation& o : obs) {
      if (o.id < 0 || o.id >= P) continue;
      const int l = data.labels[o.id];
      Eigen::Vector2d r, Jb;
      Eigen::Matrix<double, 2, 6> Jm;
      Eigen::Matrix<double, 2, 3> JN;
      Eigen::Matrix2d Ju;
      if (planeBatchResidual(at.t[k], Eigen::Vector3d::Zero(), at.R[k], at.beta, at.N[l], at.ref[o.id], o.uv,
                             data.sigma_uv, &r, &Jm, &Jb, &JN, &Ju) != MeasureStatus::Ok) {
        out.message = fmt::format("bound: point {} cannot be projected at frame {}", o.id, k);
        return out;
      }
      // The observation's kept columns (local indices) and their Jacobian.
      int idx[6];
      Eigen::Matrix<double, 2, 6> Jc;
      int q = 0;
      idx[q] = local(iBeta);
      Jc.col(q++) = Jb;
      for (int a = 0; a < 3; ++a)
        if (iN[3 * l + a] >= 0) {
          idx[q] = local(iN[3 * l + a]);
          Jc.col(q++) = JN.col(a);
        }
      for (int a = 0; a < 2; ++a) {
        idx[q] = local(2 * o.id + a);
        Jc.col(q++) = Ju.col(a);
      }
      Hmm += Jm.transpose() * Jm;
      const Eigen::MatrixXd JmtJc = Jm.transpose() * Jc.leftCols(q);
      const Eigen::MatrixXd JctJc = Jc.leftCols(q).transpose() * Jc.leftCols(q);
      for (int a = 0; a < q; ++a) {
        Hmc.col(idx[a]) += JmtJc.col(a);
        for (int b = 0; b < q; ++b) Hcc(idx[a], idx[b]) += JctJc(a, b);
      }
    }
    const Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt(Hmm);
    if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 1e-12 * ldlt.vectorD().maxCoeff())) {
      out.message = fmt::format("bound: the motion of frame {} is not determined by its observations", k);
      return out;
    }
    const Eigen::MatrixXd red = Hcc - Hmc.transpose() * ldlt.solve(Hmc);
    for (int a = 0; a < c; ++a)
      for (int b = 0; b < c; ++b) S(cols[a], cols[b]) += red(a, b);
  }
  // Null space and pseudo-inverse. Scale to unit diagonal first (parameters differ in units).
  // A parameter whose information is negligible against the largest (a plane under pure rotation:
  // only rounding) keeps the largest's scale, so that it shows in the null space.
  const double dmax = std::max(1e-300, S.diagonal().maxCoeff());
  Eigen::VectorXd d(n);
  for (int i = 0; i < n; ++i) d[i] = 1.0 / std::sqrt(S(i, i) > 1e-12 * dmax ? S(i, i) : dmax);
  const Eigen::MatrixXd Ss = d.asDiagonal() * S * d.asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(Ss);
  if (es.info() != Eigen::Success) {
    out.message = "bound: eigen-decomposition failed";
    return out;
  }
  const Eigen::VectorXd& lam = es.eigenvalues();
  const double tol = 1e-10 * std::max(1e-300, lam.maxCoeff());
  Eigen::MatrixXd Vnull(n, 0);
  Eigen::MatrixXd pinv = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) {
    const Eigen::VectorXd v = es.eigenvectors().col(i);
    if (lam[i] <= tol) {
      Vnull.conservativeResize(n, Vnull.cols() + 1);
      Vnull.col(Vnull.cols() - 1) = v;
    } else {
      pinv += v * v.transpose() / lam[i];
    }
  }
  out.null_dim = static_cast<int>(Vnull.cols());
  // Back to the original units: cov = D pinv D.
  const Eigen::MatrixXd cov = d.asDiagonal() * pinv * d.asDiagonal();
  // A functional g (gradient in original units) is estimable when D^-1 ... in scaled units its
  // gradient is D g; estimable iff D g is orthogonal to the scaled null space.
  auto estimable = [&](const Eigen::VectorXd& g) {
    if (Vnull.cols() == 0) return true;
    const Eigen::VectorXd gs = d.cwiseProduct(g);
    return (Vnull.transpose() * gs).norm() <= 1e-6 * gs.norm();
  };
  {
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
    g[iBeta] = 1;
    out.beta_estimable = estimable(g);
    out.var_beta = cov(iBeta, iBeta);
  }
  for (int j = 0; j < m; ++j) {
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b)
        if (iN[3 * j + a] >= 0 && iN[3 * j + b] >= 0) C(a, b) = cov(iN[3 * j + a], iN[3 * j + b]);
    out.cov_N.push_back(C);
    // The direction's two tangent functionals: rows of (I - n n^T) / |N| on the kept components.
    const Eigen::Vector3d Nj = at.N[j], nj = Nj.normalized();
    const Eigen::Matrix3d J = (Eigen::Matrix3d::Identity() - nj * nj.transpose()) / Nj.norm();
    bool ok = true;
    for (int row = 0; row < 3 && ok; ++row) {
      Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
      for (int a = 0; a < 3; ++a)
        if (iN[3 * j + a] >= 0) g[iN[3 * j + a]] = J(row, a);
      if (g.norm() > 0) ok = estimable(g);
    }
    out.normal_estimable.push_back(ok);
  }
  out.ok = true;
  out.message = fmt::format("bound: {} parameters after eliminating {} motions, null space of dimension {}", n, F,
                            out.null_dim);
  return out;
}

}  // namespace rsfm
