#pragma once
// The planar structure model of Alon & Sclaroff ([AS99] §3, eqs. 8-13; keys: docs/bibliography.md).
// State x = (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z, beta, N^1, ..., N^m): 7 + 3m
// (m = 1 is the single-plane filter of [AS99] eq. 8; m > 1 the rigid multi-plane state of its eq. 13).
// Plane j is N^j . X = 1 in the reference frame (origin on the image plane; unit normal
// N/|N|, distance 1/|N|). Point i, labelled with plane l(i), observed first at (u, v):
//   p = eta ((N_Z + beta) u, (N_Z + beta) v, 1 - N_X u - N_Y v),
//   eta = 1 / (beta N_X u + beta N_Y v + N_Z)                      ([AS99] eq. 12)
// N . X = 1 cannot represent a plane through the image-plane origin: |N| > kMaxPlaneNorm is
// reported as PlaneThroughOrigin; a ray within kMinGrazingSine of parallel to the plane as
// HorizonSingular.
#include <Eigen/Core>

#include <cmath>
#include <limits>
#include <vector>

#include "rsfm/ekf.hpp"
#include "rsfm/models/projection.hpp"

namespace rsfm {

class PlaneModel {
 public:
  /// Points needed for one plane with unknown focal length ([AS99] §3.1: 1 + 2N > 10).
  static constexpr int kMinPoints = 5;
  /// Structure columns one point's measurement depends on (its plane's N).
  static constexpr int kStructurePerPoint = 3;
  /// |N| above this (plane closer than 1e-9 units to the image-plane origin) is reported.
  static constexpr double kMaxPlaneNorm = 1e9;
  /// Rays meeting the plane at a grazing angle whose sine is below this (0.057 deg) are reported
  /// as HorizonSingular: sin = |N . d| / (|N| |d|) with the ray direction d = (beta u, beta v, 1),
  /// and N . d is exactly 1/eta. Such a point lies ~1000 plane-distances away and its
  /// Jacobian (~eta^2) would let one observation collapse P where linearization fails.
  static constexpr double kMinGrazingSine = 1e-3;

  /// Distance (normalized units) of the reference position `uv` from the plane's horizon line in
  /// the reference image, {uv : beta (N_X u + N_Y v) + N_Z = 0}, where rays from the centre of
  /// projection run parallel to the plane N . X = 1 (the denominator 1/eta of point()):
  /// |beta (N_X u + N_Y v) + N_Z| / (beta |(N_X, N_Y)|); +inf for a plane parallel to the image
  /// plane (no horizon in the image). Near it a point's depth along its ray grows as 1 / the
  /// distance: a plane seen edge-on from the reference camera (nearly containing its centre) has
  /// every point there (pipeline/refine.cpp leaves such references out).
  static double horizonDistance(const Eigen::Vector3d& N, double beta, const Eigen::Vector2d& uv) {
    const double nxy = N.head<2>().norm();
    if (!(beta * nxy > 0)) return std::numeric_limits<double>::infinity();
    return std::abs(beta * N.head<2>().dot(uv) + N.z()) / (beta * nxy);
  }

  PlaneModel() = default;
  /// `ref_uv`: first-frame normalized positions; `labels`: plane of each point (0..m-1).
  PlaneModel(std::vector<Eigen::Vector2d> ref_uv, std::vector<int> labels, int num_planes = 1);

  int numPoints() const { return static_cast<int>(ref_.size()); }
  int numPlanes() const { return planes_; }
  int stateDim() const { return 7 + 3 * planes_; }
  static int planeIndex(int plane) { return 7 + 3 * plane; }
  const Eigen::Vector2d& reference(int i) const { return ref_[i]; }
  int label(int i) const { return labels_[i]; }
  int structureIndex(int i) const { return planeIndex(labels_[i]); }

  /// Adds a point seen first at `ref_uv` (reference-frame normalized coordinates) on `plane`.
  int addPoint(const Eigen::Vector2d& ref_uv, int plane);
  /// Appends a plane, whose N the caller appends to the state at planeIndex(the returned index)
  /// (a plane that enters mid-run, TrackFilterOptions::late_planes).
  int addPlane() { return planes_++; }

  /// The reference-frame point ([AS99] eq. 6: X_C = t + R X) seen at `uv_a` by camera a and at
  /// `uv_b` by camera b (motions (R, t) from the reference frame, scene units; focal beta): the
  /// midpoint of the two rays' closest approach. Camera k's ray through uv is
  /// X_C(l) = (u, v, 0) + l (beta u, beta v, 1), its centre at l = -1/beta. HorizonSingular when
  /// the rays meet at an angle below `min_parallax_rad` (no depth), BehindCamera when the closest
  /// points are behind either centre. `parallax_rad` (may be null) receives the angle.
  static MeasureStatus twoViewPoint(double beta, const Eigen::Matrix3d& Ra, const Eigen::Vector3d& ta,
                                    const Eigen::Vector2d& uv_a, const Eigen::Matrix3d& Rb, const Eigen::Vector3d& tb,
                                    const Eigen::Vector2d& uv_b, double min_parallax_rad, Eigen::Vector3d* X,
                                    double* parallax_rad = nullptr);

  /// Validity of plane N for the ray through uv1 (see the class comment).
  static MeasureStatus checkRay(const Eigen::Vector3d& N, double beta, const Eigen::Vector2d& uv1);

  /// Reference-frame 3-D point of [AS99] eq. 12 with dp/dbeta and dp/dN (3x3, columns N_X, N_Y, N_Z)
  /// ([AS99] appendix) and dp/d(u, v) (3x2). dp/dN has rank one, ray c^T with the ray
  /// (beta u, beta v, 1): `dp_dN_coeff` receives c. Outputs may be null.
  static MeasureStatus point(const Eigen::Vector3d& N, double beta, const Eigen::Vector2d& uv1,
                             Eigen::Vector3d* p, Eigen::Vector3d* dp_dbeta,
                             Eigen::Matrix3d* dp_dN, Eigen::Matrix<double, 3, 2>* dp_duv = nullptr,
                             Eigen::Vector3d* dp_dN_coeff = nullptr);

  /// Transfer of a point first seen in a later frame (docs/conventions.md, "New features"): the
  /// reference-frame image position of the point of plane N (reference frame) seen at `uv` in the
  /// camera with motion (R, t) ([AS99] eq. 6: X_C = t + R X, t = (t_X, t_Y, t_Z) in scene units)
  /// and focal beta.
  /// The ray X_C(l) = (u (1 + beta l), v (1 + beta l), l) meets R N . (X_C - t) = 1 at
  /// l = (1 + m.t - m_X u - m_Y v) / (beta (m_X u + m_Y v) + m_Z), m = R N; then X = R^T (X_C - t)
  /// and uv_ref = (X, Y) / (1 + beta Z). Fails (HorizonSingular / BehindCamera) when the ray is
  /// within kMinGrazingSine of the plane or the point is behind either camera.
  static MeasureStatus transferToReference(const Eigen::Vector3d& N, double beta, const Eigen::Matrix3d& R,
                                           const Eigen::Vector3d& t, const Eigen::Vector2d& uv,
                                           Eigen::Vector2d* uv_ref);
  /// Point i's reference position as a function of the state, where it was transferred from its
  /// current observation z through the state's plane and motion (transferToReference, so that
  /// h(x, u_i) = z): by the implicit function theorem du_i/dx = -Hu^-1 H_x (2 x n, H_x the
  /// measurement's Jacobian, Hu = dh/du_i, both measure()'s), and z's noise sigma^2 I reaches u_i
  /// as sigma^2 Hu^-1 Hu^-T (`cov`, may be null). HorizonSingular when Hu is singular (the ray
  /// grazes the plane: the transfer does not determine the reference). docs/filter.md, "Points
  /// that join later".
  MeasureStatus transferredReferenceJacobian(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i, double sigma,
                                             Eigen::MatrixXd* G, Eigen::Matrix2d* cov) const;
  /// Replaces point i's reference position (reference refinement, see recursive_filter.hpp).
  void setReference(int i, const Eigen::Vector2d& uv) { ref_[i] = uv; }

  /// Predicted measurement of point i and its Jacobian with respect to the whole state (2 x n).
  MeasureStatus measure(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg, int i,
                        Eigen::Vector2d* h, Eigen::MatrixXd* H) const;

  /// Fast form: 2x7 motion block, 2x3 block of the point's plane and dh/d(u, v)^1 (2x2).
  MeasureStatus measure(const MotionContext& m, const Eigen::VectorXd& x, int i,
                        Eigen::Vector2d* h, Eigen::Matrix<double, 2, 7>* Hm,
                        Eigen::Matrix<double, 2, 3>* Hn, Eigen::Matrix2d* Hu = nullptr) const;

  /// Linearizes every observation: O(N). R = sigma^2 I (+ Hu C_i Hu^T with `ref_cov`).
  /// Failed predictions are left out and counted; `used` receives each block's observation index.
  void linearize(const Eigen::VectorXd& x, const Eigen::Matrix3d& Rg,
                 const std::vector<Observation>& obs, double sigma,
                 const std::vector<Eigen::Matrix2d>* ref_cov, BlockBatch* batch,
                 int* invalid, MeasureStatus* first_problem, std::vector<int>* used = nullptr,
                 int reference_index = -1) const;

 private:
  std::vector<Eigen::Vector2d> ref_;
  std::vector<int> labels_;
  int planes_ = 1;
};

}  // namespace rsfm
