#pragma once
// The messages stillpoint publishes to other processes. Every transport carries the
// same content; each wire format also carries its schema version so a reader can
// refuse a schema it does not know.
#include <array>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "stillpoint/core/health_causes.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"

namespace stillpoint::ipc {

// kNoDepth: the frame had too little depth to track (no pose); kNewMap: the
// first pose of a map started after a loss (map_id changed). Poses are
// valid in kOk, kRelocalised and kNewMap.
enum class TrackingState : std::uint8_t {
  kInitialising = 0,
  kOk = 1,
  kLost = 2,
  kRelocalised = 3,
  kNoDepth = 4,
  kNewMap = 5,
};
const char* toString(TrackingState state);
// Accepts 0..5; anything else is an error (a newer writer or a corrupt message).
Result<TrackingState> trackingStateFromInt(std::int64_t value);

// How far to trust a pose (slam::PoseHealth; docs/pose-health.md).
enum class PoseHealth : std::uint8_t { kGood = 0, kDegraded = 1, kUnreliable = 2, kLost = 3 };
const char* toString(PoseHealth health);
Result<PoseHealth> poseHealthFromInt(std::int64_t value);

// Schema 2 added the pose health, schema 3 what lowered it and the semantic
// masks' age, schema 4 the pose's covariance; a message without a pose carries
// NaN in position and orientation (nothing a consumer could take for a pose).
// The shared-memory ring numbers its own schema (stillpoint_shm.h; 4 has the covariance).
struct PoseMessage {
  static constexpr std::uint32_t kSchemaVersion = 4;
  static constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

  Timestamp sensor_stamp;         // capture time of the frame
  Timestamp publish_stamp;        // wall clock (CLOCK_REALTIME) when sent; set by the Publisher
  std::uint64_t frame_counter = 0;
  // T_map_camera: position [m] and unit quaternion (x, y, z, w) of the camera in the map.
  // NaN until set: the default state has no pose.
  std::array<double, 3> position{kNaN, kNaN, kNaN};
  std::array<double, 4> orientation{kNaN, kNaN, kNaN, kNaN};
  TrackingState state = TrackingState::kInitialising;
  std::uint32_t tracked_features = 0;
  std::uint32_t dynamic_rejected_features = 0;
  std::uint32_t keyframes = 0;
  std::uint64_t map_id = 0;  // changes when the map is reset
  PoseHealth health = PoseHealth::kLost;
  float dynamic_share = 0;        // features kept out as moving / (those + inliers)
  float reprojection_rms_px = 0;  // of the inliers
  float conditioning = 0;         // 0..1: how well the inliers pin all six degrees of freedom
  std::uint16_t health_causes = 0;  // what lowered the health: health_cause::k* bits (stillpoint/core/health_causes.hpp)
  // Seconds from the image of the newest semantic masks to the frame; infinity
  // when no keyframe near the camera has any, -1 when not known (the module off).
  float mask_age_s = -1;
  // The pose's covariance (docs/pose-health.md, "The covariance"): the upper
  // triangle, row by row, of the 6 x 6 matrix over the camera's position [m]
  // and its rotation about the map's x, y and z axes [rad], in that order (as
  // geometry_msgs/PoseWithCovariance orders them). All zero without a pose.
  std::array<float, 21> covariance{};

  // Equal fields; NaN equals NaN (a message without a pose).
  bool operator==(const PoseMessage& o) const;
};

struct ThreadStats {
  std::string name;
  double loop_rate_hz = 0.0;
  double latency_ms_median = 0.0;
  double latency_ms_max = 0.0;
  bool operator==(const ThreadStats&) const = default;
};

struct QueueStats {
  std::string name;
  std::uint32_t depth = 0;
  std::uint32_t capacity = 0;
  std::uint64_t dropped = 0;
  bool operator==(const QueueStats&) const = default;
};

// Schema 2 added the tracking state and pose health of the newest frame,
// schema 3 what lowered that health and the semantic masks' age.
struct StatusMessage {
  static constexpr std::uint32_t kSchemaVersion = 3;
  static constexpr std::size_t kMaxThreads = 16;
  static constexpr std::size_t kMaxQueues = 16;
  static constexpr std::size_t kMaxNameLength = 31;

  Timestamp publish_stamp;  // set by the Publisher
  double uptime_s = 0.0;
  std::uint64_t frames_received = 0;
  std::uint64_t frames_dropped = 0;
  std::uint64_t map_id = 0;
  TrackingState tracking_state = TrackingState::kInitialising;  // of the newest frame tracked
  PoseHealth health = PoseHealth::kLost;                         // of the newest frame tracked
  std::uint16_t health_causes = 0;                               // of the newest frame tracked (PoseMessage)
  float mask_age_s = -1;                                         // of the newest frame tracked (PoseMessage)
  std::vector<ThreadStats> threads;
  std::vector<QueueStats> queues;

  bool operator==(const StatusMessage&) const = default;
};

// Something seen moving in one frame (slam::DynamicObject; docs/dynamic-objects.md),
// in the map frame of the frame's pose message.
struct ObjectMessage {
  static constexpr std::uint8_t kGeometry = 1, kSemantic = 2;
  std::uint32_t id = 0;            // stable while the object is followed from frame to frame
  std::string label = "unknown";   // semantic class, or "unknown"
  std::uint8_t sources = 0;        // kGeometry | kSemantic
  std::array<float, 3> centroid{};  // [m]
  std::array<float, 3> extent{};    // size per map axis [m]
  std::array<float, 3> velocity{};  // [m/s]; zero until has_velocity
  bool has_velocity = false;
  std::uint32_t samples = 0;        // surface points it was measured from
  bool operator==(const ObjectMessage&) const = default;
};

// The dynamic objects of one frame with a pose (none: nothing moves there).
struct ObjectsMessage {
  static constexpr std::uint32_t kSchemaVersion = 2;  // its own: unchanged by the pose's version 3
  static constexpr std::size_t kMaxObjects = 32;
  static constexpr std::size_t kMaxLabelLength = 31;
  Timestamp sensor_stamp;
  Timestamp publish_stamp;  // set by the Publisher
  std::uint64_t frame_counter = 0;  // its pose message's
  std::uint64_t map_id = 0;
  std::vector<ObjectMessage> objects;
  bool operator==(const ObjectsMessage&) const = default;
};

// The static map's points, now and then (ROS 2 only: sensor_msgs/PointCloud2).
struct MapCloudMessage {
  Timestamp sensor_stamp;  // of the newest frame when it was taken
  Timestamp publish_stamp;  // set by the Publisher
  std::uint64_t map_id = 0;
  std::vector<std::array<float, 3>> points;  // map frame, as the poses [m]
};

// Limits every transport can carry (DDS uses fixed-size arrays): at most kMaxThreads
// threads and kMaxQueues queues, names of 1..kMaxNameLength printable characters.
Status validate(const StatusMessage& status);
// With a pose (kOk, kRelocalised, kNewMap): unit quaternion (|q| within 1e-6
// of 1), finite position. Without: NaN in every pose field.
Status validate(const PoseMessage& pose);
// At most kMaxObjects objects, labels of 1..kMaxLabelLength printable
// characters, finite numbers, sources within kGeometry | kSemantic.
Status validate(const ObjectsMessage& objects);
bool hasPose(TrackingState state);

}  // namespace stillpoint::ipc
