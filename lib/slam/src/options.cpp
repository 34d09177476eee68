#include "stillpoint/slam/options.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <functional>
#include <map>
#include <sstream>

namespace stillpoint::slam {

Status TrackingOptions::validate() const {
  if (min_init_features < 20) return Error{"tracking.min_init_features must be >= 20"};
  if (min_inliers_local_map < 6) return Error{"tracking.min_inliers_local_map must be >= 6"};
  if (min_inliers_after_reloc < min_inliers_local_map)
    return Error{"tracking.min_inliers_after_reloc must be >= tracking.min_inliers_local_map"};
  if (!(close_depth_baselines > 0)) return Error{"tracking.close_depth_baselines must be > 0"};
  if (local_keyframes_max < 1) return Error{"tracking.local_keyframes_max must be >= 1"};
  if (relocalisation_candidates < 1) return Error{"tracking.relocalisation_candidates must be >= 1"};
  if (trajectory_records < -1) return Error{"tracking.trajectory_records must be >= -1 (-1: every frame)"};
  if (motion_prior_sigma_m < 0) return Error{"tracking.motion_prior_sigma_m must be >= 0 (0: no prior)"};
  if (motion_prior_sigma_deg <= 0) return Error{"tracking.motion_prior_sigma_deg must be > 0"};
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
  return Status::success();
}

Status SemanticOptions::validate() const {
  if (mask_dilation_px < 0 || mask_dilation_px > 100) return Error{"semantic.mask_dilation_px must be in 0..100"};
  if (queue_capacity < 1 || queue_capacity > 1000) return Error{"semantic.queue_capacity must be in 1..1000"};
  if (sequential_latency_frames < 0 || sequential_latency_frames > 1000)
    return Error{"semantic.sequential_latency_frames must be in 0..1000"};
  if (threads < 0 || threads > 64) return Error{"semantic.threads must be in 0..64"};
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
  for (const std::string& d : model_dirs)
    if (d.empty()) return Error{"semantic.model_dirs: empty folder name"};
  return Status::success();
}

Status SlamOptions::validate() const {
  for (const Status& s : {orb.validate(), tracking.validate(), keyframes.validate(), mapping.validate(),
                          geometry.validate(), semantic.validate()})
    if (!s) return s;
  return Status::success();
}

namespace {

// One table drives both reading and writing, so the two cannot drift apart.
template <typename Visitor>
void visitFields(SlamOptions& o, Visitor&& v) {
  v("orb", "num_features", o.orb.num_features);
  v("orb", "num_levels", o.orb.num_levels);
  v("orb", "scale_factor", o.orb.scale_factor);
  v("orb", "fast_threshold", o.orb.fast_threshold);
  v("orb", "min_fast_threshold", o.orb.min_fast_threshold);
  v("orb", "cell_size", o.orb.cell_size);
  v("tracking", "min_init_features", o.tracking.min_init_features);
  v("tracking", "min_inliers_local_map", o.tracking.min_inliers_local_map);
  v("tracking", "min_inliers_after_reloc", o.tracking.min_inliers_after_reloc);
  v("tracking", "close_depth_baselines", o.tracking.close_depth_baselines);
  v("tracking", "local_keyframes_max", o.tracking.local_keyframes_max);
  v("tracking", "relocalisation_candidates", o.tracking.relocalisation_candidates);
  v("tracking", "trajectory_records", o.tracking.trajectory_records);
  v("tracking", "motion_prior_sigma_m", o.tracking.motion_prior_sigma_m);
  v("tracking", "motion_prior_sigma_deg", o.tracking.motion_prior_sigma_deg);
  v("tracking", "mover_cells_every", o.tracking.mover_cells_every);
  v("tracking", "mover_cells_min_share", o.tracking.mover_cells_min_share);
  v("tracking", "mover_cells_radius_px", o.tracking.mover_cells_radius_px);
  v("keyframes", "max_interval_s", o.keyframes.max_interval_s);
  v("keyframes", "min_interval_frames", o.keyframes.min_interval_frames);
  v("keyframes", "tracked_ratio", o.keyframes.tracked_ratio);
  v("keyframes", "close_tracked_min", o.keyframes.close_tracked_min);
  v("keyframes", "close_untracked_min", o.keyframes.close_untracked_min);
  v("keyframes", "min_new_points", o.keyframes.min_new_points);
  v("mapping", "local_ba", o.mapping.local_ba);
  v("mapping", "ba_iterations", o.mapping.ba_iterations);
  v("mapping", "ba_max_keyframes", o.mapping.ba_max_keyframes);
  v("mapping", "redundant_ratio", o.mapping.redundant_ratio);
  v("mapping", "redundant_min_observers", o.mapping.redundant_min_observers);
  v("mapping", "point_found_ratio", o.mapping.point_found_ratio);
  v("mapping", "keep_culled_keyframes", o.mapping.keep_culled_keyframes);
  v("geometry", "enabled", o.geometry.enabled);
  v("geometry", "clusters", o.geometry.clustering.clusters_at_vga);
  v("geometry", "sample_step", o.geometry.clustering.sample_step_at_vga);
  v("geometry", "kmeans_iterations", o.geometry.clustering.max_iterations);
  v("geometry", "kmeans_converged_fraction", o.geometry.clustering.converged_fraction);
  v("geometry", "warm_start", o.geometry.clustering.warm_start);
  v("geometry", "freespace_tolerance_m", o.geometry.freespace_tolerance_m);
  v("geometry", "freespace_tolerance_z2", o.geometry.freespace_tolerance_z2);
  v("geometry", "freespace_frames", o.geometry.freespace_frames);
  v("geometry", "freespace_flag", o.geometry.freespace_flag);
  v("geometry", "freespace_split_keep", o.geometry.freespace_split_keep);
  v("geometry", "freespace_grow_plane_m", o.geometry.freespace_grow_plane_m);
  v("geometry", "freespace_grow_angle_deg", o.geometry.freespace_grow_angle_deg);
  v("geometry", "freespace_split_radius_m", o.geometry.freespace_split_radius_m);
  v("geometry", "freespace_split_min_samples", o.geometry.freespace_split_min_samples);
  v("geometry", "freespace_split_protect_chi2", o.geometry.freespace_split_protect_chi2);
  v("geometry", "rho_cap", o.geometry.verdict.rho_cap);
  v("geometry", "min_features", o.geometry.verdict.min_features);
  v("geometry", "reference_quantile", o.geometry.verdict.reference_quantile);
  v("geometry", "relative_factor", o.geometry.verdict.relative_factor);
  v("geometry", "absolute_floor", o.geometry.verdict.absolute_floor);
  v("geometry", "ceiling_fraction", o.geometry.verdict.ceiling_fraction);
  v("geometry", "hold_fraction", o.geometry.verdict.hold_fraction);
  v("geometry", "hold_factor", o.geometry.verdict.hold_factor);
  v("geometry", "hold_floor", o.geometry.verdict.hold_floor);
  v("geometry", "deadline_ms", o.geometry.deadline_ms);
  v("geometry", "point_dynamic_weight", o.geometry.point_dynamic_weight);
  v("geometry", "anchor_frames", o.geometry.anchor_frames);
  v("geometry", "carried_frames", o.geometry.carried_frames);
  v("geometry", "near_anchor_frames", o.geometry.near_anchor_frames);
  v("geometry", "lone_moving_chi2", o.geometry.lone_moving_chi2);
  v("geometry", "max_dynamic_fraction", o.geometry.max_dynamic_fraction);
  v("geometry", "consensus_ratio", o.geometry.consensus_ratio);
  v("geometry", "consensus_samples", o.geometry.consensus_samples);
  v("geometry", "evidence_ratio", o.geometry.evidence_ratio);
  v("geometry", "evidence_depth_max_m", o.geometry.evidence_depth_max_m);
  v("geometry", "static_match_margin", o.geometry.static_match_margin);
  v("geometry", "photo_release_ncc", o.geometry.photo_release_ncc);
  v("geometry", "photo_depth_share", o.geometry.photo_depth_share);
  v("geometry", "photo_patch_radius", o.geometry.photo_patch_radius);
  v("geometry", "photo_frames", o.geometry.photo_frames);
  v("geometry", "photo_one_ncc", o.geometry.photo_one_ncc);
  v("geometry", "photo_one_others", o.geometry.photo_one_others);
  v("geometry", "photo_detect_share", o.geometry.photo_detect_share);
  v("geometry", "photo_detect_min", o.geometry.photo_detect_min);
  v("geometry", "photo_detect_gate", o.geometry.photo_detect_gate);
  v("geometry", "photo_release_memory", o.geometry.photo_release_memory);
  v("geometry", "photo_release_anchored", o.geometry.photo_release_anchored);
  v("geometry", "photo_frames_back", o.geometry.photo_frames_back);
  v("geometry", "photo_fallback", o.geometry.photo_fallback);
  v("geometry", "probation_frames", o.geometry.probation_frames);
  v("geometry", "probation_min_trusted", o.geometry.probation_min_trusted);
  v("semantic", "enabled", o.semantic.enabled);
  v("semantic", "model_card", o.semantic.model_card);
  v("semantic", "model_dirs", o.semantic.model_dirs);
  v("semantic", "movable_furniture", o.semantic.movable_furniture);
  v("semantic", "mask_dilation_px", o.semantic.mask_dilation_px);
  v("semantic", "queue_capacity", o.semantic.queue_capacity);
  v("semantic", "sequential_latency_frames", o.semantic.sequential_latency_frames);
  v("semantic", "threads", o.semantic.threads);
  v("semantic", "min_region_fraction", o.semantic.min_region_fraction);
  v("semantic", "min_region_confidence", o.semantic.min_region_confidence);
  v("semantic", "static_overlap_iou", o.semantic.static_overlap_iou);
  v("semantic", "depth_agreement", o.semantic.depth_agreement);
  v("semantic", "confirm_with_geometry", o.semantic.confirm_with_geometry);
  v("semantic", "confirm_min_flagged", o.semantic.confirm_min_flagged);
  v("semantic", "confirm_ratio", o.semantic.confirm_ratio);
  v("semantic", "max_removed_fraction", o.semantic.max_removed_fraction);
  v("semantic", "point_masked_ratio", o.semantic.point_masked_ratio);
  v("semantic", "propagate_masks", o.semantic.propagate_masks);
  v("semantic", "propagate_grow_px", o.semantic.propagate_grow_px);
  v("semantic", "propagate_grow_passes", o.semantic.propagate_grow_passes);
  v("semantic", "propagate_from_last", o.semantic.propagate_from_last);
  v("semantic", "temp_exclusion_px", o.semantic.temp_exclusion_px);
  v("semantic", "track_score_ratio", o.semantic.track_score_ratio);
  v("semantic", "track_iou", o.semantic.track_iou);
  v("semantic", "track_max_keyframes", o.semantic.track_max_keyframes);
  v("semantic", "track_min_hits", o.semantic.track_min_hits);
  v("semantic", "track_any_class", o.semantic.track_any_class);
  v("", "sequential", o.sequential);
}

}  // namespace

Result<SlamOptions> loadSlamOptions(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    return Error{"config '" + path + "': cannot be opened"};
  } catch (const YAML::Exception& e) {
    return Error{"config '" + path + "': line " + std::to_string(e.mark.line + 1) + ": " + e.msg};
  }
  SlamOptions options;
  if (root.IsNull()) return options;
  if (!root.IsMap()) return Error{"config '" + path + "': expected a mapping at the top level"};
  std::map<std::string, bool> known;
  std::string error;
  visitFields(options, [&](const std::string& section, const std::string& key, auto& field) {
    known[section.empty() ? key : section + "." + key] = true;
    if (!error.empty()) return;
    const YAML::Node& croot = root;
    auto lookup = [&]() -> YAML::Node {
      if (section.empty()) return croot[key];
      const YAML::Node sub = croot[section];
      if (!sub.IsDefined() || !sub.IsMap()) return YAML::Node(YAML::NodeType::Undefined);
      return sub[key];
    };
    const YAML::Node node = lookup();
    if (!node.IsDefined() || node.IsNull()) return;
    try {
      field = node.as<std::decay_t<decltype(field)>>();
    } catch (const YAML::Exception&) {
      error = "config '" + path + "': line " + std::to_string(node.Mark().line + 1) + ": field '" +
              (section.empty() ? key : section + "." + key) + "' has the wrong type";
    }
  });
  if (!error.empty()) return Error{error};
  for (const auto& top : root) {
    const std::string name = top.first.as<std::string>();
    if (top.second.IsMap()) {
      for (const auto& sub : top.second) {
        const std::string full = name + "." + sub.first.as<std::string>();
        if (!known.count(full))
          return Error{"config '" + path + "': line " + std::to_string(sub.first.Mark().line + 1) +
                       ": unknown field '" + full + "'"};
      }
    } else if (!known.count(name)) {
      return Error{"config '" + path + "': line " + std::to_string(top.first.Mark().line + 1) +
                   ": unknown field '" + name + "'"};
    }
  }
  if (Status s = options.validate(); !s) return Error{"config '" + path + "': " + s.error()};
  return options;
}

std::string toYaml(const SlamOptions& options) {
  SlamOptions copy = options;
  YAML::Node root;
  visitFields(copy, [&](const std::string& section, const std::string& key, auto& field) {
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

}  // namespace stillpoint::slam
