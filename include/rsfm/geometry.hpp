#pragma once
// Plane geometry helpers (no I/O). Frames: reference camera frame with origin on the image plane.
#include <Eigen/Core>
#include <vector>

namespace rsfm {

/// Total-least-squares plane through 3-D points: unit normal n (sign: n_z >= 0) and offset
/// d = n . centroid, so the plane is n . X = d. Returns false for fewer than 3 points or
/// non-finite input.
bool fitPlane(const std::vector<Eigen::Vector3d>& pts, Eigen::Vector3d* n, double* d);

/// Plane N . X = 1 from n . X = d (N = n / d). Returns false when |d| is tiny (plane through
/// the origin cannot be written as N . X = 1).
bool planeFromNormalOffset(const Eigen::Vector3d& n, double d, Eigen::Vector3d* N);

/// Angle (radians) between the lines spanned by a and b (sign of the normals ignored).
double normalAngle(const Eigen::Vector3d& a, const Eigen::Vector3d& b);

/// The same angle, theta = atan2(|a x b|, |a . b|) in [0, pi/2] (a and b need not be unit
/// vectors: it depends on their directions only), and in J its gradient with respect to (a, b)
/// (1 x 6; each half is orthogonal to its vector). Two points are not differentiable: parallel
/// lines (theta = 0, a cone point: J is set to zero) and perpendicular ones (theta = pi/2, a
/// fold: the angle between lines turns back there, and J is the gradient of the angle between
/// the vectors, |J| the same from both sides). Zero and non-finite vectors give 0 and J zero.
double normalAngle(const Eigen::Vector3d& a, const Eigen::Vector3d& b, Eigen::Matrix<double, 1, 6>* J);

/// Jacobian of the unit direction n = N / |N| with respect to N: (I - n n^T) / |N| (3 x 3,
/// symmetric; n spans its null space, so only the tangent part of dN moves the direction). The
/// linearization behind every normal's sd: cov(n) = J cov(N) J^T. Zero for a zero or
/// non-finite N.
Eigen::Matrix3d unitDirectionJacobian(const Eigen::Vector3d& N);

/// The RMS angle (radians) of the unit direction of N under the covariance C of N:
/// sqrt(trace(J C J^T)), J = unitDirectionJacobian(N) (to first order the root mean square of
/// the angle between n and its perturbed self; the sd every reported normal carries, the sum of
/// the two tangent variances, so up to sqrt(2) times the larger principal sd). Infinite for
/// a zero or non-finite N or a non-finite C: nothing then bounds the direction.
double directionRmsAngle(const Eigen::Vector3d& N, const Eigen::Matrix3d& C);

/// Elementary rotation about the y axis by theta (radians): [[c,0,s],[0,1,0],[-s,0,c]].
Eigen::Matrix3d rotationY(double theta);

}  // namespace rsfm
