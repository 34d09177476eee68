#pragma once
// Local mapping: takes new keyframes from tracking, culls weak and dynamic
// points and redundant keyframes, applies semantic masks, and refines the
// local window with bundle adjustment.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <list>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <utility>

#include "map.hpp"
#include "semantic_worker.hpp"
#include "stillpoint/slam/options.hpp"

namespace stillpoint::slam {

// The most recent kCapacity samples of a timing (a ring): its statistics
// cover a bounded window however long the process runs.
class RecentSamples {
 public:
  static constexpr std::size_t kCapacity = 1024;
  void add(double value) {
    if (values_.size() < kCapacity) values_.push_back(value);
    else values_[next_] = value;
    next_ = (next_ + 1) % kCapacity;
  }
  const std::vector<double>& values() const { return values_; }  // unordered

 private:
  std::vector<double> values_;
  std::size_t next_ = 0;
};

// What the semantic results did to the map (written under the map's
// exclusive lock, read under a shared one).
struct SemanticStats {
  int segmented = 0, failures = 0;
  int features_removed = 0, points_removed = 0, points_culled = 0;
  int instances_applied = 0, instances_unconfirmed = 0, instances_capped = 0, instances_continued = 0;
  int instances_followed = 0;  // applied over the cap: the pose had followed them
  int instances_known_static = 0;  // left alone: the map had seen their place standing (StaticSightings)
  int features_on_standing = 0;    // in applied regions, kept: on places seen standing, not seen moving
  RecentSamples latency_ms;  // keyframe creation -> result applied
  RecentSamples segment_ms;
};

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
  // Waits until every queued keyframe is processed, at most `timeout`;
  // false on a timeout.
  bool waitIdle(std::chrono::duration<double, std::milli> timeout);
  std::size_t pending() const;
  void finish();  // drains the queue, joins the worker

  // Called with each keyframe's id once it is processed (on the mapping
  // thread): loop closing takes it from there. Set before start().
  void setKeyFrameDone(std::function<void(std::int64_t)> done) { keyframe_done_ = std::move(done); }

  // Readable from any thread (stillpointd's status line).
  int baRuns() const { return ba_runs_.load(); }
  double totalMs() const { return total_ms_.load(); }
  int dynamicPointsCulled() const { return dynamic_points_culled_.load(); }

  // Semantic results arrive from any thread into a mailbox; local mapping (the
  // map's single writer) applies them under the map's exclusive lock at the
  // start of process(), or as soon as it is idle, and in finish().
  void postSemantic(SemanticResult result);
  // Applies every waiting result now (sequential mode, tests). Caller must
  // not hold the map lock.
  void applySemanticResults();
  // Masks need the geometry module's agreement (confirm_with_geometry).
  void setSemanticConfirmation(bool required) { semantic_confirm_ = required; }
  bool semanticConfirmation() const { return semantic_confirm_; }
  const SemanticStats& semanticStats() const { return semantic_stats_; }
  // The labels of the newest segmentation applied, with its keyframe's stamp
  // (null until one is); kept only under SlamOptions::report_fates.
  std::pair<std::shared_ptr<const cv::Mat>, Timestamp> latestSemanticLabels() const;

 private:
  void run(std::stop_token stop);
  void cullRecentPoints(KeyFrame* kf);
  void cullDynamicPoints(KeyFrame* kf);
  void cullKeyFrames(KeyFrame* kf);
  void applySemantic(const SemanticResult& result);  // map lock held exclusively

  SlamOptions options_;
  std::function<void(std::int64_t)> keyframe_done_;
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
  std::atomic<int> ba_runs_{0};
  std::atomic<double> total_ms_{0};
  std::atomic<int> dynamic_points_culled_{0};
  std::deque<SemanticResult> mailbox_;  // guarded by queue_mutex_
  bool semantic_confirm_ = false;
  SemanticStats semantic_stats_;
  mutable std::mutex labels_mutex_;
  std::shared_ptr<const cv::Mat> latest_labels_;  // guarded by labels_mutex_
  Timestamp latest_labels_stamp_;                 // guarded by labels_mutex_
};

}  // namespace stillpoint::slam
