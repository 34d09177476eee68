#pragma once
// stillpoint's frames as ROS 2 sees them (ipc/README.md, "Axes and the robot's
// body"): REP-103 axes, the map frame being the child frame where the first
// pose was taken.
#include <array>

#include <Eigen/Geometry>

namespace stillpoint::ipc {

// The camera's optical frame (x right, y down, z forward) in the child frame:
// `camera_extrinsic` (Ros2Options: the camera's body frame in the child frame,
// x y z qx qy qz qw) after the optical -> body axes.
Eigen::Isometry3d opticalInChild(const std::array<double, 7>& camera_extrinsic);

// A pose of stillpoint's (the optical frame in the first optical frame) as
// the child frame's pose in the ROS map frame: X T X^-1, X = opticalInChild.
inline Eigen::Isometry3d childInMap(const Eigen::Isometry3d& optical_in_child, const Eigen::Isometry3d& T) {
  return optical_in_child * T * optical_in_child.inverse();
}

// The covariance of a pose of stillpoint's (position, then rotation about the
// axes of the first optical frame; PoseMessage::covariance) as the covariance
// of childInMap(optical_in_child, T) in the ROS map frame, the same order.
Eigen::Matrix<double, 6, 6> childCovarianceInMap(const Eigen::Isometry3d& optical_in_child, const Eigen::Isometry3d& T,
                                                 const Eigen::Matrix<double, 6, 6>& covariance);

}  // namespace stillpoint::ipc
