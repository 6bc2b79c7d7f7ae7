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

namespace {

/// A point of its plane in the reference frame ([AS99] eq. 12) with its partials: shared by every
/// frame that observes it.
struct PlanePoint {
  MeasureStatus status = MeasureStatus::Ok;
  Eigen::Vector3d p, dpb;
  Eigen::Matrix3d dpN;
  Eigen::Matrix<double, 3, 2> dpu;
};

PlanePoint planePoint(const Eigen::Vector3d& N, double beta, const Eigen::Vector2d& ref) {
  PlanePoint pt;
  pt.status = PlaneModel::point(N, beta, ref, &pt.p, &pt.dpb, &pt.dpN, &pt.dpu);
  return pt;
}

/// The residual of one observation from its frame's motion and its point.
MeasureStatus residualFrom(const MotionContext& m, const PlanePoint& pt, double beta, const Eigen::Vector2d& z, double sigma,
                           Eigen::Vector2d* r, Eigen::Matrix<double, 2, 6>* J_motion, Eigen::Vector2d* J_beta,
                           Eigen::Matrix<double, 2, 3>* J_N, Eigen::Matrix2d* J_ref, const Eigen::Vector4d* camera,
                           Eigen::Matrix<double, 2, 4>* J_camera) {
  if (pt.status != MeasureStatus::Ok) return pt.status;
  Eigen::Vector2d h;
  Eigen::Matrix<double, 2, 7> Hm;
  Eigen::Matrix<double, 2, 3> dhdp;
  const MeasureStatus s = projectWithJacobian(m, pt.p, pt.dpb, &h, &Hm, &dhdp);
  if (s != MeasureStatus::Ok) return s;
  const double w = 1.0 / sigma;
  if (!camera) {
    *r = (h - z) * w;
    if (J_motion) *J_motion = Hm.leftCols<6>() * w;
    if (J_beta) *J_beta = Hm.col(6) * w;
    if (J_N) *J_N = dhdp * pt.dpN * w;
    if (J_ref) *J_ref = dhdp * pt.dpu * w;
    return MeasureStatus::Ok;
  }
  Eigen::Matrix2d Jh;
  Eigen::Vector2d Jb;
  const Eigen::Vector2d u = RadialCamera::apply(*camera, beta, h, &Jh, &Jb, J_camera);
  *r = (u - z) * w;
  if (J_motion) *J_motion = Jh * Hm.leftCols<6>() * w;
  if (J_beta) *J_beta = (Jh * Hm.col(6) + Jb) * w;
  if (J_N) *J_N = Jh * dhdp * pt.dpN * w;
  if (J_ref) *J_ref = Jh * dhdp * pt.dpu * w;
  if (J_camera) *J_camera *= w;
  return MeasureStatus::Ok;
}

}  // namespace

MeasureStatus planeBatchResidual(const Eigen::Vector3d& t, const Eigen::Vector3d& omega,
                                 const Eigen::Matrix3d& R_base, double beta,
                                 const Eigen::Vector3d& N, const Eigen::Vector2d& ref,
                                 const Eigen::Vector2d& z, double sigma, Eigen::Vector2d* r,
                                 Eigen::Matrix<double, 2, 6>* J_motion, Eigen::Vector2d* J_beta,
                                 Eigen::Matrix<double, 2, 3>* J_N, Eigen::Matrix2d* J_ref,
                                 const Eigen::Vector4d* camera, Eigen::Matrix<double, 2, 4>* J_camera) {
  Eigen::Matrix<double, 7, 1> x;
  x << t, omega, beta;
  const MotionContext m = MotionContext::fromState(x, R_base);
  return residualFrom(m, planePoint(N, beta, ref), beta, z, sigma, r, J_motion, J_beta, J_N, J_ref, camera, J_camera);
}

MeasureStatus planeBatchRotationResidual(const Eigen::Vector3d& omega, const Eigen::Matrix3d& R_base, double beta,
                                         const Eigen::Vector2d& ref, const Eigen::Vector2d& z, double sigma,
                                         const Eigen::Vector4d* camera, Eigen::Vector2d* r,
                                         Eigen::Matrix<double, 2, 3>* J_omega, Eigen::Vector2d* J_beta,
                                         Eigen::Matrix2d* J_ref, Eigen::Matrix<double, 2, 4>* J_camera) {
  if (!incrementalRotationValid(omega) || !(beta > 0)) return MeasureStatus::InvalidRotation;
  const Eigen::Matrix3d R = incrementalRotation(omega) * R_base;
  const Eigen::Vector3d d(beta * ref.x(), beta * ref.y(), 1.0);
  const Eigen::Vector3d w = R * d;
  if (!(w.z() > 1e-12)) return MeasureStatus::BehindCamera;
  const Eigen::Vector2d h(w.x() / (beta * w.z()), w.y() / (beta * w.z()));
  // dh/dw
  Eigen::Matrix<double, 2, 3> dhdw;
  dhdw << 1.0 / (beta * w.z()), 0.0, -w.x() / (beta * w.z() * w.z()), 0.0, 1.0 / (beta * w.z()),
      -w.y() / (beta * w.z() * w.z());
  Eigen::Matrix<double, 2, 3> Jw;
  const auto dRi = incrementalRotationDerivatives(omega);
  for (int j = 0; j < 3; ++j) Jw.col(j) = dhdw * (dRi[j] * R_base * d);
  const Eigen::Matrix<double, 2, 2> Jr = dhdw * R.leftCols<2>() * beta;
  const Eigen::Vector2d Jb = dhdw * (R.leftCols<2>() * ref) - h / beta;
  const double wgt = 1.0 / sigma;
  if (!camera) {
    *r = (h - z) * wgt;
    if (J_omega) *J_omega = Jw * wgt;
    if (J_beta) *J_beta = Jb * wgt;
    if (J_ref) *J_ref = Jr * wgt;
    return MeasureStatus::Ok;
  }
  Eigen::Matrix2d Jh;
  Eigen::Vector2d Jbc;
  const Eigen::Vector2d u = RadialCamera::apply(*camera, beta, h, &Jh, &Jbc, J_camera);
  *r = (u - z) * wgt;
  if (J_omega) *J_omega = Jh * Jw * wgt;
  if (J_beta) *J_beta = (Jh * Jb + Jbc) * wgt;
  if (J_ref) *J_ref = Jh * Jr * wgt;
  if (J_camera) *J_camera *= wgt;
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

/// Memoized per-frame motion and per-point plane point: Ceres evaluates one frame's (or one
/// point's) residual blocks one after the other at the same parameter values, so each is
/// computed once per evaluation instead of once per observation (same arithmetic, same result).
struct MotionCache {
  std::array<double, 7> key{};
  bool valid = false;
  MotionContext m;
};
struct PointCache {
  std::array<double, 6> key{};
  bool valid = false;
  PlanePoint pt;
};

/// Where a point's reference position sits in its parameter block: the refinement keeps the
/// references of `group` consecutive points in one block (PlaneBatchOptions::reference_group),
/// this point's at 2 x index. A residual's Jacobian block for it is 2 x (2 group), zero but for
/// the point's two columns.
struct RefSlot {
  int group = 1, index = 0;
  /// The point's reference position in `block`.
  Eigen::Vector2d read(const double* block) const { return {block[2 * index], block[2 * index + 1]}; }
  /// Its 2 x 2 Jacobian `Ju` as the residual's 2 x (2 group) row-major block `J`.
  void write(const Eigen::Matrix2d& Ju, double* J) const {
    const int w = 2 * group;
    std::fill(J, J + 2 * w, 0.0);
    for (int r = 0; r < 2; ++r)
      for (int c = 0; c < 2; ++c) J[r * w + 2 * index + c] = Ju(r, c);  // row-major
  }
};

/// A rolling shutter's readout (PlaneBatchData::readout_shift) in a residual: the prediction
/// moved by readout x shift, so the whitened residual by readout x shift / sigma, which is also
/// its Jacobian with respect to the readout (one more parameter block, the last, of size 1).
struct ReadoutTerm {
  bool on = false;
  Eigen::Vector2d shift = Eigen::Vector2d::Zero();
  /// Adds the term to `residuals` and writes the block's Jacobian; `block` is the readout's.
  void apply(const double* block, double sigma, double* residuals, double* jacobian) const {
    const double w = 1.0 / sigma;
    residuals[0] += block[0] * shift.x() * w;
    residuals[1] += block[0] * shift.y() * w;
    if (jacobian) {
      jacobian[0] = shift.x() * w;
      jacobian[1] = shift.y() * w;
    }
  }
};

/// One observation at frame k >= 1. Parameter blocks: motion (6), beta (1), N (3)[, ref (2 group)][, camera (4)][,
/// readout (1)].
class ObservationCost final : public ceres::CostFunction {
 public:
  ObservationCost(const Eigen::Matrix3d& R_base, const Eigen::Vector2d& z, double sigma,
                  const Eigen::Vector2d* fixed_ref, bool camera, MotionCache* mc, PointCache* pc, RefSlot slot = {},
                  ReadoutTerm readout = {})
      : R_base_(R_base), z_(z), sigma_(sigma), has_fixed_ref_(fixed_ref != nullptr), camera_(camera), mc_(mc), pc_(pc),
        slot_(slot), readout_(readout) {
    if (fixed_ref) fixed_ref_ = *fixed_ref;
    set_num_residuals(2);
    mutable_parameter_block_sizes()->push_back(6);
    mutable_parameter_block_sizes()->push_back(1);
    mutable_parameter_block_sizes()->push_back(3);
    if (!has_fixed_ref_) mutable_parameter_block_sizes()->push_back(2 * slot_.group);
    if (camera_) mutable_parameter_block_sizes()->push_back(4);
    if (readout_.on) mutable_parameter_block_sizes()->push_back(1);
  }

  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    const Eigen::Map<const Eigen::Matrix<double, 6, 1>> motion(params[0]);
    const double beta = params[1][0];
    const Eigen::Map<const Eigen::Vector3d> N(params[2]);
    const Eigen::Vector2d ref =
        has_fixed_ref_ ? fixed_ref_ : slot_.read(params[3]);
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
    const std::array<double, 7> mk{motion[0], motion[1], motion[2], motion[3], motion[4], motion[5], beta};
    if (!mc_->valid || mc_->key != mk) {
      Eigen::Matrix<double, 7, 1> x;
      x << motion, beta;
      mc_->m = MotionContext::fromState(x, R_base_);
      mc_->key = mk;
      mc_->valid = true;
    }
    const std::array<double, 6> pk{N.x(), N.y(), N.z(), beta, ref.x(), ref.y()};
    if (!pc_->valid || pc_->key != pk) {
      pc_->pt = planePoint(N, beta, ref);
      pc_->key = pk;
      pc_->valid = true;
    }
    if (residualFrom(mc_->m, pc_->pt, beta, z_, sigma_, &r, want ? &Jm : nullptr, want ? &Jb : nullptr,
                     want ? &JN : nullptr, want ? &Ju : nullptr, camera_ ? &cam : nullptr,
                     want && camera_ ? &Jc : nullptr) != MeasureStatus::Ok)
      return false;  // Ceres treats the step as unsuccessful and shrinks it
    residuals[0] = r[0];
    residuals[1] = r[1];
    if (readout_.on) {
      const int b = cam_block + (camera_ ? 1 : 0);
      readout_.apply(params[b], sigma_, residuals, jacobians ? jacobians[b] : nullptr);
    }
    if (jacobians) {
      using M26 = Eigen::Matrix<double, 2, 6, Eigen::RowMajor>;
      using M23 = Eigen::Matrix<double, 2, 3, Eigen::RowMajor>;
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
      if (!has_fixed_ref_ && jacobians[3]) slot_.write(Ju, jacobians[3]);
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
  MotionCache* mc_;
  PointCache* pc_;
  RefSlot slot_;
  ReadoutTerm readout_;
  Eigen::Vector2d fixed_ref_ = Eigen::Vector2d::Zero();
};

/// One observation at frame k >= 1 under pure rotation. Blocks: motion (6; its translation held),
/// beta (1), ref (2)[, camera (4)][, readout (1)].
class RotationObservationCost final : public ceres::CostFunction {
 public:
  RotationObservationCost(const Eigen::Matrix3d& R_base, const Eigen::Vector2d& z, double sigma, bool camera,
                          RefSlot slot = {}, ReadoutTerm readout = {})
      : R_base_(R_base), z_(z), sigma_(sigma), camera_(camera), slot_(slot), readout_(readout) {
    set_num_residuals(2);
    mutable_parameter_block_sizes()->push_back(6);
    mutable_parameter_block_sizes()->push_back(1);
    mutable_parameter_block_sizes()->push_back(2 * slot_.group);
    if (camera_) mutable_parameter_block_sizes()->push_back(4);
    if (readout_.on) mutable_parameter_block_sizes()->push_back(1);
  }
  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    const Eigen::Vector3d omega(params[0][3], params[0][4], params[0][5]);
    const Eigen::Vector2d ref = slot_.read(params[2]);
    Eigen::Vector4d cam = Eigen::Vector4d::Zero();
    if (camera_) cam = Eigen::Map<const Eigen::Vector4d>(params[3]);
    Eigen::Vector2d r, Jb;
    Eigen::Matrix<double, 2, 3> Jw;
    Eigen::Matrix2d Ju;
    Eigen::Matrix<double, 2, 4> Jc;
    if (planeBatchRotationResidual(omega, R_base_, params[1][0], ref, z_, sigma_, camera_ ? &cam : nullptr, &r, &Jw, &Jb, &Ju,
                                   camera_ ? &Jc : nullptr) != MeasureStatus::Ok)
      return false;
    residuals[0] = r[0];
    residuals[1] = r[1];
    if (readout_.on) {
      const int b = camera_ ? 4 : 3;
      readout_.apply(params[b], sigma_, residuals, jacobians ? jacobians[b] : nullptr);
    }
    if (jacobians) {
      if (jacobians[0]) {
        Eigen::Map<Eigen::Matrix<double, 2, 6, Eigen::RowMajor>> J0(jacobians[0]);
        J0.leftCols<3>().setZero();
        J0.rightCols<3>() = Jw;
      }
      if (jacobians[1]) {
        Eigen::Map<Eigen::Vector2d> J1(jacobians[1]);
        J1 = Jb;
      }
      if (jacobians[2]) slot_.write(Ju, jacobians[2]);
      if (camera_ && jacobians[3]) {
        Eigen::Map<Eigen::Matrix<double, 2, 4, Eigen::RowMajor>> J3(jacobians[3]);
        J3 = Jc;
      }
    }
    return true;
  }

 private:
  Eigen::Matrix3d R_base_;
  Eigen::Vector2d z_;
  double sigma_;
  bool camera_;
  RefSlot slot_;
  ReadoutTerm readout_;
};

/// Gaussian priors on the camera's components about zero: (camera_c / sd_c) for sd_c > 0.
class CameraPriorCost final : public ceres::SizedCostFunction<4, 4> {
 public:
  explicit CameraPriorCost(const std::array<double, 4>& sd) {
    for (int c = 0; c < 4; ++c) w_[c] = sd[c] > 0 ? 1.0 / sd[c] : 0.0;
  }
  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    for (int c = 0; c < 4; ++c) residuals[c] = params[0][c] * w_[c];
    if (jacobians && jacobians[0]) {
      for (int i = 0; i < 16; ++i) jacobians[0][i] = 0.0;
      for (int c = 0; c < 4; ++c) jacobians[0][5 * c] = w_[c];
    }
    return true;
  }

 private:
  std::array<double, 4> w_{};
};

/// A Gaussian prior on the readout about zero: readout / sd.
class ReadoutPriorCost final : public ceres::SizedCostFunction<1, 1> {
 public:
  explicit ReadoutPriorCost(double sd) : w_(1.0 / sd) {}
  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    residuals[0] = params[0][0] * w_;
    if (jacobians && jacobians[0]) jacobians[0][0] = w_;
    return true;
  }

 private:
  double w_;
};

/// Reference-frame observation through the camera: blocks ref (2 group), beta (1), camera (4)[, readout (1)].
class ReferenceCameraCost final : public ceres::CostFunction {
 public:
  ReferenceCameraCost(const Eigen::Vector2d& z, double sigma, RefSlot slot = {}, ReadoutTerm readout = {})
      : z_(z), sigma_(sigma), slot_(slot), readout_(readout) {
    set_num_residuals(2);
    mutable_parameter_block_sizes()->push_back(2 * slot_.group);
    mutable_parameter_block_sizes()->push_back(1);
    mutable_parameter_block_sizes()->push_back(4);
    if (readout_.on) mutable_parameter_block_sizes()->push_back(1);
  }
  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    const Eigen::Vector2d ref = slot_.read(params[0]);
    const Eigen::Map<const Eigen::Vector4d> cam(params[2]);
    Eigen::Vector2d r, Jb;
    Eigen::Matrix2d Ju;
    Eigen::Matrix<double, 2, 4> Jc;
    planeBatchReferenceResidual(ref, params[1][0], cam, z_, sigma_, &r, &Ju, &Jb, &Jc);
    residuals[0] = r[0];
    residuals[1] = r[1];
    if (readout_.on) readout_.apply(params[3], sigma_, residuals, jacobians ? jacobians[3] : nullptr);
    if (jacobians) {
      if (jacobians[0]) slot_.write(Ju, jacobians[0]);
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
  RefSlot slot_;
  ReadoutTerm readout_;
};

/// Reference-frame observation of a point whose reference position is a parameter (block: ref (2 group)).
class ReferenceCost final : public ceres::CostFunction {
 public:
  ReferenceCost(const Eigen::Vector2d& z, double sigma, RefSlot slot = {}) : z_(z), w_(1.0 / sigma), slot_(slot) {
    set_num_residuals(2);
    mutable_parameter_block_sizes()->push_back(2 * slot_.group);
  }
  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    const Eigen::Vector2d ref = slot_.read(params[0]);
    residuals[0] = (ref.x() - z_.x()) * w_;
    residuals[1] = (ref.y() - z_.y()) * w_;
    if (jacobians && jacobians[0]) slot_.write(Eigen::Matrix2d::Identity() * w_, jacobians[0]);
    return true;
  }

 private:
  Eigen::Vector2d z_;
  double w_;
  RefSlot slot_;
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

bool stalledAfterInvalidSteps(const std::vector<SolveStep>& steps, double function_tolerance) {
  bool invalid_tail = false;
  for (auto it = steps.rbegin(); it != steps.rend(); ++it) {
    if (it->successful) {
      const double before = it->cost + it->cost_change;
      return invalid_tail && before > 0 && it->cost_change / before > function_tolerance;
    }
    if (!(it->cost < 1e300)) invalid_tail = true;  // Ceres records an unevaluable step's cost as the largest double
  }
  return false;  // no successful step: nothing was falling
}

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
  // One buffer for every parameter but the motions, in a fixed order (beta, the planes, the
  // camera, the references, the readout): Ceres orders the blocks of one elimination group by address, so
  // this layout fixes the arithmetic whatever the heap looked like (every caller gets the same
  // numbers for the same problem).
  const int m = data.num_planes;
  std::vector<double> store(1 + 3 * m + 4 + 2 * P + 1);
  double& beta = store[0];
  beta = start.beta;
  std::vector<Eigen::Map<Eigen::Vector3d>> N;
  for (int j = 0; j < m; ++j) {
    N.emplace_back(store.data() + 1 + 3 * j);
    N.back() = start.N[j];
  }
  Eigen::Map<Eigen::Vector4d> camera(store.data() + 1 + 3 * m);
  camera = start.camera;
  std::vector<Eigen::Map<Eigen::Vector2d>> ref;
  for (int i = 0; i < P; ++i) {
    ref.emplace_back(store.data() + 1 + 3 * m + 4 + 2 * i);
    ref.back() = start.ref[i];
  }
  // The readout: a parameter block of its own whenever the data carry a rolling shutter's shifts
  // and it is free or non-zero; it then goes with the camera's block (held at zero when unused:
  // RadialCamera of the zero camera is the identity), so the frame-0 residuals have one form.
  if (!data.readoutShiftMatches()) {
    res.message = "batch: readout_shift does not match the observations";
    return res;
  }
  double& readout = store.back();
  readout = start.readout;
  const bool use_readout = data.hasReadout() && (options.readout_free || readout != 0.0);
  const bool use_camera = std::any_of(options.camera_free.begin(), options.camera_free.end(), [](bool b) { return b; }) ||
                          !camera.isZero(0.0) || use_readout;
  auto readoutTerm = [&](int k, std::size_t j) {
    ReadoutTerm t;
    t.on = use_readout;
    if (use_readout) t.shift = data.readout_shift[k][j];
    return t;
  };
  ceres::LossFunction* loss = nullptr;  // one instance for every residual, owned by loss_owner
  if (options.loss == PlaneBatchOptions::Loss::Huber) loss = new ceres::HuberLoss(options.loss_scale);
  if (options.loss == PlaneBatchOptions::Loss::Cauchy) loss = new ceres::CauchyLoss(options.loss_scale);

  ceres::Problem::Options po;
  po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  std::unique_ptr<ceres::LossFunction> loss_owner(loss);
  ceres::Problem problem(po);
  for (int k = 1; k <= F; ++k) {
    problem.AddParameterBlock(motion[k].data(), 6);
    if (options.rotation_only) problem.SetManifold(motion[k].data(), new ceres::SubsetManifold(6, {0, 1, 2}));
    if (options.translation_only) problem.SetManifold(motion[k].data(), new ceres::SubsetManifold(6, {3, 4, 5}));
  }
  problem.AddParameterBlock(&beta, 1);
  if (options.hold_beta) problem.SetParameterBlockConstant(&beta);
  for (int j = 0; j < data.num_planes && !options.rotation_only; ++j) {
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
    std::array<double, 4> prior{0, 0, 0, 0};
    for (int c = 0; c < 4; ++c)
      if (options.camera_free[c]) prior[c] = options.camera_prior_sd[c];
    if (std::any_of(prior.begin(), prior.end(), [](double v) { return v > 0; }))
      problem.AddResidualBlock(new CameraPriorCost(prior), nullptr, camera.data());
  }
  if (use_readout) {
    problem.AddParameterBlock(&readout, 1);
    if (!options.readout_free) problem.SetParameterBlockConstant(&readout);
    if (options.readout_free && options.readout_prior_sd > 0)
      problem.AddResidualBlock(new ReadoutPriorCost(options.readout_prior_sd), nullptr, &readout);
  }
  // The references' parameter blocks: with the motions eliminated first, Ceres' Schur
  // elimination updates the reduced matrix one cell per pair of blocks seen in a frame, each cell
  // behind a lock (docs/performance.md, "The refinement"); `reference_group` consecutive points
  // observed in the problem share one block, so there are group^2 times fewer, larger cells.
  // The problem and its optimum are the same (a block's other columns have zero Jacobians).
  std::vector<RefSlot> slot(P);  // a point never observed: {1, 0}, not a parameter
  {
    const int g = options.eliminate_motions_first ? std::max(1, options.reference_group) : 1;
    std::vector<char> seen(P, 0);
    for (int k = options.estimate_references ? 0 : 1; k <= F; ++k)
      for (const Observation& o : data.frames[k])
        if (o.id >= 0 && o.id < P) seen[o.id] = 1;
    for (int i = 0; i < P;) {
      if (!seen[i]) {
        ++i;
        continue;
      }
      int n = 0;
      while (n < g && i + n < P && seen[i + n]) ++n;
      for (int j = 0; j < n; ++j) slot[i + j] = RefSlot{n, j};
      i += n;
    }
  }
  auto refBlock = [&](int i) { return ref[i - slot[i].index].data(); };  // its group's first point
  if (options.estimate_references) {
    for (std::size_t j = 0; j < data.frames[0].size(); ++j) {
      const Observation& o = data.frames[0][j];
      if (o.id < 0 || o.id >= P) continue;
      if (use_camera) {
        std::vector<double*> blocks{refBlock(o.id), &beta, camera.data()};
        if (use_readout) blocks.push_back(&readout);
        problem.AddResidualBlock(new ReferenceCameraCost(o.uv, data.sigma_uv, slot[o.id], readoutTerm(0, j)), loss, blocks);
      } else
        problem.AddResidualBlock(new ReferenceCost(o.uv, data.sigma_uv, slot[o.id]), loss, refBlock(o.id));
      ++res.residuals;
    }
  }
  std::vector<MotionCache> motion_cache(F + 1);
  std::vector<PointCache> point_cache(P);
  for (int k = 1; k <= F; ++k)
    for (std::size_t j = 0; j < data.frames[k].size(); ++j) {
      const Observation& o = data.frames[k][j];
      if (o.id < 0 || o.id >= P) continue;
      const int l = data.labels[o.id];
      if (options.rotation_only) {
        std::vector<double*> rblocks{motion[k].data(), &beta, refBlock(o.id)};
        if (use_camera) rblocks.push_back(camera.data());
        if (use_readout) rblocks.push_back(&readout);
        problem.AddResidualBlock(
            new RotationObservationCost(start.R[k], o.uv, data.sigma_uv, use_camera, slot[o.id], readoutTerm(k, j)), loss,
            rblocks);
        ++res.residuals;
        continue;
      }
      std::vector<double*> blocks{motion[k].data(), &beta, N[l].data()};
      if (options.estimate_references) blocks.push_back(refBlock(o.id));
      if (use_camera) blocks.push_back(camera.data());
      if (use_readout) blocks.push_back(&readout);
      problem.AddResidualBlock(
          new ObservationCost(start.R[k], o.uv, data.sigma_uv, options.estimate_references ? nullptr : &start.ref[o.id], use_camera,
                              &motion_cache[k], &point_cache[o.id], slot[o.id], readoutTerm(k, j)),
          loss, blocks);
      ++res.residuals;
    }

  ceres::Solver::Options so;
  so.linear_solver_type = ceres::SPARSE_SCHUR;
  if (options.eliminate_motions_first) {
    auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
    for (int k = 1; k <= F; ++k) ordering->AddElementToGroup(motion[k].data(), 0);
    ordering->AddElementToGroup(&beta, 1);
    for (auto& n : N)
      if (problem.HasParameterBlock(n.data())) ordering->AddElementToGroup(n.data(), 1);
    for (auto& u : ref)
      if (problem.HasParameterBlock(u.data())) ordering->AddElementToGroup(u.data(), 1);
    if (use_camera) ordering->AddElementToGroup(camera.data(), 1);
    if (use_readout) ordering->AddElementToGroup(&readout, 1);
    so.linear_solver_ordering = ordering;
    so.linear_solver_type = ceres::DENSE_SCHUR;
  }
  if (options.trust_region == PlaneBatchOptions::TrustRegion::Dogleg) so.trust_region_strategy_type = ceres::DOGLEG;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = options.function_tolerance;
  so.parameter_tolerance = options.parameter_tolerance;
  so.num_threads = 1;  // callers parallelize over trials
  so.logging_type = ceres::SILENT;
  // The caller's progress after every iteration, and its test after every successful step: Ceres
  // then writes each step's values back into `store` (update_state_every_iteration), where N and
  // the references lie contiguously.
  struct Watch final : ceres::IterationCallback {
    const PlaneBatchOptions::StopWhen* test = nullptr;
    const std::function<void(int, double)>* on_iteration = nullptr;
    const std::vector<double>* store = nullptr;
    int m = 0, P = 0;
    bool fired = false;
    ceres::CallbackReturnType operator()(const ceres::IterationSummary& it) override {
      if (on_iteration) (*on_iteration)(it.iteration, it.cost);
      if (!test || it.iteration == 0 || !it.step_is_successful) return ceres::SOLVER_CONTINUE;
      const double* base = store->data();
      fired = (*test)(base[0], Eigen::Map<const Eigen::Matrix3Xd>(base + 1, 3, m),
                      Eigen::Map<const Eigen::Matrix2Xd>(base + 1 + 3 * m + 4, 2, P));
      return fired ? ceres::SOLVER_TERMINATE_SUCCESSFULLY : ceres::SOLVER_CONTINUE;
    }
  } watch;
  if (options.stop_when) {
    watch.test = &options.stop_when;
    watch.store = &store;
    watch.m = m;
    watch.P = P;
    so.update_state_every_iteration = true;
  }
  if (options.on_iteration) watch.on_iteration = &options.on_iteration;
  if (options.stop_when || options.on_iteration) so.callbacks.push_back(&watch);
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  res.iterations = static_cast<int>(summary.iterations.size());
  res.initial_cost = summary.initial_cost;
  res.final_cost = summary.final_cost;
  res.message = summary.BriefReport();
  res.converged = summary.IsSolutionUsable() && std::isfinite(summary.final_cost);
  res.at_iteration_limit = res.converged && summary.termination_type == ceres::NO_CONVERGENCE;
  res.stopped_early = res.converged && watch.fired && summary.termination_type == ceres::USER_SUCCESS;
  if (res.converged && summary.termination_type == ceres::CONVERGENCE) {
    std::vector<SolveStep> steps;
    for (const auto& it : summary.iterations)
      if (it.iteration > 0) steps.push_back({it.step_is_successful, it.cost, it.cost_change});
    res.stalled = stalledAfterInvalidSteps(steps, options.function_tolerance);
  }

  // Result state: fold each frame's omega into its base rotation.
  res.state.R = start.R;
  res.state.t = start.t;
  for (int k = 1; k <= F; ++k) {
    const Eigen::Vector3d w = motion[k].tail<3>();
    if (!incrementalRotationValid(w)) {
      res.converged = false;
      res.message = "batch: rotation left the incremental domain at frame " + std::to_string(data.frameName(k));
      return res;
    }
    res.state.R[k] = incrementalRotation(w) * start.R[k];
    res.state.t[k] = motion[k].head<3>();
  }
  res.state.beta = beta;
  res.state.N.assign(N.begin(), N.end());
  res.state.ref.assign(ref.begin(), ref.end());
  res.state.camera = camera;
  res.state.readout = readout;

  if (options.compute_covariance && res.converged && !options.hold_beta && !options.rotation_only) {
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
