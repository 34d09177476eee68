#include "probe_messages.hpp"

#include <cmath>
#include <cstring>
#include <limits>

namespace stillpoint::ipc::probe {

PoseMessage testPose(std::uint64_t k) {
  PoseMessage p;
  p.sensor_stamp = Timestamp::fromNanoseconds(1'700'000'000'123'456'789LL + static_cast<std::int64_t>(k) * 33'333'333);
  p.frame_counter = k;
  // Values with full mantissas and a negative zero-ish one: a text or float round trip would show.
  const double a = static_cast<double>(k) * 0.001;
  p.position = {std::sin(a) * 3.14159265358979, -std::ldexp(static_cast<double>(k), -7) / 3.0, 1.0 / (k + 3.0)};
  const double half = 0.5 * std::fmod(a * 7.0, 6.28318530717958);
  const double ax[3] = {0.267261241912424, 0.534522483824849, 0.801783725737273};  // unit axis
  p.orientation = {ax[0] * std::sin(half), ax[1] * std::sin(half), ax[2] * std::sin(half), std::cos(half)};
  p.state = static_cast<TrackingState>(k % 4);
  if (!hasPose(p.state)) {  // initialising, lost: no pose, as every decoder insists
    p.position.fill(std::numeric_limits<double>::quiet_NaN());
    p.orientation.fill(std::numeric_limits<double>::quiet_NaN());
  }
  p.tracked_features = static_cast<std::uint32_t>(400 + k % 700);
  p.dynamic_rejected_features = static_cast<std::uint32_t>(k % 37);
  p.keyframes = static_cast<std::uint32_t>(k / 10);
  p.map_id = 0xC0FFEE0000000000ULL | (k / 100);  // top bit set: unsigned survives signed wire types
  p.health = static_cast<PoseHealth>(k % 4);
  p.dynamic_share = static_cast<float>(k % 101) / 100.0f;
  p.reprojection_rms_px = 0.5f + static_cast<float>(k % 13) / 7.0f;
  p.conditioning = 1.0f / static_cast<float>(k + 2);
  p.health_causes = static_cast<std::uint16_t>(k * 0x2F1Bu);  // bit 15 too: unsigned survives signed wire types
  p.mask_age_s = k % 3 == 0 ? std::numeric_limits<float>::infinity() : k % 3 == 1 ? -1.0f : 0.1f * static_cast<float>(k);
  // Full float mantissas, a sign per entry: an order or precision slip would show.
  for (std::size_t i = 0; i < p.covariance.size(); ++i)
    p.covariance[i] = (i % 2 ? -1.0f : 1.0f) * static_cast<float>(k + 1) / static_cast<float>(3 * i + 7);
  return p;
}

StatusMessage testStatus(std::uint64_t k) {
  StatusMessage s;
  s.uptime_s = 0.25 * static_cast<double>(k) + 1.0 / 3.0;
  s.frames_received = 30 * k;
  s.frames_dropped = k % 5;
  s.map_id = 0xC0FFEE0000000000ULL | k;
  s.tracking_state = static_cast<TrackingState>(k % 6);
  s.health = static_cast<PoseHealth>(k % 4);
  s.health_causes = static_cast<std::uint16_t>(0xFFFFu - k);
  s.mask_age_s = k % 2 ? std::numeric_limits<float>::infinity() : 0.25f * static_cast<float>(k);
  s.threads = {{"tracking", 29.97, 11.9 + 0.01 * static_cast<double>(k), 15.5},
               {"local_mapping", 2.5, 40.0, 165.0},
               {"publisher", 30.0, 0.004, 0.05}};
  s.queues = {{"camera", static_cast<std::uint32_t>(k % 3), 4, k / 7},
              {"publish", 0, 8, 0xFFFFFFFFFFFFFFF0ULL}};
  return s;
}

ObjectsMessage testObjects(std::uint64_t k) {
  ObjectsMessage m;
  m.sensor_stamp = testPose(k).sensor_stamp;
  m.frame_counter = k;
  m.map_id = 0xC0FFEE0000000000ULL | (k / 100);
  for (std::uint64_t j = 0; j < k % 4; ++j) {
    ObjectMessage o;
    o.id = static_cast<std::uint32_t>(1000 * j + k / 3);
    o.label = j == 0 ? "person" : j == 1 ? "unknown" : std::string(ObjectsMessage::kMaxLabelLength, 'x');
    o.sources = static_cast<std::uint8_t>(1 + j % 3);
    const float f = static_cast<float>(k) / 7.0f + static_cast<float>(j);
    o.centroid = {f, -f / 3.0f, 1.0f / (f + 1.0f)};
    o.extent = {0.5f + f / 100.0f, 1.7f, 0.3f};
    o.velocity = {-0.1f * f, 0.0f, 1e-7f * f};
    o.has_velocity = (k + j) % 2 == 1;
    o.samples = static_cast<std::uint32_t>(k * 13 + j);
    m.objects.push_back(o);
  }
  return m;
}

std::string diff(const ObjectsMessage& e, const ObjectsMessage& g) {
  if (e.sensor_stamp != g.sensor_stamp) return "sensor_stamp";
  if (e.frame_counter != g.frame_counter) return "frame_counter";
  if (e.map_id != g.map_id) return "map_id";
  if (e.objects.size() != g.objects.size()) return "object count";
  for (std::size_t j = 0; j < e.objects.size(); ++j)
    if (!(e.objects[j] == g.objects[j])) return "object " + std::to_string(j);
  return "";
}

namespace {
bool same(double a, double b) { return std::memcmp(&a, &b, sizeof(double)) == 0; }
}  // namespace

std::string diff(const PoseMessage& e, const PoseMessage& g) {
  if (e.sensor_stamp != g.sensor_stamp) return "sensor_stamp";
  if (e.frame_counter != g.frame_counter) return "frame_counter";
  for (int i = 0; i < 3; ++i)
    if (!same(e.position[i], g.position[i])) return "position[" + std::to_string(i) + "]";
  for (int i = 0; i < 4; ++i)
    if (!same(e.orientation[i], g.orientation[i])) return "orientation[" + std::to_string(i) + "]";
  if (e.state != g.state) return "state";
  if (e.tracked_features != g.tracked_features) return "tracked_features";
  if (e.dynamic_rejected_features != g.dynamic_rejected_features) return "dynamic_rejected_features";
  if (e.keyframes != g.keyframes) return "keyframes";
  if (e.map_id != g.map_id) return "map_id";
  if (e.health != g.health) return "health";
  if (e.dynamic_share != g.dynamic_share) return "dynamic_share";
  if (e.reprojection_rms_px != g.reprojection_rms_px) return "reprojection_rms_px";
  if (e.conditioning != g.conditioning) return "conditioning";
  if (e.health_causes != g.health_causes) return "health_causes";
  if (e.mask_age_s != g.mask_age_s) return "mask_age_s";
  for (std::size_t i = 0; i < e.covariance.size(); ++i)
    if (e.covariance[i] != g.covariance[i]) return "covariance[" + std::to_string(i) + "]";
  return {};
}

std::string diff(const StatusMessage& e, const StatusMessage& g) {
  StatusMessage a = e;
  StatusMessage b = g;
  a.publish_stamp = b.publish_stamp = Timestamp();
  if (!same(a.uptime_s, b.uptime_s)) return "uptime_s";
  if (a.threads.size() != b.threads.size()) return "threads";
  for (std::size_t i = 0; i < a.threads.size(); ++i)
    if (!same(a.threads[i].latency_ms_median, b.threads[i].latency_ms_median)) return "threads.latency";
  if (!(a == b)) return "status fields";
  return {};
}

}  // namespace stillpoint::ipc::probe
