#include "stillpoint/ipc/publisher.hpp"

#include <chrono>
#include <type_traits>
#include <variant>

#include "stillpoint/core/log.hpp"

namespace stillpoint::ipc {
namespace {
const log::Logger kLog("ipc");

Timestamp wallClockNow() {
  return Timestamp::fromNanoseconds(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}
}  // namespace

Publisher::Publisher(std::vector<std::unique_ptr<Transport>> transports, std::uint32_t queue_capacity,
                     Mode mode)
    : transports_(std::move(transports)), capacity_(queue_capacity == 0 ? 1 : queue_capacity), mode_(mode) {
  stats_.queue_capacity = capacity_;
  if (mode_ == Mode::kThreaded) thread_ = std::jthread([this](std::stop_token stop) { run(stop); });
}

Result<std::unique_ptr<Publisher>> Publisher::create(const IpcOptions& options, Mode mode) {
  if (Status s = options.validate(); !s) return Error{s.error()};
  // The ring is local and its errors are the configuration's (a path taken,
  // another writer): fatal. The network transports are retried until they
  // come up.
  std::vector<std::unique_ptr<Transport>> transports;
  if (options.shm.enabled) {
    auto t = makeShmTransport(options.shm);
    if (!t) return Error{t.error()};
    transports.push_back(std::move(t.value()));
  }
  constexpr auto kRetry = std::chrono::seconds(5);
  if (options.lcm.enabled)
    transports.push_back(makeRetryingTransport("lcm", [o = options.lcm] { return makeLcmTransport(o); }, kRetry));
  if (options.dds.enabled)
    transports.push_back(makeRetryingTransport("dds", [o = options.dds] { return makeDdsTransport(o); }, kRetry));
  if (options.ros2.enabled)
    transports.push_back(makeRetryingTransport("ros2", [o = options.ros2] { return makeRos2Transport(o); }, kRetry));
  return std::make_unique<Publisher>(std::move(transports), options.queue_capacity, mode);
}

Publisher::~Publisher() {
  close();
  if (thread_.joinable()) thread_.join();
  flush();  // kInline leftovers, or anything a racing publish slipped in
}

void Publisher::close() {
  {
    std::lock_guard lock(mutex_);
    closed_ = true;
  }
  ready_.notify_all();
}

void Publisher::push(Item item) {
  {
    std::lock_guard lock(mutex_);
    if (closed_) return;
    if (queue_.size() >= capacity_) {
      queue_.pop_front();
      ++stats_.dropped;
    }
    queue_.push_back(std::move(item));
    ++stats_.enqueued;
  }
  if (mode_ == Mode::kThreaded)
    ready_.notify_one();
  else
    flush();
}

void Publisher::publishPose(const PoseMessage& pose) { push(Item(pose)); }
void Publisher::publishStatus(StatusMessage status) { push(Item(std::move(status))); }
void Publisher::publishObjects(ObjectsMessage objects) { push(Item(std::move(objects))); }
void Publisher::publishMapCloud(MapCloudMessage cloud) { push(Item(std::move(cloud))); }

void Publisher::send(Item& item) {
  std::uint64_t errors = 0, unsent_down = 0;
  bool any_down = false;
  for (auto& t : transports_) {
    t->retry();
    any_down |= !t->up();
  }
  const Timestamp now = wallClockNow();
  const auto send_all = [&](const char* what, auto&& publish) {
    for (auto& t : transports_) {
      if (!t->up()) {
        ++unsent_down;
        continue;
      }
      if (Status s = publish(*t); !s) {
        ++errors;
        static log::RateLimiter limiter(std::chrono::seconds(5));
        SP_WARN_EVERY(kLog, limiter, t->name() << ": " << what << " not sent: " << s.error());
      }
    }
  };
  std::visit(
      [&](auto& message) {
        message.publish_stamp = now;
        using M = std::decay_t<decltype(message)>;
        if constexpr (std::is_same_v<M, PoseMessage>)
          send_all("pose", [&](Transport& t) { return t.publishPose(message); });
        else if constexpr (std::is_same_v<M, StatusMessage>)
          send_all("status", [&](Transport& t) { return t.publishStatus(message); });
        else if constexpr (std::is_same_v<M, ObjectsMessage>)
          send_all("objects", [&](Transport& t) { return t.publishObjects(message); });
        else
          send_all("map cloud", [&](Transport& t) { return t.publishMapCloud(message); });
      },
      item);
  std::lock_guard lock(mutex_);
  ++stats_.sent;
  stats_.send_errors += errors;
  stats_.unsent_down += unsent_down;
  // Names only when the set is not empty, or has just become so (no
  // allocation per message while everything is up).
  if (any_down || !stats_.down.empty()) {
    stats_.down.clear();
    for (auto& t : transports_)
      if (!t->up()) stats_.down.emplace_back(t->name());
  }
}

void Publisher::flush() {
  std::lock_guard send_lock(send_mutex_);
  for (;;) {
    Item item;
    {
      std::lock_guard lock(mutex_);
      if (queue_.empty()) return;
      item = std::move(queue_.front());
      queue_.pop_front();
    }
    send(item);
  }
}

void Publisher::run(std::stop_token stop) {
  for (;;) {
    Item item;
    {
      std::unique_lock lock(mutex_);
      ready_.wait(lock, stop, [this] { return closed_ || !queue_.empty(); });
      if (queue_.empty()) return;  // closed (or stop requested) and drained
      item = std::move(queue_.front());
      queue_.pop_front();
    }
    std::lock_guard send_lock(send_mutex_);
    send(item);
  }
}

PublisherStats Publisher::stats() const {
  std::lock_guard lock(mutex_);
  PublisherStats s = stats_;
  s.queue_depth = static_cast<std::uint32_t>(queue_.size());
  return s;
}

}  // namespace stillpoint::ipc
