#pragma once
// One long-lived thread that runs short jobs the tracking thread overlaps with
// its own work. std::async would start a thread per job, and on a loaded
// 2-core host a new thread waits about 0.65 ms for a core (the scheduler
// places a new thread behind the running ones), most of the ~0.8 ms it was
// meant to overlap; a sleeping thread woken for the job got one after 0.3 ms
// on average there (docs/decisions.md). The thread is started by the
// constructor and inherits the constructing thread's placement (cores,
// priority): SlamSystem builds its tracker on the thread that stillpointd
// places as "mapping".
#include <condition_variable>
#include <deque>
#include <future>
#include <mutex>
#include <stop_token>
#include <thread>
#include <type_traits>
#include <utility>

namespace stillpoint::slam {

class TaskThread {
 public:
  TaskThread() : thread_([this](std::stop_token stop) { loop(stop); }) {}
  // Finishes the jobs already queued, then joins.
  ~TaskThread() {
    thread_.request_stop();
    thread_.join();
  }
  TaskThread(const TaskThread&) = delete;
  TaskThread& operator=(const TaskThread&) = delete;

  // Queues `job` and returns its result's future; jobs run in the order queued.
  // An exception the job throws is rethrown by the future's get().
  template <class F>
  std::future<std::invoke_result_t<F>> run(F job) {
    std::packaged_task<std::invoke_result_t<F>()> task(std::move(job));
    auto result = task.get_future();
    {
      std::lock_guard lock(mutex_);
      jobs_.emplace_back(std::move(task));
    }
    wake_.notify_one();
    return result;
  }

 private:
  void loop(std::stop_token stop) {
    std::unique_lock lock(mutex_);
    for (;;) {
      wake_.wait(lock, stop, [this] { return !jobs_.empty(); });
      if (jobs_.empty()) return;  // stop requested, nothing left
      std::packaged_task<void()> job = std::move(jobs_.front());
      jobs_.pop_front();
      lock.unlock();
      job();
      lock.lock();
    }
  }

  std::mutex mutex_;
  std::condition_variable_any wake_;
  std::deque<std::packaged_task<void()>> jobs_;
  std::jthread thread_;  // last: starts after the members it uses
};

}  // namespace stillpoint::slam
