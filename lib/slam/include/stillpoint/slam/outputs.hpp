#pragma once
// What the SLAM core reports: per-frame tracking output (state, pose, stage
// times, the geometry module's verdict and, when asked for, every judged
// feature), trajectory poses, map statistics and keyframe views.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/health_causes.hpp"
#include "stillpoint/core/time.hpp"
#include "stillpoint/geometry/depth_clustering.hpp"
#include "stillpoint/geometry/dynamic_clusters.hpp"

namespace stillpoint::slam {

// A frame's tracking state. kRelocalised and kNewMap are the first frame
// tracked again after a loss: found in its map again, or the first keyframe
// of a new map (TrackOutput::map_id) started when relocalisation had failed
// for tracking.new_map_after_lost_s. kNoDepth: the frame had too little
// depth to be tracked (tracking.min_depth_share); it has no pose.
enum class TrackingState { kInitialising, kOk, kLost, kRelocalised, kNoDepth, kNewMap };
const char* toString(TrackingState state);
// The states in which TrackOutput::T_w_c is a pose.
constexpr bool hasPose(TrackingState s) {
  return s == TrackingState::kOk || s == TrackingState::kRelocalised || s == TrackingState::kNewMap;
}

// How far to trust a frame's pose (docs/pose-health.md). kLost: no pose.
// Worse states take over at once; a better one only after it has held for
// PoseQuality::kRecoveryFrames frames in a row (hysteresis).
enum class PoseHealth : std::uint8_t { kGood = 0, kDegraded = 1, kUnreliable = 2, kLost = 3 };
const char* toString(PoseHealth health);

struct PoseQuality {
  static constexpr int kRecoveryFrames = 15;
  // With the semantic module alone, masks older than these make a pose
  // degraded and unreliable.
  static constexpr float kDegradedMaskAgeS = 0.6f, kUnreliableMaskAgeS = 2.0f;
  PoseHealth health = PoseHealth::kLost;
  int inliers = 0;              // map points in the final pose
  float dynamic_share = 0;      // features kept out as moving / (those + inliers)
  float outlier_share = 0;      // map-point matches the final pose rejected / all of them
  float reprojection_rms_px = 0;  // of the inliers, image plane
  // How well the inliers pin all six degrees of freedom: sqrt(lambda_min /
  // lambda_max) of the pose's information matrix (translation scaled by the
  // median depth), 1 = every direction equally, 0 = one is free.
  float conditioning = 0;
  // The semantic module: seconds from the image of the newest masks followed
  // into this frame to this frame, infinity when no keyframe near the camera
  // has masks (-1: not known, the module off or the frame relocalised), and
  // whether those masks kept anything out.
  float mask_age_s = -1;
  bool masks_found_movers = false;
  // What lowered the health (health_cause::k* bits): every measure past its
  // bound this frame, and health_cause::kRecovering while the frame's own
  // level is better than the one reported but has not held for
  // kRecoveryFrames yet. 0 for a good pose and for no pose.
  std::uint16_t causes = 0;
  // The pose's covariance in the map: the camera's centre [m], then its
  // rotation about the map's x, y and z axes [rad] (a small rotation
  // exp(r) R), from the inliers' information (docs/pose-health.md, "The
  // covariance"). Zero when the frame has no pose.
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
};

// Where one frame's tracking time went (milliseconds).
struct StageTimes {
  double extract = 0;         // ORB extraction and depth lookup
  double initial_pose = 0;    // motion model / reference keyframe / relocalisation matching
  double local_map = 0;       // local map update and projection search
  double pose_optimisation = 0;  // every pose-only optimisation of the frame
  double keyframe = 0;        // keyframe decision and creation
  double geometry = 0;        // waiting for the clusters and judging them (tracking thread)
  double objects = 0;         // the frame's dynamic objects (TrackOutput::objects)
  double semantic = 0;        // carrying the newest masks to the frame (tracking thread)
  // Live, a young map: waiting for local mapping to finish the keyframe the
  // last frame made (MappingOptions::young_map_keyframes).
  double mapping_wait = 0;
};

// A feature matched in the first tracking stage and judged by the geometry
// module; (u, v) in distorted image pixels.
struct JudgedFeature {
  float u = 0, v = 0;
  bool dynamic = false;
  int cluster = -1;
  float chi2 = 0;  // squared reprojection error / level sigma^2 under the pose it was judged under
  // What chi2 was measured against: the anchor frame's match, a stage-1 map
  // point, or a match carried from the last frame's dynamic features / the
  // reference keyframe.
  enum class Evidence : std::uint8_t { kAnchor = 0, kMapPoint = 1, kCarried = 2 };
  Evidence evidence = Evidence::kMapPoint;
  bool inherited = false;  // matched to a feature that was dynamic before
  float depth = 0;         // keypoint depth in metres (0: none)
  int distance = 0;        // Hamming distance of the evidence match
  // Its distance over the second best in the search window (0: none or not a
  // projection match; anchor and keyframe matches passed a 0.7 ratio test).
  float ratio = 0;
  // chi2's components: u, v and the depth term, each over its sigma.
  Eigen::Vector3f residual = Eigen::Vector3f::Zero();
  float freespace = -1;  // its cluster's GeometryOutput::freespace
  // Its evidence disagreed, but the static hypothesis explains it as well
  // (geometry.static_match_margin): left out of
  // the verdict, reported with its outcome all the same.
  bool explained = false;
  // kAnchor: how many frames back its anchor match lies (geometry.anchor_frames,
  // or fewer for a nearer anchor: geometry.near_anchor_frames); else 0.
  int baseline = 0;
};

// What the geometry module saw in one frame (for visualisation and scoring).
struct GeometryOutput {
  bool ran = false;              // clusters arrived in time and were judged
  bool deadline_missed = false;  // clusters were not ready within deadline_ms
  int clusters = 0;
  int dynamic_clusters = 0;
  int dynamic_features = 0;      // features excluded from pose and mapping
  bool anchor_fallback = false;  // judged by stage-1 matches: the anchor evidence disagreed with most of the view
  bool consensus_pose = false;   // judged under the consensus pose of the anchor matches (geometry.consensus_ratio)
  bool freespace_vetoed = false; // free space would have flagged most of the view: the pose is off, nothing added
  double threshold = 0;          // score above which a cluster was dynamic
  double clustering_ms = 0;      // K-Means time (in the module's thread)
  std::vector<geometry::ClusterScore> scores;
  // Per cluster: share of its depth samples in space the anchor frame saw
  // empty (-1: fewer than 8 samples could be tested).
  std::vector<float> freespace;
  std::shared_ptr<const geometry::DepthClusters> labels;
  std::vector<JudgedFeature> judged;
};

// What became of a feature in its frame (TrackOutput::fates: pictures of a run).
enum class FeatureFate : std::uint8_t {
  kInPose = 0,           // matched to a map point and an inlier of the final pose
  kGeometryDynamic = 1,  // kept out by the geometry module
  kSemanticDynamic = 2,  // kept out by the semantic module (a movable mask, or a known mover)
  kNoDepth = 3,          // no depth at the keypoint, and not in the pose
  kUnused = 4,           // has depth, but unmatched or an outlier
};
const char* toString(FeatureFate fate);

struct FeatureView {
  float u = 0, v = 0;  // distorted image pixels
  FeatureFate fate = FeatureFate::kUnused;
};

// Something seen moving in one frame (docs/dynamic-objects.md): a region of
// depth clusters the geometry module judged dynamic, or features of a movable
// semantic class, or both where they overlap. Positions in the map frame of
// TrackOutput::map_id (the first camera's optical axes: x right, y down, z
// forward), from the depth of its visible surface.
struct DynamicObject {
  static constexpr std::uint8_t kGeometry = 1, kSemantic = 2;
  // Stable while the object is followed from frame to frame; a new id when it
  // is lost for DynamicObjectTracker's memory or the map changes.
  std::uint32_t id = 0;
  std::string label = "unknown";  // the semantic class, or "unknown"
  std::uint8_t sources = 0;       // kGeometry | kSemantic
  Vec3 centroid = Vec3::Zero();   // median of its surface points [m]
  Vec3 extent = Vec3::Zero();     // 5-95 % range of its surface points per axis [m]
  Vec3 velocity = Vec3::Zero();   // of the centroid [m/s], smoothed; zero until seen twice
  bool has_velocity = false;
  int samples = 0;                // surface points it was measured from
  int frames = 1;                 // frames it has been followed through, this one included
};

struct TrackOutput {
  TrackingState state = TrackingState::kInitialising;
  SE3 T_w_c = SE3::Identity();  // valid when hasPose(state)
  // The map the pose is in: 0 for the first, one more for each map started
  // after a loss (tracking.new_map_after_lost_s). Poses of different maps are
  // in different frames.
  std::uint32_t map_id = 0;
  int features = 0;
  int tracked = 0;  // inlier matches to map points
  PoseQuality quality;
  // Features matched to the masked features of the newest segmented keyframe
  // and kept out of the pose (semantic module).
  int semantic_features = 0;
  bool new_keyframe = false;
  std::size_t keyframes = 0;
  double extract_ms = 0;  // ORB extraction
  double track_ms = 0;    // whole tracking step, extraction included
  StageTimes stages;
  GeometryOutput geometry;
  // What moves in this frame (frames with a pose; empty otherwise).
  std::vector<DynamicObject> objects;
  // Filled only when SlamOptions::report_fates asks for it (pictures of a
  // run): every feature of the frame with its fate, and the labels of the
  // newest segmentation applied to the map (CV_8U, image size: 0 = none, k =
  // the k-th movable instance), null until one is, with its keyframe's stamp.
  std::vector<FeatureView> fates;
  std::shared_ptr<const cv::Mat> semantic_labels;
  Timestamp semantic_stamp;
};

struct TrajectoryPose {
  Timestamp stamp;
  SE3 T_w_c;
  std::uint32_t map_id = 0;  // TrackOutput::map_id
};

struct MapStats {
  std::size_t keyframes = 0;  // in the map (every map)
  std::size_t points = 0;     // in the map
  std::uint32_t maps = 0;     // maps started (1 + new maps after losses); 0 before the first
  std::size_t no_depth_frames = 0;  // frames with too little depth to track (TrackingState::kNoDepth)
  // Relocalised poses refused: their inliers' depth put the camera more than
  // 5 cm along the view from the pose (docs/place-recognition.md).
  int relocalisations_refused = 0;
  // Memory held: keyframes and map points still allocated (culled ones not
  // yet freed included), and tracked frames kept for trajectory().
  std::size_t keyframes_in_memory = 0;
  std::size_t points_in_memory = 0;
  std::size_t trajectory_records = 0;
  int local_ba_runs = 0;
  double local_mapping_ms_total = 0;
  // Frames that waited for local mapping in a young map, and how long in all
  // (MappingOptions::young_map_keyframes; live runs only).
  int young_map_waits = 0;
  double young_map_wait_ms_total = 0;
  int dynamic_points_culled = 0;          // map points removed by the geometry module
  // Place recognition and loop closing (docs/place-recognition.md).
  std::string vocabulary;                 // the file in use; empty: none
  int loops_detected = 0;                 // consistent candidates
  int loops_rejected = 0;                 // of those, failed the geometric check
  int loops_closed = 0;
  // Frames that came back to an older place without a keyframe there, checked
  // for a loop, and of those the loops closed (in loops_closed too).
  int loops_crossings_checked = 0;
  int loops_crossings_closed = 0;
  int global_ba_runs = 0, global_ba_dropped = 0;
  int global_ba_out_of_time = 0;  // of all global BAs, those cut at place.global_ba_max_s
  std::int64_t geometry_deadline_misses = 0;
  // Semantic module (all 0 when it is off).
  int semantic_keyframes_segmented = 0;  // results applied to keyframes
  // Results applied to frames segmented where no keyframe is made
  // (localisation, a place a loaded map holds).
  int semantic_frames_segmented = 0;
  int semantic_frame_regions_known_static = 0;  // of their regions, left alone as below
  int semantic_keyframes_no_colour = 0;  // keyframes from frames without colour (not segmented)
  int semantic_keyframes_dropped = 0;    // left unsegmented: queue full (drop-oldest)
  int semantic_failures = 0;             // segment() errors
  int semantic_features_removed = 0;     // keyframe features dropped inside movable masks
  int semantic_points_removed = 0;       // map points those features had created
  int semantic_points_culled = 0;        // older map points seen mostly inside masks
  int semantic_instances_applied = 0;
  int semantic_instances_unconfirmed = 0;  // needed geometry's agreement and had none
  int semantic_instances_capped = 0;       // over max_removed_fraction without confirmation
  int semantic_instances_followed = 0;     // of the applied: over it, the pose had followed them (other_motion_share)
  int semantic_instances_continued = 0;    // of the applied: kept only by the detector hysteresis (track_*)
  int semantic_instances_known_static = 0;  // left alone: the map had seen their place standing (static_memory_*)
  int semantic_features_on_standing = 0;     // in applied regions, kept: on places seen standing, not seen moving
  std::size_t semantic_sighting_cells = 0;   // 10 cm cells of that memory (saved with the map, loaded with it)
  // Over the most recent 1024 keyframes.
  double semantic_latency_ms_median = 0, semantic_latency_ms_p95 = 0;  // keyframe creation -> mask applied
  double segmentation_ms_median = 0, segmentation_ms_p95 = 0;          // segment() per keyframe
  std::string semantic_model;  // card name and why it was chosen
};

// One keyframe's features as the map holds them (inspection, scoring, tests).
struct KeyFrameFeature {
  float u = 0, v = 0;    // distorted image pixels
  bool mapped = false;   // holds a (live) map point
  bool dynamic = false;  // dropped by the geometry or the semantic module
};

struct KeyFrameView {
  std::int64_t id = 0;
  std::uint32_t map_id = 0;
  Timestamp stamp;
  bool bad = false;        // culled as redundant
  bool segmented = false;  // the semantic module's result was applied
  SE3 T_w_c = SE3::Identity();  // current estimate (a culled keyframe's follows its parent)
  std::vector<KeyFrameFeature> features;
};

}  // namespace stillpoint::slam
