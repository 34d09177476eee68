// The semantic module's masks, in one place: how a segmented keyframe's
// masks change the map (local mapping's thread, LocalMapper::applySemantic),
// and how they follow their objects into the frames between keyframes
// (tracking's thread, Tracker::markSemanticMovers).
#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_set>

#include "local_mapping.hpp"
#include "matcher.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/geometry/rules.hpp"
#include "tracking.hpp"

namespace stillpoint::slam {

namespace {
log::Logger logger("semantic");
// Features of a region that must lie where a static object was seen
// standing before the region counts as that object (and a majority of those
// with depth).
constexpr int kMinStanding = 5;
// Feature j of `to` was found as feature i of `from`: it takes its class.
void copyMovableClass(const Frame& from, int i, Frame* to, int j) {
  if (from.movable_class.empty() || from.movable_class[i] == 0) return;
  to->movable_class.resize(to->size(), 0);
  to->movable_class[j] = from.movable_class[i];
}

// Whether regions consult the map's memory of what stands (StaticSightings).
// It needs the geometry module: a static object's mask spills over a person
// beside it, and only the module's flags keep the person's place from being
// remembered as standing (docs/dynamic-objects.md).
bool staticMemoryOn(const SlamOptions& o) { return o.semantic.static_memory_sightings > 0 && o.geometry.enabled; }

// Which regions of one segmentation a view keeps out: the rule a segmented
// keyframe and a segmented frame share. A region most of whose judged
// features the geometry module found moving is confirmed and always kept out;
// the others, best score first, may together take at most
// semantic.max_removed_fraction of the view's features with a map point, or
// more while semantic.min_kept_points of those stay outside them, and none
// when the model needs confirmation. A region of the person model beside the
// main one (SemanticRegion::second_opinion, only where a map starts) is never
// kept out: that model also paints things that stand (the box under the TUM
// teddy bear), and the points the map start made there serve a mover's
// probation instead (Frame::suspect).
//
// An unconfirmed region most of whose features with depth lie where the map
// has seen a static object standing (`seen_standing` per feature: 1 yes, 0
// no, -1 not known; may be null) is that object under another label, and is
// left alone: its mask would take a static object out of the pose, keyframe
// after keyframe. In a frame segmented where no keyframe is made
// (`frame_only`), only while the geometry module flags a smaller share of its
// judged features than lie there: the memory knows the place, the module what
// moves there now (a person standing just in front of a chair). There the map
// already holds the place and its points carry the pose, so a relabelled
// object costs little and a person left alone much; a keyframe's flags on a
// static object are often half of it (it shares a depth cluster with the
// person beside it), and there the memory is what keeps it in the pose.
//
// The cap keeps a false positive from emptying the map: a share alone would
// also keep out the person who fills most of a keyframe near the camera,
// whose mask leaves the room hundreds of points. It does not hold for
// a region the geometry module took for the world: when it flags a larger
// share of the judged features outside every region than of the region's own,
// and at least semantic.other_motion_share of them, the pose follows the
// region's motion and the rest of the view is the other motion. A textured
// person in front of a bare room then holds most of the keyframe's points,
// and the mask is what tells which motion is the world's.
struct RegionChoice {
  std::vector<int> region_of;   // per feature: its region (1-based), 0 for none
  std::vector<int> with_point;  // per region: its features with a map point
  std::vector<char> applied;    // per label (0 = no region): kept out
  std::vector<char> known;      // per label: left alone, its place seen standing
  int with_point_total = 0;
  int unconfirmed = 0;    // regions left alone for want of confirmation
  int capped = 0;         // regions left alone over the removal cap
  int followed = 0;       // applied over the cap: the pose followed them
  int known_static = 0;   // regions left alone: the map saw their place standing
};

RegionChoice chooseRegions(const SemanticResult& r, const Frame& f, const std::vector<char>& has_point,
                           const std::vector<int>* seen_standing, bool frame_only, const SemanticOptions& o,
                           bool confirmation_required) {
  const int n_regions = static_cast<int>(r.regions.size());
  RegionChoice c;
  c.region_of.assign(f.size(), 0);
  c.with_point.assign(n_regions, 0);
  c.applied.assign(n_regions + 1, 0);
  c.known.assign(n_regions + 1, 0);
  std::vector<int> flagged(n_regions, 0), judged(n_regions, 0), tested(n_regions, 0), standing(n_regions, 0);
  int flagged_outside = 0, judged_outside = 0;
  for (int i = 0; i < f.size(); ++i) {
    c.with_point_total += has_point[i];
    const bool moving = f.dynamic[i] == kGeometryDynamic;
    const bool in_cluster = f.cluster[i] >= 0;
    const int label = regionAt(r, f.keys[i].pt);
    if (label == 0) {
      flagged_outside += moving;
      judged_outside += in_cluster;
      continue;
    }
    c.region_of[i] = label;
    c.with_point[label - 1] += has_point[i];
    if (seen_standing && (*seen_standing)[i] >= 0) {
      ++tested[label - 1];
      standing[label - 1] += (*seen_standing)[i];
    }
    flagged[label - 1] += moving;
    judged[label - 1] += in_cluster;
  }
  const double outside_share = judged_outside > 0 ? static_cast<double>(flagged_outside) / judged_outside : 0.0;
  const double budget = std::max(o.max_removed_fraction * c.with_point_total,
                                 o.min_kept_points > 0 ? static_cast<double>(c.with_point_total - o.min_kept_points) : 0.0);
  int removed = 0;
  for (int k = n_regions - 1; k >= 0; --k) {  // regions come in ascending score
    const bool confirmed = flagged[k] >= o.confirm_min_flagged && flagged[k] >= o.confirm_ratio * judged[k];
    if (!confirmed && standing[k] >= kMinStanding && 2 * standing[k] > tested[k] &&
        (!frame_only || static_cast<long>(standing[k]) * judged[k] > static_cast<long>(flagged[k]) * tested[k])) {
      ++c.known_static;
      c.known[k + 1] = 1;
      continue;
    }
    if (r.regions[k].second_opinion || (!confirmed && confirmation_required)) {
      ++c.unconfirmed;
      continue;
    }
    if (!confirmed) {
      if (removed + c.with_point[k] > budget) {
        const double own_share = judged[k] > 0 ? static_cast<double>(flagged[k]) / judged[k] : 0.0;
        const bool followed =
            o.other_motion_share > 0 && outside_share >= o.other_motion_share && outside_share > own_share;
        if (!followed) {
          ++c.capped;
          continue;
        }
        ++c.followed;
      }
      removed += c.with_point[k];
    }
    c.applied[k + 1] = 1;
  }
  return c;
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

  // The geometry module's flags are read before `dynamic` is touched below.
  std::vector<char> live(f.size(), 0);
  for (int i = 0; i < f.size(); ++i) live[i] = f.points[i] && !f.points[i]->bad;
  const SemanticOptions& o = options_.semantic;
  // Where the map has seen a static object standing, read before this
  // result adds its own sightings.
  const bool memory = staticMemoryOn(options_);
  std::vector<int> seen_standing(f.size(), -1);
  std::vector<Vec3> world(memory ? f.size() : 0);
  if (memory) {
    for (int i = 0; i < f.size(); ++i) {
      if (!(f.depth[i] > 0)) continue;
      world[i] = f.unprojectToWorld(i);
      seen_standing[i] =
          map_->staticSightings().seenStanding(kf->map_id, world[i], o.static_memory_sightings, o.static_memory_span_s);
    }
  }
  const RegionChoice choice = chooseRegions(r, f, live, &seen_standing, false, o, semantic_confirm_);
  const std::vector<char>& applied = choice.applied;
  st.instances_unconfirmed += choice.unconfirmed;
  st.instances_capped += choice.capped;
  st.instances_followed += choice.followed;
  st.instances_known_static += choice.known_static;
  // A mask spills over what stands beside its object (COCO's mask of a
  // person over the teddy bear next to it; depth agreement keeps both when
  // they are as far away). Its features on a place the map has seen standing
  // that the geometry module does not see moving are not the region's: the
  // mask speaks of the object, the memory of the place. A person standing on
  // such a place (sitting on the chair) keeps it too until the module sees
  // it move.
  std::vector<int> region_of = choice.region_of;
  int features_on_standing = 0;
  for (int i = 0; memory && i < f.size(); ++i)
    if (region_of[i] != 0 && applied[region_of[i]] && seen_standing[i] == 1 && f.dynamic[i] != kGeometryDynamic) {
      region_of[i] = 0;
      ++features_on_standing;
    }
  // This keyframe's sightings: in an applied region or flagged by the
  // geometry module a moving one, else on a static instance a static one.
  if (memory) {
    std::vector<Vec3> on_static, in_movable;
    for (int i = 0; i < f.size(); ++i) {
      if (seen_standing[i] < 0) continue;  // no depth
      if (applied[region_of[i]] || f.dynamic[i] == kGeometryDynamic)
        in_movable.push_back(world[i]);
      else if (onStaticObject(r, f.keys[i].pt))
        on_static.push_back(world[i]);
    }
    map_->staticSightings().add(kf->map_id, f.stamp, on_static, in_movable);
  }
  for (int k = 0; k < n_regions; ++k) {
    if (!applied[k + 1]) {
      SP_DEBUG(logger, "keyframe " << kf->id << ": '" << r.regions[k].class_name << "' ("
                                   << choice.with_point[k] << " of " << choice.with_point_total
                                   << " points) left alone"
                                   << (choice.known[k + 1] ? ": the map saw its place standing" : ""));
      continue;
    }
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
  // So are the marks a map start gave a person model's region that the
  // keyframe's own verdict leaves alone (markMovable).
  int unmarked = 0;
  for (int i = 0; i < f.size(); ++i) {
    const int k = region_of[i];
    const bool second_left = k != 0 && !applied[k] && r.regions[k - 1].second_opinion;
    if ((k != 0 && !second_left) || f.dynamic[i] != kSemanticDynamic) continue;
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
  st.features_on_standing += features_on_standing;
  st.latency_ms.add(
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - r.created).count());
  SP_DEBUG(logger, "keyframe " << kf->id << ": " << n_regions << " movable regions, " << features_removed
                               << " features dropped, " << points_removed << " points removed, " << points_culled
                               << " culled, " << unmarked << " earlier marks dropped, " << features_on_standing
                               << " kept on places seen standing");
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
  // The regions are chosen as a keyframe's (chooseRegions), the removal cap
  // counted on the frame's map-point matches, regions on places the map has
  // seen standing left alone. Its own result replaces the marks the frame
  // carried from earlier masks: one that found no one ends them. Only
  // keyframes add sightings.
  const SemanticOptions& o = options_.semantic;
  std::vector<int> seen_standing(f.size(), -1);
  if (staticMemoryOn(options_)) {
    std::shared_lock lock(map_->mutex());
    const StaticSightings& memory = map_->staticSightings();
    for (int i = 0; i < f.size(); ++i)
      if (f.depth[i] > 0 && regionAt(r, f.keys[i].pt) != 0)
        seen_standing[i] =
            memory.seenStanding(map_id_, f.unprojectToWorld(i), o.static_memory_sightings, o.static_memory_span_s);
  }
  const RegionChoice choice = chooseRegions(r, f, awaiting_matched_, &seen_standing, true, o, confirmation_required);
  frame_regions_known_static_ += choice.known_static;
  for (std::size_t k = 1; k < choice.known.size(); ++k)
    if (choice.known[k])
      SP_DEBUG(logger, "frame " << f.id << ": '" << r.regions[k - 1].class_name << "' ("
                                << choice.with_point[k - 1] << " of " << choice.with_point_total
                                << " matched features) left alone: the map saw its place standing");
  const std::vector<int>& region_of = choice.region_of;
  const std::vector<char>& applied = choice.applied;
  std::vector<std::uint8_t> class_of(applied.size(), 0);
  for (std::size_t k = 1; k < applied.size(); ++k)
    if (applied[k]) class_of[k] = map_->classId(r.regions[k - 1].class_name);
  f.movable_class.resize(f.size(), 0);
  for (int i = 0; i < f.size(); ++i) {
    if (f.dynamic[i] == kSemanticDynamic) f.dynamic[i] = kNotDynamic;
    f.movable_class[i] = class_of[region_of[i]];
    if (applied[region_of[i]]) f.dynamic[i] = kSemanticDynamic;
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
  if (!from) {
    mask_age_s_ = std::numeric_limits<float>::infinity();  // none within reach: as if never segmented
    return;
  }
  mask_age_s_ = static_cast<float>(std::max(0.0, secondsBetween(current_.stamp, from->stamp)));
  masks_found_movers_ = from->hasSemanticFlags();
  // Most keyframes mask nothing: skip the brute-force pass then.
  if (!masks_found_movers_) return;
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
  if (options_.semantic.propagate_from_last && has_last_ && last_.hasSemanticFlags()) {
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

void Tracker::noteMaskedPlaces() {
  std::vector<Vec3> points;
  for (int i = 0; i < current_.size(); ++i)
    if (current_.dynamic[i] == kSemanticDynamic && current_.depth[i] > 0) points.push_back(current_.unprojectToWorld(i));
  if (points.empty()) return;
  last_masked_ = {std::move(points), current_.id, map_id_};
}

std::unordered_set<std::uint64_t> Tracker::recentlyMasked() const {
  // A mover's mask may end while it is still in view: the segmenter stops
  // finding it (COCO calls a person beside the teddy bear a second teddy
  // bear) and the masks followed from keyframes end with it. Where it then
  // stands still for a moment, the points a keyframe makes on it pass the
  // ordinary probation and hold the pose when it walks on. In a frame
  // without marks, the places where the last masks kept features out (the
  // 10 cm cell of one, or a cell next to it, as the mover turns) are where
  // points made serve a mover's probation; their features are not kept out
  // (that place holds static objects beside the mover too). While masks mark
  // features, they are what keeps the mover out.
  const MaskedPlaces& last = last_masked_;
  if (!options_.semantic.probation_after_masks || semantic_marked_ > 0 || last.points.empty() ||
      last.map_id != map_id_ || current_.id - last.frame_id > options_.geometry.mover_probation_frames)
    return {};
  std::unordered_set<std::uint64_t> places;
  for (const Vec3& x : last.points) places.insert(cellKey(placeCell(x)));
  return places;
}

}  // namespace stillpoint::slam
