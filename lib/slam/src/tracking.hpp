#pragma once
// Frame-to-map tracking. A frame's path (Tracker::track):
//   1. stage 1, the initial pose: motion model, else reference keyframe
//      (tracking.cpp); relocalisation when lost (relocalisation.cpp);
//   2. the dynamic-object detector judges the frame under that pose, drops
//      the features of moving surfaces and refits (dynamic_detector.cpp);
//   3. stage 2, the local map: more matches, the final pose (tracking.cpp);
//   4. the motion check: a pose no camera reaches is dropped (tracking.cpp);
//   5. the keyframe decision (keyframe_policy.cpp);
//   6. trajectory bookkeeping (trajectory.hpp).
// Semantic masks reach the frames between keyframes before stage 1
// (semantic_masks.cpp).
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <unordered_set>
#include <vector>

#include "dynamic_detector.hpp"
#include "dynamic_objects.hpp"
#include "map.hpp"
#include "trajectory.hpp"
#include "stillpoint/geometry/clustering_worker.hpp"
#include "stillpoint/slam/options.hpp"
#include "stillpoint/slam/system.hpp"

namespace stillpoint::slam {

struct SemanticResult;

class Tracker {
 public:
  struct StampedPose {
    Timestamp stamp;
    SE3 T_c_w;
    // The keyframe the pose hangs on, which local BA may move (map lock).
    std::shared_ptr<const PoseAnchor> reference;
    SE3 T_c_ref = SE3::Identity();
  };

  // `clustering` (may be null: geometry module off) delivers the depth
  // clusters of frames submitted to it.
  Tracker(const CameraModel& camera, const SlamOptions& options, const LevelInfo& levels, Map* map,
          geometry::ClusteringWorker* clustering);

  // Tracks `frame` (features built, pose unset). `mapping_idle` tells whether
  // local mapping can take a keyframe now; `clusters_pending` whether the
  // frame's depth went to the clustering worker. Returns the new keyframe or null.
  KeyFrame* track(Frame frame, bool mapping_idle, bool clusters_pending, TrackOutput* out);

  // The most recent tracking.trajectory_records tracked frames (all with -1).
  const std::deque<TrajectoryRecord>& records() const { return trajectory_.records(); }
  TrackingState state() const { return state_; }
  // The map tracked frames are in (TrackOutput::map_id).
  std::uint32_t mapId() const { return map_id_; }
  // A frame with too little depth to track (tracking.min_depth_share) was
  // left out: tracking does not see it, but the time without a pose counts
  // towards tracking.new_map_after_lost_s should tracking fail after it.
  void noDepth(Timestamp stamp);
  // A map was loaded (exclusive lock held, before the first frame): frames
  // relocalise against it, as after a loss.
  void mapLoaded();
  // Place recognition's vocabulary (null: none; keyframes are then found by
  // their small views). Set before the first frame; outlives the tracker.
  void setVocabulary(const features::Vocabulary* vocabulary) { vocabulary_ = vocabulary; }
  // Called with the frame a map is about to be built from (the first map, or
  // a new one after a loss), outside the map lock: it may flag the frame's
  // movers (kSemanticDynamic, the semantic module segmenting the frame ahead),
  // which then make no points; returns whether it flagged any. Set before the
  // first frame; null: none.
  void setMapStartMasks(std::function<bool(Frame*)> flag) { map_start_masks_ = std::move(flag); }
  // The words of a frame's static features (dynamic ones take no part in
  // recognising a place); empty without a vocabulary.
  features::BowVector staticWords(const Frame& frame) const;
  // Where the last frame's movers were, for the next frame's feature budget
  // (tracking.mover_cells_*): CV_8UC1 at 1/8 of the image size, non-zero near
  // its dynamic features; empty when they were too few or tracking failed.
  const cv::Mat& moverCells() const { return mover_cells_; }
  // Where the last frame made no keyframe because its place is mapped
  // (localisation, or a place a loaded map holds): no keyframe's masks will
  // reach its movers, so the semantic module segments frames there instead.
  bool mapsNothingHere() const { return options_.localisation || known_place_; }
  // Keeps the last tracked frame until its segmentation comes back; returns
  // its id (SemanticJob::frame_id).
  std::int64_t keepForMasks();
  // Applies the segmentation of the frame keepForMasks() kept (another
  // frame's is ignored) as a keyframe's is applied (`confirmation_required`:
  // only regions the geometry module confirms): its masked features are
  // looked up in the frames after it as a segmented keyframe's are
  // (markSemanticMovers), when it is newer than that keyframe. Returns
  // whether it was applied.
  bool applyFrameMasks(const SemanticResult& r, bool confirmation_required);
  // Regions of such frames left alone: the map had seen their place standing
  // (StaticSightings). Any thread.
  int frameRegionsKnownStatic() const { return frame_regions_known_static_.load(); }
  // The last frame tracked, its pose and matches, and the keyframe most of
  // those matches hang on (null before a map): where the camera is, for a
  // loop check (LoopCloser::crossingDue). A map lock held for the keyframe.
  const Frame& lastFrame() const { return last_; }
  const KeyFrame* referenceKeyFrame() const { return reference_; }
  // Relocalised poses refused because their inliers' depth disagreed
  // (relocalise()). Any thread.
  int relocalisationsRefused() const { return relocalisations_refused_.load(); }

 private:
  // State machine (tracking.cpp).
  bool trackFrame(bool clusters_pending);
  // Starts a map at the current frame, posed at `start`: from every feature
  // with depth not flagged, or from `only` these when given.
  bool initialise(const std::vector<int>* only = nullptr, const SE3& start = SE3::Identity());
  // The semantic module segments the frame a map is about to start from
  // (map_start_masks_), unless the start has waited new_map_after_lost_s for
  // a view its movers do not fill.
  void flagMapStartMovers();
  // Whether the masks flagMapStartMovers() set leave too few points for a
  // map (initialise(only)); the start then waits for a later frame. Called
  // before anything of the lost map is let go.
  bool mapStartRefused(const std::vector<int>* only);
  // Lost for tracking.new_map_after_lost_s, or the view moves as the camera
  // did (staticSupport) outside a place a loaded map holds, and the frame
  // could start a map.
  bool newMapDue();
  // Whether this frame is in a place a loaded map holds (known_place_,
  // on_loaded_map_).
  void noteLoadedMapSupport();
  // The features of current_ that moved from last_ as the camera did: from
  // the `predicted` motion (last_ to current_, allowing for its error), the
  // matches it explains refitted (relocalisation.cpp).
  struct StaticSupport {
    std::vector<int> agree;  // ascending
    std::vector<int> moved;  // matched, moved otherwise
    SE3 motion = SE3::Identity();  // last_ to current_, fitted to `agree`
  };
  StaticSupport staticSupport(const SE3& predicted) const;
  // The features of current_ found near where `motion` (last_ to current_)
  // puts a feature of last_ with depth, by descriptor, at the depth that
  // motion predicts.
  std::vector<char> guidedStaticMatches(const SE3& motion) const;
  static constexpr float kGuidedRadiusPx = 6;
  // Leaves the lost map as it is and starts a new one at the current frame
  // (map lock held exclusively).
  bool startNewMap();
  bool initialPose();
  // with_prior: the prediction is a prior of the fit (a real velocity; not
  // the last pose standing in for one).
  bool trackWithMotionModel(bool with_prior = true);
  bool trackReferenceKeyFrame();
  // Rebuilds the local map from the frame's matches first; a frame with no
  // match left to vote keeps the last frame's (updateLocalMap). The points
  // it searched in view count as seen (MapPoint::visible, found) at once, or,
  // with `seen`, are only listed there: a relocalisation candidate's pose
  // counts only if the frame takes it (countSightings, under the same map
  // lock, so the points are still there).
  bool trackLocalMap(int min_inliers, std::vector<MapPoint*>* seen = nullptr);
  void countSightings(const std::vector<MapPoint*>& seen);
  // Stage 2 left too few inliers because movers were kept out: the pose on
  // the established static points (tracking.cpp). Sets starved_.
  bool keepPoseOnStaticEvidence();
  // Stage 1 failed on a frame whose flagged features are most of it: the
  // same, from the predicted pose (tracking.cpp). Sets starved_.
  bool keepPredictedPoseOnStaticEvidence();
  void updateLocalMap();
  void refreshLastFrame();
  int setAsideCarried();
  bool keepPoseOnLastFrame();  // a young map's frame on its matches to the last frame
  bool refitFromPrediction();  // a pose plausibleMotion() refused, fitted again from the prediction
  int discardOutliers();
  int timedOptimizePose(const SE3* prior = nullptr);
  // The motion model's pose for current_, from `last` (the last frame's pose).
  SE3 predictedPose(const SE3& last) const;
  // Whether the frame's pose moves as a camera can from the motion model's
  // prediction (tracking.max_acceleration).
  bool plausibleMotion();
  // The steady poses where their keyframes are now (a map lock held).
  void followMapUnderSteadyPoses();
  void updateVelocity();
  void updateProbation();
  void markMoverCells(bool tracked);
  void reportFates(bool ok, TrackOutput* out) const;
  // The frame's pose health (pose_health.cpp), with hysteresis.
  PoseQuality measureQuality(bool ok);
  PoseHealth health_ = PoseHealth::kLost;
  int better_frames_ = 0;
  // A loop closure or global BA moved the world since the last frame:
  // re-express the last pose through its reference keyframe. A map lock held.
  void followWorldMoves();
  // Relocalisation (relocalisation.cpp).
  bool relocalise();
  bool relocalise(const std::vector<KeyFrame*>& candidates);
  // Keyframes to relocalise against by place recognition (`words`: the
  // frame's static words), at most n alike views: of the tracked map (and its
  // newest few), or of the other maps, where a camera back in a place an
  // older map knows goes on.
  std::vector<KeyFrame*> placeCandidates(const features::BowVector& words, std::size_t n, bool other_maps) const;
  // The map relocalise() placed the frame in, when not the active one:
  // processFrame() makes it the active map (switchToMap) under the
  // exclusive lock.
  std::optional<std::uint32_t> switch_to_map_;
  void switchToMap(std::uint32_t id);
  // A pose for `frame` from its map-point matches: PnP RANSAC (EPnP).
  bool poseFromMatches(Frame* frame) const;
  // Maps started after a loss rejoin older ones (map_merge.cpp): call with
  // no map lock held.
  void lookForOlderMaps();
  void mergeInto(std::uint32_t older, const SE3& T_older_newer, KeyFrame* older_keyframe);
  // Keyframe policy (keyframe_policy.cpp).
  bool needNewKeyFrame(bool mapping_idle) const;
  KeyFrame* createKeyFrame();
  // Keeps where the current frame's masks keep features out, if anywhere.
  void noteMaskedPlaces();
  // The places (cellKey, in the current map) where masks kept features out
  // in the last geometry.mover_probation_frames frames, for a frame without
  // marks (empty: none such); a new point near one (nearPlace) is a mover's.
  std::unordered_set<std::uint64_t> recentlyMasked() const;
  // Frees the keyframes local mapping culled, after dropping our own pointers
  // to them (map lock held exclusively).
  void releaseCulledKeyFrames();
  // A point of a keyframe whose segmentation is under way stays out of pose
  // fits without the geometry module. With it, the point's probation is its
  // hold: points held until their mask came left tracking only the map's
  // older points whenever segmentation fell behind the keyframes, and it
  // drifted (docs/dynamic-objects.md, "Points waiting for their mask").
  bool heldForMask(const MapPoint& p) const { return !detector_ && map_->awaitingMask(p.first_keyframe_id); }
  // Semantic masks between keyframes (semantic_masks.cpp).
  void markSemanticMovers();

  const CameraModel& camera_;
  const SlamOptions options_;
  const LevelInfo& levels_;
  Map* map_;
  std::unique_ptr<DynamicDetector> detector_;  // null: geometry module off
  DynamicObjectTracker objects_{camera_};
  const double close_depth_;
  const features::Vocabulary* vocabulary_ = nullptr;

  TrackingState state_ = TrackingState::kInitialising;
  std::uint32_t map_id_ = 0;
  // Since when no frame has had a pose: the first lost frame, or the first
  // frame without depth before it (unset while tracking).
  std::optional<Timestamp> lost_since_, blind_since_;
  // A lookup that placed the current map in an older one, waiting for a
  // second that agrees (map_merge.cpp).
  struct MergeCandidate {
    std::uint32_t older = 0;
    SE3 T_older_newer;
    Timestamp stamp;
  };
  std::optional<MergeCandidate> merge_candidate_;
  Frame current_, last_;
  bool has_last_ = false;
  // The last frame's pose relative to its reference keyframe, and the map
  // epoch it was taken in: when a loop closure or a global BA moves the
  // world, the last pose is re-expressed through the keyframe.
  SE3 T_last_reference_ = SE3::Identity();
  std::uint64_t seen_epoch_ = 0;
  // The same for the current frame between its pose and its record: the
  // map lock is released in between (a keyframe insertion takes the
  // exclusive one), and a loop closure may move the world there.
  std::uint64_t pose_epoch_ = 0;
  SE3 reference_at_pose_ = SE3::Identity();
  void notePoseWorld();     // a map lock held
  void catchUpWithWorld();  // a map lock held
  KeyFrame* reference_ = nullptr;
  Timestamp last_keyframe_stamp_;
  std::int64_t last_keyframe_frame_id_ = 0;
  std::int64_t last_reloc_frame_id_ = -100;
  // Relocalisation tries older keyframes in turn: the next window starts
  // below this id (wrapping to the newest).
  std::int64_t reloc_window_next_id_ = -1;
  std::int64_t local_searches_ = 0;  // updateLocalMap's count: the marks of its searches
  SE3 velocity_ = SE3::Identity();
  bool has_velocity_ = false;
  // The velocity of the last frame whose pose stood on the map (not kept on
  // fallback evidence), and that frame's id.
  SE3 steady_velocity_ = SE3::Identity();
  std::int64_t steady_velocity_frame_ = -100;
  // The velocity when the loss began (identity without one), and the lost
  // frame's static support (staticSupport).
  SE3 loss_velocity_ = SE3::Identity();
  StaticSupport static_support_;
  std::function<bool(Frame*)> map_start_masks_;
  bool masked_ahead_ = false;                         // this frame's movers masked by it
  std::optional<Timestamp> map_start_waiting_since_;  // a map start refused for want of points
  // A place a loaded map holds (noteLoadedMapSupport): this frame's view
  // shows less new ground than a keyframe would map (no keyframe is made);
  // its pose also stands on at least kMapMatchesWithoutTemporary of the
  // file's points (the next fit leans on them alone); the last frame of
  // which both were true; and whether the loss began within
  // tracking.new_map_after_lost_s of that frame (a new map then waits for
  // relocalisation: newMapDue).
  bool known_place_ = false;
  bool on_loaded_map_ = false;
  std::optional<Timestamp> last_on_loaded_map_;
  bool lost_in_known_place_ = false;
  // The last frame of a map started on static support that makes no
  // keyframe (needNewKeyFrame).
  std::int64_t young_map_until_frame_ = -1;
  double velocity_dt_ = 0;  // s between the two frames velocity_ was measured on
  int inliers_ = 0;
  std::vector<KeyFrame*> local_keyframes_;
  std::vector<std::shared_ptr<MapPoint>> local_points_;
  TrajectoryLog trajectory_;

  // Per frame.
  StageTimes times_;
  GeometryOutput geometry_;
  int semantic_marked_ = 0;
  // The newest masks markSemanticMovers followed (PoseQuality::mask_age_s).
  float mask_age_s_ = -1;
  bool masks_found_movers_ = false;
  // A frame segmented because no keyframe was made there (keepForMasks),
  // until its result is back; then the newest such frame, with its masks.
  std::optional<Frame> awaiting_masks_, masked_frame_;
  std::vector<char> awaiting_matched_;  // per feature of awaiting_masks_: a map-point inlier
  // Where masks last kept features out (recentlyMasked()): the world
  // positions of those with depth, the frame and its map.
  struct MaskedPlaces {
    std::vector<Vec3> points;
    std::int64_t frame_id = -1;
    std::uint32_t map_id = 0;
  } last_masked_;
  std::atomic<int> frame_regions_known_static_{0};
  std::atomic<int> relocalisations_refused_{0};
  bool rejected_ = false;  // the frame's pose failed plausibleMotion(): no pose, tracking goes on
  int predicted_frames_ = 0;  // frames in a row the motion predicted within plausibleMotion()'s bounds
  std::deque<StampedPose> steady_poses_;  // the last steady frames' poses (plausibleMotion())
  bool last_pose_departed_ = false;  // plausibleMotion() found the last steady pose off: it predicts no more
  bool starved_ = false;  // the pose stands on keepPoseOnStaticEvidence()
  // Stage-1 matches to the last frame's moving features (evidence only).
  std::vector<std::shared_ptr<MapPoint>> carried_;
  // Per keypoint of the current frame: best / second-best Hamming distance of
  // its motion-model match (0: none, or matched by a ratio-tested search).
  std::vector<float> match_ratio_;
  cv::Mat mover_cells_;  // moverCells()
};

}  // namespace stillpoint::slam
