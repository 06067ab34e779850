#include "omni/octomap_builder/frame_poser.h"

namespace omni::octo {

Eigen::Isometry3d MountToIsometry(const CameraMount& m) {
  // Optical axes in a camera body frame (x forward, y left, z up): optical z -> body x,
  // optical x -> body -y, optical y -> body -z.
  Eigen::Matrix3d body_from_optical;
  body_from_optical << 0, 0, 1,  //
      -1, 0, 0,                  //
      0, -1, 0;
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = (Eigen::AngleAxisd(m.yaw_rad, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(m.tilt_rad, Eigen::Vector3d::UnitY()))
                   .toRotationMatrix() *
               body_from_optical *
               Eigen::AngleAxisd(m.roll_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  t.translation() = Eigen::Vector3d(m.x_m, m.y_m, m.height_m);
  return t;
}

Eigen::Isometry3d CameraInMap(const Pose2& robot_in_map, const CameraMount& mount) {
  return robot_in_map.ToIsometry3() * MountToIsometry(mount);
}

}  // namespace omni::octo
