#pragma once
// Options of the SLAM core, one plain struct per module, loaded from one YAML
// file (config/slam.yaml; docs/configuration.md lists the keys). validate()
// names the offending field.
//
// Two tiers of fields:
// - settings a user changes, read from YAML (marked "YAML" below; the table
//   in options.cpp names each key once, for reading, writing and the docs);
// - tuned constants, not read from YAML: named defaults with the reason for
//   their value; tests and experiments set them in code to isolate a cue.
//   The measurements behind them: docs/dynamic-objects.md, docs/decisions.md.
#include <string>
#include <vector>

#include "stillpoint/core/result.hpp"
#include "stillpoint/features/orb_extractor.hpp"
#include "stillpoint/geometry/depth_clustering.hpp"
#include "stillpoint/geometry/dynamic_clusters.hpp"

namespace stillpoint::slam {

struct TrackingOptions {
  int min_inliers_local_map = 30;      // YAML: map inliers to accept a tracked pose
  int relocalisation_candidates = 30;  // YAML: keyframes tried per lost frame (newest N, then N older in turn)
  int trajectory_records = -1;         // YAML: tracked frames kept for the trajectory: -1 all, 0 none, N the last N
  // YAML: lost this long (s, frame stamps; frames without depth before the
  // loss included) with relocalisation failing, tracking starts a new map at
  // the next frame that can start one and keeps the old map (0: never).
  double new_map_after_lost_s = 1.0;
  // Sooner (not in YAML): at a lost frame whose matches to the last frame
  // agree with the camera's motion before the loss this many times, a
  // static view a map can stand on, the mover that caused the loss left out
  // (0: only after new_map_after_lost_s). Relocalisation failed on it.
  int new_map_min_static_matches = 100;
  // YAML: a frame whose share of pixels with valid depth is below this has
  // no pose and the state kNoDepth (a covered or blinded camera).
  double min_depth_share = 0.02;
  int min_init_features = 300;         // keypoints with depth needed to start a map
  int min_inliers_after_reloc = 50;    // a relocalised pose needs more support than a tracked one
  double close_depth_baselines = 40.0; // "close" points (depth < this x baseline): ORB-SLAM2's stereo rule
  int local_keyframes_max = 60;        // local map size: bounds the projection search per frame
  // Stage 1: the motion model's prediction is a prior of this sigma per frame
  // (m, degrees): a mover near the camera cannot drag the first pose (0: none).
  double motion_prior_sigma_m = 0.002;
  double motion_prior_sigma_deg = 1.0;
  // A tracked frame whose pose departs from the last steady frames' motion
  // carried on (from the last frame, and from the one before it) by more than
  // max_jump_m + max_acceleration dt^2 / 2 (m/s^2) in position, or
  // max_jump_deg + max_angular_acceleration dt^2 / 2 (deg/s^2) in rotation,
  // dt since the frame predicted from, has no pose: no camera moves so
  // (10 m/s^2 is 1 g, a hand-held camera's true departure from its motion
  // carried on is at most 1 cm a frame on the excerpt), the pose rests on
  // wrong matches. Tracking goes on from the last frame, as after a blind
  // one (0: no check; docs/pose-health.md). The jumps cover the noise of a
  // velocity taken from two poses (at most 1.1 cm and 1.3 degrees at 30 Hz
  // on the excerpt).
  double max_acceleration = 10.0;
  double max_angular_acceleration = 3000.0;
  double max_jump_m = 0.03;
  double max_jump_deg = 3.0;
  // After a frame with at least min_share dynamic features, the ORB cells
  // within radius_px of them (at 640 px width) get `every` times fewer
  // features: a mover filling 40 % of the view would take 40 % of the budget.
  int mover_cells_every = 2;  // 1: off
  double mover_cells_min_share = 0.2;
  double mover_cells_radius_px = 32;
  Status validate() const;
};

struct KeyframeOptions {
  double max_interval_s = 1.0;  // YAML: insert at least this often while tracking degrades
  int min_interval_frames = 0;  // frames between keyframes at least (0: as the mapper keeps up)
  // Insert when tracked / reference-keyframe points falls below: frequent
  // keyframes are what accuracy on real data follows (0.4: 0.0111 m, 0.6: 0.0086 m).
  double tracked_ratio = 0.6;
  int close_tracked_min = 100;    // ...or fewer keypoints with depth than this are tracked
  int close_untracked_min = 70;   // ...while this many with depth could be added
  // A new keyframe maps at least this many points, nearest first: far
  // structure pins the rotation (100: 0.0082 m on the excerpt, 500: 0.0049 m).
  int min_new_points = 500;
  Status validate() const;
};

struct MappingOptions {
  bool local_ba = true;                // YAML: local bundle adjustment after each keyframe
  int ba_max_keyframes = 20;           // YAML: the optimised window (best covisible keyframes)
  bool keep_culled_keyframes = false;  // YAML: keep culled keyframes in memory (inspection); false frees them
  // YAML: keyframes keep their depth and colour at a quarter of the
  // resolution (about 150 KB each) for the dense static cloud
  // (SlamSystem::exportDenseCloud).
  bool dense_views = false;
  int ba_iterations = 10;              // Levenberg-Marquardt iterations per local bundle adjustment, 1..100
  double redundant_ratio = 0.9;        // keyframe culling: this share of its points seen by 3 others
  int redundant_min_observers = 3;
  double point_found_ratio = 0.25;     // a new point found in fewer of the frames that saw it is culled
  // Live: while the map being extended holds at most this many keyframes,
  // tracking waits for local mapping to finish each new keyframe before it
  // takes the next frame, as a sequential run does (0: never waits). A young
  // map makes a keyframe every frame or two, each one cuts the running
  // bundle adjustment short, and the next frames are then tracked on points
  // and poses no adjustment has refined; a mover filling the view there
  // decides whether the map follows it (docs/architecture.md, "Queues").
  // Tuned, not read from YAML.
  int young_map_keyframes = 6;
  double young_map_wait_ms = 100.0;  // the longest wait per keyframe, (0, 1000]
  Status validate() const;
};

// The geometry module: two-stage tracking that drops the features of depth
// clusters moving against the initial pose (docs/dynamic-objects.md).
struct GeometryOptions {
  bool enabled = true;                     // YAML: the module on (stillpoint-replay --modules overrides)
  geometry::ClusteringOptions clustering;  // YAML: clusters (clusters_at_vga); the rest tuned
  geometry::DynamicClusterOptions verdict;
  double deadline_ms = 10.0;  // YAML: longest tracking waits for the clusters; a miss tracks the frame without the module
  // A map point whose recent observations (each new one weighted this much)
  // lie mostly in dynamic clusters is culled.
  double point_dynamic_weight = 0.5;
  // Evidence baseline: features are matched (no search window) to the frame
  // this many back; a mover's error grows with the baseline, a static
  // point's does not (0: stage-1 matches only).
  int anchor_frames = 5;
  // Carried evidence is judged against the oldest position of its chain of
  // moving matches, this many frames back at most, chi2 over the links.
  int carried_frames = 3;
  // A cluster with too few anchor matches is matched to the frames this
  // many, ..., 2 back (0: off; else 2..30).
  int near_anchor_frames = 3;
  // A feature of a cluster too small to judge, matched to a mover and
  // disagreeing with the pose above this chi2, is moving (0: off).
  double lone_moving_chi2 = 3.0;
  // The view veto: more than this share of the view dynamic means the pose
  // is wrong, not the world (anchor evidence, free space, photometric cues).
  double max_dynamic_fraction = 0.6;
  // Known movers (clusters most of whose anchor matches were found moving
  // before) do not vote for the consensus pose, and the view veto is applied
  // to the rest of the judged view when that holds at least this many judged
  // features: a mover grown to fill the view is not a wrong pose (0: off, the
  // veto counts the whole view).
  int known_mover_min_rest = 20;
  // The frame is judged under the pose that best explains the anchor matches
  // when its truncated cost is below this share of the initial pose's: a
  // slowly starting mover leaves a compromise both it and the room pass (0: off).
  double consensus_ratio = 0.9;
  int consensus_samples = 48;  // three-match hypotheses per frame
  // A projection match is evidence only when its distance is at most this
  // share of the window's second best: repetitive texture mismatches (0: all).
  double evidence_ratio = 0.8;
  // Depth at or beyond this is no evidence: far sensor depth is off by
  // decimetres between frames; 3.2 m is 40 baselines (0: no limit).
  double evidence_depth_max_m = 3.2;
  // Disagreeing evidence is dropped when a keypoint where the point projects
  // matches it within this many bits of the matched one (another copy of a
  // repeating pattern; < 0: off).
  int static_match_margin = 10;
  // The photometric test: a dropped feature whose patch, warped by its depth
  // into the frames photo_frames_back, half and a quarter as many back under
  // the pose fitted without the dynamic clusters, matches there (NCC above
  // photo_release_ncc, depth agreeing on photo_depth_share of its pixels) is
  // static (0: off).
  double photo_release_ncc = 0.6;
  double photo_depth_share = 0.9;
  int photo_patch_radius = 4;  // (2r+1)^2 pixels, 1..15
  int photo_frames = 3;        // 1..3: a self-similar mover matches by chance in one frame, seldom in all
  double photo_one_ncc = 0.3;  // one frame of three may be this low when the others are above photo_one_others
  double photo_one_others = 0.65;
  // Photometric detection: a cluster with too few anchor matches, more than
  // photo_detect_share of whose depth-agreeing patches fail the test (at
  // least photo_detect_min tested), is dynamic; clusters at or below
  // photo_detect_gate x the frame's reference score are not tested (0: off).
  double photo_detect_share = 0.8;
  int photo_detect_min = 4;
  double photo_detect_gate = 1.0;
  bool photo_release_memory = true;    // freed features still pass on their cluster's memory
  bool photo_release_anchored = true;  // features with an anchor match may be freed too
  int photo_frames_back = 10;          // 1..30: the further back, the slower the movers told apart
  bool photo_fallback = true;          // a patch leaving the image that far back is tested at half the distance
  // Free space: depth samples in front of what the frame freespace_frames
  // back saw along the same ray (by more than tolerance_m + tolerance_z2 z^2).
  double freespace_tolerance_m = 0.03;
  double freespace_tolerance_z2 = 0.02;
  int freespace_frames = 5;       // 1..30 (10 and 15: no better)
  double freespace_flag = 0.2;    // a cluster with this share of its samples there is dynamic (0: off)
  // A dynamic cluster holding violations but fewer than this share of its
  // features on the surface grown from them is split: the features off it
  // whose own evidence agrees are static (a walker and the floor; 0: off).
  double freespace_split_keep = 0.8;
  double freespace_grow_plane_m = 0.02;    // growth: neighbours within plane_m (1 + z^2) of the tangent plane
  double freespace_grow_angle_deg = 30.0;  // ...and normals within this angle
  double freespace_split_radius_m = 0.1;   // a feature this near the grown surface is on it
  int freespace_split_min_samples = 4;     // isolated violations are depth noise
  double freespace_split_protect_chi2 = 7.815;  // a feature off the surface whose evidence exceeds this stays moving
  // New map points stay out of pose fits until matched this many frames
  // consistently with a pose fitted without them, while probation_min_trusted
  // other matches remain: a mover mapped unflagged cannot drag the pose (0: off).
  // probation_min_trusted also bounds the semantic module's hold on the
  // points of keyframes whose segmentation is under way.
  int probation_frames = 3;
  int probation_min_trusted = 30;
  // Points made on a known mover (a person who stopped) serve this many
  // frames instead: a mover that stands still for a moment must not hold the
  // pose when it walks on. When fewer than probation_min_trusted other
  // matches remain, every other held point joins the fit, and these only as
  // many as are still missing, fewest frames to go first.
  int mover_probation_frames = 15;
  // Diagnostics, built only when asked for: every judged feature with its
  // evidence in GeometryOutput::judged (stillpoint-replay --features-out, tests).
  bool report_features = false;
  Status validate() const;
};

// The semantic module: keyframes are segmented in their own thread and their
// features on movable objects leave the map (docs/dynamic-objects.md).
struct SemanticOptions {
  bool enabled = false;  // YAML: the module on (stillpoint-replay --modules overrides)
  // YAML: model card; "" = the recommended model (COCO when its ONNX file is
  // found in model_dirs / $STILLPOINT_MODEL_DIR, with the in-tree person model
  // consulted where a map starts; else the in-tree person model alone). A
  // relative path not found from the working directory is looked
  // up in the project's models/ folder.
  std::string model_card;
  std::vector<std::string> model_dirs;  // YAML: folders searched first for the card's model file
  bool movable_furniture = false;       // YAML: chairs, couches, ... count as movable too
  int mask_dilation_px = 5;             // YAML: instance masks grow by this much, 0..100
  // YAML: keyframes waiting for segmentation; full, the oldest is left
  // unsegmented (drop-oldest: tracking never waits). 1: masks stay fresh.
  int queue_capacity = 1;
  // YAML, sequential mode only (evaluation): apply each segmentation this many
  // frames late, a live run's delay modelled deterministically (0: at once).
  int sequential_latency_frames = 0;
  int threads = 1;  // YAML: OpenCV inference threads (process-wide in OpenCV; 0: leave as is)
  // YAML: where inference runs (semantic::SegmenterOptions::device): cpu,
  // cuda, cuda_fp16, opencl or opencl_fp16; the CPU, with a warning, where the
  // OpenCV build cannot.
  std::string device = "cpu";
  // YAML: masks need the geometry module's agreement: "card" (as the model
  // card says), "always" or "never".
  std::string confirm_with_geometry = "card";
  // Segmenter post-filter (lib/semantic/README.md).
  double min_region_fraction = 0.001;
  double min_region_confidence = 0.0;
  double static_overlap_iou = 0.6;
  bool depth_agreement = true;  // cut mask pixels far from their instance's median depth
  // A confirmed instance: the geometry module flagged at least this many of
  // its features and this share of its judged ones (0.3 let a teddy bear through).
  int confirm_min_flagged = 3;
  double confirm_ratio = 0.7;
  // Share of a keyframe's map points unconfirmed masks may remove: a false
  // positive must not empty the map. They may remove more while at least
  // min_kept_points of those points stay outside them (0: the share alone):
  // a person filling most of the view near the camera leaves the rest of
  // the view enough to track on, and a map start needs no more
  // (tracking.new_map_min_static_matches).
  double max_removed_fraction = 0.5;
  int min_kept_points = 100;
  // ...unless the geometry module took the region for the world: it flags at
  // least this share of the judged features outside every region, and a
  // larger one than of the region's own (0: the cap always holds).
  double other_motion_share = 0.25;
  // A map point seen in masks by more than this share of its segmented keyframes is culled.
  double point_masked_ratio = 0.5;
  // Frames between keyframes keep out the features matching the newest
  // segmented keyframe's masked ones (a masked object keeps moving), grown
  // over their surface (propagate_grow_px, passes), and first the features
  // matching the last frame's flagged ones.
  bool propagate_masks = true;
  float propagate_grow_px = 16.0f;  // 0: matches only
  int propagate_grow_passes = 3;
  bool propagate_from_last = true;
  // Last-frame features with two flagged ones within this radius at their
  // depth lend no temporary point: the unflagged rest of a masked object (0: off).
  float temp_exclusion_px = 24.0f;
  // With the geometry module: in the geometry.mover_probation_frames frames
  // after the last masks, a frame no mask marks gives the points it makes in
  // or next to the 10 cm cell of a feature those masks kept out a mover's
  // probation (the segmenter may stop finding a mover that is still there).
  bool probation_after_masks = true;
  // Detector hysteresis (instance models): after a keyframe that kept a
  // movable instance, a detection overlapping it (IoU >= track_iou) at
  // track_score_ratio x the card's threshold is kept too, for at most
  // track_max_keyframes keyframes, for tracks seen strongly track_min_hits
  // times. 0: off. track_any_class: a detection of another class may continue
  // it too (COCO sometimes calls a person in front of a teddy bear "teddy
  // bear"); off, because the teddy bear the person stands behind is
  // labelled on the person's box as confidently, and its mask then held the
  // static bear out of tracking (docs/dynamic-objects.md).
  double track_score_ratio = 0.5;
  double track_iou = 0.3;
  int track_max_keyframes = 8;
  int track_min_hits = 2;
  bool track_any_class = false;
  // What the map has seen standing (with the geometry module): a feature of
  // a segmented keyframe on an instance of a static class scoring at least
  // static_memory_score is a static sighting of its place (10 cm cells). A
  // region of a movable class most of whose features lie where static
  // objects were seen in at least static_memory_sightings keyframes over at
  // least static_memory_span_s, and more often than movers, is that static
  // object under another label (COCO calls the teddy bear a person beside a
  // person) and is left alone, unless the geometry module confirms it moving
  // (0 sightings: off).
  double static_memory_score = 0.5;
  int static_memory_sightings = 2;
  double static_memory_span_s = 2.0;
  Status validate() const;
};

// Place recognition (a vocabulary of binary words: relocalisation, map
// merging) and loop closing (docs/place-recognition.md).
struct PlaceOptions {
  // YAML: the vocabulary file (stillpoint-vocab train); empty: the one
  // shipped in models/ (defaultVocabularyPath()). Without one, relocalisation
  // and map merging rank keyframes by small views and loops are not closed.
  std::string vocabulary;
  bool loop_closing = true;  // YAML: close loops in their own thread (pose graph, then a global BA)
  // YAML: a bundle adjustment of the map in the background after each loop
  // (its depth weighed as disparity; the 400 keyframes nearest the loop on a
  // larger map). On the generated room's lap and a half it makes the
  // trajectory 2-4 times better, live as well as sequential; on the real
  // excerpt played there and back it costs 0.0001-0.0002 m
  // (docs/place-recognition.md). On, tracked frames that come back to an
  // older place without a keyframe there close loops too (crossings): with
  // the essential graph alone their correction did not pay.
  bool global_ba = true;
  // Tuned (not in YAML): in threaded runs a global BA stops after this many
  // seconds with the best map it found (each accepted step lowers the cost);
  // it shares local mapping's core. Sequential runs stop at the iterations
  // alone, so that they stay deterministic.
  double global_ba_max_s = 3.0;
  // Tuned (not in YAML): a loop candidate must be confirmed by this many
  // consecutive keyframes (covisibility consistency), and its rigid motion
  // must explain this many 3D-3D matches and find as many map points.
  int loop_consistency = 3;
  int loop_min_inliers = 40;
  Status validate() const;
};

struct SlamOptions {
  features::OrbOptions orb;  // YAML: num_features, num_levels, scale_factor; the rest tuned
  TrackingOptions tracking;
  KeyframeOptions keyframes;
  MappingOptions mapping;
  GeometryOptions geometry;
  SemanticOptions semantic;
  PlaceOptions place;
  bool sequential = false;  // YAML: one thread, deterministic (tests, evaluation)
  // YAML: track against a loaded map only (SlamSystem::loadMap): no keyframe,
  // no map point and no new map is made, so memory stays as loaded; a lost
  // frame tries relocalisation until the camera sees the map again.
  bool localisation = false;
  // Diagnostics, built only when asked for: TrackOutput::fates and
  // TrackOutput::semantic_labels (stillpoint-replay --render).
  bool report_fates = false;
  Status validate() const;
};

// The vocabulary shipped with stillpoint (models/ in the source tree, else
// the installed copy); place.vocabulary empty means this one.
std::string defaultVocabularyPath();

// Reads options from a YAML file; unknown keys, duplicate keys and bad values
// are errors naming the file, line and key.
Result<SlamOptions> loadSlamOptions(const std::string& path);
// Writes the YAML keys back (round trip; --print-config).
std::string toYaml(const SlamOptions& options);
// The YAML keys as a Markdown table: key, default, meaning (docs/configuration.md).
std::string optionsReference();

}  // namespace stillpoint::slam
