#pragma once
// Trajectory and structure error metrics (docs/evaluate.md). Eigen only, no I/O.
//
// Poses are camera poses in a common reference frame: p = camera centre, R = rotation
// camera -> reference (the TUM convention of rsfm::io::TumPose).
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

namespace rsfm::eval {

/// Similarity transform y = s R x + t.
struct Sim3 {
  double s = 1;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  Eigen::Vector3d apply(const Eigen::Vector3d& x) const { return s * (R * x) + t; }
};

struct UmeyamaResult {
  Sim3 T;
  /// Singular values of the cross-covariance (descending); a small second or third value
  /// relative to the first means the rotation about the points' main axis is ill-determined.
  Eigen::Vector3d singular_values = Eigen::Vector3d::Zero();
  bool ok = false;  ///< false with < 2 points or all source points equal
};

/// Least-squares similarity (Umeyama 1991) mapping src onto dst: minimizes
/// sum |dst_i - (s R src_i + t)|^2 with det R = +1. With `with_scale` false, s = 1 (SE(3)).
/// Requires src.size() == dst.size().
UmeyamaResult umeyama(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst,
                      bool with_scale = true);

struct ErrorStats {
  int n = 0;
  double rmse = 0, mean = 0, median = 0, max = 0;
};
/// Statistics of non-negative errors (n = 0: all zero).
ErrorStats errorStats(std::vector<double> e);

struct Pose {
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
};

struct AteResult {
  UmeyamaResult alignment;        ///< estimate -> truth
  std::vector<double> errors;     ///< per pose |truth p - aligned estimate p|
  ErrorStats stats;
};
/// Absolute trajectory error: positions of `est` aligned onto `truth` (same length, associated)
/// by Umeyama Sim(3) (or SE(3) with with_scale = false), then per-pose position errors.
AteResult absoluteTrajectoryError(const std::vector<Pose>& est, const std::vector<Pose>& truth,
                                  bool with_scale = true);

struct RpeResult {
  int pairs = 0;
  ErrorStats translation;   ///< trajectory (truth) units, estimate scaled by `scale`
  ErrorStats rotation_deg;
};
/// Relative pose error over index pairs (i, j) with frame[j] == frame[i] + delta (frame numbers
/// of the associated poses, increasing). Per pair: E = (T_i^-1 T_j)_truth^-1 (T_i^-1 T_j)_est
/// with the estimate's translations multiplied by `scale` (the Sim(3) scale; its rotation and
/// translation cancel in relative poses); errors |t_E| and the angle of R_E.
RpeResult relativePoseError(const std::vector<Pose>& est, const std::vector<Pose>& truth,
                            const std::vector<long long>& frame, long long delta, double scale);

/// Angle in degrees between two unit vectors (directions compared as given, no sign flip).
double angleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b);

struct PlaneMatch {
  /// For each truth plane, the index of its estimated plane, or -1 when unmatched.
  std::vector<int> estimate_of_truth;
  /// For each estimated plane, its truth plane or -1.
  std::vector<int> truth_of_estimate;
  /// Angle (deg) of each truth plane to its match (NaN when unmatched).
  std::vector<double> angle_deg;
};
/// Best one-to-one matching of estimated to truth normals: min(#truth, #est) pairs with the least
/// total angle (exhaustive search when both sides have <= 9 planes, else greedy by angle).
/// Normals are compared directly (both must be in the same frame and sign convention).
PlaneMatch matchPlanes(const std::vector<Eigen::Vector3d>& truth, const std::vector<Eigen::Vector3d>& est);

/// The same with distances as a tie-breaker for parallel planes (a box top and the floor it stands
/// on): the cost of a pair is `angle_deg + deg_per_log * |ln(scale * d_est / d_truth)|`, `scale`
/// being the estimate -> truth scale (Sim(3) alignment). `angle_deg` in the result is still the
/// pure normal angle. Non-positive distances count as a factor-e mismatch.
PlaneMatch matchPlanes(const std::vector<Eigen::Vector3d>& truth, const std::vector<double>& truth_d,
                       const std::vector<Eigen::Vector3d>& est, const std::vector<double>& est_d, double scale,
                       double deg_per_log = 20.0);

/// Least-total-cost one-to-one assignment of rows to columns (min(rows, cols) pairs); returns the
/// column of each row or -1. Exhaustive when both sides have <= 9 entries, else greedy.
std::vector<int> minCostAssignment(const std::vector<std::vector<double>>& cost);

}  // namespace rsfm::eval
