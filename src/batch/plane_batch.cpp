#include "rsfm/batch/plane_batch.hpp"

#include <ceres/ceres.h>
#include <glog/logging.h>

#include <memory>
#include <mutex>

#include "rsfm/camera.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {

MeasureStatus planeBatchResidual(const Eigen::Vector3d& t, const Eigen::Vector3d& omega,
                                 const Eigen::Matrix3d& R_base, double beta,
                                 const Eigen::Vector3d& N, const Eigen::Vector2d& ref,
                                 const Eigen::Vector2d& z, double sigma, Eigen::Vector2d* r,
                                 Eigen::Matrix<double, 2, 6>* J_motion, Eigen::Vector2d* J_beta,
                                 Eigen::Matrix<double, 2, 3>* J_N, Eigen::Matrix2d* J_ref) {
  Eigen::Matrix<double, 7, 1> x;
  x << t, omega, beta;
  const MotionContext m = MotionContext::fromState(Eigen::VectorXd(x), R_base);
  Eigen::Vector3d p, dpb;
  Eigen::Matrix3d dpN;
  Eigen::Matrix<double, 3, 2> dpu;
  MeasureStatus s = PlaneModel::point(N, beta, ref, &p, &dpb, &dpN, &dpu);
  if (s != MeasureStatus::Ok) return s;
  Eigen::Vector2d h;
  Eigen::Matrix<double, 2, 7> Hm;
  Eigen::Matrix<double, 2, 3> dhdp;
  s = projectWithJacobian(m, p, dpb, &h, &Hm, &dhdp);
  if (s != MeasureStatus::Ok) return s;
  const double w = 1.0 / sigma;
  *r = (h - z) * w;
  if (J_motion) *J_motion = Hm.leftCols<6>() * w;
  if (J_beta) *J_beta = Hm.col(6) * w;
  if (J_N) *J_N = dhdp * dpN * w;
  if (J_ref) *J_ref = dhdp * dpu * w;
  return MeasureStatus::Ok;
}

namespace {

/// One observation at frame k >= 1. Parameter blocks: motion (6), beta (1), N (3)[, ref (2)].
class ObservationCost final : public ceres::CostFunction {
 public:
  ObservationCost(const Eigen::Matrix3d& R_base, const Eigen::Vector2d& z, double sigma,
                  const Eigen::Vector2d* fixed_ref)
      : R_base_(R_base), z_(z), sigma_(sigma), has_fixed_ref_(fixed_ref != nullptr) {
    if (fixed_ref) fixed_ref_ = *fixed_ref;
    set_num_residuals(2);
    mutable_parameter_block_sizes()->push_back(6);
    mutable_parameter_block_sizes()->push_back(1);
    mutable_parameter_block_sizes()->push_back(3);
    if (!has_fixed_ref_) mutable_parameter_block_sizes()->push_back(2);
  }

  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    const Eigen::Map<const Eigen::Matrix<double, 6, 1>> motion(params[0]);
    const double beta = params[1][0];
    const Eigen::Map<const Eigen::Vector3d> N(params[2]);
    const Eigen::Vector2d ref =
        has_fixed_ref_ ? fixed_ref_ : Eigen::Vector2d(params[3][0], params[3][1]);
    Eigen::Vector2d r;
    Eigen::Matrix<double, 2, 6> Jm;
    Eigen::Vector2d Jb;
    Eigen::Matrix<double, 2, 3> JN;
    Eigen::Matrix2d Ju;
    const bool want = jacobians != nullptr;
    if (planeBatchResidual(motion.head<3>(), motion.tail<3>(), R_base_, beta, N, ref, z_, sigma_,
                           &r, want ? &Jm : nullptr, want ? &Jb : nullptr, want ? &JN : nullptr,
                           want ? &Ju : nullptr) != MeasureStatus::Ok)
      return false;  // Ceres treats the step as unsuccessful and shrinks it
    residuals[0] = r[0];
    residuals[1] = r[1];
    if (jacobians) {
      using M26 = Eigen::Matrix<double, 2, 6, Eigen::RowMajor>;
      using M23 = Eigen::Matrix<double, 2, 3, Eigen::RowMajor>;
      using M22 = Eigen::Matrix<double, 2, 2, Eigen::RowMajor>;
      if (jacobians[0]) {
        Eigen::Map<M26> J0(jacobians[0]);
        J0 = Jm;
      }
      if (jacobians[1]) {
        Eigen::Map<Eigen::Vector2d> J1(jacobians[1]);
        J1 = Jb;
      }
      if (jacobians[2]) {
        Eigen::Map<M23> J2(jacobians[2]);
        J2 = JN;
      }
      if (!has_fixed_ref_ && jacobians[3]) {
        Eigen::Map<M22> J3(jacobians[3]);
        J3 = Ju;
      }
    }
    return true;
  }

 private:
  Eigen::Matrix3d R_base_;
  Eigen::Vector2d z_;
  double sigma_;
  bool has_fixed_ref_;
  Eigen::Vector2d fixed_ref_ = Eigen::Vector2d::Zero();
};

/// Reference-frame observation of a point whose reference position is a parameter.
class ReferenceCost final : public ceres::SizedCostFunction<2, 2> {
 public:
  ReferenceCost(const Eigen::Vector2d& z, double sigma) : z_(z), w_(1.0 / sigma) {}
  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    residuals[0] = (params[0][0] - z_.x()) * w_;
    residuals[1] = (params[0][1] - z_.y()) * w_;
    if (jacobians && jacobians[0]) {
      jacobians[0][0] = w_;
      jacobians[0][1] = 0.0;
      jacobians[0][2] = 0.0;
      jacobians[0][3] = w_;
    }
    return true;
  }

 private:
  Eigen::Vector2d z_;
  double w_;
};

}  // namespace

namespace {
/// Ceres logs through glog; its messages (e.g. an unusable start, a rank-deficient covariance)
/// are reported through PlaneBatchResult instead, so glog is initialized once and kept quiet.
void quietGlog() {
  static std::once_flag once;
  std::call_once(once, [] {
    if (!google::IsGoogleLoggingInitialized()) google::InitGoogleLogging("rsfm");
    FLAGS_minloglevel = google::GLOG_FATAL;
    FLAGS_logtostderr = false;
    FLAGS_stderrthreshold = google::GLOG_FATAL;
  });
}
}  // namespace

PlaneBatchResult solvePlaneBatch(const PlaneBatchData& data, const PlaneBatchState& start,
                                 const PlaneBatchOptions& options) {
  quietGlog();
  PlaneBatchResult res;
  const int F = static_cast<int>(data.frames.size()) - 1;
  const int P = static_cast<int>(data.labels.size());
  if (F < 1 || static_cast<int>(start.R.size()) != F + 1 || static_cast<int>(start.t.size()) != F + 1 ||
      static_cast<int>(start.N.size()) != data.num_planes || static_cast<int>(start.ref.size()) != P ||
      data.gauge_plane < 0 || data.gauge_plane >= data.num_planes || data.gauge_component < 0 ||
      data.gauge_component > 2) {
    res.message = "batch: inconsistent problem sizes";
    return res;
  }
  // Parameter storage (Ceres keeps pointers into these).
  std::vector<Eigen::Matrix<double, 6, 1>> motion(F + 1, Eigen::Matrix<double, 6, 1>::Zero());
  for (int k = 1; k <= F; ++k) motion[k].head<3>() = start.t[k];
  double beta = start.beta;
  std::vector<Eigen::Vector3d> N = start.N;
  std::vector<Eigen::Vector2d> ref = start.ref;

  ceres::Problem::Options po;
  ceres::Problem problem(po);
  for (int k = 1; k <= F; ++k) problem.AddParameterBlock(motion[k].data(), 6);
  problem.AddParameterBlock(&beta, 1);
  for (int j = 0; j < data.num_planes; ++j) {
    problem.AddParameterBlock(N[j].data(), 3);
    if (j == data.gauge_plane)
      problem.SetManifold(N[j].data(), new ceres::SubsetManifold(3, {data.gauge_component}));
  }
  std::vector<bool> ref_used(P, false);
  if (options.estimate_references) {
    for (const Observation& o : data.frames[0]) {
      if (o.id < 0 || o.id >= P) continue;
      problem.AddResidualBlock(new ReferenceCost(o.uv, data.sigma_uv), nullptr, ref[o.id].data());
      ref_used[o.id] = true;
      ++res.residuals;
    }
  }
  for (int k = 1; k <= F; ++k)
    for (const Observation& o : data.frames[k]) {
      if (o.id < 0 || o.id >= P) continue;
      const int l = data.labels[o.id];
      if (options.estimate_references) {
        if (!ref_used[o.id]) continue;  // no reference observation: cannot be anchored
        problem.AddResidualBlock(new ObservationCost(start.R[k], o.uv, data.sigma_uv, nullptr),
                                 nullptr, motion[k].data(), &beta, N[l].data(), ref[o.id].data());
      } else {
        problem.AddResidualBlock(new ObservationCost(start.R[k], o.uv, data.sigma_uv, &ref[o.id]),
                                 nullptr, motion[k].data(), &beta, N[l].data());
      }
      ++res.residuals;
    }

  ceres::Solver::Options so;
  so.linear_solver_type = ceres::SPARSE_SCHUR;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = options.function_tolerance;
  so.parameter_tolerance = options.parameter_tolerance;
  so.num_threads = 1;  // callers parallelize over trials
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  res.iterations = static_cast<int>(summary.iterations.size());
  res.initial_cost = summary.initial_cost;
  res.final_cost = summary.final_cost;
  res.message = summary.BriefReport();
  res.converged = summary.IsSolutionUsable() && std::isfinite(summary.final_cost);

  // Result state: fold each frame's omega into its base rotation.
  res.state.R = start.R;
  res.state.t = start.t;
  for (int k = 1; k <= F; ++k) {
    const Eigen::Vector3d w = motion[k].tail<3>();
    if (!incrementalRotationValid(w)) {
      res.converged = false;
      res.message = "batch: rotation left the incremental domain at frame " + std::to_string(k);
      return res;
    }
    res.state.R[k] = incrementalRotation(w) * start.R[k];
    res.state.t[k] = motion[k].head<3>();
  }
  res.state.beta = beta;
  res.state.N = N;
  res.state.ref = ref;

  if (options.compute_covariance && res.converged) {
    ceres::Covariance::Options co;
    co.algorithm_type = ceres::SPARSE_QR;
    co.num_threads = 1;
    ceres::Covariance cov(co);
    std::vector<std::pair<const double*, const double*>> blocks;
    blocks.emplace_back(&beta, &beta);
    for (int j = 0; j < data.num_planes; ++j) {
      blocks.emplace_back(N[j].data(), N[j].data());
      blocks.emplace_back(&beta, N[j].data());
    }
    if (!cov.Compute(blocks, &problem)) {
      res.message += " (covariance: rank-deficient Jacobian, no bound)";
    } else {
      res.covariance_ok = true;
      cov.GetCovarianceBlock(&beta, &beta, &res.var_beta);
      for (int j = 0; j < data.num_planes; ++j) {
        Eigen::Matrix<double, 3, 3, Eigen::RowMajor> C;
        cov.GetCovarianceBlock(N[j].data(), N[j].data(), C.data());
        res.cov_N.push_back(C);
        Eigen::RowVector3d cb;
        cov.GetCovarianceBlock(&beta, N[j].data(), cb.data());
        res.cov_beta_N.push_back(cb);
      }
    }
  }
  return res;
}

}  // namespace rsfm
