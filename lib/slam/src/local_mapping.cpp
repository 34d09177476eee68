#include "local_mapping.hpp"

#include <algorithm>
#include <chrono>

#include "matcher.hpp"
#include "optimizer.hpp"
#include "stillpoint/core/log.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("mapping");
}

LocalMapper::LocalMapper(const SlamOptions& options, double close_depth, Map* map)
    : options_(options), close_depth_(close_depth), map_(map) {}

LocalMapper::~LocalMapper() { finish(); }

void LocalMapper::process(KeyFrame* kf) {
  const auto t0 = std::chrono::steady_clock::now();
  applySemanticResults();
  {
    std::unique_lock lock(map_->mutex());
    for (const auto& p : kf->frame.points)
      if (p && !p->bad && p->first_keyframe_id == kf->id) recent_points_.push_back(p);
    cullRecentPoints(kf);
    cullDynamicPoints(kf);
    kf->updateConnections();
  }
  abort_ba_ = false;
  if (options_.mapping.local_ba && map_->nextKeyFrameId() > 2) {
    const LocalBaStats s = localBundleAdjustment(map_, kf, options_.mapping.ba_max_keyframes,
                                                 options_.mapping.ba_iterations, &abort_ba_);
    ++ba_runs_;
    SP_DEBUG(logger, "keyframe " << kf->id << ": local BA over " << s.keyframes << "+" << s.fixed_keyframes
                                 << " keyframes, " << s.points << " points, cost " << s.initial_cost << " -> "
                                 << s.final_cost << ", " << s.outliers_removed << " outliers, "
                                 << s.out_of_range_removed << " points out of range");
  }
  const std::int64_t id = kf->id;  // kf may be culled now
  {
    std::unique_lock lock(map_->mutex());
    cullKeyFrames(kf);
  }
  if (keyframe_done_) keyframe_done_(id);
  total_ms_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

void LocalMapper::cullRecentPoints(KeyFrame* kf) {
  const int min_observers = 3;
  for (auto it = recent_points_.begin(); it != recent_points_.end();) {
    const auto& p = *it;
    const std::int64_t age = kf->id - p->first_keyframe_id;
    if (p->bad) {
      it = recent_points_.erase(it);
    } else if (p->foundRatio() < options_.mapping.point_found_ratio ||
               (age >= 2 && static_cast<int>(p->observations.size()) < min_observers)) {
      map_->erasePoint(p);
      it = recent_points_.erase(it);
    } else if (age >= 3) {
      it = recent_points_.erase(it);  // survived its probation
    } else {
      ++it;
    }
  }
}

void LocalMapper::cullDynamicPoints(KeyFrame* kf) {
  // Points tracking kept finding on moving surfaces leave the map: a mover
  // that was static when mapped must not anchor the pose once it moves.
  int culled = 0;
  for (const auto& p : kf->dynamic_suspects) {
    if (p->bad || p->geometry.dynamic_score.load(std::memory_order_relaxed) <= 0.5f) continue;
    map_->erasePoint(p);
    ++culled;
  }
  kf->dynamic_suspects.clear();
  dynamic_points_culled_ += culled;
  if (culled > 0) SP_DEBUG(logger, "keyframe " << kf->id << ": culled " << culled << " dynamic points");
}

void LocalMapper::cullKeyFrames(KeyFrame* kf) {
  // A keyframe is redundant when most of its close points are seen by enough
  // other keyframes at the same or a finer scale.
  for (KeyFrame* n : kf->bestNeighbours(1000)) {
    // Keyframes newer than kf wait in our queue: not processed, never culled
    // (tracking frees culled keyframes, and the queue still holds them).
    if (n->origin || n->bad || n == kf || n->id > kf->id) continue;
    int total = 0, redundant = 0;
    for (int i = 0; i < n->frame.size(); ++i) {
      const auto& p = n->frame.points[i];
      if (!p || p->bad) continue;
      if (n->frame.depth[i] > close_depth_ || n->frame.depth[i] < 0) continue;
      ++total;
      if (static_cast<int>(p->observations.size()) <= options_.mapping.redundant_min_observers) continue;
      const int level = n->frame.keys[i].octave;
      int observers = 0;
      for (const auto& [other, idx] : p->observations) {
        if (other == n || other->bad) continue;
        if (other->frame.keys[idx].octave <= level + 1) ++observers;
        if (observers >= options_.mapping.redundant_min_observers) break;
      }
      if (observers >= options_.mapping.redundant_min_observers) ++redundant;
    }
    if (total > 0 && redundant > options_.mapping.redundant_ratio * total) {
      SP_DEBUG(logger, "keyframe " << n->id << " is redundant (" << redundant << "/" << total << ")");
      map_->setKeyFrameBad(n);
    }
  }
}

void LocalMapper::start() {
  worker_ = std::jthread([this](std::stop_token stop) { run(stop); });
}

void LocalMapper::enqueue(KeyFrame* kf) {
  std::unique_lock lock(queue_mutex_);
  // Blocking when full: keyframes are never dropped (tracking slows instead).
  queue_cv_.wait(lock, [&] { return queue_.size() < kQueueCapacity || closed_; });
  if (closed_) return;
  queue_.push_back(kf);
  idle_ = false;
  abort_ba_ = true;  // a newer keyframe makes the running BA less useful
  queue_cv_.notify_all();
}

void LocalMapper::postSemantic(SemanticResult result) {
  {
    std::lock_guard lock(queue_mutex_);
    mailbox_.push_back(std::move(result));
  }
  queue_cv_.notify_all();
}

void LocalMapper::applySemanticResults() {
  std::deque<SemanticResult> results;
  {
    std::lock_guard lock(queue_mutex_);
    results.swap(mailbox_);
  }
  if (results.empty()) return;
  std::unique_lock lock(map_->mutex());
  for (const SemanticResult& r : results) applySemantic(r);
}

std::size_t LocalMapper::pending() const {
  std::lock_guard lock(queue_mutex_);
  return queue_.size();
}

void LocalMapper::run(std::stop_token stop) {
  while (true) {
    KeyFrame* kf = nullptr;
    {
      std::unique_lock lock(queue_mutex_);
      queue_cv_.wait(lock, [&] {
        return !queue_.empty() || !mailbox_.empty() || closed_ || stop.stop_requested();
      });
      if (queue_.empty() && !mailbox_.empty()) {
        // No keyframe waiting: apply semantic results now.
        lock.unlock();
        applySemanticResults();
        continue;
      }
      if (queue_.empty()) return;  // closed and drained
      kf = queue_.front();
      queue_.pop_front();
      queue_cv_.notify_all();
    }
    process(kf);
    std::lock_guard lock(queue_mutex_);
    if (queue_.empty()) {
      idle_ = true;
      queue_cv_.notify_all();
    }
  }
}

bool LocalMapper::waitIdle(std::chrono::duration<double, std::milli> timeout) {
  std::unique_lock lock(queue_mutex_);
  return queue_cv_.wait_for(lock, timeout, [&] { return (queue_.empty() && idle_.load()) || closed_; });
}

void LocalMapper::finish() {
  {
    std::lock_guard lock(queue_mutex_);
    closed_ = true;
  }
  queue_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
  applySemanticResults();  // results that arrived after the last keyframe
}

}  // namespace stillpoint::slam
