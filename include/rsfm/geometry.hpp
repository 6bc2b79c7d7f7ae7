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

/// Elementary rotation about the y axis by theta (radians): [[c,0,s],[0,1,0],[-s,0,c]].
Eigen::Matrix3d rotationY(double theta);

}  // namespace rsfm
