// LCM transport. Types come from msg/*.lcm through lcm-gen at build time.
#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <cstring>
#include <iterator>
#include <optional>
#include <string>
#include <string_view>

#include "stillpoint/ipc/transport.hpp"
#include "stillpoint_lcm/objects_t.hpp"
#include "stillpoint_lcm/pose_t.hpp"
#include "stillpoint_lcm/status_t.hpp"

namespace stillpoint::ipc {
namespace {

// Unsigned values travel in LCM's signed types bit for bit.
std::int64_t asSigned(std::uint64_t v) { return static_cast<std::int64_t>(v); }
std::uint64_t asUnsigned(std::int64_t v) { return static_cast<std::uint64_t>(v); }

stillpoint_lcm::pose_t toLcm(const PoseMessage& p) {
  stillpoint_lcm::pose_t m{};
  m.schema_version = PoseMessage::kSchemaVersion;
  m.sensor_stamp_ns = p.sensor_stamp.nanoseconds();
  m.publish_stamp_ns = p.publish_stamp.nanoseconds();
  m.frame_counter = asSigned(p.frame_counter);
  for (int i = 0; i < 3; ++i) m.position[i] = p.position[i];
  for (int i = 0; i < 4; ++i) m.orientation[i] = p.orientation[i];
  m.tracking_state = static_cast<std::int8_t>(p.state);
  m.tracked_features = p.tracked_features;
  m.dynamic_rejected_features = p.dynamic_rejected_features;
  m.keyframes = p.keyframes;
  m.map_id = asSigned(p.map_id);
  m.health = static_cast<std::int8_t>(p.health);
  m.dynamic_share = p.dynamic_share;
  m.reprojection_rms_px = p.reprojection_rms_px;
  m.conditioning = p.conditioning;
  m.health_causes = static_cast<std::int16_t>(p.health_causes);
  m.mask_age_s = p.mask_age_s;
  std::copy(p.covariance.begin(), p.covariance.end(), m.covariance);
  return m;
}

// The generated decoder sizes objects_t's array from its count before it
// reads a single element: a 60-byte message counting 10^8 objects would
// allocate and fill gigabytes before the decode fails. The count is the last
// field before the array, and no object encodes to fewer bytes than one with
// an empty label; both sizes are taken from the generated encoder. Returns
// why the message cannot hold its count, or nothing.
std::optional<std::string> countBeyondItsBytes(const stillpoint_lcm::objects_t*, const void* data, std::size_t size) {
  static const std::size_t header = [] {
    stillpoint_lcm::objects_t m{};
    return static_cast<std::size_t>(m.getEncodedSize());  // with count 0: the hash and every field up to the count
  }();
  static const std::size_t element = [] {
    stillpoint_lcm::objects_t m{};
    m.count = 1;
    m.objects.resize(1);
    return static_cast<std::size_t>(m.getEncodedSize()) - header;
  }();
  if (size < header) return std::nullopt;  // too short for the fields: the decoder says so
  const auto* bytes = static_cast<const unsigned char*>(data) + header - 4;
  const std::int32_t count = static_cast<std::int32_t>((std::uint32_t{bytes[0]} << 24) | (std::uint32_t{bytes[1]} << 16) |
                                                       (std::uint32_t{bytes[2]} << 8) | std::uint32_t{bytes[3]});
  if (count >= 0 && static_cast<std::size_t>(count) <= (size - header) / element) return std::nullopt;
  return ": its count of " + std::to_string(count) + " objects needs at least " + std::to_string(element) +
         " bytes each, it has " + std::to_string(size - header);
}
// The status's arrays count in int16_t (at most 32767 small elements) and the
// pose has none: the decoder's own checks are enough.
std::optional<std::string> countBeyondItsBytes(const void*, const void*, std::size_t) { return std::nullopt; }

template <typename T>
Result<T> narrow(std::int64_t v, const char* field) {
  if (v < 0 || static_cast<std::uint64_t>(v) > std::numeric_limits<T>::max())
    return Error{std::string("lcm: field ") + field + " out of range: " + std::to_string(v)};
  return static_cast<T>(v);
}

Result<PoseMessage> fromLcm(const stillpoint_lcm::pose_t& m) {
  if (m.schema_version != static_cast<std::int32_t>(PoseMessage::kSchemaVersion))
    return Error{"lcm: pose schema version " + std::to_string(m.schema_version) + ", this build reads " +
                 std::to_string(PoseMessage::kSchemaVersion)};
  auto state = trackingStateFromInt(m.tracking_state);
  auto tracked = narrow<std::uint32_t>(m.tracked_features, "tracked_features");
  auto rejected = narrow<std::uint32_t>(m.dynamic_rejected_features, "dynamic_rejected_features");
  auto keyframes = narrow<std::uint32_t>(m.keyframes, "keyframes");
  if (!state) return Error{"lcm: " + state.error()};
  if (!tracked) return Error{tracked.error()};
  if (!rejected) return Error{rejected.error()};
  if (!keyframes) return Error{keyframes.error()};
  auto health = poseHealthFromInt(m.health);
  if (!health) return Error{"lcm: " + health.error()};
  PoseMessage p;
  p.sensor_stamp = Timestamp::fromNanoseconds(m.sensor_stamp_ns);
  p.publish_stamp = Timestamp::fromNanoseconds(m.publish_stamp_ns);
  p.frame_counter = asUnsigned(m.frame_counter);
  for (int i = 0; i < 3; ++i) p.position[i] = m.position[i];
  for (int i = 0; i < 4; ++i) p.orientation[i] = m.orientation[i];
  p.state = *state;
  p.tracked_features = *tracked;
  p.dynamic_rejected_features = *rejected;
  p.keyframes = *keyframes;
  p.map_id = asUnsigned(m.map_id);
  p.health = *health;
  p.dynamic_share = m.dynamic_share;
  p.reprojection_rms_px = m.reprojection_rms_px;
  p.conditioning = m.conditioning;
  p.health_causes = static_cast<std::uint16_t>(m.health_causes);
  p.mask_age_s = m.mask_age_s;
  std::copy(std::begin(m.covariance), std::end(m.covariance), p.covariance.begin());
  if (Status v = validate(p); !v) return Error{"lcm: " + v.error()};
  return p;
}

stillpoint_lcm::status_t toLcm(const StatusMessage& s) {
  stillpoint_lcm::status_t m{};
  m.schema_version = StatusMessage::kSchemaVersion;
  m.publish_stamp_ns = s.publish_stamp.nanoseconds();
  m.uptime_s = s.uptime_s;
  m.frames_received = asSigned(s.frames_received);
  m.frames_dropped = asSigned(s.frames_dropped);
  m.map_id = asSigned(s.map_id);
  m.tracking_state = static_cast<std::int8_t>(s.tracking_state);
  m.health = static_cast<std::int8_t>(s.health);
  m.health_causes = static_cast<std::int16_t>(s.health_causes);
  m.mask_age_s = s.mask_age_s;
  m.num_threads = static_cast<std::int16_t>(s.threads.size());
  for (const auto& t : s.threads)
    m.threads.push_back({t.name, t.loop_rate_hz, t.latency_ms_median, t.latency_ms_max});
  m.num_queues = static_cast<std::int16_t>(s.queues.size());
  for (const auto& q : s.queues) m.queues.push_back({q.name, q.depth, q.capacity, asSigned(q.dropped)});
  return m;
}

Result<StatusMessage> fromLcm(const stillpoint_lcm::status_t& m) {
  if (m.schema_version != static_cast<std::int32_t>(StatusMessage::kSchemaVersion))
    return Error{"lcm: status schema version " + std::to_string(m.schema_version) + ", this build reads " +
                 std::to_string(StatusMessage::kSchemaVersion)};
  StatusMessage s;
  s.publish_stamp = Timestamp::fromNanoseconds(m.publish_stamp_ns);
  s.uptime_s = m.uptime_s;
  s.frames_received = asUnsigned(m.frames_received);
  s.frames_dropped = asUnsigned(m.frames_dropped);
  s.map_id = asUnsigned(m.map_id);
  auto state = trackingStateFromInt(m.tracking_state);
  if (!state) return Error{"lcm: status " + state.error()};
  auto health = poseHealthFromInt(m.health);
  if (!health) return Error{"lcm: status " + health.error()};
  s.tracking_state = *state;
  s.health = *health;
  s.health_causes = static_cast<std::uint16_t>(m.health_causes);
  s.mask_age_s = m.mask_age_s;
  for (const auto& t : m.threads) s.threads.push_back({t.name, t.loop_rate_hz, t.latency_ms_median, t.latency_ms_max});
  for (const auto& q : m.queues) {
    auto depth = narrow<std::uint32_t>(q.depth, "queues.depth");
    auto capacity = narrow<std::uint32_t>(q.capacity, "queues.capacity");
    if (!depth) return Error{depth.error()};
    if (!capacity) return Error{capacity.error()};
    s.queues.push_back({q.name, *depth, *capacity, asUnsigned(q.dropped)});
  }
  if (Status v = validate(s); !v) return Error{"lcm: " + v.error()};
  return s;
}

stillpoint_lcm::objects_t toLcm(const ObjectsMessage& o) {
  stillpoint_lcm::objects_t m{};
  m.schema_version = ObjectsMessage::kSchemaVersion;
  m.sensor_stamp_ns = o.sensor_stamp.nanoseconds();
  m.publish_stamp_ns = o.publish_stamp.nanoseconds();
  m.frame_counter = asSigned(o.frame_counter);
  m.map_id = asSigned(o.map_id);
  m.count = static_cast<std::int32_t>(o.objects.size());
  for (const ObjectMessage& x : o.objects) {
    stillpoint_lcm::object_t y{};
    y.id = static_cast<std::int32_t>(x.id);
    y.label = x.label;
    y.sources = static_cast<std::int8_t>(x.sources);
    for (int k = 0; k < 3; ++k) y.centroid[k] = x.centroid[k], y.extent[k] = x.extent[k], y.velocity[k] = x.velocity[k];
    y.has_velocity = x.has_velocity;
    y.samples = static_cast<std::int32_t>(x.samples);
    m.objects.push_back(std::move(y));
  }
  return m;
}

Result<ObjectsMessage> fromLcm(const stillpoint_lcm::objects_t& m) {
  if (m.schema_version != static_cast<std::int32_t>(ObjectsMessage::kSchemaVersion))
    return Error{"lcm: objects schema version " + std::to_string(m.schema_version) + ", this build reads " +
                 std::to_string(ObjectsMessage::kSchemaVersion)};
  ObjectsMessage o;
  o.sensor_stamp = Timestamp::fromNanoseconds(m.sensor_stamp_ns);
  o.publish_stamp = Timestamp::fromNanoseconds(m.publish_stamp_ns);
  o.frame_counter = asUnsigned(m.frame_counter);
  o.map_id = asUnsigned(m.map_id);
  for (const auto& y : m.objects) {
    ObjectMessage x;
    x.id = static_cast<std::uint32_t>(y.id);
    x.label = y.label;
    x.sources = static_cast<std::uint8_t>(y.sources);
    for (int k = 0; k < 3; ++k) x.centroid[k] = y.centroid[k], x.extent[k] = y.extent[k], x.velocity[k] = y.velocity[k];
    x.has_velocity = y.has_velocity;
    auto samples = narrow<std::uint32_t>(y.samples, "objects.samples");
    if (!samples) return Error{samples.error()};
    x.samples = *samples;
    o.objects.push_back(std::move(x));
  }
  if (Status v = validate(o); !v) return Error{"lcm: " + v.error()};
  return o;
}

Status checkUrl(const std::string& url) {
  // lcm::LCM prints its own complaint and leaves the object unusable; say which URL.
  if (url.find("://") == std::string::npos)
    return Error{"lcm: URL '" + url + "' is not of the form provider://address (e.g. udpm://239.255.76.67:7667?ttl=0)"};
  return Status::success();
}

class LcmTransport final : public Transport {
 public:
  explicit LcmTransport(const LcmOptions& options) : options_(options), lcm_(options.url) {}
  bool good() { return lcm_.good(); }
  std::string_view name() const override { return "lcm"; }

  Status publishPose(const PoseMessage& pose) override {
    const auto m = toLcm(pose);
    if (lcm_.publish(options_.pose_channel, &m) != 0) return Error{"lcm: publish on " + options_.pose_channel + " failed"};
    return Status::success();
  }
  Status publishStatus(const StatusMessage& status) override {
    if (Status v = validate(status); !v) return v;
    const auto m = toLcm(status);
    if (lcm_.publish(options_.status_channel, &m) != 0)
      return Error{"lcm: publish on " + options_.status_channel + " failed"};
    return Status::success();
  }
  Status publishObjects(const ObjectsMessage& objects) override {
    if (options_.objects_channel.empty()) return Status::success();
    if (Status v = validate(objects); !v) return v;
    const auto m = toLcm(objects);
    if (lcm_.publish(options_.objects_channel, &m) != 0)
      return Error{"lcm: publish on " + options_.objects_channel + " failed"};
    return Status::success();
  }

 private:
  LcmOptions options_;
  lcm::LCM lcm_;
};

class LcmSubscriber final : public Subscriber {
 public:
  explicit LcmSubscriber(const LcmOptions& options) : options_(options), lcm_(options.url) {}

  Status start() {
    if (!lcm_.good()) return Error{"lcm: cannot open URL '" + options_.url + "'"};
    // Raw callbacks: decode failures (another schema on our channel) become errors
    // returned from poll() instead of being dropped silently.
    // LCM drops messages beyond a subscription's queue capacity (default 30) when the
    // caller polls late; a subscriber descheduled for 30 ms at 1 kHz would lose poses.
    lcm_.subscribeFunction(options_.pose_channel, &onRaw<stillpoint_lcm::pose_t, &LcmSubscriber::pose_handler_>, this)
        ->setQueueCapacity(1024);
    lcm_.subscribeFunction(options_.status_channel, &onRaw<stillpoint_lcm::status_t, &LcmSubscriber::status_handler_>,
                           this)
        ->setQueueCapacity(64);
    if (!options_.objects_channel.empty())
      lcm_.subscribeFunction(options_.objects_channel,
                             &onRaw<stillpoint_lcm::objects_t, &LcmSubscriber::objects_handler_>, this)
          ->setQueueCapacity(1024);
    return Status::success();
  }

  Result<int> poll(std::chrono::milliseconds timeout) override {
    handled_ = 0;
    error_.clear();
    const int rc = lcm_.handleTimeout(static_cast<int>(timeout.count()));
    if (!error_.empty()) return Error{error_};
    if (rc < 0) return Error{"lcm: receive failed on '" + options_.url + "' (end of log for file://)"};
    // Drain what else is already waiting without blocking.
    while (lcm_.handleTimeout(0) > 0) {
      if (!error_.empty()) return Error{error_};
    }
    return handled_;
  }

 private:
  // One raw callback per message type: a message that does not decode as
  // Wire (another schema on our channel) or does not convert becomes poll()'s
  // error; a good one goes to the handler the member pointer names.
  // Nothing may cross liblcm's C dispatcher: the generated decoder throws
  // (std::length_error, std::bad_alloc) on a count or string length its
  // bytes cannot hold, and so may the caller's handler; either is poll()'s
  // error.
  template <typename Wire, auto handler>
  static void onRaw(const lcm::ReceiveBuffer* rbuf, const std::string& channel, LcmSubscriber* self) noexcept {
    const auto cannot = [&](const std::string& why) {
      const std::string type = Wire::getTypeName();
      const char* article = std::string_view("aeiou").find(type.front()) == std::string_view::npos ? "a " : "an ";
      self->error_ = "lcm: cannot decode " + (article + type) + " on " + channel + why;
    };
    try {
      Wire m;
      if (auto why = countBeyondItsBytes(&m, rbuf->data, rbuf->data_size)) {
        cannot(*why);
        return;
      }
      if (m.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) < 0) {
        cannot(" (different schema?)");
        return;
      }
      auto message = fromLcm(m);
      if (!message) {
        self->error_ = message.error();
        return;
      }
      ++self->handled_;
      if (self->*handler) (self->*handler)(*message);
    } catch (const std::exception& e) {
      cannot(std::string(": ") + e.what());
    } catch (...) {
      cannot(": unknown error");
    }
  }
  LcmOptions options_;
  lcm::LCM lcm_;
  int handled_ = 0;
  std::string error_;
};

}  // namespace

Result<std::unique_ptr<Transport>> makeLcmTransport(const LcmOptions& options) {
  if (Status s = checkUrl(options.url); !s) return Error{s.error()};
  auto t = std::make_unique<LcmTransport>(options);
  if (!t->good()) return Error{"lcm: cannot open URL '" + options.url + "'"};
  return std::unique_ptr<Transport>(std::move(t));
}

Result<std::unique_ptr<Subscriber>> makeLcmSubscriber(const LcmOptions& options) {
  if (Status s = checkUrl(options.url); !s) return Error{s.error()};
  auto sub = std::make_unique<LcmSubscriber>(options);
  if (Status s = sub->start(); !s) return Error{s.error()};
  return std::unique_ptr<Subscriber>(std::move(sub));
}

}  // namespace stillpoint::ipc
