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

/// Elementary rotation about the y axis by theta (radians): [[c,0,s],[0,1,0],[-s,0,c]].
Eigen::Matrix3d rotationY(double theta);

}  // namespace rsfm
