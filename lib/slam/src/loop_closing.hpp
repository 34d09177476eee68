#pragma once
// Loop closing: after local mapping has processed a keyframe, look for an
// older place of the same map that it sees again, and close the loop.
//   1. Candidates: keyframes of the map, not covisible with it, whose views
//      score (place recognition) at least as high as its least similar
//      covisible neighbour's.
//   2. Covisibility consistency: a candidate counts only when
//      place.loop_consistency consecutive keyframes found candidates that
//      are covisible with one another.
//   3. Geometry: descriptor matches with depth on both sides give 3D-3D
//      pairs; RANSAC finds the rigid motion (RGB-D has no scale drift) that
//      at least place.loop_min_inliers reproject under the chi-square gate in
//      both views, and as many of the older place's map points projected
//      into the keyframe must be found there.
//   4. Correction (map lock held exclusively): the keyframe and its
//      neighbours move to where the loop puts them with their points, the
//      two sides' duplicate points are fused, and the essential graph
//      (spanning tree, strong covisibility, loop links) spreads the
//      correction over the map (optimizePoseGraph). Every point follows its
//      reference keyframe. The map's epoch changes: tracking re-expresses its
//      last pose, bundle adjustments in flight drop their results.
//   5. A global bundle adjustment of the map (place.global_ba), without the
//      lock, written back unless the world moved meanwhile.
// Features flagged dynamic take no part (nor do their words).
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include "map.hpp"
#include "stillpoint/slam/options.hpp"

namespace stillpoint::slam {

struct LoopStats {
  int detected = 0;  // candidates that passed the consistency check
  int rejected = 0;  // of those, failed the geometric check
  int closed = 0;
  int global_ba_runs = 0, global_ba_dropped = 0;
  double last_correction_m = 0;  // how far the loop moved its keyframe
};

class LoopCloser {
 public:
  LoopCloser(const SlamOptions& options, const CameraModel& camera, Map* map);
  ~LoopCloser();

  // Looks for a loop at this keyframe and closes it, on the calling thread
  // (by id: the keyframe may have been culled meanwhile).
  void process(std::int64_t keyframe_id);

  // Threaded use: a worker takes keyframe ids from a bounded queue; when
  // full, the oldest is dropped (a loop missed at one keyframe is found at
  // the next).
  void start();
  void enqueue(std::int64_t keyframe_id);
  void finish();  // drains the queue (and a global BA under way), joins

  LoopStats stats() const;

 private:
  friend class LoopCorrection;  // the unit test of correct()
  struct Loop {
    std::int64_t keyframe = -1, candidate = -1;
    SE3 T_kf_candidate;
    // Keyframe feature -> the older side's map point it sees.
    std::vector<std::pair<int, std::shared_ptr<MapPoint>>> fused;
  };
  bool detect(std::int64_t keyframe_id, Loop* loop);  // shared lock inside
  bool verify(const KeyFrame& kf, const KeyFrame& candidate, Loop* loop) const;
  void correct(const Loop& loop);  // exclusive lock inside
  // The candidate's and its best neighbours' static points (a map lock held).
  std::vector<std::shared_ptr<MapPoint>> olderPoints(const KeyFrame& candidate) const;
  // Per feature of `a` at pose T_a_w: the point among `points` that projects
  // within `radius` px and matches its descriptor best (null: none).
  std::vector<std::shared_ptr<MapPoint>> seenAt(const Frame& a, const SE3& T_a_w,
                                                const std::vector<std::shared_ptr<MapPoint>>& points,
                                                float radius) const;
  void run(std::stop_token stop);

  SlamOptions options_;
  const CameraModel& camera_;
  Map* map_;

  // Groups of keyframe ids that found candidates, with how many consecutive
  // keyframes confirmed each.
  struct Group {
    std::set<std::int64_t> members;
    int count = 0;
  };
  std::vector<Group> groups_;
  std::int64_t last_loop_keyframe_ = -1;

  static constexpr std::size_t kQueueCapacity = 16;
  mutable std::mutex mutex_;
  std::condition_variable_any cv_;
  std::deque<std::int64_t> queue_;
  bool closed_ = false;
  bool busy_ = false;
  LoopStats stats_;  // guarded by mutex_
  std::atomic<bool> abort_{false};
  std::jthread worker_;
};

}  // namespace stillpoint::slam
