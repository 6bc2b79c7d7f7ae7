#include "rsfm/batch/plane_batch.hpp"

#include <ceres/ceres.h>
#include <glog/logging.h>

#include <algorithm>
#include <memory>
#include <mutex>

#include "rsfm/camera.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/models/radial_camera.hpp"
#include "rsfm/rotation.hpp"

namespace rsfm {

MeasureStatus planeBatchResidual(const Eigen::Vector3d& t, const Eigen::Vector3d& omega,
                                 const Eigen::Matrix3d& R_base, double beta,
                                 const Eigen::Vector3d& N, const Eigen::Vector2d& ref,
                                 const Eigen::Vector2d& z, double sigma, Eigen::Vector2d* r,
                                 Eigen::Matrix<double, 2, 6>* J_motion, Eigen::Vector2d* J_beta,
                                 Eigen::Matrix<double, 2, 3>* J_N, Eigen::Matrix2d* J_ref,
                                 const Eigen::Vector4d* camera, Eigen::Matrix<double, 2, 4>* J_camera) {
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
  if (!camera) {
    *r = (h - z) * w;
    if (J_motion) *J_motion = Hm.leftCols<6>() * w;
    if (J_beta) *J_beta = Hm.col(6) * w;
    if (J_N) *J_N = dhdp * dpN * w;
    if (J_ref) *J_ref = dhdp * dpu * w;
    return MeasureStatus::Ok;
  }
  Eigen::Matrix2d Jh;
  Eigen::Vector2d Jb;
  const Eigen::Vector2d u = RadialCamera::apply(*camera, beta, h, &Jh, &Jb, J_camera);
  *r = (u - z) * w;
  if (J_motion) *J_motion = Jh * Hm.leftCols<6>() * w;
  if (J_beta) *J_beta = (Jh * Hm.col(6) + Jb) * w;
  if (J_N) *J_N = Jh * dhdp * dpN * w;
  if (J_ref) *J_ref = Jh * dhdp * dpu * w;
  if (J_camera) *J_camera *= w;
  return MeasureStatus::Ok;
}

void planeBatchReferenceResidual(const Eigen::Vector2d& ref, double beta, const Eigen::Vector4d& camera,
                                 const Eigen::Vector2d& z, double sigma, Eigen::Vector2d* r, Eigen::Matrix2d* J_ref,
                                 Eigen::Vector2d* J_beta, Eigen::Matrix<double, 2, 4>* J_camera) {
  const double w = 1.0 / sigma;
  *r = (RadialCamera::apply(camera, beta, ref, J_ref, J_beta, J_camera) - z) * w;
  if (J_ref) *J_ref *= w;
  if (J_beta) *J_beta *= w;
  if (J_camera) *J_camera *= w;
}

namespace {

/// One observation at frame k >= 1. Parameter blocks: motion (6), beta (1), N (3)[, ref (2)][, camera (4)].
class ObservationCost final : public ceres::CostFunction {
 public:
  ObservationCost(const Eigen::Matrix3d& R_base, const Eigen::Vector2d& z, double sigma,
                  const Eigen::Vector2d* fixed_ref, bool camera = false)
      : R_base_(R_base), z_(z), sigma_(sigma), has_fixed_ref_(fixed_ref != nullptr), camera_(camera) {
    if (fixed_ref) fixed_ref_ = *fixed_ref;
    set_num_residuals(2);
    mutable_parameter_block_sizes()->push_back(6);
    mutable_parameter_block_sizes()->push_back(1);
    mutable_parameter_block_sizes()->push_back(3);
    if (!has_fixed_ref_) mutable_parameter_block_sizes()->push_back(2);
    if (camera_) mutable_parameter_block_sizes()->push_back(4);
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
    Eigen::Matrix<double, 2, 4> Jc;
    const bool want = jacobians != nullptr;
    const int cam_block = has_fixed_ref_ ? 3 : 4;
    Eigen::Vector4d cam = Eigen::Vector4d::Zero();
    if (camera_) cam = Eigen::Map<const Eigen::Vector4d>(params[cam_block]);
    if (planeBatchResidual(motion.head<3>(), motion.tail<3>(), R_base_, beta, N, ref, z_, sigma_,
                           &r, want ? &Jm : nullptr, want ? &Jb : nullptr, want ? &JN : nullptr,
                           want ? &Ju : nullptr, camera_ ? &cam : nullptr,
                           want && camera_ ? &Jc : nullptr) != MeasureStatus::Ok)
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
      if (camera_ && jacobians[cam_block]) {
        Eigen::Map<Eigen::Matrix<double, 2, 4, Eigen::RowMajor>> J4(jacobians[cam_block]);
        J4 = Jc;
      }
    }
    return true;
  }

 private:
  Eigen::Matrix3d R_base_;
  Eigen::Vector2d z_;
  double sigma_;
  bool has_fixed_ref_;
  bool camera_;
  Eigen::Vector2d fixed_ref_ = Eigen::Vector2d::Zero();
};

/// Reference-frame observation through the camera: blocks ref (2), beta (1), camera (4).
class ReferenceCameraCost final : public ceres::SizedCostFunction<2, 2, 1, 4> {
 public:
  ReferenceCameraCost(const Eigen::Vector2d& z, double sigma) : z_(z), sigma_(sigma) {}
  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    const Eigen::Vector2d ref(params[0][0], params[0][1]);
    const Eigen::Map<const Eigen::Vector4d> cam(params[2]);
    Eigen::Vector2d r, Jb;
    Eigen::Matrix2d Ju;
    Eigen::Matrix<double, 2, 4> Jc;
    planeBatchReferenceResidual(ref, params[1][0], cam, z_, sigma_, &r, &Ju, &Jb, &Jc);
    residuals[0] = r[0];
    residuals[1] = r[1];
    if (jacobians) {
      if (jacobians[0]) {
        Eigen::Map<Eigen::Matrix<double, 2, 2, Eigen::RowMajor>> J0(jacobians[0]);
        J0 = Ju;
      }
      if (jacobians[1]) {
        Eigen::Map<Eigen::Vector2d> J1(jacobians[1]);
        J1 = Jb;
      }
      if (jacobians[2]) {
        Eigen::Map<Eigen::Matrix<double, 2, 4, Eigen::RowMajor>> J2(jacobians[2]);
        J2 = Jc;
      }
    }
    return true;
  }

 private:
  Eigen::Vector2d z_;
  double sigma_;
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
  Eigen::Vector4d camera = start.camera;
  const bool use_camera = std::any_of(options.camera_free.begin(), options.camera_free.end(), [](bool b) { return b; }) ||
                          !camera.isZero(0.0);
  ceres::LossFunction* loss = nullptr;  // owned by the problem (one shared instance)
  if (options.loss == PlaneBatchOptions::Loss::Huber) loss = new ceres::HuberLoss(options.loss_scale);
  if (options.loss == PlaneBatchOptions::Loss::Cauchy) loss = new ceres::CauchyLoss(options.loss_scale);

  ceres::Problem::Options po;
  po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  std::unique_ptr<ceres::LossFunction> loss_owner(loss);
  ceres::Problem problem(po);
  for (int k = 1; k <= F; ++k) problem.AddParameterBlock(motion[k].data(), 6);
  problem.AddParameterBlock(&beta, 1);
  for (int j = 0; j < data.num_planes; ++j) {
    problem.AddParameterBlock(N[j].data(), 3);
    if (j == data.gauge_plane)
      problem.SetManifold(N[j].data(), new ceres::SubsetManifold(3, {data.gauge_component}));
  }
  if (use_camera) {
    problem.AddParameterBlock(camera.data(), 4);
    std::vector<int> held;
    for (int c = 0; c < 4; ++c)
      if (!options.camera_free[c]) held.push_back(c);
    if (held.size() == 4)
      problem.SetParameterBlockConstant(camera.data());
    else if (!held.empty())
      problem.SetManifold(camera.data(), new ceres::SubsetManifold(4, held));
  }
  if (options.estimate_references) {
    for (const Observation& o : data.frames[0]) {
      if (o.id < 0 || o.id >= P) continue;
      if (use_camera)
        problem.AddResidualBlock(new ReferenceCameraCost(o.uv, data.sigma_uv), loss, ref[o.id].data(), &beta,
                                 camera.data());
      else
        problem.AddResidualBlock(new ReferenceCost(o.uv, data.sigma_uv), loss, ref[o.id].data());
      ++res.residuals;
    }
  }
  for (int k = 1; k <= F; ++k)
    for (const Observation& o : data.frames[k]) {
      if (o.id < 0 || o.id >= P) continue;
      const int l = data.labels[o.id];
      std::vector<double*> blocks{motion[k].data(), &beta, N[l].data()};
      if (options.estimate_references) blocks.push_back(ref[o.id].data());
      if (use_camera) blocks.push_back(camera.data());
      problem.AddResidualBlock(
          new ObservationCost(start.R[k], o.uv, data.sigma_uv, options.estimate_references ? nullptr : &ref[o.id], use_camera),
          loss, blocks);
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
  res.state.camera = camera;

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
