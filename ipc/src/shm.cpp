// Shared-memory transport: poses go into the pose ring and dynamic objects into a
// ring of their own (one record per object); status is not carried (it travels over
// LCM or DDS).
#include <cerrno>
#include <chrono>
#include <algorithm>
#include <cstdio>
#include <cstring>
#include <iterator>
#include <thread>
#include <vector>

#include "stillpoint/ipc/shm_writer.hpp"
#include "stillpoint/ipc/transport.hpp"

namespace stillpoint::ipc {
namespace {

sp_pose_record toRecord(const PoseMessage& p) {
  sp_pose_record r{};
  r.sensor_stamp_ns = p.sensor_stamp.nanoseconds();
  r.publish_stamp_ns = p.publish_stamp.nanoseconds();
  r.frame_counter = p.frame_counter;
  for (int i = 0; i < 3; ++i) r.position[i] = p.position[i];
  for (int i = 0; i < 4; ++i) r.orientation[i] = p.orientation[i];
  r.tracking_state = static_cast<std::uint32_t>(p.state);
  r.tracked_features = p.tracked_features;
  r.dynamic_rejected_features = p.dynamic_rejected_features;
  r.keyframes = p.keyframes;
  r.map_id = p.map_id;
  r.health = static_cast<std::uint32_t>(p.health);
  r.dynamic_share = p.dynamic_share;
  r.reprojection_rms_px = p.reprojection_rms_px;
  r.conditioning = p.conditioning;
  r.health_causes = p.health_causes;
  r.mask_age_s = p.mask_age_s;
  std::copy(p.covariance.begin(), p.covariance.end(), r.covariance);
  return r;
}

Result<PoseMessage> fromRecord(const sp_pose_record& r) {
  PoseMessage p;
  auto state = trackingStateFromInt(r.tracking_state);
  if (!state) return Error{"shm: " + state.error()};
  p.state = *state;
  p.sensor_stamp = Timestamp::fromNanoseconds(r.sensor_stamp_ns);
  p.publish_stamp = Timestamp::fromNanoseconds(r.publish_stamp_ns);
  p.frame_counter = r.frame_counter;
  for (int i = 0; i < 3; ++i) p.position[i] = r.position[i];
  for (int i = 0; i < 4; ++i) p.orientation[i] = r.orientation[i];
  p.tracked_features = r.tracked_features;
  p.dynamic_rejected_features = r.dynamic_rejected_features;
  p.keyframes = r.keyframes;
  p.map_id = r.map_id;
  auto health = poseHealthFromInt(r.health);
  if (!health) return Error{"shm: " + health.error()};
  p.health = *health;
  p.dynamic_share = r.dynamic_share;
  p.reprojection_rms_px = r.reprojection_rms_px;
  p.conditioning = r.conditioning;
  p.health_causes = static_cast<std::uint16_t>(r.health_causes);
  p.mask_age_s = r.mask_age_s;
  std::copy(std::begin(r.covariance), std::end(r.covariance), p.covariance.begin());
  if (Status v = validate(p); !v) return Error{"shm: " + v.error()};
  return p;
}

// A frame's objects as records: one per object, or one with count 0.
std::vector<sp_object_record> toRecords(const ObjectsMessage& m) {
  std::vector<sp_object_record> out(std::max<std::size_t>(1, m.objects.size()));
  for (std::size_t k = 0; k < out.size(); ++k) {
    sp_object_record& r = out[k];
    r.sensor_stamp_ns = m.sensor_stamp.nanoseconds();
    r.publish_stamp_ns = m.publish_stamp.nanoseconds();
    r.frame_counter = m.frame_counter;
    r.map_id = m.map_id;
    r.index = static_cast<std::uint16_t>(k);
    r.count = static_cast<std::uint16_t>(m.objects.size());
    if (m.objects.empty()) break;
    const ObjectMessage& o = m.objects[k];
    r.id = o.id;
    r.sources = o.sources;
    r.samples = o.samples;
    for (int i = 0; i < 3; ++i) r.centroid[i] = o.centroid[i], r.extent[i] = o.extent[i], r.velocity[i] = o.velocity[i];
    r.has_velocity = o.has_velocity;
    std::snprintf(r.label, sizeof(r.label), "%s", o.label.c_str());
  }
  return out;
}

class ShmTransport final : public Transport {
 public:
  ShmTransport(std::unique_ptr<ShmPoseWriter> writer, std::unique_ptr<ShmPoseWriter> objects)
      : writer_(std::move(writer)), objects_(std::move(objects)) {}
  std::string_view name() const override { return "shm"; }
  Status publishPose(const PoseMessage& pose) override {
    writer_->write(toRecord(pose));
    return Status::success();
  }
  Status publishStatus(const StatusMessage&) override { return Status::success(); }
  Status publishObjects(const ObjectsMessage& objects) override {
    if (!objects_) return Status::success();
    if (Status v = validate(objects); !v) return v;
    for (const sp_object_record& r : toRecords(objects)) objects_->write(r);
    return Status::success();
  }

 private:
  std::unique_ptr<ShmPoseWriter> writer_;
  std::unique_ptr<ShmPoseWriter> objects_;  // null: off
};

class ShmSubscriber final : public Subscriber {
 public:
  ShmSubscriber(std::string name, std::string objects_name, ShmSubscriberOptions options)
      : name_(std::move(name)), objects_name_(std::move(objects_name)), options_(options) {
    sp_shm_reader_init(&reader_);
    sp_shm_reader_init(&objects_);
    if (options_.owner_uid >= 0)
      reader_.owner_uid = objects_.owner_uid = static_cast<std::uint32_t>(options_.owner_uid);
  }
  ~ShmSubscriber() override {
    sp_shm_reader_close(&reader_);
    sp_shm_reader_close(&objects_);
  }

  Status open() {
    const int start = options_.from_oldest ? SP_SHM_START_OLDEST : SP_SHM_START_LATEST;
    int rc = sp_shm_reader_open(&reader_, name_.c_str(), start);
    int err = errno;
    if (!(rc == SP_SHM_OK || (rc == SP_SHM_ERR_NO_RING && options_.wait_for_ring))) return Error{describe(rc, err)};
    if (!options_.objects) return Status::success();
    if (objects_name_.empty()) return Error{"shm: objects asked for, but ipc.shm.objects is off"};
    rc = sp_shm_reader_open_objects(&objects_, objects_name_.c_str(), start);
    err = errno;
    if (rc == SP_SHM_OK || (rc == SP_SHM_ERR_NO_RING && options_.wait_for_ring)) return Status::success();
    return Error{"shm: objects ring " + objects_name_ + ": " + sp_shm_strerror(rc) +
                 (rc == SP_SHM_ERR_OPEN ? std::string(": ") + std::strerror(err) : std::string())};
  }

  Result<int> poll(std::chrono::milliseconds timeout) override {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    int handled = 0;
    sp_pose_record record;
    for (;;) {
      if (options_.objects) {
        auto got = drainObjects();
        if (!got) return Error{got.error()};
        handled += *got;
      }
      const int rc = sp_shm_reader_next(&reader_, &record);
      const int err = errno;
      if (rc == SP_SHM_OK) {
        auto pose = fromRecord(record);
        if (!pose) return Error{pose.error()};
        ++handled;
        if (pose_handler_) pose_handler_(*pose);
        continue;  // drain everything available before returning
      }
      if (rc == SP_SHM_RESTARTED) {
        if (restart_handler_) restart_handler_();
        continue;
      }
      if (rc < 0 && !(rc == SP_SHM_ERR_NO_RING && options_.wait_for_ring)) return Error{describe(rc, err)};
      if (handled > 0 || std::chrono::steady_clock::now() >= deadline) return handled;
      if (rc == SP_SHM_EMPTY) {
        if (Status writer = checkWriter(); !writer) return Error{writer.error()};
      }
      if (!options_.busy_poll) std::this_thread::sleep_for(std::chrono::microseconds(50));
    }
  }

  std::uint64_t lost() const override { return reader_.lost; }

 private:
  // How often an idle subscriber asks whether the writer is still there.
  static constexpr std::chrono::milliseconds kLivenessPeriod{100};

  // Nothing new arrived: an error when the writer died and no new writer took over.
  Status checkWriter() {
    const auto now = std::chrono::steady_clock::now();
    if (reader_.base == nullptr || now < next_liveness_check_) return Status::success();
    next_liveness_check_ = now + kLivenessPeriod;
    const int died = sp_shm_reader_writer_died(&reader_);
    if (died < 0)
      return Error{"shm: cannot tell whether the writer of " + std::string(reader_.path) +
                   " is alive: " + sp_shm_strerror(died)};
    if (died == 0 || options_.wait_for_ring) return Status::success();
    return Error{"shm: ring " + std::string(reader_.path) + ": writer gone (pid " +
                 std::to_string(sp_shm_reader_header(&reader_)->writer_pid) +
                 " ended without closing the ring: killed or crashed)"};
  }

  // The reader's code as a message naming the file; err: errno right after the call.
  std::string describe(int rc, int err) const {
    const std::string where = reader_.path[0] != '\0' ? std::string(reader_.path) : name_;
    if (rc == SP_SHM_ERR_NOT_REGULAR)
      return "shm: " + where + " is a " + sp_shm_file_kind(reader_.found_mode) +
             ", not a regular file; refusing to use it";
    if (rc == SP_SHM_ERR_OWNER)
      return "shm: " + where + " is owned by uid " + std::to_string(reader_.found_uid) + ", not by uid " +
             std::to_string(reader_.owner_uid) + " (the expected writer); refusing to use it";
    if (rc == SP_SHM_ERR_OPEN) return "shm: ring " + where + ": " + sp_shm_strerror(rc) + ": " + std::strerror(err);
    return "shm: ring " + where + ": " + sp_shm_strerror(rc);
  }

  // Collects a frame's object records; a frame is handed over once its last
  // record arrived (records of a frame whose first ones were overwritten are
  // dropped with it).
  Result<int> drainObjects() {
    int handled = 0;
    sp_object_record r;
    for (;;) {
      const int rc = sp_shm_reader_next_object(&objects_, &r);
      if (rc == SP_SHM_RESTARTED) {
        pending_.objects.clear();
        continue;
      }
      if (rc == SP_SHM_EMPTY || (rc == SP_SHM_ERR_NO_RING && options_.wait_for_ring)) return handled;
      if (rc < 0) return Error{"shm: objects ring " + objects_name_ + ": " + sp_shm_strerror(rc)};
      if (r.index == 0) {
        pending_ = ObjectsMessage{};
        pending_.sensor_stamp = Timestamp::fromNanoseconds(r.sensor_stamp_ns);
        pending_.publish_stamp = Timestamp::fromNanoseconds(r.publish_stamp_ns);
        pending_.frame_counter = r.frame_counter;
        pending_.map_id = r.map_id;
        pending_open_ = true;
      } else if (!pending_open_ || r.frame_counter != pending_.frame_counter ||
                 r.index != pending_.objects.size()) {
        pending_open_ = false;  // its start was lost
        continue;
      }
      if (r.count > 0) {
        ObjectMessage o;
        o.id = r.id;
        o.sources = static_cast<std::uint8_t>(r.sources);
        o.samples = r.samples;
        for (int i = 0; i < 3; ++i) o.centroid[i] = r.centroid[i], o.extent[i] = r.extent[i], o.velocity[i] = r.velocity[i];
        o.has_velocity = r.has_velocity != 0;
        o.label = std::string(r.label, strnlen(r.label, sizeof(r.label)));
        pending_.objects.push_back(std::move(o));
      }
      if (pending_.objects.size() >= r.count) {
        pending_open_ = false;
        if (Status v = validate(pending_); !v) return Error{"shm: " + v.error()};
        ++handled;
        if (objects_handler_) objects_handler_(pending_);
      }
    }
  }

  std::string name_, objects_name_;
  ShmSubscriberOptions options_;
  sp_shm_reader reader_, objects_;
  ObjectsMessage pending_;
  bool pending_open_ = false;
  std::chrono::steady_clock::time_point next_liveness_check_{};
};

}  // namespace

Result<std::unique_ptr<Transport>> makeShmTransport(const ShmOptions& options) {
  auto writer = ShmPoseWriter::create(options.name, options.capacity);
  if (!writer) return Error{writer.error()};
  std::unique_ptr<ShmPoseWriter> objects;
  if (const std::string ring = options.objectsRing(); !ring.empty()) {
    // A few records per frame: four times the pose ring's depth.
    auto made = ShmPoseWriter::create(ring, std::min<std::uint32_t>(options.capacity * 4, SP_SHM_MAX_CAPACITY),
                                      SP_SHM_OBJECTS_MAGIC);
    if (!made) return Error{made.error()};
    objects = std::move(made.value());
  }
  return std::unique_ptr<Transport>(new ShmTransport(std::move(writer.value()), std::move(objects)));
}

Result<std::unique_ptr<Subscriber>> makeShmSubscriber(const ShmOptions& options, const ShmSubscriberOptions& sub) {
  auto s = std::make_unique<ShmSubscriber>(options.name, options.objectsRing(), sub);
  if (Status st = s->open(); !st) return Error{st.error()};
  return std::unique_ptr<Subscriber>(std::move(s));
}

}  // namespace stillpoint::ipc
