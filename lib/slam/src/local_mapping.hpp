#pragma once
// Local mapping: takes new keyframes from tracking, fuses duplicate points
// with neighbours, culls weak points and redundant keyframes, and refines the
// local window with bundle adjustment.
#include <atomic>
#include <condition_variable>
#include <deque>
#include <list>
#include <mutex>
#include <thread>

#include "map.hpp"
#include "stillpoint/slam/options.hpp"

namespace stillpoint::slam {

class LocalMapper {
 public:
  LocalMapper(const SlamOptions& options, double close_depth, Map* map);
  ~LocalMapper();

  // Processes one keyframe completely on the calling thread.
  void process(KeyFrame* kf);

  // Threaded use: a worker takes keyframes from a bounded blocking queue.
  void start();
  void enqueue(KeyFrame* kf);
  bool idle() const { return idle_.load() && pending() == 0; }
  std::size_t pending() const;
  void finish();  // drains the queue, joins the worker

  int baRuns() const { return ba_runs_; }
  double totalMs() const { return total_ms_; }
  int dynamicPointsCulled() const { return dynamic_points_culled_.load(); }

 private:
  void run(std::stop_token stop);
  void cullRecentPoints(KeyFrame* kf);
  void cullDynamicPoints(KeyFrame* kf);
  void fuseWithNeighbours(KeyFrame* kf);
  void cullKeyFrames(KeyFrame* kf);

  SlamOptions options_;
  double close_depth_;
  Map* map_;
  std::list<std::shared_ptr<MapPoint>> recent_points_;

  static constexpr std::size_t kQueueCapacity = 8;
  mutable std::mutex queue_mutex_;
  std::condition_variable_any queue_cv_;
  std::deque<KeyFrame*> queue_;
  bool closed_ = false;
  std::atomic<bool> idle_{true};
  std::atomic<bool> abort_ba_{false};
  std::jthread worker_;
  int ba_runs_ = 0;
  double total_ms_ = 0;
  std::atomic<int> dynamic_points_culled_{0};
};

}  // namespace stillpoint::slam
