#include "omni/pose_graph_mapper/node_options.h"

namespace omni::pgm {

Result<PoseGraphNodeOptions> PoseGraphNodeOptions::Load(ConfigReader& r) {
  PoseGraphNodeOptions o;
  r.Get("scan_channel", &o.scan_channel, Optional(), NonEmpty());
  r.Get("odom_channel", &o.odom_channel, Optional(), NonEmpty());
  r.Get("pose_channel", &o.pose_channel, Optional(), NonEmpty());
  r.Get("grid_channel", &o.grid_channel, Optional(), NonEmpty());
  r.Get("trajectory_channel", &o.trajectory_channel, Optional(), NonEmpty());
  r.Get("map_frame", &o.map_frame, Optional(), NonEmpty());
  r.Get("absolute_channel", &o.absolute_channel, Optional());
  r.Get("imu_channel", &o.imu_channel, Optional(), NonEmpty());
  r.Get("max_odom_wait_s", &o.max_odom_wait_s, Optional(), InRange(0.0, 60.0));
  // (Bounded: a huge "never" overflowed its microseconds and published at every tick.)
  r.Get("grid_publish_interval_s", &o.grid_publish_interval_s, Optional(), InRange(0.0, 86400.0));
  r.Get("trajectory_publish_interval_s", &o.trajectory_publish_interval_s, Optional(),
        InRange(0.0, 86400.0));
  r.Get("grid_resolution_m", &o.grid_resolution_m, Optional(), InRange(0.005, 1.0));
  return o;
}

}  // namespace omni::pgm
