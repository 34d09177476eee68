#include "stillpoint/slam/options.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <functional>
#include <map>
#include <sstream>

#include "stillpoint/core/yaml_file.hpp"
#include "stillpoint/semantic/segmenter.hpp"

namespace stillpoint::slam {

Status TrackingOptions::validate() const {
  if (min_init_features < 20) return Error{"tracking.min_init_features must be >= 20"};
  // A relocalised pose needs at least the support of a tracked one
  // (min_inliers_after_reloc, a tuned constant): the YAML key's range says so.
  if (min_inliers_local_map < 6 || min_inliers_local_map > min_inliers_after_reloc)
    return Error{"tracking.min_inliers_local_map must be in [6, " + std::to_string(min_inliers_after_reloc) + "]"};
  if (!(close_depth_baselines > 0)) return Error{"tracking.close_depth_baselines must be > 0"};
  if (local_keyframes_max < 1) return Error{"tracking.local_keyframes_max must be >= 1"};
  if (relocalisation_candidates < 1) return Error{"tracking.relocalisation_candidates must be >= 1"};
  if (!(new_map_after_lost_s >= 0 && new_map_after_lost_s <= 3600))
    return Error{"tracking.new_map_after_lost_s must be in [0, 3600] (0: never)"};
  if (new_map_min_static_matches < 0) return Error{"tracking.new_map_min_static_matches must be >= 0 (0: off)"};
  if (!(min_depth_share >= 0 && min_depth_share < 1)) return Error{"tracking.min_depth_share must be in [0, 1)"};
  if (trajectory_records < -1) return Error{"tracking.trajectory_records must be >= -1 (-1: every frame)"};
  if (motion_prior_sigma_m < 0) return Error{"tracking.motion_prior_sigma_m must be >= 0 (0: no prior)"};
  if (motion_prior_sigma_deg <= 0) return Error{"tracking.motion_prior_sigma_deg must be > 0"};
  if (!(max_acceleration >= 0)) return Error{"tracking.max_acceleration must be >= 0 (m/s^2; 0: no check)"};
  if (!(max_angular_acceleration > 0)) return Error{"tracking.max_angular_acceleration must be > 0 (deg/s^2)"};
  if (!(max_jump_m >= 0)) return Error{"tracking.max_jump_m must be >= 0"};
  if (!(max_jump_deg >= 0)) return Error{"tracking.max_jump_deg must be >= 0"};
  if (mover_cells_every < 1) return Error{"tracking.mover_cells_every must be >= 1 (1: off)"};
  if (!(mover_cells_min_share >= 0 && mover_cells_min_share <= 1))
    return Error{"tracking.mover_cells_min_share must be in [0, 1]"};
  if (!(mover_cells_radius_px > 0)) return Error{"tracking.mover_cells_radius_px must be > 0"};
  return Status::success();
}

Status KeyframeOptions::validate() const {
  if (!(max_interval_s > 0)) return Error{"keyframes.max_interval_s must be > 0"};
  if (min_interval_frames < 0) return Error{"keyframes.min_interval_frames must be >= 0"};
  if (!(tracked_ratio > 0 && tracked_ratio < 1)) return Error{"keyframes.tracked_ratio must be in (0, 1)"};
  if (close_tracked_min < 0) return Error{"keyframes.close_tracked_min must be >= 0"};
  if (close_untracked_min < 0) return Error{"keyframes.close_untracked_min must be >= 0"};
  if (min_new_points < 0) return Error{"keyframes.min_new_points must be >= 0"};
  return Status::success();
}

Status MappingOptions::validate() const {
  if (ba_iterations < 1 || ba_iterations > 100) return Error{"mapping.ba_iterations must be in 1..100"};
  if (ba_max_keyframes < 2) return Error{"mapping.ba_max_keyframes must be >= 2"};
  if (!(redundant_ratio > 0 && redundant_ratio <= 1)) return Error{"mapping.redundant_ratio must be in (0, 1]"};
  if (redundant_min_observers < 1) return Error{"mapping.redundant_min_observers must be >= 1"};
  if (!(point_found_ratio >= 0 && point_found_ratio < 1)) return Error{"mapping.point_found_ratio must be in [0, 1)"};
  if (young_map_keyframes < 0) return Error{"mapping.young_map_keyframes must be >= 0"};
  if (!(young_map_wait_ms > 0 && young_map_wait_ms <= 1000))
    return Error{"mapping.young_map_wait_ms must be in (0, 1000]"};
  return Status::success();
}

Status GeometryOptions::validate() const {
  if (Status s = clustering.validate(); !s) return s;
  if (Status s = verdict.validate(); !s) return s;
  if (!(deadline_ms > 0 && deadline_ms <= 1000)) return Error{"geometry.deadline_ms must be in (0, 1000]"};
  if (!(point_dynamic_weight > 0 && point_dynamic_weight <= 1))
    return Error{"geometry.point_dynamic_weight must be in (0, 1]"};
  if (!(max_dynamic_fraction > 0 && max_dynamic_fraction <= 1))
    return Error{"geometry.max_dynamic_fraction must be in (0, 1]"};
  if (anchor_frames < 0 || anchor_frames > 30) return Error{"geometry.anchor_frames must be in [0, 30]"};
  if (carried_frames < 1 || carried_frames > 30) return Error{"geometry.carried_frames must be in [1, 30]"};
  if (near_anchor_frames != 0 && (near_anchor_frames < 2 || near_anchor_frames > 30))
    return Error{"geometry.near_anchor_frames must be 0 (off) or in [2, 30]"};
  if (!(consensus_ratio >= 0 && consensus_ratio <= 1)) return Error{"geometry.consensus_ratio must be in [0, 1] (0: off)"};
  if (known_mover_min_rest < 0) return Error{"geometry.known_mover_min_rest must be >= 0"};
  if (consensus_samples < 1 || consensus_samples > 10000)
    return Error{"geometry.consensus_samples must be in [1, 10000]"};
  if (!(lone_moving_chi2 >= 0)) return Error{"geometry.lone_moving_chi2 must be >= 0 (0: off)"};
  if (!(evidence_ratio >= 0 && evidence_ratio <= 1)) return Error{"geometry.evidence_ratio must be in [0, 1]"};
  if (!(evidence_depth_max_m >= 0)) return Error{"geometry.evidence_depth_max_m must be >= 0"};
  if (static_match_margin > 256) return Error{"geometry.static_match_margin must be <= 256 (< 0: off)"};
  if (!(photo_release_ncc >= 0 && photo_release_ncc <= 1)) return Error{"geometry.photo_release_ncc must be in [0, 1] (0: off)"};
  if (!(photo_depth_share >= 0 && photo_depth_share <= 1)) return Error{"geometry.photo_depth_share must be in [0, 1]"};
  if (photo_patch_radius < 1 || photo_patch_radius > 15) return Error{"geometry.photo_patch_radius must be in [1, 15]"};
  if (photo_frames < 1 || photo_frames > 3) return Error{"geometry.photo_frames must be 1, 2 or 3"};
  if (!(photo_one_ncc >= 0 && photo_one_ncc <= 1)) return Error{"geometry.photo_one_ncc must be in [0, 1] (0: off)"};
  if (!(photo_one_others >= 0 && photo_one_others <= 1)) return Error{"geometry.photo_one_others must be in [0, 1]"};
  if (!(photo_detect_share >= 0 && photo_detect_share < 1)) return Error{"geometry.photo_detect_share must be in [0, 1) (0: off)"};
  if (photo_detect_min < 1) return Error{"geometry.photo_detect_min must be >= 1"};
  if (!(photo_detect_gate >= 0 && std::isfinite(photo_detect_gate))) return Error{"geometry.photo_detect_gate must be >= 0"};
  if (photo_frames_back < 1 || photo_frames_back > 30) return Error{"geometry.photo_frames_back must be in [1, 30]"};
  if (freespace_frames < 1 || freespace_frames > 30) return Error{"geometry.freespace_frames must be in [1, 30]"};
  if (!(freespace_flag >= 0 && freespace_flag <= 1)) return Error{"geometry.freespace_flag must be in [0, 1]"};
  if (!(freespace_tolerance_m >= 0)) return Error{"geometry.freespace_tolerance_m must be >= 0"};
  if (!(freespace_tolerance_z2 >= 0)) return Error{"geometry.freespace_tolerance_z2 must be >= 0"};
  if (!(freespace_split_keep >= 0 && freespace_split_keep <= 1))
    return Error{"geometry.freespace_split_keep must be in [0, 1]"};
  if (freespace_split_min_samples < 1) return Error{"geometry.freespace_split_min_samples must be >= 1"};
  if (!(freespace_split_radius_m >= 0)) return Error{"geometry.freespace_split_radius_m must be >= 0"};
  if (!(freespace_split_protect_chi2 >= 0)) return Error{"geometry.freespace_split_protect_chi2 must be >= 0"};
  if (!(freespace_grow_plane_m > 0)) return Error{"geometry.freespace_grow_plane_m must be > 0"};
  if (!(freespace_grow_angle_deg > 0 && freespace_grow_angle_deg < 90))
    return Error{"geometry.freespace_grow_angle_deg must be in (0, 90)"};
  if (probation_frames < 0 || probation_frames > 100) return Error{"geometry.probation_frames must be in [0, 100]"};
  if (probation_min_trusted < 10 || probation_min_trusted > 1000)
    return Error{"geometry.probation_min_trusted must be in [10, 1000]"};
  if (mover_probation_frames < 0 || mover_probation_frames > 1000)
    return Error{"geometry.mover_probation_frames must be in [0, 1000]"};
  return Status::success();
}

Status SemanticOptions::validate() const {
  if (mask_dilation_px < 0 || mask_dilation_px > 100) return Error{"semantic.mask_dilation_px must be in 0..100"};
  if (queue_capacity < 1 || queue_capacity > 1000) return Error{"semantic.queue_capacity must be in 1..1000"};
  if (sequential_latency_frames < 0 || sequential_latency_frames > 1000)
    return Error{"semantic.sequential_latency_frames must be in 0..1000"};
  if (threads < 0 || threads > 64) return Error{"semantic.threads must be in 0..64"};
  if (Status s = semantic::checkDevice(device); !s) return Error{"semantic.device: " + s.error()};
  if (!(min_region_fraction >= 0 && min_region_fraction < 1))
    return Error{"semantic.min_region_fraction must be in [0, 1)"};
  if (!(min_region_confidence >= 0 && min_region_confidence <= 1))
    return Error{"semantic.min_region_confidence must be in [0, 1]"};
  if (!(static_overlap_iou >= 0 && static_overlap_iou <= 1))
    return Error{"semantic.static_overlap_iou must be in [0, 1]"};
  if (confirm_with_geometry != "card" && confirm_with_geometry != "always" && confirm_with_geometry != "never")
    return Error{"semantic.confirm_with_geometry must be 'card', 'always' or 'never'"};
  if (confirm_min_flagged < 1) return Error{"semantic.confirm_min_flagged must be >= 1"};
  if (!(confirm_ratio >= 0 && confirm_ratio <= 1)) return Error{"semantic.confirm_ratio must be in [0, 1]"};
  if (!(max_removed_fraction >= 0 && max_removed_fraction <= 1))
    return Error{"semantic.max_removed_fraction must be in [0, 1]"};
  if (min_kept_points < 0) return Error{"semantic.min_kept_points must be >= 0 (0: off)"};
  if (!(other_motion_share >= 0 && other_motion_share <= 1))
    return Error{"semantic.other_motion_share must be in [0, 1] (0: off)"};
  if (!(point_masked_ratio >= 0 && point_masked_ratio < 1))
    return Error{"semantic.point_masked_ratio must be in [0, 1)"};
  if (!(propagate_grow_px >= 0 && propagate_grow_px <= 200))
    return Error{"semantic.propagate_grow_px must be in [0, 200]"};
  if (propagate_grow_passes < 1 || propagate_grow_passes > 20)
    return Error{"semantic.propagate_grow_passes must be in [1, 20]"};
  if (!(temp_exclusion_px >= 0 && temp_exclusion_px <= 200))
    return Error{"semantic.temp_exclusion_px must be in [0, 200]"};
  if (!(track_score_ratio >= 0 && track_score_ratio <= 1))
    return Error{"semantic.track_score_ratio must be in [0, 1]"};
  if (!(track_iou > 0 && track_iou <= 1)) return Error{"semantic.track_iou must be in (0, 1]"};
  if (track_max_keyframes < 1 || track_max_keyframes > 100)
    return Error{"semantic.track_max_keyframes must be in [1, 100]"};
  if (track_min_hits < 1 || track_min_hits > 100) return Error{"semantic.track_min_hits must be in [1, 100]"};
  if (!(static_memory_score >= 0 && static_memory_score <= 1))
    return Error{"semantic.static_memory_score must be in [0, 1]"};
  if (static_memory_sightings < 0 || static_memory_sightings > 1000)
    return Error{"semantic.static_memory_sightings must be in [0, 1000] (0: off)"};
  if (!(static_memory_span_s >= 0 && static_memory_span_s <= 3600))
    return Error{"semantic.static_memory_span_s must be in [0, 3600]"};
  for (const std::string& d : model_dirs)
    if (d.empty()) return Error{"semantic.model_dirs: empty folder name"};
  return Status::success();
}

Status PlaceOptions::validate() const {
  if (loop_consistency < 1 || loop_consistency > 10) return Error{"place.loop_consistency must be in [1, 10]"};
  if (loop_min_inliers < 12) return Error{"place.loop_min_inliers must be >= 12"};
  if (!(global_ba_max_s > 0 && global_ba_max_s <= 600)) return Error{"place.global_ba_max_s must be in (0, 600]"};
  return Status::success();
}

Status SlamOptions::validate() const {
  for (const Status& s : {orb.validate(), tracking.validate(), keyframes.validate(), mapping.validate(),
                          geometry.validate(), semantic.validate(), place.validate()})
    if (!s) return s;
  return Status::success();
}

namespace {

// The YAML keys: one table drives reading, writing and the reference, so
// they cannot drift apart. Tuned constants are not in it (options.hpp).
template <typename Visitor>
void visitFields(SlamOptions& o, Visitor&& v) {
  v("orb", "num_features", o.orb.num_features, "keypoints per frame over all pyramid levels, 50..20000");
  v("orb", "num_levels", o.orb.num_levels, "scale pyramid levels, 1..16");
  v("orb", "scale_factor", o.orb.scale_factor, "scale between pyramid levels, (1, 2]");
  v("tracking", "min_inliers_local_map", o.tracking.min_inliers_local_map, "map inliers to accept a tracked pose, 6..50");
  v("tracking", "relocalisation_candidates", o.tracking.relocalisation_candidates,
    "keyframes tried per lost frame: the newest N, then N older ones in turn");
  v("tracking", "trajectory_records", o.tracking.trajectory_records,
    "tracked frames kept for the trajectory: -1 all, 0 none, N the last N");
  v("tracking", "new_map_after_lost_s", o.tracking.new_map_after_lost_s,
    "lost this long (s) without relocalising: start a new map, keep the old one (0: never)");
  v("tracking", "min_depth_share", o.tracking.min_depth_share,
    "frames with a smaller share of pixels with depth have no pose (state no_depth), [0, 1)");
  v("keyframes", "max_interval_s", o.keyframes.max_interval_s, "insert a keyframe at least this often (s) while tracking degrades");
  v("mapping", "local_ba", o.mapping.local_ba, "local bundle adjustment after each keyframe");
  v("mapping", "ba_max_keyframes", o.mapping.ba_max_keyframes, "keyframes in the bundle adjustment window, >= 2");
  v("mapping", "keep_culled_keyframes", o.mapping.keep_culled_keyframes,
    "keep culled keyframes in memory for inspection (memory grows); false frees them");
  v("mapping", "dense_views", o.mapping.dense_views,
    "keyframes keep depth and colour at 1/4 resolution (~150 KB each) for the dense static cloud");
  v("geometry", "enabled", o.geometry.enabled, "the geometry module (depth clusters, moving features out of the pose)");
  v("geometry", "clusters", o.geometry.clustering.clusters_at_vga, "K-Means clusters at 640x480, scaled by pixel count, 2..255");
  v("geometry", "deadline_ms", o.geometry.deadline_ms,
    "longest tracking waits for a frame's clusters; a miss tracks the frame without the module");
  v("semantic", "enabled", o.semantic.enabled, "the semantic module (keyframe segmentation, movable objects out of the map)");
  v("semantic", "model_card", o.semantic.model_card, "model card YAML; empty: COCO if its ONNX file is found (with the person model where a map starts), else the person model");
  v("semantic", "model_dirs", o.semantic.model_dirs, "folders searched first for the model file (then $STILLPOINT_MODEL_DIR)");
  v("semantic", "movable_furniture", o.semantic.movable_furniture, "chairs, couches, beds, tables, benches count as movable too");
  v("semantic", "mask_dilation_px", o.semantic.mask_dilation_px, "instance masks grow by this many pixels, 0..100");
  v("semantic", "queue_capacity", o.semantic.queue_capacity,
    "keyframes waiting for segmentation; when full the oldest is left unsegmented");
  v("semantic", "sequential_latency_frames", o.semantic.sequential_latency_frames,
    "sequential mode only: apply each segmentation this many frames late (a live run's delay)");
  v("semantic", "threads", o.semantic.threads, "OpenCV inference threads (0: leave OpenCV's setting)");
  v("semantic", "device", o.semantic.device,
    "cpu, cuda, cuda_fp16, opencl or opencl_fp16: OpenCV dnn's backend and target (the CPU, with a warning, where the build lacks it)");
  v("semantic", "confirm_with_geometry", o.semantic.confirm_with_geometry,
    "card, always or never: whether masks need the geometry module's agreement (card: as the model card says)");
  v("place", "vocabulary", o.place.vocabulary, "vocabulary file (stillpoint-vocab train); empty: the one shipped in models/");
  v("place", "loop_closing", o.place.loop_closing, "detect and close loops in their own thread (needs a vocabulary)");
  v("place", "global_ba", o.place.global_ba, "after a loop, a bundle adjustment of the map in the background (of the 400 keyframes nearest the loop on a larger map; off: the essential graph only); on, tracked frames that come back to an older place without a keyframe there also close loops");
  v("", "sequential", o.sequential, "one thread, deterministic (tests, evaluation)");
  v("", "localisation", o.localisation, "track against a loaded map only: no new keyframes, points or maps");
}

std::string lineOf(const YAML::Node& node) { return "line " + std::to_string(node.Mark().line + 1); }

// Every key of a mapping must be a scalar and appear once: yaml-cpp keeps the
// first of duplicates silently, and a typo'd second value would be ignored.
// `known` maps each key to whether it is a section (a mapping of keys).
std::string checkKeys(const YAML::Node& map, const std::string& prefix, const std::map<std::string, bool>& known) {
  std::map<std::string, bool> seen;
  for (const auto& entry : map) {
    if (!entry.first.IsScalar()) return lineOf(entry.first) + ": keys must be plain names";
    const std::string name = prefix + entry.first.Scalar();
    if (!seen.emplace(name, true).second) return lineOf(entry.first) + ": duplicate field '" + name + "'";
    const auto k = known.find(name);
    if (k == known.end()) return lineOf(entry.first) + ": unknown field '" + name + "'";
    if (!k->second || entry.second.IsNull()) continue;
    if (!entry.second.IsMap()) return lineOf(entry.second) + ": '" + name + "' must be a mapping of keys";
    if (std::string e = checkKeys(entry.second, name + ".", known); !e.empty()) return e;
  }
  return {};
}

template <typename T>
std::string yamlText(const T& value) {
  YAML::Emitter out;
  out.SetDoublePrecision(10);
  out << YAML::Flow << YAML::Node(value);
  const std::string text = out.c_str();
  return text.empty() ? "\"\"" : text;
}

}  // namespace

Result<SlamOptions> loadSlamOptions(const std::string& path) {
  try {
    auto loaded = loadYamlFile(path, "config '" + path + "'");
    if (!loaded) return Error{loaded.error()};
    const YAML::Node root = *loaded;
    SlamOptions options;
    if (root.IsNull()) return options;
    if (!root.IsMap()) return Error{"config '" + path + "': expected a mapping at the top level"};
    std::map<std::string, bool> known;  // key -> is a section
    visitFields(options, [&](const std::string& section, const std::string& key, auto&, const char*) {
      if (!section.empty()) known[section] = true;
      known[section.empty() ? key : section + "." + key] = false;
    });
    if (std::string e = checkKeys(root, "", known); !e.empty()) return Error{"config '" + path + "': " + e};
    std::string error;
    const YAML::Node& croot = root;
    visitFields(options, [&](const std::string& section, const std::string& key, auto& field, const char*) {
      if (!error.empty()) return;
      const YAML::Node sub = section.empty() ? croot : croot[section];
      if (!sub.IsDefined() || !sub.IsMap()) return;  // no such section (checked above)
      const YAML::Node node = sub[key];
      if (!node.IsDefined() || node.IsNull()) return;
      try {
        field = node.as<std::decay_t<decltype(field)>>();
      } catch (const YAML::Exception&) {
        error = "config '" + path + "': " + lineOf(node) + ": field '" + (section.empty() ? key : section + "." + key) +
                "' has the wrong type";
      }
    });
    if (!error.empty()) return Error{error};
    if (Status s = options.validate(); !s) return Error{"config '" + path + "': " + s.error()};
    return options;
  } catch (const std::exception& e) {  // yaml-cpp on input it does not expect: still a bad file, never a crash
    return Error{"config '" + path + "': " + e.what()};
  }
}

std::string toYaml(const SlamOptions& options) {
  SlamOptions copy = options;
  YAML::Node root;
  visitFields(copy, [&](const std::string& section, const std::string& key, auto& field, const char*) {
    if (section.empty())
      root[key] = field;
    else
      root[section][key] = field;
  });
  YAML::Emitter out;
  out.SetDoublePrecision(10);
  out << root;
  return std::string(out.c_str()) + "\n";
}

std::string optionsReference() {
  SlamOptions defaults;
  std::ostringstream out;
  out << "| key | default | meaning |\n|---|---|---|\n";
  visitFields(defaults, [&](const std::string& section, const std::string& key, auto& field, const char* meaning) {
    out << "| `" << (section.empty() ? key : section + "." + key) << "` | `" << yamlText(field) << "` | " << meaning
        << " |\n";
  });
  return out.str();
}

}  // namespace stillpoint::slam
