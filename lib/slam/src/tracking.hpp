#pragma once
// Frame-to-map tracking: motion model, reference keyframe, local map,
// relocalisation, and the keyframe decision.
#include <deque>
#include <future>
#include <memory>
#include <optional>
#include <unordered_map>
#include <utility>
#include <vector>

#include "map.hpp"
#include "task_thread.hpp"
#include "stillpoint/geometry/clustering_worker.hpp"
#include "stillpoint/slam/options.hpp"
#include "stillpoint/slam/system.hpp"

namespace stillpoint::slam {

// A tracked frame's pose relative to its reference keyframe's anchor, so that
// it follows bundle adjustment and survives the keyframe's culling.
struct TrajectoryRecord {
  Timestamp stamp;
  std::shared_ptr<const PoseAnchor> reference;
  SE3 T_c_ref;
  SE3 T_c_w() const { return renormalized(T_c_ref * reference->T_c_w()); }
};

class Tracker {
 public:
  // `clustering` (may be null: geometry module off) delivers the depth
  // clusters of frames submitted to it.
  Tracker(const CameraModel& camera, const SlamOptions& options, const LevelInfo& levels, Map* map,
          geometry::ClusteringWorker* clustering);

  // Tracks `frame` (features built, pose unset). `mapping_idle` tells whether
  // local mapping can take a keyframe now; `clusters_pending` whether the
  // frame's depth went to the clustering worker. Returns the new keyframe or null.
  KeyFrame* track(Frame frame, bool mapping_idle, bool clusters_pending, TrackOutput* out);

  // The most recent tracking.trajectory_records tracked frames (all with -1).
  const std::deque<TrajectoryRecord>& records() const { return records_; }
  TrackingState state() const { return state_; }
  // Where the last frame's movers were, for the next frame's feature budget
  // (tracking.mover_cells_*): CV_8UC1 at 1/8 of the image size, non-zero near
  // its dynamic features; empty when they were too few or tracking failed.
  const cv::Mat& moverCells() const { return mover_cells_; }

 private:
  bool initialise();
  // with_prior: the prediction is a prior of the fit (a real velocity; not
  // the last pose standing in for one).
  bool trackWithMotionModel(bool with_prior = true);
  bool trackReferenceKeyFrame();
  bool relocalise();
  bool trackLocalMap(int min_inliers);
  void updateLocalMap();
  void refreshLastFrame();
  int discardOutliers();
  int countMapInliers() const;
  // Geometry module, between the two stages: judges the depth clusters by the
  // reprojection errors of the stage-1 matches, drops dynamic features and
  // re-estimates the initial pose without them.
  void removeDynamicFeatures();
  // Features matching the masked features of the newest segmented keyframe.
  void markSemanticMovers();
  // Motion gate of the mask warp: whether the `mask` matches ((current,
  // keyframe f) index pairs) miss by more than `gate_px` (median) and twice the
  // `still` matches, reprojected through the motion model's pose refined on
  // the still matches.
  bool maskMoves(const Frame& f, const std::vector<std::pair<int, int>>& still,
                 const std::vector<std::pair<int, int>>& mask, float gate_px) const;
  int timedOptimizePose(const SE3* prior = nullptr);
  // The motion model's pose for current_, from `last` (the last frame's pose).
  SE3 predictedPose(const SE3& last) const;
  void updateProbation();
  bool needNewKeyFrame(bool mapping_idle) const;
  KeyFrame* createKeyFrame();

  const CameraModel& camera_;
  SlamOptions options_;
  const LevelInfo& levels_;
  Map* map_;
  geometry::ClusteringWorker* clustering_;
  double close_depth_;

  TrackingState state_ = TrackingState::kInitialising;
  Frame current_, last_;
  bool has_last_ = false;
  KeyFrame* reference_ = nullptr;
  Timestamp last_keyframe_stamp_;
  std::int64_t last_keyframe_frame_id_ = 0;
  std::int64_t last_reloc_frame_id_ = -100;
  // Relocalisation tries older keyframes in turn: the next window starts
  // below this id (wrapping to the newest).
  std::int64_t reloc_window_next_id_ = -1;
  SE3 velocity_ = SE3::Identity();
  bool has_velocity_ = false;
  double velocity_dt_ = 0;  // s between the two frames velocity_ was measured on
  int inliers_ = 0;
  int semantic_marked_ = 0;
  std::vector<KeyFrame*> local_keyframes_;
  std::vector<std::shared_ptr<MapPoint>> local_points_;
  std::optional<TrajectoryRecord> last_record_;  // the last tracked frame (motion model)
  std::deque<TrajectoryRecord> records_;
  void record(const TrajectoryRecord& r);
  void markMoverCells(bool tracked);
  // Frees the keyframes local mapping culled, after dropping our own pointers
  // to them (map lock held exclusively).
  void releaseCulledKeyFrames();
  StageTimes times_;
  GeometryOutput geometry_;
  std::vector<std::shared_ptr<MapPoint>> dynamic_suspects_;
  // Stage-1 matches to last frame's moving features (evidence only).
  std::vector<std::shared_ptr<MapPoint>> carried_;
  // The last frame's feature each carried point stands for (refreshLastFrame).
  std::unordered_map<const MapPoint*, int> carried_from_;
  // Per feature of the current / last frame: the world positions of the chain
  // of moving features it was carried from, the last frame's first, at most
  // geometry.carried_frames (empty: not carried).
  std::vector<std::vector<Vec3>> chain_, last_chain_;
  // Per keypoint of the current frame: best / second-best Hamming distance of
  // its motion-model match (0: none, or matched by a ratio-tested search).
  std::vector<float> match_ratio_;
  // The current frame's depth clusters, fetched once (null: none or late).
  bool clusters_pending_ = false, clusters_fetched_ = false;
  std::shared_ptr<const geometry::DepthClusters> clusters_;
  std::shared_ptr<const geometry::DepthClusters> currentClusters();
  // The current frame's (index, anchor index) descriptor matches to the oldest anchor.
  std::vector<std::pair<int, int>> matchAnchor() const;
  // geometry.exclude_known_movers: keeps the stage-1 matches of clusters
  // mostly matched to the last frame's dynamic features out of the initial
  // pose (returned as outliers, still evidence).
  void holdKnownMoversOutOfPose();
  std::vector<std::shared_ptr<MapPoint>> held_;
  int setAsideCarried();
  // The last geometry.anchor_frames tracked frames (keypoints, descriptors,
  // depth, final pose; no matches), oldest first: the geometry module's
  // evidence baseline. Cleared when tracking is lost.
  std::deque<Frame> anchors_;
  // The current frame's descriptor matches to the oldest anchor, which need no
  // pose: in threaded mode `helper_` computes them while stage 1 runs
  // (sequential replays compute them inline, when they are needed).
  std::future<std::vector<std::pair<int, int>>> anchor_matches_;
  std::unique_ptr<TaskThread> helper_;  // threaded mode with the geometry module only
  // A current feature matched to keypoint `keypoint` of the anchor kept
  // `frames_back` frames back (geometry.near_anchor_frames).
  struct NearerAnchor {
    int feature, keypoint, frames_back;
  };
  // Features of the current / last frame that the photometric test freed from
  // a dynamic cluster (with geometry.photo_release_memory): static for the
  // pose and the map, but they pass on their cluster's memory.
  std::vector<char> photo_released_, last_photo_released_;
  // The depth images of the last geometry.freespace_frames tracked frames
  // and their final poses, oldest first (empty image: none): the free-space
  // baseline, which may reach further back than the anchors.
  struct SeenDepth {
    cv::Mat depth;
    cv::Mat gray;  // empty unless the photometric test is on
    SE3 T_c_w;
  };
  std::deque<SeenDepth> seen_depth_;
  void rememberAnchor();
  // The current frame's depth samples against the oldest seen depth image
  // (seen_depth_): which lie in space that frame saw empty, and per cluster
  // the share that do
  // (GeometryOutput::freespace).
  struct FreeSpace {
    std::vector<float> share;      // per cluster; -1: fewer than 8 samples tested
    std::vector<int> violations;   // per cluster: samples in free space
    cv::Mat violated;  // CV_8U on the sample grid
    cv::Mat points;    // CV_32FC3 on the sample grid, camera frame (z = 0: no depth)
  };
  FreeSpace freeSpaceViolations(const geometry::DepthClusters& clusters) const;
  // The samples connected to a violating one over a continuous surface (no
  // depth jump, no crease): the whole moving object, not only the part that
  // entered empty space. CV_8U on the sample grid.
  cv::Mat growMovedSurface(const geometry::DepthClusters& clusters, const FreeSpace& free) const;
  // Squared error of feature i of the current frame against world point p_w
  // under the current pose, in units of its measurement sigma (3 dof with depth).
  struct EvidenceError {
    double pixel2 = 0;  // squared image error (u, v and, with depth, virtual right u) [px^2]
    int dof = 0;        // coordinates in pixel2
    double inv_level_sigma2 = 1;
    double depth_chi2 = 0;  // depth_sigma_at_1m's term, or 1e6 behind the camera
    double level_chi2 = 0;  // the whole error normalised by the level sigma
    Vec3 residual = Vec3::Zero();  // its components (u, v, depth term) over the level sigma, predicted minus measured
  };
  EvidenceError evidenceError(int i, const Vec3& p_w) const;
  // geometry.consensus_ratio: replaces the initial pose by consensusPose
  // over the anchor matches (feature i -> world point anchor_point[i] where
  // has_anchor[i]) when that explains them clearly better. True when it did.
  bool adoptConsensusPose(const std::vector<char>& has_anchor, const std::vector<Vec3>& anchor_point,
                          const std::vector<char>& inherited);
  // The static hypothesis tested on pixels: feature i's patch warped pixel by
  // pixel with its depth (`depth`: the current frame's depth image) into the
  // seen frame `frame` (0: the oldest) under the current pose. False when the patch leaves
  // either image or that frame kept no grey image.
  struct PhotoAgreement {
    double ncc = -1;         // zero-mean NCC of the patch and the seen image there (-1: a flat patch)
    double depth_share = 0;  // share of the patch's pixels whose depth agrees there
  };
  bool photoAgreement(int i, const cv::Mat& depth, std::size_t frame, PhotoAgreement* out) const;
  cv::Mat mover_cells_;  // moverCells()
};

// Photometric detection: a cluster at least photo_detect_min of whose
// features' patches were tested (their depth agreeing) and more than
// photo_detect_share of them failed is dynamic.
bool photoDetects(int tested, int failed, const GeometryOptions& options);

// The photometric test's verdict over the frames a patch is tested against,
// their NCC added one at a time (a patch whose depth disagrees in a frame has
// no verdict and never gets here): it passes when every frame is above
// geometry.photo_release_ncc, or when three or more were tested, the worst
// is above photo_one_ncc (> 0) and every other above photo_one_others. A
// frame added never turns a failure into a pass, so the test may stop at the
// first failure.
class PhotoVote {
 public:
  explicit PhotoVote(const GeometryOptions& options) : options_(options) {}
  void add(double ncc);
  bool failed() const { return !(worst_ > options_.photo_release_ncc) && !oneMayMiss(); }
  bool passed() const {
    return frames_ > 0 && (worst_ > options_.photo_release_ncc || (frames_ >= 3 && oneMayMiss()));
  }

 private:
  bool oneMayMiss() const {
    return options_.photo_one_ncc > 0 && worst_ > options_.photo_one_ncc && second_ > options_.photo_one_others;
  }
  const GeometryOptions& options_;
  double worst_ = 1, second_ = 1;
  int frames_ = 0;
};

}  // namespace stillpoint::slam
