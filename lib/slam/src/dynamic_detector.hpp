#pragma once
// The geometry module's frame-level pipeline: between the two pose stages it
// judges the frame's depth clusters by what each feature's evidence says
// about its motion, drops the features of moving surfaces from the pose and
// refits it. It owns the history it needs across frames (anchor frames, seen
// depth and grey images, chains of carried matches). The cues themselves
// (cluster verdict, free space, photometric test) live in lib/geometry.
#include <cstdint>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "map.hpp"
#include "task_thread.hpp"
#include "stillpoint/geometry/clustering_worker.hpp"
#include "stillpoint/geometry/free_space.hpp"
#include "stillpoint/geometry/photometric.hpp"
#include "stillpoint/slam/options.hpp"
#include "stillpoint/slam/system.hpp"

namespace stillpoint::slam {

// What stage 1 leaves the detector besides the frame and its pose.
struct StageOneMatches {
  // Per feature: the last frame's moving feature it matched (evidence only,
  // kept out of the pose; null: none). Empty when stage 1 did not search the
  // last frame.
  const std::vector<std::shared_ptr<MapPoint>>* carried = nullptr;
  // Per feature: best / second-best Hamming distance of its projection-search
  // match (0: none, or matched by a ratio-tested search).
  const std::vector<float>* match_ratio = nullptr;
  const KeyFrame* reference = nullptr;  // the reference keyframe (may be null or bad)
};

// Refits the frame's pose on its current matches (the tracker's pose-only
// optimisation); returns the inliers.
using PoseRefit = std::function<int()>;

class DynamicDetector {
 public:
  // `clustering` delivers the depth clusters of the frames submitted to it.
  // With `threaded`, descriptor matching against the anchor frames runs on a
  // helper thread while stage 1 runs.
  DynamicDetector(const CameraModel& camera, const LevelInfo& levels, const SlamOptions& options,
                  geometry::ClusteringWorker* clustering, bool threaded);

  // A new frame, before stage 1. `clusters_pending`: its depth went to the
  // clustering worker. `match_now` (threaded mode): start its matching to
  // the oldest anchor; `frame` then stays at this address until endFrame().
  void startFrame(const Frame& frame, bool clusters_pending, bool match_now);
  // Gives the last frame's moving features temporary evidence points, so that
  // stage 1's projection search finds them in this frame (then set aside as
  // StageOneMatches::carried). Features the last frame's photometric test
  // freed are carried too: their cluster keeps its memory.
  void carryMovers(Frame* last);
  bool freedInLastFrame(int i) const {
    return i < static_cast<int>(last_photo_released_.size()) && last_photo_released_[i];
  }
  // Judges the frame under its stage-1 pose, drops the features of moving
  // surfaces from its matches (marking them Frame::dynamic), and refits the
  // pose through `refit`. Returns what it saw.
  GeometryOutput judge(Frame* frame, const StageOneMatches& stage_one, const PoseRefit& refit);
  // Where a remembered frame's pose hangs: relative to its reference
  // keyframe's anchor, taken in map epoch `epoch` (Map::epoch).
  struct Placement {
    std::shared_ptr<const PoseAnchor> reference;
    SE3 T_c_ref = SE3::Identity();
    std::uint64_t epoch = 0;
  };
  // The frame is done: `tracked` frames become history (placed at `where`),
  // a lost one clears it.
  void endFrame(const Frame& frame, bool tracked, const Placement& where);
  // The frame is dropped (its pose was implausible): it neither becomes
  // history nor clears it.
  void skipFrame();
  // A loop closure or a global BA moved the world (the map is in `epoch`
  // now; a map lock held): the history's poses follow their keyframes. The
  // evidence it holds is frame to frame and stays valid; the map right after
  // a loop closure is not yet consistent, and judged by map points alone
  // static surfaces look moving.
  void followWorld(std::uint64_t epoch);
  // The world frame moved under the history (maps merged, a new map, a
  // relocalisation in another map): forget it. Waits for the helper's match
  // against the oldest anchor, which it drops (threaded mode).
  void forgetHistory();
  // Whether the helper's match of the current frame to the oldest anchor is
  // under way or waiting to be used (threaded mode, from startFrame() to
  // judge() or endFrame()).
  bool anchorMatchPending() const { return anchor_matches_.valid(); }
  // Map points found in dynamic clusters since the last call (for the next
  // keyframe: local mapping culls those that stay dynamic).
  std::vector<std::shared_ptr<MapPoint>> takeSuspects();
  // Whether feature i of the current frame is on a known mover: in the depth
  // cluster of one, and seen moving or new there (no anchor match). False
  // before judge() or when the frame was not judged.
  bool onKnownMover(int i) const { return i < static_cast<int>(on_known_mover_.size()) && on_known_mover_[i]; }

 private:
  struct FrameJudgement;  // per-frame working state (dynamic_detector.cpp)
  struct NearerAnchor {
    int feature, keypoint, frames_back;
  };
  // Grey and depth images of tracked frames with their final poses, oldest
  // first: the free-space and photometric baselines.
  struct SeenFrame {
    cv::Mat depth;  // empty: none
    cv::Mat gray;   // empty unless the photometric test is on
    SE3 T_c_w;
    Placement where;
  };

  std::shared_ptr<const geometry::DepthClusters> fetchClusters(GeometryOutput* out);
  std::vector<std::pair<int, int>> matchAnchor(const Frame& frame) const;
  void gatherEvidence(FrameJudgement& j);
  geometry::FreeSpace freeSpace(const Frame& frame, const geometry::DepthClusters& clusters) const;
  void labelFeatures(FrameJudgement& j) const;
  std::vector<NearerAnchor> nearerAnchors(const Frame& frame, std::vector<int> anchored_in_cluster) const;
  void takeNearerAnchors(FrameJudgement& j, const std::vector<NearerAnchor>& nearer) const;
  geometry::ClusterVerdict judgeClusters(FrameJudgement& j, bool anchored) const;
  bool staticExplains(const FrameJudgement& j, int i, const Vec3& p_w, const std::uint8_t* descriptor,
                      int distance) const;
  std::vector<char> knownMovers(const FrameJudgement& j) const;
  bool poseDisagreesWithView(const FrameJudgement& j, const geometry::ClusterVerdict& verdict) const;
  bool adoptConsensusPose(FrameJudgement& j) const;
  geometry::ClusterVerdict verdictUnderBestPose(FrameJudgement& j) const;
  void addFreeSpace(FrameJudgement& j, geometry::ClusterVerdict* verdict) const;
  void splitByMovedSurface(FrameJudgement& j, const geometry::ClusterVerdict& verdict) const;
  bool dropped(const FrameJudgement& j, int i, const geometry::ClusterVerdict& verdict) const;
  void dropDynamic(FrameJudgement& j, const PoseRefit& refit) const;
  void detectPhotometrically(FrameJudgement& j, const PoseRefit& refit) const;
  void releasePhotometrically(FrameJudgement& j, const PoseRefit& refit);
  int photoVerdict(const FrameJudgement& j, int i) const;
  void report(FrameJudgement& j);
  void rememberFrame(const Frame& frame, const Placement& where);

  const CameraModel& camera_;
  const LevelInfo& levels_;
  const GeometryOptions options_;
  geometry::ClusteringWorker* clustering_;
  std::unique_ptr<TaskThread> helper_;  // threaded mode only

  // The current frame's depth clusters, fetched once (null: none or late).
  std::int64_t frame_id_ = -1;
  bool clusters_pending_ = false, clusters_fetched_ = false;
  std::shared_ptr<const geometry::DepthClusters> clusters_;
  // The current frame's descriptor matches to the oldest anchor (threaded:
  // computed on the helper while stage 1 runs).
  std::future<std::vector<std::pair<int, int>>> anchor_matches_;
  // The last geometry.anchor_frames tracked frames (keypoints, descriptors,
  // depth, final pose; no matches), oldest first: the evidence baseline.
  std::deque<Frame> anchors_;
  std::deque<Placement> anchor_places_;  // one per anchor
  std::deque<SeenFrame> seen_;
  // The last frame's feature each carried evidence point stands for, and
  // those of its features this module found moving (not a mask's).
  std::unordered_map<const MapPoint*, int> carried_from_;
  std::unordered_set<int> carried_moving_;
  // Per feature of the current / last frame: the world positions of the chain
  // of moving features it was carried from, the last frame's first, at most
  // geometry.carried_frames (empty: not carried).
  std::vector<std::vector<Vec3>> chain_, last_chain_;
  // Features of the current / last frame the photometric test freed from a
  // dynamic cluster (with geometry.photo_release_memory).
  std::vector<char> photo_released_, last_photo_released_;
  std::vector<std::shared_ptr<MapPoint>> suspects_;
  std::vector<char> on_known_mover_;  // per feature of the current frame
};

// Gives the moving features of `last` (Frame::dynamic, or `freed` by the
// photometric test) temporary evidence points (MapPoint::moving): stage 1's
// projection search finds them in the next frame, where they are set aside
// from the pose. Returns the feature each point stands for.
std::unordered_map<const MapPoint*, int> carryMovingFeatures(Frame* last, const std::vector<char>& freed);

// Map inliers of a frame's matches: not outliers, not temporary, observed.
int countMapInliers(const Frame& frame);

}  // namespace stillpoint::slam
