#pragma once
// Keeps a camera's frame stamps increasing, as tracking needs them
// (SlamSystem::track refuses a stamp that is not after the last one's).
//
// A camera plugged back in may start its clock again (OpenNI2 devices stamp
// frames from their own clock, which a power cycle resets): the first frame
// after a reconnect whose stamp lies at or before the last one goes on from
// the last stamp by the time that passed between their arrivals, and the
// frames after it keep that offset. Without a reconnect, a stamp at or before
// the last one is a bad frame (a driver that repeats a frame).
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <optional>

#include "stillpoint/core/time.hpp"

namespace stillpoint::daemon {

class SourceStamps {
 public:
  using Clock = std::chrono::steady_clock;

  // The camera was opened again: its clock may have started again.
  void reconnected() { reconnected_ = true; }

  // The stamp to track the frame with, or nullopt for a frame to skip.
  // `rebased` (optional) says whether this frame started a new offset.
  std::optional<Timestamp> next(Timestamp camera, Clock::time_point arrival, bool* rebased = nullptr) {
    if (rebased) *rebased = false;
    std::int64_t t = camera.nanoseconds() + offset_ns_;
    if (last_ns_ && t <= *last_ns_) {
      if (!reconnected_) return std::nullopt;
      const std::int64_t passed = std::chrono::duration_cast<std::chrono::nanoseconds>(arrival - last_arrival_).count();
      const std::int64_t resumed = *last_ns_ + std::max<std::int64_t>(passed, 1'000'000);  // at least 1 ms on
      offset_ns_ += resumed - t;
      t = resumed;
      if (rebased) *rebased = true;
    }
    reconnected_ = false;
    last_ns_ = t;
    last_arrival_ = arrival;
    return Timestamp::fromNanoseconds(t);
  }

 private:
  std::optional<std::int64_t> last_ns_;
  Clock::time_point last_arrival_;
  std::int64_t offset_ns_ = 0;
  bool reconnected_ = false;
};

}  // namespace stillpoint::daemon
