#pragma once
// A bounded queue between two threads with an explicit policy: kBlock (replay:
// the producer waits, nothing is lost) or kDropOldest (live camera: the
// producer never waits; the oldest item is discarded and counted). close() is
// the stop signal: pop() returns what is left (drain) or nothing (discard).
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>

namespace stillpoint::daemon {

template <typename T>
class BoundedQueue {
 public:
  enum class Policy { kBlock, kDropOldest };
  BoundedQueue(std::size_t capacity, Policy policy) : capacity_(capacity ? capacity : 1), policy_(policy) {}

  // False when the queue is closed (the item is dropped).
  bool push(T item) {
    std::unique_lock lock(mutex_);
    if (policy_ == Policy::kBlock) not_full_.wait(lock, [&] { return closed_ || items_.size() < capacity_; });
    if (closed_) return false;
    if (items_.size() >= capacity_) {
      items_.pop_front();
      ++dropped_;
    }
    items_.push_back(std::move(item));
    not_empty_.notify_one();
    return true;
  }

  // Waits up to `timeout`; nullopt on timeout or when closed and empty.
  std::optional<T> pop(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    not_empty_.wait_for(lock, timeout, [&] { return closed_ || !items_.empty(); });
    if (items_.empty()) return std::nullopt;
    T item = std::move(items_.front());
    items_.pop_front();
    not_full_.notify_one();
    return item;
  }

  // drain: pop() still returns the queued items; otherwise they are discarded.
  void close(bool drain) {
    std::lock_guard lock(mutex_);
    closed_ = true;
    if (!drain) {
      discarded_ += items_.size();
      items_.clear();
    }
    not_empty_.notify_all();
    not_full_.notify_all();
  }
  bool closedAndEmpty() const {
    std::lock_guard lock(mutex_);
    return closed_ && items_.empty();
  }
  std::uint64_t dropped() const {
    std::lock_guard lock(mutex_);
    return dropped_;
  }
  std::uint64_t discarded() const {
    std::lock_guard lock(mutex_);
    return discarded_;
  }
  std::size_t depth() const {
    std::lock_guard lock(mutex_);
    return items_.size();
  }
  std::size_t capacity() const { return capacity_; }

 private:
  const std::size_t capacity_;
  const Policy policy_;
  mutable std::mutex mutex_;
  std::condition_variable not_empty_, not_full_;
  std::deque<T> items_;
  bool closed_ = false;
  std::uint64_t dropped_ = 0, discarded_ = 0;
};

}  // namespace stillpoint::daemon
