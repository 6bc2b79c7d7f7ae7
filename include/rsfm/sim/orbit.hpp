#pragma once
// Pieces shared by the synthetic scenes (A&P coordinates: origin on the image plane, COP at
// (0, 0, -1/beta); camera-k coordinates X_C = R_k X + t_k).
#include <Eigen/Core>
#include <vector>

namespace rsfm {

/// Truth of an orbit about the y axis through `centre`: R_k = R_y(k theta), t_k = (I - R_k) centre
/// for k = 0..frames (theta in degrees per frame).
void orbitAboutY(int frames, double deg_per_frame, const Eigen::Vector3d& centre,
                 std::vector<Eigen::Matrix3d>* R, std::vector<Eigen::Vector3d>* t);

/// True when X is in front of every camera (1 + beta Z_C >= 0.1) and projects within
/// |u|, |v| <= lim (normalized units) in every frame.
bool visibleInAllFrames(const std::vector<Eigen::Matrix3d>& R, const std::vector<Eigen::Vector3d>& t,
                        double beta, const Eigen::Vector3d& X, double lim);

/// Noise-free normalized projections [frame][point].
std::vector<std::vector<Eigen::Vector2d>> projectAll(const std::vector<Eigen::Matrix3d>& R,
                                                     const std::vector<Eigen::Vector3d>& t, double beta,
                                                     const std::vector<Eigen::Vector3d>& points);

}  // namespace rsfm
