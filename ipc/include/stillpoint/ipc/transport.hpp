#pragma once
// One publishing interface, three transports (shared memory, LCM, Cyclone DDS), and
// the matching subscribers used by stillpoint-echo, the tests and the benchmarks.
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "stillpoint/core/result.hpp"
#include "stillpoint/ipc/messages.hpp"
#include "stillpoint/ipc/options.hpp"

namespace stillpoint::ipc {

// Sends messages. Called from one thread (the Publisher's); implementations need not
// be thread-safe. Errors are returned, never thrown.
class Transport {
 public:
  virtual ~Transport() = default;
  virtual std::string_view name() const = 0;
  virtual Status publishPose(const PoseMessage& pose) = 0;
  virtual Status publishStatus(const StatusMessage& status) = 0;
  // Transports that do not carry these ignore them.
  virtual Status publishObjects(const ObjectsMessage&) { return Status::success(); }
  virtual Status publishMapCloud(const MapCloudMessage&) { return Status::success(); }
  // Readers currently matched (DDS); -1 when the transport cannot know (shm, LCM).
  virtual int matchedReaders() const { return -1; }
  // A network transport that could not come up (no route, no interface yet)
  // is down: the publisher skips it and calls retry() now and then.
  virtual bool up() const { return true; }
  virtual void retry() {}
};

// A transport made by `make`, retried every `period` while it cannot be made
// (a robot that boots before its network): never fatal, down until then.
std::unique_ptr<Transport> makeRetryingTransport(std::string name,
                                                 std::function<Result<std::unique_ptr<Transport>>()> make,
                                                 std::chrono::steady_clock::duration period);

Result<std::unique_ptr<Transport>> makeShmTransport(const ShmOptions& options);
Result<std::unique_ptr<Transport>> makeLcmTransport(const LcmOptions& options);
Result<std::unique_ptr<Transport>> makeDdsTransport(const DdsOptions& options);
// ROS 2 geometry_msgs/msg/PoseStamped over Cyclone DDS (Ros2Options).
Result<std::unique_ptr<Transport>> makeRos2Transport(const Ros2Options& options);
// Every transport enabled in `options`, in the order shm, lcm, dds.
Result<std::vector<std::unique_ptr<Transport>>> makeTransports(const IpcOptions& options);

// Receives messages. poll() waits up to `timeout` and calls the handlers for what
// arrived; it returns how many messages it handled.
class Subscriber {
 public:
  using PoseHandler = std::function<void(const PoseMessage&)>;
  using StatusHandler = std::function<void(const StatusMessage&)>;
  using ObjectsHandler = std::function<void(const ObjectsMessage&)>;
  // Called once per detected writer restart (shared memory only).
  using RestartHandler = std::function<void()>;

  virtual ~Subscriber() = default;
  virtual Result<int> poll(std::chrono::milliseconds timeout) = 0;
  // Messages the transport told us we missed (shm: overwritten before read).
  virtual std::uint64_t lost() const { return 0; }
  // Writers matched on every topic (DDS); -1 when the transport cannot know.
  virtual int matchedWriters() const { return -1; }

  void onPose(PoseHandler handler) { pose_handler_ = std::move(handler); }
  void onStatus(StatusHandler handler) { status_handler_ = std::move(handler); }
  // A frame's objects (transports that carry them; shm: with
  // ShmSubscriberOptions::objects).
  void onObjects(ObjectsHandler handler) { objects_handler_ = std::move(handler); }
  void onRestart(RestartHandler handler) { restart_handler_ = std::move(handler); }

 protected:
  PoseHandler pose_handler_;
  StatusHandler status_handler_;
  ObjectsHandler objects_handler_;
  RestartHandler restart_handler_;
};

struct ShmSubscriberOptions {
  bool from_oldest = false;  // start with the oldest record still in the ring
  bool busy_poll = false;    // spin instead of sleeping 50 us between empty polls
  // A missing ring, or one whose writer died, is not an error: keep trying until a
  // writer (re)creates it. Otherwise poll() fails with "writer gone" on a dead ring.
  bool wait_for_ring = false;
  std::int64_t owner_uid = -1;  // user that must own the ring; -1: this process's effective uid
  // Also read the dynamic-objects ring (ShmOptions::objects_name), for onObjects().
  bool objects = false;
};
Result<std::unique_ptr<Subscriber>> makeShmSubscriber(const ShmOptions& options,
                                                      const ShmSubscriberOptions& sub = {});
Result<std::unique_ptr<Subscriber>> makeLcmSubscriber(const LcmOptions& options);
// pose_history: keep-last depth of the pose reader (the writer keeps only the last).
Result<std::unique_ptr<Subscriber>> makeDdsSubscriber(const DdsOptions& options,
                                                      int pose_history = 64);

}  // namespace stillpoint::ipc
