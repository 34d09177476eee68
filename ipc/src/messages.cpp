#include "stillpoint/ipc/messages.hpp"

#include <cmath>

namespace stillpoint::ipc {

const char* toString(TrackingState state) {
  switch (state) {
    case TrackingState::kInitialising: return "initialising";
    case TrackingState::kOk: return "ok";
    case TrackingState::kLost: return "lost";
    case TrackingState::kRelocalised: return "relocalised";
    case TrackingState::kNoDepth: return "no_depth";
    case TrackingState::kNewMap: return "new_map";
  }
  return "unknown";
}

Result<TrackingState> trackingStateFromInt(std::int64_t value) {
  if (value < 0 || value > 5) return Error{"tracking state " + std::to_string(value) + " is not one of 0..5"};
  return static_cast<TrackingState>(value);
}

namespace {
Status validateName(const std::string& what, const std::string& name) {
  if (name.empty() || name.size() > StatusMessage::kMaxNameLength)
    return Error{what + " name '" + name + "' must have 1.." + std::to_string(StatusMessage::kMaxNameLength) +
                 " characters"};
  for (char c : name)
    if (c < 0x20 || c > 0x7e) return Error{what + " name '" + name + "' has a non-printable character"};
  return Status::success();
}
}  // namespace

Status validate(const StatusMessage& status) {
  if (status.threads.size() > StatusMessage::kMaxThreads)
    return Error{"status: " + std::to_string(status.threads.size()) + " threads, at most " +
                 std::to_string(StatusMessage::kMaxThreads)};
  if (status.queues.size() > StatusMessage::kMaxQueues)
    return Error{"status: " + std::to_string(status.queues.size()) + " queues, at most " +
                 std::to_string(StatusMessage::kMaxQueues)};
  for (const auto& t : status.threads)
    if (Status s = validateName("status: thread", t.name); !s) return s;
  for (const auto& q : status.queues)
    if (Status s = validateName("status: queue", q.name); !s) return s;
  return Status::success();
}

Status validate(const ObjectsMessage& m) {
  if (m.objects.size() > ObjectsMessage::kMaxObjects)
    return Error{"objects: " + std::to_string(m.objects.size()) + " objects, at most " +
                 std::to_string(ObjectsMessage::kMaxObjects)};
  for (const ObjectMessage& o : m.objects) {
    if (o.label.empty() || o.label.size() > ObjectsMessage::kMaxLabelLength)
      return Error{"objects: label '" + o.label + "' must have 1.." + std::to_string(ObjectsMessage::kMaxLabelLength) +
                   " characters"};
    for (char c : o.label)
      if (c < 0x20 || c > 0x7e) return Error{"objects: label '" + o.label + "' has a non-printable character"};
    if ((o.sources & ~(ObjectMessage::kGeometry | ObjectMessage::kSemantic)) != 0)
      return Error{"objects: sources " + std::to_string(o.sources) + " is not a combination of 1 and 2"};
    for (const auto* v : {&o.centroid, &o.extent, &o.velocity})
      for (float x : *v)
        if (!std::isfinite(x)) return Error{"objects: object " + std::to_string(o.id) + " has a non-finite number"};
  }
  return Status::success();
}

bool hasPose(TrackingState s) {
  return s == TrackingState::kOk || s == TrackingState::kRelocalised || s == TrackingState::kNewMap;
}

const char* toString(PoseHealth health) {
  switch (health) {
    case PoseHealth::kGood: return "good";
    case PoseHealth::kDegraded: return "degraded";
    case PoseHealth::kUnreliable: return "unreliable";
    case PoseHealth::kLost: return "lost";
  }
  return "?";
}

Result<PoseHealth> poseHealthFromInt(std::int64_t value) {
  if (value < 0 || value > 3) return Error{"pose health " + std::to_string(value) + " is not 0..3"};
  return static_cast<PoseHealth>(value);
}

bool PoseMessage::operator==(const PoseMessage& o) const {
  auto same = [](double a, double b) { return a == b || (std::isnan(a) && std::isnan(b)); };
  for (int i = 0; i < 3; ++i)
    if (!same(position[i], o.position[i])) return false;
  for (int i = 0; i < 4; ++i)
    if (!same(orientation[i], o.orientation[i])) return false;
  return sensor_stamp == o.sensor_stamp && publish_stamp == o.publish_stamp && frame_counter == o.frame_counter &&
         state == o.state && tracked_features == o.tracked_features &&
         dynamic_rejected_features == o.dynamic_rejected_features && keyframes == o.keyframes && map_id == o.map_id &&
         health == o.health && same(dynamic_share, o.dynamic_share) &&
         same(reprojection_rms_px, o.reprojection_rms_px) && same(conditioning, o.conditioning) &&
         health_causes == o.health_causes && same(mask_age_s, o.mask_age_s) && covariance == o.covariance;
}

Status validate(const PoseMessage& pose) {
  if (!hasPose(pose.state)) {
    for (double v : pose.position)
      if (!std::isnan(v)) return Error{"pose: a message without a pose must carry NaN in position"};
    for (double v : pose.orientation)
      if (!std::isnan(v)) return Error{"pose: a message without a pose must carry NaN in orientation"};
    return Status::success();
  }
  for (double v : pose.position)
    if (!std::isfinite(v)) return Error{"pose: position is not finite"};
  double n2 = 0.0;
  for (double v : pose.orientation) n2 += v * v;
  if (!std::isfinite(n2) || std::abs(std::sqrt(n2) - 1.0) > 1e-6)
    return Error{"pose: orientation is not a unit quaternion (|q| = " + std::to_string(std::sqrt(n2)) + ")"};
  return Status::success();
}

}  // namespace stillpoint::ipc
