#pragma once
// Calway's affine-patch model ([Cal00]; docs/patches.md): K tracked affine patches, each with its own
// tangent plane, observed through the 6 parameters of its local affine map between consecutive
// frames.
//
// State x = (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z, beta, s_1, ..., s_K): 7 + 3K, with
// s_k = (p1, p2, p4) the normalized plane parameters of patch k (docs/patches.md, "Model"):
//   patch plane n . X = d in the CURRENT camera frame (A&P coordinates: origin on the image plane,
//   centre of projection at (0, 0, -1/beta)), sigma = n_3 + beta d > 0 for a visible plane,
//   (p1, p2, p3, p4) = (n_1, n_2, n_3, d) / sigma, so p3 = 1 - beta p4 is not stored.
//   For image points (u, v) of the plane: g = Z / (1 + beta Z) = p4 - p1 u - p2 v.
// Motion (t, omega) is the INTER-FRAME motion from the previous camera to the current one,
// X_cur = t + R(dq(omega)) X_prev ([AS99] eq. 6 with the previous frame as reference), kept with
// identity dynamics (constant velocity); t_Z is stored as t_Z beta. Units: normalized image units
// (docs/conventions.md) and the scene units fixed by the gauge.
//
// Measurement of patch k ([Cal00] eqn (8), re-derived in docs/patches.md), about its centre
// c = (u_k, v_k) in the previous frame, as z = (h_u, h_v, A_11, A_12, A_21, A_22): h is the
// centre's position in the current frame and A the 2x2 local Jacobian of the image map
// previous -> current at c.
//   Exact:  H = R + beta tbar P^T (the plane-induced homography in centre-of-projection
//           coordinates), tbar = t + (I - R) (0, 0, 1/beta), P = (p1, p2, p3); with the ray
//           y = (beta u, beta v, 1) and w = H y:  h = (w_1, w_2) / (beta w_3),
//           A = (H[0:2, 0:2] - beta h H[2, 0:2]) / w_3  (= K H K^-1 linearized, K = diag(1/beta, 1/beta, 1)).
//   Instantaneous: first order in the motion (V = t, W = beta t_Z, Omega = omega):
//           h = c + b, A = I + a with b, a the flow formulas of docs/patches.md.
// The two agree to first order in the motion (tests/test_patches.cpp).
//
// Transition (Murray & Shapiro, [MS96] via [Cal00]; re-derived in docs/patches.md): after each
// update the structure is carried into the new current frame,
//   P' = R P / s, p4' = (p4 + (R P) . t) / s, s = (R P)_3 + beta p4 + beta (R P) . t,
// and then the whole scene is rescaled about the centre of projection so that the gauge patch keeps
// its fixed p4 (see regauge()). Motion and beta keep identity dynamics.
#include <Eigen/Core>
#include <vector>

#include "rsfm/models/projection.hpp"

namespace rsfm {

using Vector6d = Eigen::Matrix<double, 6, 1>;
/// Jacobian of one patch quantity with respect to (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z,
/// beta, p1, p2, p4): 7 motion columns then the patch's 3 structure columns.
template <int Rows>
using PatchJacobian = Eigen::Matrix<double, Rows, 10>;

/// Which affine measurement function the patch filter uses (docs/patches.md).
enum class AffineMeasurement {
  Exact,          ///< plane-induced homography linearized at the patch centre
  Instantaneous,  ///< first-order (velocity) flow form
};

/// One patch's measurement in the current frame.
struct AffineObservation {
  int id = 0;  ///< patch index in the model (state slot)
  /// (h_u, h_v, A_11, A_12, A_21, A_22): the patch centre in the current frame (normalized units)
  /// and the local affine map from the previous frame to the current one (unitless); with
  /// PatchCentres::State the map from the patch's template frame instead (cumulative).
  Vector6d z = Vector6d::Zero();
  /// Extra covariance of the map entries (A_11, A_12, A_21, A_22), added to the filter's R: e.g.
  /// the uncertainty of the previous cumulative map when A is derived from fused maps
  /// (pipeline/patch_pipeline.hpp). Zero by default.
  Eigen::Matrix4d map_cov = Eigen::Matrix4d::Zero();
};

class PatchModel {
 public:
  static constexpr int kMeasDim = 6;
  static constexpr int kStructurePerPatch = 3;
  /// Patches needed per update: 6K measurements against 6 motion parameters, beta and 3K - 1 free
  /// structure parameters per frame (6K > 7 + 3K - 1 for K >= 3).
  static constexpr int kMinPatches = 3;
  /// 1 - beta g (the ratio of image-plane-origin to centre-of-projection depth) below this means the
  /// patch centre is (nearly) at or behind the centre of projection: reported as BehindCamera.
  static constexpr double kMinDepthFactor = 1e-6;

  PatchModel() = default;
  /// `centres`: each patch's centre in the current (first) frame (normalized units).
  explicit PatchModel(std::vector<Eigen::Vector2d> centres) : centres_(std::move(centres)) {}

  int numPatches() const { return static_cast<int>(centres_.size()); }
  int stateDim() const { return 7 + 3 * numPatches(); }
  static int structureIndex(int k) { return 7 + 3 * k; }
  /// State index of patch k's p4 (the gauge candidate).
  static int p4Index(int k) { return 7 + 3 * k + 2; }
  const Eigen::Vector2d& centre(int k) const { return centres_[k]; }
  void setCentre(int k, const Eigen::Vector2d& c) { centres_[k] = c; }
  int addPatch(const Eigen::Vector2d& centre) {
    centres_.push_back(centre);
    return numPatches() - 1;
  }
  void removePatch(int k) { centres_.erase(centres_.begin() + k); }

  /// Exact measurement of a patch centred at c (previous frame) with structure s = (p1, p2, p4)
  /// under motion m = x.head<7>(); J (optional) is dz/d(m, s), Jc (optional) dz/dc:
  /// dh/dc = A and dA/dc_j = -(beta / w_3) (A e_j H[2, 0:2] + H[2, j] A).
  static MeasureStatus exact(const Eigen::Matrix<double, 7, 1>& m, const Eigen::Vector3d& s,
                             const Eigen::Vector2d& c, Vector6d* z, PatchJacobian<6>* J,
                             Eigen::Matrix<double, 6, 2>* Jc = nullptr);
  /// A patch's cumulative map w = (c, A) (centre in the previous frame, 2x2 map from the patch's
  /// template frame, row-major) carried into the current frame by the exact inter-frame map
  /// (h, B) about c: w' = (h, B A). J (optional) is dw'/d(m, s), Jw (optional) dw'/dw.
  /// Used by PatchCentres::State.
  static MeasureStatus composeMap(const Eigen::Matrix<double, 7, 1>& m, const Eigen::Vector3d& s, const Vector6d& w,
                                  Vector6d* w_new, PatchJacobian<6>* J, Eigen::Matrix<double, 6, 6>* Jw);
  /// Instantaneous (first-order) measurement, same layout.
  static MeasureStatus instantaneous(const Eigen::Matrix<double, 7, 1>& m, const Eigen::Vector3d& s,
                                     const Eigen::Vector2d& c, Vector6d* z, PatchJacobian<6>* J);
  static MeasureStatus measure(AffineMeasurement kind, const Eigen::Matrix<double, 7, 1>& m,
                               const Eigen::Vector3d& s, const Eigen::Vector2d& c, Vector6d* z,
                               PatchJacobian<6>* J) {
    return kind == AffineMeasurement::Exact ? exact(m, s, c, z, J) : instantaneous(m, s, c, z, J);
  }

  /// Murray-Shapiro transition of one patch's structure under motion m (no gauge); J (optional)
  /// is ds'/d(m, s). Fails (BehindCamera) when the plane is not visible from the new camera (s <= 0).
  static MeasureStatus propagate(const Eigen::Matrix<double, 7, 1>& m, const Eigen::Vector3d& s,
                                 Eigen::Vector3d* s_new, PatchJacobian<3>* J);

  /// Rescales the scene about the centre of projection by 1/lambda, lambda = (1 - beta c) /
  /// (1 - beta x[p4Index(gauge)]) with c = `gauge_value`, so that the gauge patch's p4 becomes c:
  ///   every patch P -> lambda P (p1, p2 scale; p4 -> (1 - lambda (1 - beta p4)) / beta),
  ///   the translation beta tbar -> beta tbar / lambda (t_X, t_Y, t_Z beta follow; omega, beta kept).
  /// Writes the new state and, if G is given, its Jacobian d x'/d x (n x n). Returns lambda (<= 0 or
  /// non-finite on failure). With gauge_value = x[p4Index(gauge)] it is the identity map whose
  /// Jacobian moves the gauge (the gauge patch's p4 row becomes zero).
  static double regauge(const Eigen::VectorXd& x, int gauge, double gauge_value, Eigen::VectorXd* x_new,
                        Eigen::MatrixXd* G);

  /// Whole-state transition: every patch propagated, then regauged to keep the gauge patch's p4
  /// at `gauge_value`. F (optional) = d x'/d x. `lambda` receives the scale factor (one new scene
  /// unit = lambda old units).
  MeasureStatus transition(const Eigen::VectorXd& x, int gauge, double gauge_value, Eigen::VectorXd* x_new,
                           Eigen::MatrixXd* F, double* lambda) const;

  /// Unit normal (current frame) of structure s: n ∝ (p1, p2, 1 - beta p4) = (n1, n2, n3) / sigma,
  /// so it points away from the camera (sigma = beta times the signed COP-to-plane distance > 0).
  static Eigen::Vector3d normal(const Eigen::Vector3d& s, double beta);
  /// Depth Z (A&P, current frame) of the patch plane on the ray through image point c.
  static double depthAt(const Eigen::Vector3d& s, double beta, const Eigen::Vector2d& c);
  /// Normalized structure (p1, p2, p4) of the plane n . X = d (current frame, A&P coordinates);
  /// false when sigma = n_3 + beta d <= 0 (plane not visible).
  static bool structureFromPlane(const Eigen::Vector3d& n, double d, double beta, Eigen::Vector3d* s);

 private:
  std::vector<Eigen::Vector2d> centres_;  // each patch's centre in the current frame
};

}  // namespace rsfm
