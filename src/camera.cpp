#include "rsfm/camera.hpp"

namespace rsfm {

CameraPose copCentredPose(const Eigen::Matrix3d& R, const Eigen::Vector3d& t, double beta) {
  const Eigen::Vector3d ez(0, 0, 1.0 / beta);
  const Eigen::Vector3d t_cop = t + ez - R * ez;
  CameraPose pose;
  pose.orientation = Eigen::Quaterniond(R.transpose()).normalized();
  pose.position = -R.transpose() * t_cop;
  return pose;
}

}  // namespace rsfm
