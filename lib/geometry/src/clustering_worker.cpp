#include "stillpoint/geometry/clustering_worker.hpp"

#include "stillpoint/core/log.hpp"

namespace stillpoint::geometry {
namespace {
log::Logger logger("geometry");
}

ClusteringWorker::ClusteringWorker(const CameraModel& camera, ClusteringOptions options, bool threaded)
    : camera_(camera), clusterer_(options), threaded_(threaded) {
  if (threaded_) thread_ = std::jthread([this](std::stop_token stop) { run(stop); });
}

ClusteringWorker::~ClusteringWorker() {
  if (thread_.joinable()) {
    thread_.request_stop();
    wake_.notify_all();
    thread_.join();
  }
}

void ClusteringWorker::submit(std::int64_t frame_id, cv::Mat depth_m) {
  {
    std::lock_guard lock(mutex_);
    pending_id_ = frame_id;
    pending_depth_ = std::move(depth_m);
  }
  wake_.notify_one();
}

void ClusteringWorker::restart() {
  std::lock_guard lock(mutex_);
  taken_centres_.clear();
}

std::shared_ptr<const DepthClusters> ClusteringWorker::process(const cv::Mat& depth_m) {
  {
    std::lock_guard lock(mutex_);
    clusterer_.warmStartFrom(taken_centres_);
  }
  const auto t0 = std::chrono::steady_clock::now();
  auto clusters = clusterer_.cluster(depth_m, camera_);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  {
    std::lock_guard lock(mutex_);
    last_ms_ = ms;
  }
  if (!clusters) {
    if (fail_log_.allow()) SP_WARN(logger, "depth clustering failed: " << clusters.error());
    return nullptr;
  }
  return std::make_shared<const DepthClusters>(std::move(*clusters));
}

void ClusteringWorker::run(std::stop_token stop) {
  while (true) {
    std::int64_t id;
    cv::Mat depth;
    {
      std::unique_lock lock(mutex_);
      if (!wake_.wait(lock, stop, [&] { return pending_id_ >= 0; })) return;
      id = pending_id_;
      depth = std::move(pending_depth_);
      pending_id_ = -1;
    }
    auto clusters = process(depth);
    {
      std::lock_guard lock(mutex_);
      result_id_ = clustered_id_ = id;
      result_ = std::move(clusters);
    }
    done_.notify_all();
  }
}

std::shared_ptr<const DepthClusters> ClusteringWorker::result(std::int64_t frame_id,
                                                              std::chrono::microseconds deadline) {
  if (!threaded_) {
    cv::Mat depth;
    {
      std::lock_guard lock(mutex_);
      if (pending_id_ != frame_id) return nullptr;
      depth = std::move(pending_depth_);
      pending_id_ = -1;
    }
    auto clusters = process(depth);
    std::lock_guard lock(mutex_);
    clustered_id_ = frame_id;
    if (clusters) taken_centres_ = clusters->centres;
    return clusters;
  }
  std::unique_lock lock(mutex_);
  const bool ready = done_.wait_for(lock, deadline, [&] { return result_id_ >= frame_id; });
  if (ready && result_id_ == frame_id) {
    if (result_) taken_centres_ = result_->centres;
    return result_;
  }
  ++misses_;
  return nullptr;
}

std::int64_t ClusteringWorker::lastClusteredFrame() const {
  std::lock_guard lock(mutex_);
  return clustered_id_;
}

std::int64_t ClusteringWorker::deadlineMisses() const {
  std::lock_guard lock(mutex_);
  return misses_;
}

double ClusteringWorker::lastClusteringMs() const {
  std::lock_guard lock(mutex_);
  return last_ms_;
}

}  // namespace stillpoint::geometry
