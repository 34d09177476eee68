#pragma once
// Runs depth clustering in its own thread, overlapping it with feature
// extraction and the first tracking stage of the same frame. A one-slot
// mailbox: a new frame replaces a job that has not started (drop-oldest), and
// the tracker waits for a result at most until its deadline.
//
// Each K-Means starts from the centres of the last clustering the tracker
// took (result()), not from the last one the thread ran: the thread also
// clusters frames the tracker does not judge (the first, lost and
// relocalised ones, late ones), and a frame's clusters then depend only on
// the frames tracking judged, in a live run as in a replay without the
// thread.
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <stop_token>
#include <thread>
#include <vector>

#include "stillpoint/core/log.hpp"
#include "stillpoint/geometry/depth_clustering.hpp"

namespace stillpoint::geometry {

class ClusteringWorker {
 public:
  // threaded = false: no thread; result() clusters inline (deterministic replay, tests).
  ClusteringWorker(const CameraModel& camera, ClusteringOptions options, bool threaded);
  ~ClusteringWorker();  // stops and joins the thread
  ClusteringWorker(const ClusteringWorker&) = delete;
  ClusteringWorker& operator=(const ClusteringWorker&) = delete;

  // Hands over the depth image of frame `frame_id` (the worker keeps a reference).
  void submit(std::int64_t frame_id, cv::Mat depth_m);
  // The clusters of `frame_id`, waiting at most `deadline`; null when they are
  // not ready in time, or clustering failed. Counts misses. The next
  // clustering starts from the centres of the clusters returned.
  std::shared_ptr<const DepthClusters> result(std::int64_t frame_id, std::chrono::microseconds deadline);

  // Clusters one image in the caller's thread (what the thread runs), from
  // the centres of the last clusters result() returned.
  std::shared_ptr<const DepthClusters> process(const cv::Mat& depth_m);
  // The next clustering starts from fresh centres, not from the last
  // frame's: the view before (a loss, another map) says nothing of it.
  void restart();

  // The last frame clustered, taken by result() or not (-1: none yet).
  std::int64_t lastClusteredFrame() const;
  std::int64_t deadlineMisses() const;
  double lastClusteringMs() const;

 private:
  void run(std::stop_token stop);

  CameraModel camera_;
  DepthClusterer clusterer_;
  bool threaded_;

  mutable std::mutex mutex_;
  std::condition_variable_any wake_;
  std::condition_variable done_;
  std::int64_t pending_id_ = -1;  // submitted, not started
  cv::Mat pending_depth_;
  std::int64_t result_id_ = -1;   // finished (threaded)
  std::int64_t clustered_id_ = -1;  // lastClusteredFrame()
  std::shared_ptr<const DepthClusters> result_;
  std::int64_t misses_ = 0;
  std::vector<Vec3> taken_centres_;  // of the last clusters result() returned
  double last_ms_ = 0;
  log::RateLimiter fail_log_{std::chrono::seconds(5)};
  std::jthread thread_;  // last: starts after the members it uses
};

}  // namespace stillpoint::geometry
