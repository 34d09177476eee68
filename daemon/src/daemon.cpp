#include "daemon.hpp"

#include <opencv2/core.hpp>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <optional>
#include <thread>
#include <vector>

#include "bounded_queue.hpp"
#include "source_stamps.hpp"
#include "stillpoint/core/covariance.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint/ipc/publisher.hpp"
#include "stillpoint/platform/openni2_source.hpp"
#include "stillpoint/platform/replay_source.hpp"
#include "stillpoint/platform/v4l2_source.hpp"
#include "stillpoint/slam/system.hpp"
#include "threads.hpp"

namespace stillpoint::daemon {
namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

const log::Logger logger("stillpointd");

// Pose latency in 0.05 ms bins up to 2 s: fixed memory however long the daemon runs.
class LatencyHistogram {
 public:
  void add(double ms) {
    const auto bin = static_cast<std::size_t>(std::clamp(ms / kBinMs, 0.0, double(kBins - 1)));
    std::lock_guard lock(mutex_);
    ++bins_[bin];
    ++count_;
    max_ = std::max(max_, ms);
  }
  // Upper edge of the bin holding quantile q (0..1); 0 when empty.
  double quantile(double q) const {
    std::lock_guard lock(mutex_);
    if (count_ == 0) return 0.0;
    const auto target = static_cast<std::uint64_t>(std::ceil(q * count_));
    std::uint64_t seen = 0;
    for (std::size_t i = 0; i < kBins; ++i) {
      seen += bins_[i];
      if (seen >= std::max<std::uint64_t>(target, 1)) return (i + 1) * kBinMs;
    }
    return max_;
  }
  double max() const {
    std::lock_guard lock(mutex_);
    return max_;
  }

 private:
  static constexpr double kBinMs = 0.05;
  static constexpr std::size_t kBins = 40000;
  mutable std::mutex mutex_;
  std::vector<std::uint32_t> bins_ = std::vector<std::uint32_t>(kBins, 0);
  std::uint64_t count_ = 0;
  double max_ = 0;
};

double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

ipc::TrackingState toIpc(slam::TrackingState s) {
  switch (s) {
    case slam::TrackingState::kInitialising: return ipc::TrackingState::kInitialising;
    case slam::TrackingState::kOk: return ipc::TrackingState::kOk;
    case slam::TrackingState::kLost: return ipc::TrackingState::kLost;
    case slam::TrackingState::kRelocalised: return ipc::TrackingState::kRelocalised;
    case slam::TrackingState::kNoDepth: return ipc::TrackingState::kNoDepth;
    case slam::TrackingState::kNewMap: return ipc::TrackingState::kNewMap;
  }
  return ipc::TrackingState::kLost;
}

ipc::ObjectsMessage toIpc(const std::vector<slam::DynamicObject>& objects, const ipc::PoseMessage& pose) {
  ipc::ObjectsMessage m;
  m.sensor_stamp = pose.sensor_stamp;
  m.frame_counter = pose.frame_counter;
  m.map_id = pose.map_id;
  // The largest first when a frame has more than a message carries.
  std::vector<const slam::DynamicObject*> order;
  for (const auto& o : objects) order.push_back(&o);
  std::stable_sort(order.begin(), order.end(), [](auto* a, auto* b) { return a->samples > b->samples; });
  if (order.size() > ipc::ObjectsMessage::kMaxObjects) order.resize(ipc::ObjectsMessage::kMaxObjects);
  for (const slam::DynamicObject* o : order) {
    ipc::ObjectMessage x;
    x.id = o->id;
    x.label = o->label.substr(0, ipc::ObjectsMessage::kMaxLabelLength);
    x.sources = o->sources;
    for (int k = 0; k < 3; ++k) {
      x.centroid[k] = static_cast<float>(o->centroid[k]);
      x.extent[k] = static_cast<float>(o->extent[k]);
      x.velocity[k] = static_cast<float>(o->velocity[k]);
    }
    x.has_velocity = o->has_velocity;
    x.samples = static_cast<std::uint32_t>(o->samples);
    m.objects.push_back(std::move(x));
  }
  return m;
}

void logWarnings(const std::vector<std::string>& warnings) {
  for (const auto& w : warnings) SP_WARN(logger, w);
}

// Runs `fn` on a short-lived thread that carries `placement`: threads `fn`
// starts inherit its name, CPU affinity and scheduling policy.
template <typename Fn>
void runPlaced(const std::string& name, const ThreadPlacement& placement, const std::vector<int>& available,
               const std::string& what, Fn&& fn) {
  std::thread t([&] {
    logWarnings(placeCurrentThread(name, placement, available, what));
    fn();
  });
  t.join();
}

}  // namespace

struct Daemon::Impl {
  DaemonConfig config;
  std::vector<int> available_cores;
  SystemdNotifier notifier;
  std::unique_ptr<platform::RgbdSource> source;
  std::unique_ptr<slam::SlamSystem> system;
  std::unique_ptr<ipc::Publisher> publisher;
  std::unique_ptr<BoundedQueue<platform::CameraFrame>> queue;

  std::mutex mutex;
  std::condition_variable wake;
  bool stop_requested = false;
  bool source_ended = false;
  bool tracking_done = false;
  Clock::time_point stop_time;
  const Clock::time_point start_time = Clock::now();

  std::atomic<bool> ready_sent{false};
  // A camera (OpenNI2 device) absent at start-up: the service comes up and
  // waits for it (sourceLoop opens it), READY=1 at once, the watchdog fed.
  std::atomic<bool> waiting_for_camera{false};
  std::atomic<std::uint64_t> frames_received{0}, frames_bad{0}, frames_tracked{0}, frames_lost{0},
      frames_processed{0}, reconnects{0}, keyframes{0};
  // Frames with a pose by health (good, degraded, unreliable) and by what
  // lowered it (one count per health_cause bit), over the run.
  std::array<std::atomic<std::uint64_t>, 3> frames_by_health{};
  std::array<std::atomic<std::uint64_t>, health_cause::kCount> frames_by_cause{};
  std::atomic<int> last_state{-1};
  // The newest frame's pose health (low byte) and what lowered it (the 16 bits
  // above), in one word so that a status never pairs one frame's health with
  // another's causes.
  std::atomic<std::uint32_t> last_health{static_cast<std::uint32_t>(slam::PoseHealth::kLost)};
  std::atomic<float> last_mask_age_s{-1.0f};
  std::atomic<std::uint32_t> map_id{0};
  std::atomic<std::int64_t> last_stamp_ns{0};  // sensor stamp of the newest frame tracked
  std::atomic<double> tracking_rate_hz{0};
  std::atomic<bool> device_gone{false};
  std::atomic<int> semantic_tid{0};  // the segmentation thread (nice 10 by default)
  LatencyHistogram latency;
  LatencyHistogram track_time;  // SlamSystem::track() alone, ORB extraction included
  ipc::PublisherStats publisher_stats;  // final, taken at stop

  void sourceLoop(std::stop_token stop);
  void trackingLoop();
  std::string statusLine(double fps) const;
  ipc::StatusMessage statusMessage() const;
  Status writeOutputs(const std::string& reason, double shutdown_ms);
};

Daemon::Daemon(DaemonConfig config) : impl_(std::make_unique<Impl>()) { impl_->config = std::move(config); }
Daemon::~Daemon() = default;

void Daemon::saveMap() {
  if (impl_->config.map.save.empty()) {
    SP_WARN(logger, "SIGUSR1: no map.save file configured, nothing saved");
    return;
  }
  if (!impl_->system) return;
  const auto t0 = Clock::now();
  if (Status s = impl_->system->saveMap(impl_->config.map.save); !s)
    SP_ERROR(logger, s.error());
  else
    SP_INFO(logger, "map saved to " << impl_->config.map.save << " in " << msSince(t0) << " ms");
}

void Daemon::requestStop() {
  std::lock_guard lock(impl_->mutex);
  if (!impl_->stop_requested) {
    impl_->stop_requested = true;
    impl_->stop_time = Clock::now();
  }
  impl_->wake.notify_all();
}

Status Daemon::start() {
  Impl& d = *impl_;
  const DaemonConfig& c = d.config;
  d.available_cores = availableCores();
  if (c.lock_memory) {
    bool locked = false;
    logWarnings(lockMemory(&locked));
    if (locked) SP_INFO(logger, "memory locked (mlockall)");
  }
  if (c.source.type == "openni2") d.source = std::make_unique<platform::OpenNI2Source>(c.source.openni2, c.camera);
  else if (c.source.type == "v4l2") d.source = std::make_unique<platform::V4l2Source>(c.source.v4l2, c.camera);
  else d.source = std::make_unique<platform::ReplaySource>(c.source.replay, c.camera);
  if (Status s = d.source->open(); !s) {
    // A device that is not plugged in yet is waited for; a recording that is
    // not there (a replay folder, an .oni file) is a configuration error.
    const std::string& uri = c.source.openni2.uri;
    const bool recording = uri.size() >= 4 && (uri.compare(uri.size() - 4, 4, ".oni") == 0 ||
                                                uri.compare(uri.size() - 4, 4, ".ONI") == 0);
    if (c.source.type != "openni2" || recording) return Error{"source: " + s.error()};
    SP_WARN(logger, "source: " << s.error() << "; waiting for the camera");
    d.waiting_for_camera = true;
  } else {
    SP_INFO(logger, "source: " << d.source->describe());
  }
  // Test hook (test/daemon_process_test.cpp): a start-up as slow as loading a
  // network on a loaded CPU, to signal the daemon during it. Never set in production.
  if (const char* slow = std::getenv("STILLPOINTD_TEST_SLOW_START_MS"))
    std::this_thread::sleep_for(std::chrono::milliseconds(std::atol(slow)));
  d.queue = std::make_unique<BoundedQueue<platform::CameraFrame>>(
      c.source.queue_capacity, d.source->live() ? BoundedQueue<platform::CameraFrame>::Policy::kDropOldest
                                                : BoundedQueue<platform::CameraFrame>::Policy::kBlock);
  Status status;
  // The semantic module's thread places itself through a hook; the other
  // SLAM threads inherit the set-up thread's placement.
  slam::SlamThreadHooks hooks;
  hooks.semantic_start = [&d] {
    d.semantic_tid = static_cast<int>(::gettid());
    clearInheritedPlacement(d.available_cores);  // not the mapping placement it was started under
    logWarnings(placeCurrentThread("sp-semantic", d.config.threads.semantic, d.available_cores, "threads.semantic"));
  };
  runPlaced("sp-mapping", c.threads.mapping, d.available_cores, "threads.mapping", [&] {
    auto system = slam::SlamSystem::create(c.camera, c.slam, hooks);
    if (!system) status = Error{"slam: " + system.error()};
    else d.system = std::move(*system);
  });
  if (!status) {
    // With the card checked at load, what fails here is the network itself
    // (not an ONNX file, or not the model the card describes).
    if (c.modules.semantic && status.error().find("semantic") != std::string::npos)
      return Error{"field 'modules.semantic_model_card' (card " + c.semantic_model.card_path + ", model " +
                   c.semantic_model.model_path + "): " + status.error()};
    return status;
  }
  if (!c.map.load.empty()) {
    const auto t0 = Clock::now();
    if (Status s = d.system->loadMap(c.map.load); !s) return Error{"field 'map.load': " + s.error()};
    SP_INFO(logger, "map " << c.map.load << " loaded in " << msSince(t0) << " ms"
                           << (c.map.localisation ? ", localisation only" : ""));
  }
  if (c.modules.semantic)
    SP_INFO(logger, "semantic module: " << c.semantic_model.name << " (" << c.semantic_model.reason << "), model "
                                        << c.semantic_model.model_path);
  runPlaced("sp-publisher", c.threads.publisher, d.available_cores, "threads.publisher", [&] {
    auto publisher = ipc::Publisher::create(c.ipc);
    if (!publisher) status = Error{"ipc: " + publisher.error()};
    else d.publisher = std::move(*publisher);
  });
  return status;
}

void Daemon::Impl::sourceLoop(std::stop_token stop) {
  logWarnings(placeCurrentThread("sp-source", config.threads.source, available_cores, "threads.source"));
  auto backoff = 100ms;
  // A camera can report many bad frames a second (e.g. a stalled depth stream
  // of the v4l2 source): warn at most every 2 s; frames_bad counts them all.
  log::RateLimiter bad_frames(2s);
  // Reopens the source with a growing backoff (0.1 -> 2 s) until it opens or
  // a stop is requested; false on a stop.
  auto reopen = [&](log::RateLimiter* warn_limit) {
    for (;;) {
      std::unique_lock lock(mutex);
      if (wake.wait_for(lock, backoff, [&] { return stop_requested; })) return false;
      lock.unlock();
      backoff = std::min<std::chrono::milliseconds>(backoff * 2, 2000ms);
      Status s = source->open();
      if (s) return true;
      if (warn_limit) SP_WARN_EVERY(logger, *warn_limit, "source: still waiting for the camera: " << s.error());
      else SP_WARN(logger, "source: reopen failed: " << s.error());
    }
  };
  SourceStamps stamps;
  if (waiting_for_camera) {
    log::RateLimiter waiting(30s);
    if (reopen(&waiting)) SP_INFO(logger, "source: camera found: " << source->describe());
    waiting_for_camera = false;
  }
  while (!stop.stop_requested()) {
    platform::CameraFrame frame;
    const platform::SourceResult r = source->next(frame, 100ms);
    if (r.event == platform::SourceEvent::kFrame) {
      ++frames_received;
      backoff = 100ms;
      bool rebased = false;
      const std::optional<Timestamp> stamp = stamps.next(frame.stamp, std::chrono::steady_clock::now(), &rebased);
      if (!stamp) {
        ++frames_bad;
        SP_WARN_EVERY(logger, bad_frames, "source: skipping a frame stamped at or before the last one ("
                                              << frames_bad.load() << " bad frames so far)");
        continue;
      }
      if (rebased) SP_WARN(logger, "source: the camera's clock started again; its stamps go on from the last frame's");
      frame.stamp = *stamp;
      if (!ready_sent.exchange(true)) {
        notifier.ready();  // the camera delivers: the service is up
        SP_INFO(logger, "first frame received; ready");
      }
      queue->push(std::move(frame));
    } else if (r.event == platform::SourceEvent::kBadFrame) {
      ++frames_bad;
      SP_WARN_EVERY(logger, bad_frames, "source: skipping " << r.message << " (" << frames_bad.load() << " so far)");
    } else if (r.event == platform::SourceEvent::kEnd) {
      SP_INFO(logger, "source: end of recording" << (r.message.empty() ? "" : " (" + r.message + ")"));
      break;
    } else if (r.event == platform::SourceEvent::kDeviceGone) {
      device_gone = true;
      SP_WARN(logger, "source: camera gone (" << r.message << "); reconnecting");
      source->close();
      if (reopen(nullptr)) {
        stamps.reconnected();
        ++reconnects;
        device_gone = false;
        SP_INFO(logger, "source: reconnected");
      }
    }
  }
  source->close();
  std::lock_guard lock(mutex);
  // A finished recording is drained; a stop request discards what is queued.
  queue->close(/*drain=*/!stop_requested);
  source_ended = true;
  wake.notify_all();
}

void Daemon::Impl::trackingLoop() {
  logWarnings(placeCurrentThread("sp-tracking", config.threads.tracking, available_cores, "threads.tracking"));
  log::RateLimiter limiter(2s);
  while (!queue->closedAndEmpty()) {
    std::optional<platform::CameraFrame> frame = queue->pop(100ms);
    if (!frame) continue;
    auto out = system->track({frame->stamp, frame->gray, frame->depth_m, frame->bgr});
    if (!out) {
      ++frames_bad;
      SP_WARN_EVERY(logger, limiter, "tracking: frame skipped: " << out.error());
      continue;
    }
    track_time.add(out->track_ms);
    ipc::PoseMessage pose;
    pose.sensor_stamp = frame->stamp;
    pose.frame_counter = frame->sequence;
    pose.state = toIpc(out->state);
    pose.tracked_features = static_cast<std::uint32_t>(std::max(0, out->tracked));
    pose.dynamic_rejected_features = static_cast<std::uint32_t>(std::max(0, out->geometry.dynamic_features));
    pose.keyframes = static_cast<std::uint32_t>(out->keyframes);
    pose.map_id = out->map_id;
    pose.health = static_cast<ipc::PoseHealth>(out->quality.health);
    pose.dynamic_share = out->quality.dynamic_share;
    pose.reprojection_rms_px = out->quality.reprojection_rms_px;
    pose.conditioning = out->quality.conditioning;
    pose.health_causes = out->quality.causes;
    pose.mask_age_s = out->quality.mask_age_s;
    const bool has_pose = slam::hasPose(out->state);
    if (!has_pose) {
      // Nothing a consumer could take for a pose.
      pose.position.fill(std::numeric_limits<double>::quiet_NaN());
      pose.orientation.fill(std::numeric_limits<double>::quiet_NaN());
    }
    if (has_pose) {
      const Eigen::Quaterniond q(out->T_w_c.rotation());
      const Eigen::Vector3d t = out->T_w_c.translation();
      pose.position = {t.x(), t.y(), t.z()};
      pose.orientation = {q.x(), q.y(), q.z(), q.w()};
      pose.covariance = upperTriangle<float>(out->quality.covariance);
    }
    publisher->publishPose(pose);
    if (has_pose) publisher->publishObjects(toIpc(out->objects, pose));
    latency.add(std::chrono::duration<double, std::milli>(Clock::now() - frame->arrival).count());
    ++frames_processed;
    if (has_pose) {
      ++frames_tracked;
      const auto level = static_cast<std::size_t>(out->quality.health);
      if (level < frames_by_health.size()) ++frames_by_health[level];
      for (int bit = 0; bit < health_cause::kCount; ++bit)
        if (out->quality.causes & (1u << bit)) ++frames_by_cause[static_cast<std::size_t>(bit)];
    }
    if (out->state == slam::TrackingState::kLost) ++frames_lost;
    keyframes = out->keyframes;
    map_id = out->map_id;
    last_stamp_ns = frame->stamp.nanoseconds();
    last_state = static_cast<int>(out->state);
    last_health = static_cast<std::uint32_t>(out->quality.health) | static_cast<std::uint32_t>(out->quality.causes) << 8;
    last_mask_age_s = out->quality.mask_age_s;
  }
  std::lock_guard lock(mutex);
  tracking_done = true;
  wake.notify_all();
}

std::string Daemon::Impl::statusLine(double fps) const {
  std::string state;
  if (!ready_sent || waiting_for_camera) state = "waiting for camera";
  else if (device_gone) state = "camera gone, reconnecting";
  else if (last_state < 0) state = "starting";
  else state = slam::toString(static_cast<slam::TrackingState>(last_state.load()));
  const slam::MapStats map = system->mapStats();
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "%s, %.1f fps, %" PRIu64 " frames, %" PRIu64 " lost, %" PRIu64 " dropped, map %u of %u, %zu keyframes "
                "%zu points",
                state.c_str(), fps, frames_processed.load(), frames_lost.load(), queue->dropped(), map_id.load(),
                std::max(1u, map.maps), map.keyframes, map.points);
  std::string line = buf;
  if (map.loops_closed > 0) line += ", " + std::to_string(map.loops_closed) + " loops closed";
  if (publisher) {
    const ipc::PublisherStats ps = publisher->stats();
    if (!ps.down.empty()) {
      line += ", ipc down:";
      for (const std::string& name : ps.down) line += " " + name;
    }
  }
  return line;
}

ipc::StatusMessage Daemon::Impl::statusMessage() const {
  ipc::StatusMessage m;
  m.uptime_s = std::chrono::duration<double>(Clock::now() - start_time).count();
  m.frames_received = frames_received;
  m.frames_dropped = queue->dropped();
  m.map_id = map_id;
  if (last_state >= 0) m.tracking_state = toIpc(static_cast<slam::TrackingState>(last_state.load()));
  const std::uint32_t health = last_health.load();
  m.health = static_cast<ipc::PoseHealth>(health & 0xFF);
  m.health_causes = static_cast<std::uint16_t>(health >> 8);
  m.mask_age_s = last_mask_age_s.load();
  ipc::ThreadStats tracking;
  tracking.name = "tracking";
  tracking.loop_rate_hz = tracking_rate_hz;  // frames tracked per second over the last status period
  tracking.latency_ms_median = latency.quantile(0.5);
  tracking.latency_ms_max = latency.max();
  m.threads.push_back(tracking);
  ipc::QueueStats frames;
  frames.name = "frames";
  frames.depth = static_cast<std::uint32_t>(queue->depth());
  frames.capacity = static_cast<std::uint32_t>(queue->capacity());
  frames.dropped = queue->dropped();
  m.queues.push_back(frames);
  // A network transport not up yet shows as a queue "<name> down" with the
  // messages it missed (the schema stays as it is).
  if (publisher) {
    const ipc::PublisherStats ps = publisher->stats();
    for (const std::string& name : ps.down) m.queues.push_back({name + " down", 0, 0, ps.unsent_down});
  }
  return m;
}

Status Daemon::Impl::writeOutputs(const std::string& reason, double shutdown_ms) {
  Status result;
  if (!config.map.save.empty()) {
    if (Status s = system->saveMap(config.map.save); !s) result = s;
    else SP_INFO(logger, "map saved to " << config.map.save);
  }
  if (!config.output.trajectory.empty()) {
    eval::Trajectory trajectory;
    for (const auto& p : system->trajectory()) trajectory.push_back({p.stamp, p.T_w_c, p.map_id});
    if (Status s = eval::writeTumTrajectory(config.output.trajectory, trajectory); !s) result = s;
  }
  if (!config.output.status.empty()) {
    std::FILE* f = std::fopen(config.output.status.c_str(), "w");
    if (!f) return Error{"cannot write " + config.output.status};
    const double wall_s = std::chrono::duration<double>(Clock::now() - start_time).count();
    const ipc::PublisherStats& ps = publisher_stats;
    std::fprintf(f,
                 "exit_reason=%s\nframes_received=%" PRIu64 "\nframes_processed=%" PRIu64 "\nframes_tracked=%" PRIu64
                 "\nframes_lost=%" PRIu64 "\nframes_bad=%" PRIu64 "\nframes_dropped=%" PRIu64
                 "\nframes_discarded_at_stop=%" PRIu64 "\nkeyframes=%" PRIu64 "\nreconnects=%" PRIu64
                 "\nlatency_ms_median=%.3f\nlatency_ms_p99=%.3f\nlatency_ms_max=%.3f\npublisher_sent=%" PRIu64
                 "\npublisher_dropped=%" PRIu64 "\nuptime_s=%.3f\nshutdown_ms=%.1f\ntrack_ms_median=%.3f\ntrack_ms_p99=%.3f\n",
                 reason.c_str(), frames_received.load(), frames_processed.load(), frames_tracked.load(),
                 frames_lost.load(), frames_bad.load(), queue->dropped(), queue->discarded(), keyframes.load(),
                 reconnects.load(), latency.quantile(0.5), latency.quantile(0.99), latency.max(), ps.sent, ps.dropped,
                 wall_s, shutdown_ms, track_time.quantile(0.5), track_time.quantile(0.99));
    // What the process holds (bounded memory over long runs).
    const slam::MapStats map = system->mapStats();
    std::fprintf(f,
                 "map_keyframes=%zu\nmap_points=%zu\nkeyframes_in_memory=%zu\npoints_in_memory=%zu\n"
                 "trajectory_records=%zu\nmap_id=%u\nmaps=%u\nframes_no_depth=%zu\nrelocalisations_refused=%d\n",
                 map.keyframes, map.points, map.keyframes_in_memory, map.points_in_memory, map.trajectory_records,
                 map_id.load(), map.maps, map.no_depth_frames, map.relocalisations_refused);
    // How far the run's poses could be trusted, and why not (docs/pose-health.md).
    std::fprintf(f, "frames_good=%" PRIu64 "\nframes_degraded=%" PRIu64 "\nframes_unreliable=%" PRIu64 "\n",
                 frames_by_health[0].load(), frames_by_health[1].load(), frames_by_health[2].load());
    for (int bit = 0; bit < health_cause::kCount; ++bit)
      std::fprintf(f, "frames_%s=%" PRIu64 "\n", health_cause::name(static_cast<std::uint16_t>(1u << bit)),
                   frames_by_cause[static_cast<std::size_t>(bit)].load());
    if (config.modules.semantic) {
      const slam::MapStats m = system->mapStats();
      std::fprintf(f,
                   "semantic_model=%s\nsemantic_keyframes_segmented=%d\nsemantic_keyframes_dropped=%d\n"
                   "semantic_keyframes_no_colour=%d\nsemantic_failures=%d\nsemantic_instances_applied=%d\n"
                   "semantic_features_removed=%d\nsemantic_points_removed=%d\nsemantic_points_culled=%d\n"
                   "segmentation_ms_median=%.1f\nsegmentation_ms_p95=%.1f\nsemantic_latency_ms_median=%.1f\n"
                   "semantic_latency_ms_p95=%.1f\nsemantic_sighting_cells=%zu\n",
                   m.semantic_model.c_str(), m.semantic_keyframes_segmented, m.semantic_keyframes_dropped,
                   m.semantic_keyframes_no_colour, m.semantic_failures, m.semantic_instances_applied,
                   m.semantic_features_removed, m.semantic_points_removed, m.semantic_points_culled,
                   m.segmentation_ms_median, m.segmentation_ms_p95, m.semantic_latency_ms_median,
                   m.semantic_latency_ms_p95, m.semantic_sighting_cells);
    }
    if (std::fclose(f) != 0) result = Error{"cannot write " + config.output.status};
  }
  return result;
}

int Daemon::run() {
  Impl& d = *impl_;
  if (d.waiting_for_camera && !d.ready_sent.exchange(true)) {
    // Up and waiting for its camera: started, not failed (its status says so).
    d.notifier.ready();
    d.notifier.status("waiting for camera");
  }
  std::jthread source_thread([&d](std::stop_token stop) { d.sourceLoop(stop); });
  std::jthread tracking_thread([&d] { d.trackingLoop(); });

  // Supervision: STATUS= and status messages every status period; WATCHDOG=1
  // at half the watchdog interval, but only when tracking processed a frame
  // since the previous ping.
  const auto status_period = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(d.config.status_period_s));
  const auto watchdog_period = d.notifier.watchdogInterval() / 2;
  auto tick = status_period;
  if (watchdog_period.count() > 0) tick = std::min<Clock::duration>(tick, watchdog_period);
  auto next_status = Clock::now() + status_period;
  const auto map_cloud_period =
      d.config.ipc.ros2.enabled && !d.config.ipc.ros2.map_cloud_topic.empty()
          ? std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(d.config.ipc.ros2.map_cloud_period_s))
          : Clock::duration::zero();
  auto next_map_cloud = Clock::now();
  auto next_watchdog = Clock::now() + watchdog_period;
  std::uint64_t frames_at_ping = 0, frames_at_status = 0;
  auto last_status_time = Clock::now();
  std::string reason = "end of recording";
  {
    std::unique_lock lock(d.mutex);
    while (true) {
      d.wake.wait_for(lock, tick, [&] { return d.stop_requested || d.tracking_done; });
      if (d.stop_requested) {
        reason = "signal";
        break;
      }
      if (d.tracking_done) break;
      lock.unlock();
      const auto now = Clock::now();
      const std::uint64_t processed = d.frames_processed;
      if (watchdog_period.count() > 0 && now >= next_watchdog) {
        // Waiting for a camera that is not there yet is no stall.
        if (processed > frames_at_ping || d.waiting_for_camera) d.notifier.watchdog();
        frames_at_ping = processed;
        next_watchdog = now + watchdog_period;
      }
      if (now >= next_status) {
        const double dt = std::chrono::duration<double>(now - last_status_time).count();
        const double fps = (processed - frames_at_status) / std::max(dt, 1e-3);
        d.tracking_rate_hz = fps;
        const std::string line = d.statusLine(fps);
        d.notifier.status(line);
        SP_DEBUG(logger, "status: " << line);
        d.publisher->publishStatus(d.statusMessage());
        frames_at_status = processed;
        last_status_time = now;
        next_status = now + status_period;
      }
      if (map_cloud_period.count() > 0 && now >= next_map_cloud && d.frames_tracked > 0) {
        // The static map at a low rate: a few thousand points, read under
        // the map's shared lock, off the tracking thread.
        ipc::MapCloudMessage cloud;
        cloud.map_id = d.map_id;
        cloud.sensor_stamp = Timestamp::fromNanoseconds(d.last_stamp_ns);
        for (const Vec3& p : d.system->mapPoints(static_cast<std::uint32_t>(cloud.map_id)))
          cloud.points.push_back({static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())});
        d.publisher->publishMapCloud(std::move(cloud));
        next_map_cloud = now + map_cloud_period;
      }
      lock.lock();
    }
  }
  // Stop in order: source, frame queue (closed by the source thread), tracking,
  // SLAM core (local mapping), publisher.
  d.notifier.stopping();
  d.notifier.status("stopping (" + reason + ")");
  SP_INFO(logger, "stopping: " << reason);
  const auto stop_begin = reason == "signal" ? d.stop_time : Clock::now();
  // Test hook (test/daemon_process_test.cpp): a stop slow enough for a second
  // signal or the shutdown timeout to be observed. Never set in production.
  if (const char* slow = std::getenv("STILLPOINTD_TEST_SLOW_STOP_MS"))
    std::this_thread::sleep_for(std::chrono::milliseconds(std::atol(slow)));
  source_thread.request_stop();
  if (reason == "signal") d.queue->close(/*drain=*/false);  // unblocks the source, ends tracking soon
  source_thread.join();
  tracking_thread.join();
  // On a signal, keyframes waiting for segmentation are dropped: their masks
  // would only edit a map about to be discarded, at up to seconds each.
  // A segmentation under way is waited for: back at the process's nice (where
  // permitted: CAP_SYS_NICE, which the unit grants) it ends sooner on a busy CPU.
  if (const int tid = d.semantic_tid; tid > 0 && reason == "signal")
    setpriority(PRIO_PROCESS, static_cast<id_t>(tid), getpriority(PRIO_PROCESS, 0));
  d.system->finish(/*discard_pending_segmentation=*/reason == "signal");
  d.publisher->publishStatus(d.statusMessage());
  d.publisher->close();
  d.publisher->flush();
  d.publisher_stats = d.publisher->stats();
  d.publisher.reset();  // joins the publisher thread
  const double shutdown_ms = std::chrono::duration<double, std::milli>(Clock::now() - stop_begin).count();
  Status written = d.writeOutputs(reason, shutdown_ms);
  if (!written) {
    SP_ERROR(logger, written.error());
    return 1;
  }
  SP_INFO(logger, "stopped after " << shutdown_ms << " ms; " << d.frames_processed << " frames processed");
  if (d.config.modules.semantic) {
    const slam::MapStats m = d.system->mapStats();
    SP_INFO(logger, "semantic: " << m.semantic_keyframes_segmented << " keyframes segmented, "
                                 << m.semantic_frames_segmented << " frames where no keyframe is made, "
                                 << m.semantic_keyframes_dropped << " dropped (queue full), "
                                 << m.semantic_keyframes_no_colour << " without colour; keyframe -> mask median "
                                 << m.semantic_latency_ms_median << " ms, p95 " << m.semantic_latency_ms_p95 << " ms");
  }
  return d.frames_processed > 0 || reason == "signal" ? 0 : 1;
}

}  // namespace stillpoint::daemon
