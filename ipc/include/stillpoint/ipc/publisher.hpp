#pragma once
// The tracking thread's side of pose output. publishPose() copies the message into a
// bounded drop-oldest queue and returns; a publisher thread stamps publish_stamp and
// sends it on every transport. A slow transport therefore never stalls tracking: it
// loses the oldest queued messages instead (counted in stats()).
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "stillpoint/ipc/messages.hpp"
#include "stillpoint/ipc/transport.hpp"

namespace stillpoint::ipc {

struct PublisherStats {
  std::uint64_t enqueued = 0;
  std::uint64_t dropped = 0;       // oldest messages discarded because the queue was full
  std::uint64_t sent = 0;          // messages handed to all transports
  std::uint64_t send_errors = 0;   // transport calls that returned an error
  // Network transports that could not come up yet (retried every 5 s), and
  // the messages they missed meanwhile.
  std::vector<std::string> down;
  std::uint64_t unsent_down = 0;
  std::uint32_t queue_depth = 0;
  std::uint32_t queue_capacity = 0;
};

class Publisher {
 public:
  enum class Mode { kThreaded, kInline };  // kInline: send on the caller's thread (tests, replay)

  Publisher(std::vector<std::unique_ptr<Transport>> transports, std::uint32_t queue_capacity,
            Mode mode = Mode::kThreaded);
  // Builds the transports `options` enables. Fails with the transport's error.
  static Result<std::unique_ptr<Publisher>> create(const IpcOptions& options,
                                                   Mode mode = Mode::kThreaded);
  // Sends what is still queued, then joins the thread.
  ~Publisher();
  Publisher(const Publisher&) = delete;
  Publisher& operator=(const Publisher&) = delete;

  // Never blocks on a transport. Thread-safe.
  void publishPose(const PoseMessage& pose);
  void publishStatus(StatusMessage status);
  void publishObjects(ObjectsMessage objects);
  void publishMapCloud(MapCloudMessage cloud);

  // Sends everything queued now, on the calling thread (kInline, or tests).
  void flush();
  // Closes the queue: later publish calls are ignored; the thread drains and stops.
  void close();

  PublisherStats stats() const;

 private:
  using Item = std::variant<PoseMessage, StatusMessage, ObjectsMessage, MapCloudMessage>;
  void push(Item item);
  void send(Item& item);
  void run(std::stop_token stop);

  std::vector<std::unique_ptr<Transport>> transports_;
  const std::uint32_t capacity_;
  const Mode mode_;
  mutable std::mutex mutex_;
  std::condition_variable_any ready_;
  std::deque<Item> queue_;
  bool closed_ = false;
  PublisherStats stats_;
  std::mutex send_mutex_;  // one sender at a time (thread, flush())
  std::jthread thread_;    // last member: joins before the rest is destroyed
};

}  // namespace stillpoint::ipc
