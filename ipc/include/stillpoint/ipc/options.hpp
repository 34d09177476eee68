#pragma once
// IPC configuration: the `ipc:` section of the daemon's YAML file feeds these plain
// structs. validate() names the bad field.
#include <array>
#include <cstdint>
#include <string>

#include "stillpoint/core/result.hpp"

namespace YAML {
class Node;
}

namespace stillpoint::ipc {

struct ShmOptions {
  bool enabled = true;
  std::string name = "stillpoint_pose";  // /dev/shm/<name>
  std::uint32_t capacity = 1024;         // records in the ring, power of two
  // Dynamic objects in a ring of their own: /dev/shm/<objects_name>, by
  // default <name>_objects.
  bool objects = true;
  std::string objects_name;
  // The objects ring's name; empty when objects are off.
  std::string objectsRing() const { return !objects ? "" : objects_name.empty() ? name + "_objects" : objects_name; }
};

struct LcmOptions {
  bool enabled = false;
  // ttl=0 keeps the multicast on this host.
  std::string url = "udpm://239.255.76.67:7667?ttl=0";
  std::string pose_channel = "STILLPOINT_POSE";
  std::string status_channel = "STILLPOINT_STATUS";
  std::string objects_channel = "STILLPOINT_OBJECTS";  // empty: off
};

struct DdsOptions {
  bool enabled = false;
  std::uint32_t domain_id = 0;
  // Cyclone DDS configuration: an XML string or a URI ("file:///etc/cyclonedds.xml").
  // Empty: Cyclone's defaults (and CYCLONEDDS_URI).
  std::string config;
  std::string pose_topic = "stillpoint_pose";
  std::string status_topic = "stillpoint_status";
  std::string objects_topic = "stillpoint_objects";  // empty: off
};

// Poses as ROS 2 topics (geometry_msgs/msg/PoseStamped on `pose_topic`) over
// Cyclone DDS, with ROS 2's type names and QoS a ROS 2 node matches
// (reliable: both reliable and best-effort readers match). Positions and
// orientations in REP-103 axes (x forward, y left, z up) in `frame_id`; only
// frames that have a pose are published.
struct Ros2Options {
  bool enabled = false;
  std::uint32_t domain_id = 0;  // ROS_DOMAIN_ID
  std::string config;           // Cyclone DDS XML or URI, as for dds
  std::string pose_topic = "rt/stillpoint/pose";  // ROS 2 topic /stillpoint/pose
  std::string frame_id = "map";
  // nav_msgs/msg/Odometry with the pose's covariance (empty: off).
  std::string odometry_topic = "rt/stillpoint/odometry";
  // tf2_msgs/msg/TFMessage with frame_id -> child_frame_id (empty: off).
  std::string tf_topic = "rt/tf";
  std::string child_frame_id = "camera_link";  // the camera's body frame (REP-103 axes)
  // diagnostic_msgs/msg/DiagnosticArray with every status message (empty: off).
  std::string diagnostics_topic = "rt/diagnostics";
  // visualization_msgs/msg/MarkerArray: a box and a label per dynamic object
  // (empty: off).
  std::string objects_topic = "rt/stillpoint/dynamic_objects";
  // sensor_msgs/msg/PointCloud2 of the static map every map_cloud_period_s
  // (empty: off).
  std::string map_cloud_topic = "rt/stillpoint/map_cloud";
  double map_cloud_period_s = 2.0;
  // The camera's body frame (REP-103 axes: x along the optical axis, z up) in
  // child_frame_id: x y z [m], qx qy qz qw. Identity when the child frame is
  // the camera's own. The map frame is the child frame where the first pose
  // was taken, so with a level base_link the map's z is up (REP-105).
  std::array<double, 7> camera_extrinsic{0, 0, 0, 0, 0, 0, 1};
};

struct IpcOptions {
  std::uint32_t queue_capacity = 8;  // publisher hand-off queue, drop-oldest
  ShmOptions shm;
  LcmOptions lcm;
  DdsOptions dds;
  Ros2Options ros2;

  Status validate() const;
};

// Reads the `ipc:` map (the node itself, not its parent). Omitted keys keep their
// defaults; unknown keys and wrong types are errors naming the key.
Result<IpcOptions> parseIpcOptions(const YAML::Node& node);
// Loads a YAML file whose top level has an `ipc:` map (absent: defaults).
Result<IpcOptions> loadIpcOptions(const std::string& path);

}  // namespace stillpoint::ipc
