#pragma once
// The messages stillpoint publishes to other processes. Every transport carries the
// same content; each wire format also carries kSchemaVersion so a reader can refuse a
// schema it does not know.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

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

struct PoseMessage {
  static constexpr std::uint32_t kSchemaVersion = 1;

  Timestamp sensor_stamp;         // capture time of the frame
  Timestamp publish_stamp;        // wall clock (CLOCK_REALTIME) when sent; set by the Publisher
  std::uint64_t frame_counter = 0;
  // T_map_camera: position [m] and unit quaternion (x, y, z, w) of the camera in the map.
  std::array<double, 3> position{0.0, 0.0, 0.0};
  std::array<double, 4> orientation{0.0, 0.0, 0.0, 1.0};
  TrackingState state = TrackingState::kInitialising;
  std::uint32_t tracked_features = 0;
  std::uint32_t dynamic_rejected_features = 0;
  std::uint32_t keyframes = 0;
  std::uint64_t map_id = 0;  // changes when the map is reset

  bool operator==(const PoseMessage&) const = default;
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

struct StatusMessage {
  static constexpr std::uint32_t kSchemaVersion = 1;
  static constexpr std::size_t kMaxThreads = 16;
  static constexpr std::size_t kMaxQueues = 16;
  static constexpr std::size_t kMaxNameLength = 31;

  Timestamp publish_stamp;  // set by the Publisher
  double uptime_s = 0.0;
  std::uint64_t frames_received = 0;
  std::uint64_t frames_dropped = 0;
  std::uint64_t map_id = 0;
  std::vector<ThreadStats> threads;
  std::vector<QueueStats> queues;

  bool operator==(const StatusMessage&) const = default;
};

// Limits every transport can carry (DDS uses fixed-size arrays): at most kMaxThreads
// threads and kMaxQueues queues, names of 1..kMaxNameLength printable characters.
Status validate(const StatusMessage& status);
// Unit quaternion (|q| within 1e-6 of 1) and finite position.
Status validate(const PoseMessage& pose);

}  // namespace stillpoint::ipc
