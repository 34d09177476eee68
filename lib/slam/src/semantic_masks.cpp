// The semantic module's masks, in one place: how a segmented keyframe's
// masks change the map (local mapping's thread, LocalMapper::applySemantic),
// and how they follow their objects into the frames between keyframes
// (tracking's thread, Tracker::markSemanticMovers).
#include <algorithm>

#include "local_mapping.hpp"
#include "matcher.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/geometry/rules.hpp"
#include "tracking.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("semantic");
// Feature j of `to` was found as feature i of `from`: it takes its class.
void copyMovableClass(const Frame& from, int i, Frame* to, int j) {
  if (from.movable_class.empty() || from.movable_class[i] == 0) return;
  to->movable_class.resize(to->size(), 0);
  to->movable_class[j] = from.movable_class[i];
}

}  // namespace

std::pair<std::shared_ptr<const cv::Mat>, Timestamp> LocalMapper::latestSemanticLabels() const {
  std::lock_guard lock(labels_mutex_);
  return {latest_labels_, latest_labels_stamp_};
}

void LocalMapper::applySemantic(const SemanticResult& r) {
  SemanticStats& st = semantic_stats_;
  st.segment_ms.add(r.segment_ms);
  map_->maskResolved(r.keyframe_id);  // whatever follows, its points wait no longer
  if (!r.ok) {
    ++st.failures;
    SP_WARN(logger, "keyframe " << r.keyframe_id << ": segmentation failed: " << r.error);
    return;
  }
  KeyFrame* kf = map_->keyFrame(r.keyframe_id);
  // Culled meanwhile (freed, or bad and about to be): nothing to apply. A bad
  // keyframe must not be touched: updateConnections() would link it back into
  // its neighbours, which then hold it after it is freed.
  if (!kf || kf->bad || kf->segmented) return;
  Frame& f = kf->frame;
  const int n_regions = static_cast<int>(r.regions.size());

  // Per region: its features, how many carry a live map point, and what the
  // geometry module said about them in this keyframe (before we touch `dynamic`).
  std::vector<std::vector<int>> members(n_regions);
  std::vector<int> with_point(n_regions, 0), flagged(n_regions, 0), judged(n_regions, 0);
  std::vector<int> region_of(f.size(), 0);
  int points_before = 0;
  for (int i = 0; i < f.size(); ++i) {
    const bool live = f.points[i] && !f.points[i]->bad;
    points_before += live;
    const int label = regionAt(r, f.keys[i].pt);
    if (label == 0) continue;
    const int k = label - 1;
    region_of[i] = label;
    members[k].push_back(i);
    with_point[k] += live;
    flagged[k] += f.dynamic[i] != 0;
    judged[k] += f.cluster[i] >= 0;
  }
  const SemanticOptions& o = options_.semantic;
  std::vector<char> confirmed(n_regions, 0);
  std::vector<int> order(n_regions);
  for (int k = 0; k < n_regions; ++k) {
    order[k] = n_regions - 1 - k;  // regions come in ascending score
    confirmed[k] = flagged[k] >= o.confirm_min_flagged && flagged[k] >= o.confirm_ratio * judged[k];
  }
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return confirmed[a] > confirmed[b]; });

  // Semantic evidence alone may remove at most this many of the keyframe's points.
  const double budget = o.max_removed_fraction * points_before;
  int unconfirmed_removed = 0;
  std::vector<char> applied(n_regions + 1, 0);
  for (int k : order) {
    if (semantic_confirm_ && !confirmed[k]) {
      ++st.instances_unconfirmed;
      continue;
    }
    if (!confirmed[k]) {
      if (unconfirmed_removed + with_point[k] > budget) {
        ++st.instances_capped;
        SP_DEBUG(logger, "keyframe " << kf->id << ": '" << r.regions[k].class_name << "' would remove "
                                     << with_point[k] << " of " << points_before << " points: left alone");
        continue;
      }
      unconfirmed_removed += with_point[k];
    }
    applied[k + 1] = 1;
    ++st.instances_applied;
    if (r.regions[k].continued) ++st.instances_continued;
  }

  // The segmentation is the keyframe's word on what is movable in it. Marks
  // that followed an object into the keyframe's frame (masks of earlier
  // keyframes, chained and grown: markSemanticMovers) outside every region
  // it found are dropped: a keyframe whose segmentation found no one would
  // otherwise hand its stale marks on to later frames as its own masks, and
  // their growth over a static object touching the person would go on
  // spreading from keyframe to keyframe.
  int unmarked = 0;
  for (int i = 0; i < f.size(); ++i) {
    if (region_of[i] != 0 || f.dynamic[i] != kSemanticDynamic) continue;
    f.dynamic[i] = kNotDynamic;
    if (i < static_cast<int>(f.movable_class.size())) f.movable_class[i] = 0;
    ++unmarked;
  }
  std::vector<std::uint8_t> class_of(n_regions + 1, 0);
  for (int k = 0; k < n_regions; ++k)
    if (applied[k + 1]) class_of[k + 1] = map_->classId(r.regions[k].class_name);
  int features_removed = 0, points_removed = 0, points_culled = 0;
  for (int i = 0; i < f.size(); ++i) {
    const std::shared_ptr<MapPoint> p = f.points[i] && !f.points[i]->bad ? f.points[i] : nullptr;
    if (!applied[region_of[i]]) {
      if (p) ++p->semantic.checks;
      continue;
    }
    f.dynamic[i] = kSemanticDynamic;  // tracking finds these again in later frames
    f.movable_class.resize(f.size(), 0);
    f.movable_class[i] = class_of[region_of[i]];
    ++features_removed;
    if (!p) continue;
    if (p->first_keyframe_id == kf->id) {
      map_->erasePoint(p);  // made from a movable object by this keyframe
      ++points_removed;
      continue;
    }
    ++p->semantic.checks;
    ++p->semantic.hits;
    const bool was_reference = p->reference == kf;
    kf->eraseObservation(i);
    if (p->semantic.hits > o.point_masked_ratio * p->semantic.checks || p->observations.empty()) {
      map_->erasePoint(p);
      ++points_culled;
    } else if (was_reference) {
      p->reference = p->observations.begin()->first;
    }
  }
  if (features_removed > 0) kf->updateConnections();
  kf->segmented = true;
  if (kf->dense && n_regions > 0) {
    // Movable objects leave the dense cloud too.
    auto view = std::make_shared<DenseView>(*kf->dense);
    view->moving = view->moving.clone();
    const int step = DenseView::kStep;
    for (int row = 0; row < view->moving.rows; ++row)
      for (int col = 0; col < view->moving.cols; ++col)
        if (row * step < r.labels.rows && col * step < r.labels.cols && r.labels.at<std::uint8_t>(row * step, col * step))
          view->moving.at<std::uint8_t>(row, col) = 1;
    kf->dense = std::move(view);
  }
  if (options_.report_fates) {
    std::lock_guard lock(labels_mutex_);
    latest_labels_ = std::make_shared<const cv::Mat>(r.labels);
    latest_labels_stamp_ = f.stamp;
  }
  ++st.segmented;
  st.features_removed += features_removed;
  st.points_removed += points_removed;
  st.points_culled += points_culled;
  st.latency_ms.add(
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - r.created).count());
  SP_DEBUG(logger, "keyframe " << kf->id << ": " << n_regions << " movable regions, " << features_removed
                               << " features dropped, " << points_removed << " points removed, " << points_culled
                               << " culled, " << unmarked << " earlier marks dropped");
}


std::int64_t Tracker::keepForMasks() {
  awaiting_masks_ = last_;
  Frame& f = *awaiting_masks_;
  f.gray.release();
  // Which features carried the pose (the last frame keeps its map-point
  // inliers only), for the removal cap; the points themselves are local
  // mapping's to change, and the copy needs only features and flags.
  awaiting_matched_.assign(f.size(), 0);
  for (int i = 0; i < f.size(); ++i) awaiting_matched_[i] = f.points[i] != nullptr;
  f.points.assign(f.size(), nullptr);
  return f.id;
}

bool Tracker::applyFrameMasks(const SemanticResult& r, bool confirmation_required) {
  if (!awaiting_masks_ || awaiting_masks_->id != r.frame_id) return false;
  Frame f = std::move(*awaiting_masks_);
  awaiting_masks_.reset();
  if (!r.ok) {
    SP_WARN(logger, "frame " << r.frame_id << ": segmentation failed: " << r.error);
    return false;
  }
  // As a keyframe's segmentation is applied (LocalMapper::applySemantic):
  // a region most of whose judged features the geometry module found moving
  // is confirmed; the others may together take at most
  // semantic.max_removed_fraction of the frame's map-point matches, none when
  // the model needs confirmation. Its own result replaces the marks the frame
  // carried from earlier masks: one that found no one ends them.
  const SemanticOptions& o = options_.semantic;
  const int n_regions = static_cast<int>(r.regions.size());
  std::vector<int> region_of(f.size(), 0), with_point(n_regions, 0), flagged(n_regions, 0), judged(n_regions, 0);
  int matched = 0;
  for (int i = 0; i < f.size(); ++i) {
    const bool live = awaiting_matched_[i];
    matched += live;
    const int label = regionAt(r, f.keys[i].pt);
    if (label == 0) continue;
    region_of[i] = label;
    with_point[label - 1] += live;
    flagged[label - 1] += f.dynamic[i] == kGeometryDynamic;
    judged[label - 1] += f.cluster[i] >= 0;
  }
  std::vector<char> applied(n_regions + 1, 0);
  int removed = 0;
  for (int k = n_regions - 1; k >= 0; --k) {  // regions come in ascending score
    const bool confirmed = flagged[k] >= o.confirm_min_flagged && flagged[k] >= o.confirm_ratio * judged[k];
    if (!confirmed) {
      if (confirmation_required || removed + with_point[k] > o.max_removed_fraction * matched) continue;
      removed += with_point[k];
    }
    applied[k + 1] = 1;
  }
  f.movable_class.resize(f.size(), 0);
  for (int i = 0; i < f.size(); ++i) {
    if (f.dynamic[i] == kSemanticDynamic) f.dynamic[i] = kNotDynamic;
    f.movable_class[i] = 0;
    if (!applied[region_of[i]]) continue;
    f.dynamic[i] = kSemanticDynamic;
    f.movable_class[i] = map_->classId(r.regions[region_of[i] - 1].class_name);
  }
  masked_frame_ = std::move(f);
  return true;
}

void Tracker::markSemanticMovers() {
  // The newest segmented keyframe near the camera, or the newest frame
  // segmented where no keyframe is made (keepForMasks) when it is newer:
  // features inside its movable masks are looked up in this frame by
  // descriptor alone (the object may have moved anywhere since) and kept out
  // of the pose, so a masked object does not pull the pose between keyframes.
  const KeyFrame* source = nullptr;
  const auto consider = [&](const KeyFrame* kf) {
    if (kf && !kf->bad && kf->segmented && (!source || kf->id > source->id)) source = kf;
  };
  consider(reference_);
  for (const KeyFrame* kf : local_keyframes_) consider(kf);
  const Frame* from = source ? &source->frame : nullptr;
  if (masked_frame_ && (!from || masked_frame_->id > from->id)) from = &*masked_frame_;
  if (!from) return;
  const auto has_flags = [](const Frame& other) {
    return std::find(other.dynamic.begin(), other.dynamic.end(), kSemanticDynamic) != other.dynamic.end();
  };
  // Most keyframes mask nothing: skip the brute-force pass then.
  if (!has_flags(*from)) return;
  const auto flagged = [](const Frame& other) {
    std::vector<int> out;
    for (int i = 0; i < other.size(); ++i)
      if (other.dynamic[i] == kSemanticDynamic) out.push_back(i);
    return out;
  };
  const Frame& f = *from;
  // Mutual nearest neighbours, ratio 0.7 and rotation consistency:
  // window-free matching on repetitive texture mismatches, and a static
  // feature marked here is lost to the pose. Only the masked features are
  // looked up (a mask holds a fraction of the keyframe), but the keyframe's
  // other features still take a frame feature they match better.
  for (const auto& [j, i] : matchFromSomeByDescriptor(current_, f, 0.7f, flagged(f))) {
    current_.dynamic[j] = kSemanticDynamic, ++semantic_marked_;
    copyMovableClass(f, i, &current_, j);
  }
  if (options_.semantic.propagate_from_last && has_last_ && has_flags(last_)) {
    // The last frame's flagged features, looked up here: from frame to frame
    // an object changes less than since its keyframe. (Features the geometry
    // module flagged carry its flag instead and are not followed.)
    int chained = 0;
    for (const auto& [j, i] : matchFromSomeByDescriptor(current_, last_, 0.7f, flagged(last_)))
      if (!current_.dynamic[j]) {
        current_.dynamic[j] = kSemanticDynamic, ++chained;
        copyMovableClass(last_, i, &current_, j);
      }
    semantic_marked_ += chained;
    SP_DEBUG(logger, "frame " << current_.id << ": " << chained << " flagged from the last frame");
  }
  const float grow = options_.semantic.propagate_grow_px;
  for (int pass = 0; grow > 0 && semantic_marked_ >= 5 && pass < options_.semantic.propagate_grow_passes; ++pass) {
    // Region growing from the matches, then (more passes) from what it added:
    // a feature joins with two marked neighbours on its surface
    // (maskedNeighbours), counted from the marked side, which is the smaller.
    std::vector<int> neighbours(current_.size(), 0);
    for (int s = 0; s < current_.size(); ++s) {
      if (current_.dynamic[s] != kSemanticDynamic || !(current_.depth[s] > 0)) continue;
      for (int j : current_.grid.query(current_.keys, current_.un, current_.un[s].x, current_.un[s].y, grow, 0, -1))
        neighbours[j] += !current_.dynamic[j] && current_.depth[j] > 0 &&
                         geometry::sameSurface(current_.depth[s], current_.depth[j]);
    }
    std::vector<int> grown;
    for (int j = 0; j < current_.size(); ++j)
      if (neighbours[j] >= 2) grown.push_back(j);
    for (int j : grown) current_.dynamic[j] = kSemanticDynamic;
    semantic_marked_ += static_cast<int>(grown.size());
    if (grown.empty()) break;
  }
  SP_DEBUG(logger, "frame " << current_.id << ": " << semantic_marked_ << " features matched to masks of frame " << f.id);
}

}  // namespace stillpoint::slam
