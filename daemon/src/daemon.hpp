#pragma once
// The running daemon: source thread -> bounded frame queue -> tracking thread
// -> ipc::Publisher. The main thread supervises (systemd notifications, status)
// and performs the stop in a fixed order: source first, then the frame queue
// is closed, the tracking thread joined, the SLAM core finished (local mapping
// joined), the publisher drained and joined; then the trajectory and status
// files are written.
#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>

#include "config.hpp"
#include "notify.hpp"

namespace stillpoint::daemon {

class Daemon {
 public:
  explicit Daemon(DaemonConfig config);
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  // Places threads, opens the source, creates the SLAM core and the publisher.
  // An error here is a start-up failure (exit status 1).
  Status start();
  // Runs until the recording ends or requestStop(); then stops in order and
  // writes the outputs. Returns the exit status.
  int run();
  // Thread-safe, idempotent (the signal thread calls it).
  void requestStop();
  // Writes the map to map.save now (SIGUSR1); logs the outcome. Thread-safe
  // after start(); nothing when map.save is not set.
  void saveMap();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stillpoint::daemon
