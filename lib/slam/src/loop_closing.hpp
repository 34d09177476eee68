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
// A camera can also come back to an older place without a keyframe there:
// a place the map holds makes none, and a relocalisation lands in it. With
// place.global_ba on, a tracked frame whose reference keyframe is older
// than, and unconnected to, the map's newest keyframe (a crossing) is
// placed on both sides by each side's map points, and the loop between the
// newer side's keyframe and that reference is closed as in 4 and 5.
// Features flagged dynamic take no part (nor do their words).
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
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
  int crossings_checked = 0;  // frames that crossed into an older place
  int crossings_closed = 0;   // of those, closed a loop (counted in `closed` too)
  int global_ba_runs = 0, global_ba_dropped = 0;
  int global_ba_out_of_time = 0;  // cut at place.global_ba_max_s (applied or not)
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

  // Whether a frame tracked on `reference` (the keyframe most of its matches
  // hang on) at `stamp` is a crossing worth a check: `reference` is not the
  // map's newest keyframe nor covisible with it, was made 5 s or more
  // before it, and no crossing was checked in the last 0.5 s (1, 2, 4, 8 s
  // after 1, 2, 3, 4 or more checks that closed nothing since the newest
  // keyframe was made). Returns the
  // newest keyframe's id, else -1. A map lock held; the tracking thread.
  std::int64_t crossingDue(const KeyFrame& reference, Timestamp stamp);
  // Checks a crossing (`frame` with its tracked pose) and closes its loop,
  // on the calling thread; enqueueCrossing() hands it to the worker instead
  // (a crossing waiting there is replaced). `words`: the frame's static
  // words (Tracker::staticWords), which find the newer keyframes that see
  // its place when the newest does not. `epoch`: the map's when the frame
  // was tracked (a frame tracked in a world that moved since is not
  // checked).
  void processCrossing(const Frame& frame, const features::BowVector& words, std::int64_t reference,
                       std::int64_t newest, std::uint64_t epoch);
  void enqueueCrossing(Frame frame, features::BowVector words, std::int64_t reference, std::int64_t newest,
                       std::uint64_t epoch);

  LoopStats stats() const;

 private:
  friend class LoopCorrection;  // the unit test of correct()
  friend class Crossing;        // the unit test of crossings
  struct Loop {
    std::int64_t keyframe = -1, candidate = -1;
    SE3 T_kf_candidate;
    // Keyframe feature -> the older side's map point it sees.
    std::vector<std::pair<int, std::shared_ptr<MapPoint>>> fused;
  };
  bool detect(std::int64_t keyframe_id, Loop* loop);  // shared lock inside
  bool verify(const KeyFrame& kf, const KeyFrame& candidate, Loop* loop) const;
  // The crossing's loop: the frame's pose on the points of `older` and its
  // best neighbours, and on those of `newer` and its, and where that puts
  // `newer` (a shared map lock held).
  bool placeCrossing(const Frame& frame, const KeyFrame& older, const KeyFrame& newer, Loop* loop) const;
  // Refits `*T_a_w` on the points among `points` that frame `a` sees from
  // there, searched twice (8 px, then 4 px); the number of inliers, 0 when
  // under place.loop_min_inliers. `found` (optional) gets them per feature.
  int placeOn(const Frame& a, const std::vector<std::shared_ptr<MapPoint>>& points, SE3* T_a_w,
              std::vector<std::shared_ptr<MapPoint>>* found = nullptr) const;
  // Corrects the map by a verified loop, then the global bundle adjustment.
  bool close(const Loop& loop);
  bool correct(const Loop& loop);  // exclusive lock inside; false: its keyframes went
  // A keyframe's and its best neighbours' static points (a map lock held): a
  // loop's older side, a crossing's either side.
  std::vector<std::shared_ptr<MapPoint>> groupPoints(const KeyFrame& kf) const;
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
  std::atomic<std::int64_t> last_loop_keyframe_{-1};
  // Keyframes with a smaller id were in the last global BA that ran its
  // course (written back, not cut at its time limit).
  std::atomic<std::int64_t> global_ba_covers_{-1};
  Timestamp last_crossing_;  // the tracking thread's (crossingDue)
  bool crossing_checked_ = false;
  Timestamp last_crossing_loop_;  // the frame's that closed the last crossing loop
  bool crossing_closed_ = false;
  struct Crossing {
    Frame frame;
    features::BowVector words;
    std::int64_t reference = -1, newest = -1;
    std::uint64_t epoch = 0;
  };
  std::optional<Crossing> crossing_;  // guarded by mutex_
  // Consecutive crossings that closed nothing with this newest keyframe
  // (guarded by mutex_).
  int crossing_misses_ = 0;
  std::int64_t crossing_misses_keyframe_ = -1;

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
