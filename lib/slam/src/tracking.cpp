#include "tracking.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>
#include <unordered_map>
#include <unordered_set>

#include "matcher.hpp"
#include "optimizer.hpp"
#include "stage_timer.hpp"
#include "stillpoint/core/log.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("tracking");
bool isFlagged(DynamicCause d) { return d != kNotDynamic; }
// How recent the last steady frame's velocity must be to stand for the
// camera's motion when a loss begins.
constexpr std::int64_t kSteadyVelocityFrames = 5;
// In localisation mode, the map points a frame must match before the last
// frame's temporary depth points are left out of its pose fit.
constexpr int kMapMatchesWithoutTemporary = 50;

// `motion` (a camera-frame step T_c_w' = motion T_c_w) s times over.
SE3 scaledMotion(const SE3& motion, double s) {
  SE3 v = SE3::Identity();
  v.linear() = expSO3(s * logSO3(motion.linear()));
  v.translation() = s * motion.translation();
  return v;
}

// The pose at `stamp` if the camera kept the motion from `before` to `from`.
SE3 extrapolate(const Tracker::StampedPose& before, const Tracker::StampedPose& from, Timestamp stamp) {
  const double dt = secondsBetween(from.stamp, before.stamp);
  const double s = dt > 0 ? secondsBetween(stamp, from.stamp) / dt : 1.0;
  return renormalized(scaledMotion(renormalized(from.T_c_w * before.T_c_w.inverse()), s) * from.T_c_w);
}

}  // namespace

Tracker::Tracker(const CameraModel& camera, const SlamOptions& options, const LevelInfo& levels, Map* map,
                 geometry::ClusteringWorker* clustering)
    : camera_(camera),
      options_(options),
      levels_(levels),
      map_(map),
      close_depth_(options.tracking.close_depth_baselines * camera.baseline),
      trajectory_(options.tracking.trajectory_records) {
  if (clustering)
    detector_ = std::make_unique<DynamicDetector>(camera, levels, options, clustering, !options.sequential);
}

KeyFrame* Tracker::track(Frame frame, bool mapping_idle, bool clusters_pending, TrackOutput* out) {
  current_ = std::move(frame);
  clusters_pending = clusters_pending && detector_;
  match_ratio_.assign(current_.size(), 0.0f);
  times_ = StageTimes{};
  geometry_ = GeometryOutput{};
  semantic_marked_ = 0;
  mask_age_s_ = -1;
  masks_found_movers_ = false;
  starved_ = false;
  rejected_ = false;
  carried_.clear();
  const bool tracking = hasPose(state_);
  if (detector_) detector_->startFrame(current_, clusters_pending, tracking);
  KeyFrame* new_keyframe = nullptr;
  bool ok = false;
  DynamicDetector::Placement placed;  // where the frame's pose hangs
  if (state_ == TrackingState::kInitialising) {
    flagMapStartMovers();
    std::unique_lock lock(map_->mutex());
    ok = !mapStartRefused(nullptr) && initialise();
    if (ok) new_keyframe = reference_;
    if (ok) notePoseWorld();
  } else {
    std::shared_lock lock(map_->mutex());
    // Under the lock the frame is tracked in: a loop closed just before must
    // not leave the last pose, and the motion model with it, in the old world.
    followWorldMoves();
    ok = trackFrame(clusters_pending);
    if (ok && switch_to_map_) {
      lock.unlock();
      {
        std::unique_lock write(map_->mutex());
        switchToMap(*switch_to_map_);
      }
      lock.lock();
    }
    switch_to_map_.reset();
    if (ok) notePoseWorld();
    if (!ok && newMapDue()) {
      lock.unlock();
      flagMapStartMovers();
      std::unique_lock write(map_->mutex());
      ok = startNewMap();
      if (ok) new_keyframe = reference_;
      if (ok) notePoseWorld();
    } else {
      ScopedStageTimer keyframe_timer(&times_.keyframe);
      // A pose kept on fallback evidence maps nothing: its points would
      // carry its error into the map.
      if (ok && !starved_ && needNewKeyFrame(mapping_idle)) {
        lock.unlock();
        std::unique_lock write(map_->mutex());
        new_keyframe = createKeyFrame();
      }
    }
  }
  if (ok && state_ == TrackingState::kOk) lookForOlderMaps();
  if (ok) map_start_waiting_since_.reset();  // a later map start waits afresh
  {
    // Map point positions and keyframe poses change under local BA, which
    // holds the exclusive lock.
    std::shared_lock lock(map_->mutex());
    if (options_.report_fates) reportFates(ok, out);
    out->quality = measureQuality(ok);  // before the outliers are dropped
    if (ok) {
      updateVelocity();
      // The poses the motion check extrapolates: tracked in a row on full evidence.
      if (state_ != TrackingState::kOk || starved_) steady_poses_.clear();
      if (last_pose_departed_ && !steady_poses_.empty()) {
        // The motion since the frame before the off pose, per frame.
        steady_poses_.pop_back();
        followMapUnderSteadyPoses();
        const StampedPose& before = steady_poses_.back();
        const double span = secondsBetween(current_.stamp, before.stamp);
        if (has_velocity_ && span > 0)
          steady_velocity_ = velocity_ =
              scaledMotion(renormalized(current_.T_c_w * before.T_c_w.inverse()), velocity_dt_ / span);
      }
      last_pose_departed_ = false;
      // Temporary odometry points never outlive the frame they helped track.
      for (int i = 0; i < current_.size(); ++i)
        if (current_.points[i] && (current_.points[i]->isTemporary() || current_.outlier[i]))
          current_.points[i] = nullptr;
      catchUpWithWorld();
      T_last_reference_ = renormalized(current_.T_c_w * reference_->T_c_w().inverse());
      steady_poses_.push_back({current_.stamp, current_.T_c_w, reference_->anchor(), T_last_reference_});
      if (steady_poses_.size() > 3) steady_poses_.pop_front();
      seen_epoch_ = map_->epoch();
      placed = {reference_->anchor(), T_last_reference_, seen_epoch_};
      trajectory_.record({current_.stamp, reference_->anchor(), T_last_reference_, map_id_});
      out->T_w_c = current_.T_c_w.inverse();
    }
  }
  SP_DEBUG(logger, "frame " << current_.id << " state " << toString(state_) << " inliers " << inliers_
                              << " local kfs " << local_keyframes_.size() << " local points " << local_points_.size()
                              << (new_keyframe ? " NEW KF" : ""));
  out->stages = times_;
  out->state = rejected_ ? TrackingState::kLost : state_;
  out->map_id = map_id_;
  out->features = current_.size();
  out->tracked = ok ? inliers_ : 0;
  out->new_keyframe = new_keyframe != nullptr;
  out->geometry = std::move(geometry_);
  out->semantic_features = semantic_marked_;
  {
    ScopedStageTimer timer(&out->stages.objects);
    if (ok)
      out->objects =
          objects_.update(current_, out->geometry, map_id_, [this](std::uint8_t id) { return map_->className(id); });
    else
      objects_.missed(current_.stamp);
  }
  if (rejected_) {
    // The frame never happened for what comes next: its pose is wrong.
    if (detector_) detector_->skipFrame();
    return nullptr;
  }
  markMoverCells(ok);
  if (detector_) detector_->endFrame(current_, ok, placed);
  if (ok && detector_ && options_.semantic.probation_after_masks) noteMaskedPlaces();
  last_ = std::move(current_);
  has_last_ = true;
  return new_keyframe;
}

void Tracker::notePoseWorld() {
  if (!reference_) return;
  pose_epoch_ = map_->epoch();
  reference_at_pose_ = reference_->anchor()->T_c_w();
}

void Tracker::catchUpWithWorld() {
  if (!reference_ || map_->epoch() == pose_epoch_) return;
  // T_c_w' = T_c_w D for every pose of the old world. The last frame moves
  // with the current one: the velocity taken from the two must not hold the
  // world's move, or the next frame is searched where a loop closure's
  // correction (often 0.1 m and more) puts it.
  const SE3 D = renormalized(reference_at_pose_.inverse() * reference_->anchor()->T_c_w());
  current_.T_c_w = renormalized(current_.T_c_w * D);
  if (has_last_) last_.T_c_w = renormalized(last_.T_c_w * D);
  notePoseWorld();
}

void Tracker::followWorldMoves() {
  if (!has_last_ || !reference_ || !hasPose(state_)) return;
  if (map_->epoch() == seen_epoch_ || reference_->bad) return;
  // The steady poses hang in the old world; the motion check starts over.
  steady_poses_.clear();
  last_.T_c_w = renormalized(T_last_reference_ * reference_->T_c_w());
  // A loop closure fuses the points it found again into the older ones: the
  // last frame's matches follow them there, or the next frame's motion model
  // finds mostly odometry points, and a keyframe made from it maps again what
  // the fusion just joined.
  for (auto& p : last_.points)
    for (int hops = 0; p && p->bad && hops < 4; ++hops) {
      std::shared_ptr<MapPoint> by = p->replaced_by.lock();
      if (!by) break;
      p = std::move(by);
    }
  seen_epoch_ = map_->epoch();
}

void Tracker::reportFates(bool ok, TrackOutput* out) const {
  out->fates.resize(current_.size());
  for (int i = 0; i < current_.size(); ++i) {
    FeatureView& f = out->fates[i];
    f.u = current_.keys[i].pt.x;
    f.v = current_.keys[i].pt.y;
    if (current_.dynamic[i] == kGeometryDynamic)
      f.fate = FeatureFate::kGeometryDynamic;
    else if (current_.dynamic[i] == kSemanticDynamic)
      f.fate = FeatureFate::kSemanticDynamic;
    else if (ok && current_.points[i] && !current_.outlier[i])
      f.fate = FeatureFate::kInPose;
    else
      f.fate = current_.depth[i] > 0 ? FeatureFate::kUnused : FeatureFate::kNoDepth;
  }
}

bool Tracker::trackFrame(bool clusters_pending) {
  const bool was_lost = state_ == TrackingState::kLost;
  bool ok = false, relocalised = false;
  if (was_lost) {
    ScopedStageTimer timer(&times_.initial_pose);
    ok = relocalise();
  } else {
    if (options_.semantic.enabled && options_.semantic.propagate_masks) {
      ScopedStageTimer timer(&times_.semantic);
      markSemanticMovers();
    }
    // The world may have moved since the detector started the frame (no map
    // lock was held then).
    if (detector_) detector_->followWorld(map_->epoch());
    ok = initialPose();
    const bool judged = ok && clusters_pending;
    // Stage 1 keeps its outliers so the detector sees every match.
    if (judged) {
      ScopedStageTimer timer(&times_.geometry);
      const StageOneMatches stage_one{&carried_, &match_ratio_, reference_};
      geometry_ = detector_->judge(&current_, stage_one, [this] { return timedOptimizePose(); });
    }
    if (ok) discardOutliers();
    if (ok) {
      ok = trackLocalMap(options_.tracking.min_inliers_local_map);
      if (!ok) ok = keepPoseOnStaticEvidence();
    } else {
      ok = keepPredictedPoseOnStaticEvidence();
    }
    if (!ok) ok = keepPoseOnLastFrame();
    rejected_ = ok && !plausibleMotion();
    if (rejected_ && refitFromPrediction()) rejected_ = false;
    if (rejected_) ok = false;
    // Rejected again after a frame without a pose: the place recognition's
    // pose, independent of the motion model, decides.
    if (rejected_ && blind_since_) {
      rejected_ = false;
      relocalised = ok = relocalise();
    }
    if (ok && judged) updateProbation();  // not on a frame the detector did not judge
    // The first frame with depth after a blind spell that the motion model
    // could not bridge: the camera may be anywhere the maps know.
    if (!ok && !rejected_ && blind_since_) relocalised = ok = relocalise();
  }
  if (rejected_) {
    // No pose, but not lost: the next frame is tracked from the last one as
    // after a blind frame, and relocalised if the motion model cannot.
    if (!blind_since_) blind_since_ = current_.stamp;
    return false;
  }
  on_loaded_map_ = known_place_ = false;
  if (ok) {
    state_ = was_lost || relocalised ? TrackingState::kRelocalised : TrackingState::kOk;
    lost_since_.reset();
    blind_since_.reset();
    noteLoadedMapSupport();
  } else {
    state_ = TrackingState::kLost;
    // The motion the lost frames are held to (newMapDue): the last steady
    // frame's, when it is recent. A frame movers starved keeps its pose on
    // a few inliers (keepPoseOnStaticEvidence), and the velocity from it can
    // point anywhere: then no frame of the loss moves as it says, and the
    // new map waits for tracking.new_map_after_lost_s.
    if (!lost_since_)
      loss_velocity_ = current_.id - steady_velocity_frame_ <= kSteadyVelocityFrames ? steady_velocity_
                       : has_velocity_                                           ? velocity_
                                                                                 : SE3::Identity();
    has_velocity_ = false;
    if (!lost_since_) {
      lost_since_ = blind_since_.value_or(current_.stamp);
      lost_in_known_place_ = last_on_loaded_map_ && secondsBetween(*lost_since_, *last_on_loaded_map_) <
                                                        options_.tracking.new_map_after_lost_s;
    }
  }
  return ok;
}

void Tracker::mapLoaded() {
  state_ = TrackingState::kLost;
  map_id_ = map_->activeMapId();
}

void Tracker::noDepth(Timestamp stamp) {
  objects_.missed(stamp);
  health_ = PoseHealth::kLost;
  better_frames_ = 0;
  if (!blind_since_) blind_since_ = stamp;
}

bool Tracker::newMapDue() {
  const double after_s = options_.tracking.new_map_after_lost_s;
  static_support_ = {};
  if (options_.localisation || after_s <= 0 || state_ != TrackingState::kLost || !lost_since_) return false;
  const auto with_depth = std::count_if(current_.depth.begin(), current_.depth.end(), [](float d) { return d > 0; });
  if (with_depth < options_.tracking.min_init_features) return false;
  if (secondsBetween(current_.stamp, *lost_since_) >= after_s) return true;
  // Sooner when the view is a static scene the camera moves through as it
  // did before the loss: relocalisation has failed on it (ground the map
  // has not seen), and waiting would only lose more frames. A mover that
  // still fills the view moves otherwise, and its matches do not count.
  // Not where a loaded map held the pose just before: the ground is known,
  // what lost the frame is a mover hiding it, and the view's support is
  // then mostly that mover (a new map would stand on it).
  if (lost_in_known_place_) return false;
  const int needed = options_.tracking.new_map_min_static_matches;
  if (needed <= 0) return false;
  static_support_ = staticSupport(loss_velocity_);
  const int support = static_cast<int>(static_support_.agree.size());
  SP_DEBUG(logger, "frame " << current_.id << ": lost, " << support << " matches to the last frame move as the camera did");
  return support >= needed;
}

void Tracker::noteLoadedMapSupport() {
  if (!map_->hasLoadedMap()) return;
  int loaded = 0;
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    loaded += p && !current_.outlier[i] && map_->fromLoadedMap(*p);
  }
  // New ground: features with depth whose surface point lies outside the
  // view of every loaded keyframe near the camera. One inside that matched
  // no loaded point is something in front of known ground (a mover hiding
  // it, or a change), or known ground unmatched. A frame a mover starves
  // of loaded points is still in the known place: mapping it would map the
  // mover.
  std::vector<const KeyFrame*> views;
  for (const KeyFrame* kf : local_keyframes_)
    if (!kf->bad && map_->fromLoadedMap(*kf)) views.push_back(kf);
  const auto seen = [&](const Vec3& x_w) {
    for (const KeyFrame* kf : views) {
      const Vec3 x = kf->T_c_w() * x_w;
      if (x.z() <= 0) continue;
      const Vec2 uv = camera_.project(x);
      if (uv.x() >= 0 && uv.y() >= 0 && uv.x() < camera_.width && uv.y() < camera_.height) return true;
    }
    return false;
  };
  int new_ground = 0;
  for (int i = 0; i < current_.size(); ++i) {
    if (!(current_.depth[i] > 0) || current_.dynamic[i]) continue;
    const auto& p = current_.points[i];
    if (p && !current_.outlier[i] && map_->fromLoadedMap(*p)) continue;
    new_ground += !seen(current_.unprojectToWorld(i));
  }
  // As much new ground as would warrant a keyframe
  // (keyframes.close_untracked_min): the view leaves the place the file holds.
  known_place_ = !views.empty() && new_ground < options_.keyframes.close_untracked_min;
  on_loaded_map_ = known_place_ && loaded >= kMapMatchesWithoutTemporary;
  if (on_loaded_map_) last_on_loaded_map_ = current_.stamp;
}

void Tracker::flagMapStartMovers() {
  masked_ahead_ = false;
  if (!map_start_masks_) return;
  if (map_start_waiting_since_ &&
      secondsBetween(current_.stamp, *map_start_waiting_since_) >= options_.tracking.new_map_after_lost_s)
    return;  // waited long enough: the map starts as without them
  masked_ahead_ = map_start_masks_(&current_);
  if (masked_ahead_) {
    mask_age_s_ = 0;  // the frame's own masks
    masks_found_movers_ = current_.hasSemanticFlags();
  }
}

bool Tracker::mapStartRefused(const std::vector<int>* only) {
  if (!masked_ahead_) return false;
  const auto usable = [this](int i) { return current_.depth[i] > 0 && !current_.dynamic[i]; };
  int points = 0;
  if (only)
    for (int i : *only) points += usable(i);
  else
    for (int i = 0; i < current_.size(); ++i) points += usable(i);
  const int needed = only ? options_.tracking.new_map_min_static_matches : options_.tracking.min_init_features;
  if (points >= needed) return false;
  SP_DEBUG(logger, "frame " << current_.id << ": a map would have " << points << " points outside the movers' masks, "
                            << needed << " needed");
  if (!map_start_waiting_since_) map_start_waiting_since_ = current_.stamp;
  return true;
}

bool Tracker::startNewMap() {
  const bool on_support = !static_support_.agree.empty();
  // The support was found before the frame's movers were masked. A person
  // near the camera who moves about as the camera did before the loss can
  // outnumber the room among the matches the prediction admits and take the
  // fit; the room's near surfaces then count as moved, and the map stands on
  // its far ones alone. Found again without the masked features (none left:
  // the map start is refused below, and waits).
  if (on_support && masked_ahead_) static_support_ = staticSupport(loss_velocity_);
  const std::vector<int>* only = on_support ? &static_support_.agree : nullptr;
  current_.clearMatches();
  // Masks stay: they say what the features are, whichever map they join.
  for (auto& d : current_.dynamic)
    if (d != kSemanticDynamic) d = kNotDynamic;
  // Started sooner on the view's static support: the map stands on it alone
  // (a mover's features that were not matched are not known to move), and
  // what moved otherwise is flagged.
  for (int i : static_support_.moved) current_.dynamic[i] = kGeometryDynamic;
  // A view a mover fills waits for more of the scene (the frame stays lost).
  if (mapStartRefused(only)) return false;
  SP_WARN(logger, "frame " << current_.id << ": lost for " << secondsBetween(current_.stamp, *lost_since_)
                           << " s and not relocalised: starting map " << map_->mapsStarted()
                           << " (map " << map_->activeMapId() << " is kept)");
  reference_ = nullptr;
  local_keyframes_.clear();
  local_points_.clear();
  has_velocity_ = false;
  last_reloc_frame_id_ = -100;
  reloc_window_next_id_ = -1;
  if (detector_) {
    detector_->takeSuspects();  // points of the old map
    // Its frames hang in the old map's world: evidence against them is
    // nonsense in the new one. Frames without depth (a covered camera) end
    // no frame of the detector, so a loss that began blind has not cleared
    // them.
    detector_->forgetHistory();
  }
  // The new map starts where the camera was last posed, in the frame of
  // the map it lost: a consumer's poses go on in about the same frame, off
  // by how far the camera moved unseen, not from the origin. Not carried on
  // the motion before the loss: a mover that ends tracking pulls the last
  // poses first.
  const SE3 start = trajectory_.last() ? trajectory_.last()->T_c_w() : SE3::Identity();
  if (!initialise(only, start)) return false;
  state_ = TrackingState::kNewMap;
  young_map_until_frame_ = on_support ? current_.id + options_.geometry.anchor_frames : -1;
  lost_since_.reset();
  blind_since_.reset();
  return true;
}

bool Tracker::initialPose() {
  ScopedStageTimer timer(&times_.initial_pose);
  refreshLastFrame();
  const bool use_motion = has_velocity_ && current_.id > last_reloc_frame_id_ + 2;
  bool ok = use_motion && trackWithMotionModel();
  if (!ok) ok = trackReferenceKeyFrame();
  if (!ok && !use_motion) {
    // Just after a relocalisation (or without a velocity yet): the camera
    // moved little in a frame, so the last frame's points projected at the
    // predicted pose (the last pose when there is no velocity) still find
    // their features. The reference keyframe chosen by covisibility after a
    // relocalisation can share many points but have seen them from
    // elsewhere, and its descriptor matches then fall short
    // (looped_replay_test: the frame after every relocalisation was lost).
    if (!has_velocity_) {
      velocity_ = SE3::Identity();
      velocity_dt_ = 0;
    }
    ok = trackWithMotionModel(has_velocity_);
  }
  return ok;
}

void Tracker::updateVelocity() {
  if (has_last_ && current_.id == last_.id + 1 && state_ == TrackingState::kOk) {
    velocity_ = renormalized(current_.T_c_w * last_.T_c_w.inverse());
    velocity_dt_ = secondsBetween(current_.stamp, last_.stamp);
    has_velocity_ = true;
    if (!starved_) {
      steady_velocity_ = velocity_;
      steady_velocity_frame_ = current_.id;
    }
  } else if (state_ == TrackingState::kNewMap && !static_support_.agree.empty() && current_.id == last_.id + 1) {
    // A map started on the view's static support: that support's motion
    // is the camera's, and the next frame is searched where it predicts.
    velocity_ = static_support_.motion;
    velocity_dt_ = secondsBetween(current_.stamp, last_.stamp);
    has_velocity_ = true;
  } else if (state_ != TrackingState::kOk) {
    has_velocity_ = false;
  }
}

void Tracker::refreshLastFrame() {
  // The last frame's pose follows its reference keyframe (bundle adjustment
  // may have moved it). Its moving features become evidence the motion
  // model matches and sets aside; its static ones lend temporary points from
  // depth so the motion model has enough to match against.
  if (trajectory_.last()) last_.T_c_w = trajectory_.last()->T_c_w();
  if (detector_)
    detector_->carryMovers(&last_);
  else
    carryMovingFeatures(&last_, {});
  std::vector<std::pair<float, int>> by_depth;
  for (int i = 0; i < last_.size(); ++i)
    if (last_.depth[i] > 0 && !last_.dynamic[i] && !(detector_ && detector_->freedInLastFrame(i)))
      by_depth.emplace_back(last_.depth[i], i);
  const float exclusion = options_.semantic.enabled ? options_.semantic.temp_exclusion_px : 0.0f;
  if (exclusion > 0 && std::find(last_.dynamic.begin(), last_.dynamic.end(), kSemanticDynamic) != last_.dynamic.end()) {
    // The unflagged rest of a masked object (its features nearest to the
    // camera get temporary points first) lends none.
    std::erase_if(by_depth, [&](const std::pair<float, int>& e) {
      const auto [z, i] = e;
      if (last_.points[i] && !last_.points[i]->bad) return false;
      return maskedNeighbours(last_, last_.un[i], z, exclusion) >= 2;
    });
  }
  std::sort(by_depth.begin(), by_depth.end());
  int added = 0;
  for (const auto& [z, i] : by_depth) {
    const bool has_point = last_.points[i] && !last_.points[i]->bad;
    if (!has_point) {
      last_.points[i] = MapPoint::temporary(last_, i, false);
      last_.outlier[i] = 0;
      ++added;
    }
    // As many as a keyframe would map (createKeyFrame), so the motion model
    // sees the far structure that pins the rotation.
    if (z > close_depth_ && added >= options_.keyframes.min_new_points) break;
  }
}

int Tracker::setAsideCarried() {
  int carried = 0;
  carried_.assign(current_.size(), nullptr);
  for (int i = 0; i < current_.size(); ++i) {
    if (!current_.points[i] || !current_.points[i]->moverEvidence()) continue;
    carried_[i] = std::move(current_.points[i]);
    current_.points[i] = nullptr;
    ++carried;
  }
  return carried;
}

bool Tracker::trackWithMotionModel(bool with_prior) {
  current_.T_c_w = predictedPose(last_.T_c_w);
  current_.clearMatches();
  match_ratio_.assign(current_.size(), 0.0f);
  int matches = searchByProjection(&current_, last_, 7.0f, &match_ratio_);
  matches -= setAsideCarried();
  if (matches < 20) {
    current_.clearMatches();
    match_ratio_.assign(current_.size(), 0.0f);
    matches = searchByProjection(&current_, last_, 14.0f, &match_ratio_);
    matches -= setAsideCarried();
  }
  if (matches < 20) {
    SP_DEBUG(logger, "frame " << current_.id << ": motion model found " << matches << " matches");
    return false;
  }
  const SE3 predicted = current_.T_c_w;
  timedOptimizePose(with_prior ? &predicted : nullptr);
  const int kept = countMapInliers(current_);
  SP_DEBUG(logger, "frame " << current_.id << ": motion model " << matches << " matches, " << kept << " map inliers");
  return kept >= 10;
}

bool Tracker::trackReferenceKeyFrame() {
  if (!reference_ || reference_->bad) return false;
  current_.clearMatches();
  match_ratio_.assign(current_.size(), 0.0f);  // ratio-tested matches
  const int matches = searchByDescriptor(&current_, *reference_, 0.7f);
  SP_DEBUG(logger, "frame " << current_.id << ": reference keyframe " << reference_->id << " gave " << matches
                            << " matches");
  if (matches < 15) return false;
  current_.T_c_w = last_.T_c_w;
  timedOptimizePose();
  return countMapInliers(current_) >= 10;
}

void Tracker::updateLocalMap() {
  ScopedStageTimer timer(&times_.local_map);
  // Marks are per search, not per frame: relocalisation tries several
  // keyframes' local maps in one frame, and tracking's fallbacks search again
  // from another pose; each search gathers its whole local map.
  const std::int64_t search = ++local_searches_;
  std::unordered_map<KeyFrame*, int> votes;
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p || p->bad || p->isTemporary()) continue;
    for (const auto& [kf, idx] : p->observations)
      if (!kf->bad) votes[kf]++;
  }
  if (votes.empty()) {
    // No match of this frame is left to vote (the detector flagged every
    // one, or stage 1 found too few and the frame starts from the predicted
    // pose): the camera is still where the last frame's local map is, and
    // an empty one would leave nothing to search, not even the established
    // points the starved-frame rules fall back on.
    std::erase_if(local_keyframes_, [](const KeyFrame* kf) { return kf->bad; });
    std::erase_if(local_points_, [](const auto& p) { return p->bad; });
    for (KeyFrame* kf : local_keyframes_) kf->local_search = search;
    for (const auto& p : local_points_) p->local_search = search;
    return;
  }
  local_keyframes_.clear();
  KeyFrame* best = nullptr;
  int best_votes = 0;
  for (const auto& [kf, n] : votes) {
    kf->local_search = search;
    local_keyframes_.push_back(kf);
    if (n > best_votes || (n == best_votes && best && kf->id > best->id)) {
      best = kf;
      best_votes = n;
    }
  }
  std::sort(local_keyframes_.begin(), local_keyframes_.end(),
            [&](KeyFrame* a, KeyFrame* b) { return votes[a] != votes[b] ? votes[a] > votes[b] : a->id > b->id; });
  const std::size_t max_kfs = static_cast<std::size_t>(options_.tracking.local_keyframes_max);
  const std::size_t direct = local_keyframes_.size();
  for (std::size_t k = 0; k < direct && local_keyframes_.size() < max_kfs; ++k) {
    auto add = [&](KeyFrame* n) {
      if (!n || n->bad || n->local_search == search || local_keyframes_.size() >= max_kfs) return;
      n->local_search = search;
      local_keyframes_.push_back(n);
    };
    for (KeyFrame* n : local_keyframes_[k]->bestNeighbours(10)) add(n);
    for (KeyFrame* c : local_keyframes_[k]->children) add(c);
    add(local_keyframes_[k]->parent);
  }
  if (best) reference_ = best;

  local_points_.clear();
  for (KeyFrame* kf : local_keyframes_) {
    for (const auto& p : kf->frame.points) {
      if (!p || p->bad || p->local_search == search) continue;
      p->local_search = search;
      local_points_.push_back(p);
    }
  }
}

bool Tracker::trackLocalMap(int min_inliers, std::vector<MapPoint*>* seen) {
  updateLocalMap();
  const auto sighted = [seen](MapPoint* p) {
    if (seen)
      seen->push_back(p);
    else
      p->visible++;
  };
  // Points already matched are seen; don't search them again.
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p || p->isTemporary()) continue;
    sighted(p.get());
  }
  std::vector<std::shared_ptr<MapPoint>> candidates;
  candidates.reserve(local_points_.size());
  std::vector<char> already(local_points_.size(), 0);
  std::unordered_map<MapPoint*, int> matched;
  for (int i = 0; i < current_.size(); ++i)
    if (current_.points[i]) matched[current_.points[i].get()] = i;
  // A keypoint goes to the first point that finds it, so the points waiting
  // for their keyframe's mask are searched last. Each keyframe maps its own
  // copy of a surface (points are not fused), and with a long mask delay
  // most copies in view are waiting ones: searched among the others they took
  // most keypoints (700-850 a frame against 5-60 established ones at a
  // 24-frame delay), the fit had too few established matches to hold them
  // out (probation_min_trusted), and a person they were made on pulled it.
  std::vector<std::shared_ptr<MapPoint>> waiting;
  for (const auto& p : local_points_)
    if (!matched.count(p.get())) (heldForMask(*p) ? waiting : candidates).push_back(p);
  candidates.insert(candidates.end(), waiting.begin(), waiting.end());
  {
    ScopedStageTimer search_timer(&times_.local_map);
    std::vector<char> in_view;
    // Depth-sensor keypoints jitter more between frames than the pose error
    // suggests (depth-edge corners), so the window is wider than for stereo.
    const float radius = current_.id < last_reloc_frame_id_ + 2 ? 5.0f : 3.0f;
    searchLocalPoints(&current_, candidates, radius, &in_view);
    for (std::size_t k = 0; k < candidates.size(); ++k)
      if (in_view[k]) sighted(candidates[k].get());
  }

  timedOptimizePose();
  inliers_ = 0;
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p) continue;
    if (current_.outlier[i]) continue;
    if (p->isTemporary()) continue;
    if (!seen) p->found++;
    if (!p->observations.empty()) ++inliers_;
  }
  return inliers_ >= min_inliers;
}

void Tracker::countSightings(const std::vector<MapPoint*>& seen) {
  for (const auto& p : seen) p->visible++;
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (p && !current_.outlier[i] && !p->isTemporary()) p->found++;
  }
}

bool Tracker::keepPredictedPoseOnStaticEvidence() {
  // Stage 1 matches the last frame and the reference keyframe without the
  // flagged features (masks and known movers; the geometry module judges
  // later). When those are most of the frame (a mask spilling over most of
  // a static view), stage 1 can fail for want of
  // matches although the view is the map's. From the pose the motion model
  // predicts, the local map and its established points (stage 2 and
  // keepPoseOnStaticEvidence) still decide; the pose is reported
  // unreliable and makes no keyframe whichever of them holds it.
  if (!has_last_ || !hasPose(state_) || !reference_) return false;
  const auto flagged = std::count_if(current_.dynamic.begin(), current_.dynamic.end(), isFlagged);
  if (2 * flagged <= current_.size()) return false;  // not starved by the flags: lost
  current_.clearMatches();
  current_.T_c_w = has_velocity_ ? predictedPose(last_.T_c_w) : last_.T_c_w;
  if (trackLocalMap(options_.tracking.min_inliers_local_map)) {  // on the last frame's local map
    starved_ = true;
  } else if (!keepPoseOnStaticEvidence()) {
    return false;
  }
  SP_DEBUG(logger, "frame " << current_.id << ": stage 1 starved by " << flagged
                            << " flagged features; pose kept from the prediction on " << inliers_ << " inliers");
  return true;
}

bool Tracker::keepPoseOnStaticEvidence() {
  // Stage 1 found the pose, but with the features of movers kept out the
  // local map gave too few inliers. When that removal is what starved the
  // frame, the flagged features may still match the map's established
  // points (seen by 3 keyframes, not on probation, not held for its mask, not
  // judged dynamic): masks and depth clusters spill over static background,
  // and a point the map has held from several views is the most reliable
  // static evidence there is. The pose is refitted robustly on every match;
  // it stands on at least half the usual inliers and is reported unreliable.
  const int min_inliers = options_.tracking.min_inliers_local_map;
  const auto flagged = std::count_if(current_.dynamic.begin(), current_.dynamic.end(), isFlagged);
  if (flagged <= inliers_) return false;  // not starved by the removal: lost
  std::unordered_set<const MapPoint*> matched;
  for (const auto& p : current_.points)
    if (p) matched.insert(p.get());
  std::vector<std::shared_ptr<MapPoint>> established;
  for (const auto& p : local_points_)
    if (!p->bad && !matched.count(p.get()) && p->observations.size() >= 3 && p->geometry.probation <= 0 &&
        !heldForMask(*p))
      established.push_back(p);
  const std::vector<DynamicCause> flags = current_.dynamic;
  for (int i = 0; i < current_.size(); ++i)
    if (flags[i] && !current_.points[i]) current_.dynamic[i] = kNotDynamic;
  {
    ScopedStageTimer search_timer(&times_.local_map);
    searchLocalPoints(&current_, established, 3.0f);
  }
  timedOptimizePose();
  inliers_ = 0;
  int readmitted = 0;
  for (int i = 0; i < current_.size(); ++i) {
    auto& p = current_.points[i];
    const bool inlier = p && !p->isTemporary() && !current_.outlier[i];
    if (flags[i] && !current_.dynamic[i]) {
      if (inlier) {
        ++readmitted;  // consistent with the map: static after all
      } else {
        current_.dynamic[i] = flags[i];
        p = nullptr;
        current_.outlier[i] = 0;
        continue;
      }
    }
    if (inlier && !p->observations.empty()) ++inliers_;
  }
  // The pose stands on what is left even when nothing was readmitted: a
  // few inliers short of the bar is still the best static evidence there
  // is, and losing the frame throws away the motion model with it.
  starved_ = inliers_ >= (min_inliers + 1) / 2;
  SP_DEBUG(logger, "frame " << current_.id << ": starved by " << flagged << " moving features; " << readmitted
                            << " matched established points, " << inliers_ << " inliers: "
                            << (starved_ ? "pose kept" : "lost"));
  return starved_;
}

bool Tracker::keepPoseOnLastFrame() {
  // A map started on the view's static support holds one keyframe's points
  // until its next keyframe (keyframe_policy.cpp: none while it is young),
  // and the view a mover uncovers is not among them: for those first frames
  // the frame matches the last frame (whose static features lend temporary
  // points from depth) far better than the map. The pose may then stand on
  // those frame-to-frame matches alone; it is reported unreliable and maps
  // nothing. Older maps have keyframes enough; a frame they cannot place is
  // lost as before.
  if (current_.id > young_map_until_frame_ || !has_last_ || !hasPose(state_)) return false;
  const int min_inliers = options_.tracking.min_inliers_local_map;
  current_.clearMatches();
  match_ratio_.assign(current_.size(), 0.0f);
  current_.T_c_w = has_velocity_ ? predictedPose(last_.T_c_w) : last_.T_c_w;
  const int matches = searchByProjection(&current_, last_, 7.0f, &match_ratio_) - setAsideCarried();
  if (matches < min_inliers) return false;
  timedOptimizePose();
  inliers_ = 0;
  for (int i = 0; i < current_.size(); ++i)
    if (current_.points[i] && !current_.outlier[i]) ++inliers_;
  SP_DEBUG(logger, "frame " << current_.id << ": young map, " << inliers_ << " of " << matches
                            << " matches to the last frame agree: " << (inliers_ >= min_inliers ? "pose kept" : "lost"));
  if (inliers_ < min_inliers) {
    inliers_ = 0;
    return false;
  }
  starved_ = true;
  return true;
}

bool Tracker::refitFromPrediction() {
  // The fit settled where no camera can be: wrong matches (a mover's, a
  // repeated texture's) held it. The local map searched again from where
  // the camera's motion puts it may find the view's own matches; a pose
  // that then passes is kept, reported unreliable, and maps nothing.
  if (!has_last_ || !has_velocity_ || !reference_) return false;
  current_.clearMatches();
  current_.T_c_w = predictedPose(last_.T_c_w);
  if (!trackLocalMap(options_.tracking.min_inliers_local_map) || !plausibleMotion()) return false;
  SP_DEBUG(logger, "frame " << current_.id << ": fitted again from the prediction on " << inliers_ << " inliers");
  starved_ = true;
  return true;
}

int Tracker::discardOutliers() {
  int map_matches = 0;
  for (int i = 0; i < current_.size(); ++i) {
    if (!current_.points[i]) continue;
    if (current_.outlier[i]) {
      current_.points[i] = nullptr;
      current_.outlier[i] = 0;
    } else if (!current_.points[i]->isTemporary() && !current_.points[i]->observations.empty()) {
      ++map_matches;
    }
  }
  return map_matches;
}

int Tracker::timedOptimizePose(const SE3* prior) {
  ScopedStageTimer timer(&times_.pose_optimisation);
  // The motion model's prediction as a prior (stage 1 only, `prior` set).
  const TrackingOptions& t = options_.tracking;
  Eigen::Matrix<double, 6, 1> sqrt_information;
  sqrt_information.head<3>().setConstant(1.0 / (t.motion_prior_sigma_deg * M_PI / 180.0));
  sqrt_information.tail<3>().setConstant(t.motion_prior_sigma_m > 0 ? 1.0 / t.motion_prior_sigma_m : 0.0);
  const bool use_prior = prior && t.motion_prior_sigma_m > 0;
  const auto optimise = [&] {
    return use_prior ? optimizeFramePose(&current_, prior, &sqrt_information) : optimizeFramePose(&current_);
  };
  // Map points on probation (new, not yet seen to stay put) and points
  // held for their mask (heldForMask) are left out of the fit and judged by
  // it: a mover mapped while it went unflagged cannot pull the pose before
  // it has shown its motion or its mask has removed it. Only when enough
  // trusted matches remain; then their inlier flags come from the fitted
  // pose. With fewer, every held point joins the fit but those made on a
  // known mover, which join fewest-frames-to-go first only while still too
  // few.
  //
  // A loaded map's points stayed put over a whole earlier run: where a frame
  // matches enough of them (localisation, or mapping in a place the file
  // holds), they are the static world, and the last frame's temporary depth
  // points (nearest first, refreshLastFrame) and the points this run made
  // are the least proven evidence: a person filling the near view lends most
  // of the former and went into the latter. They are judged by the pose the
  // loaded points give instead of pulling it.
  //
  // Without the geometry module the temporary points are as unchecked as
  // points awaiting their mask: made from the last frame's features, which no
  // segmentation has seen, they lie on a person wherever the masks followed
  // from the last segmented keyframe miss it (a person 2 m away, whose
  // features that lookup matches a few of). While the established points
  // alone are enough, the temporary ones are judged by the pose those give;
  // with fewer, they count as before, ahead of the points awaiting their mask.
  const int min_trusted = options_.geometry.probation_min_trusted;
  std::vector<int> held, temporary, own;
  int trusted = 0;
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p || p->bad) continue;
    if (p->isTemporary())
      temporary.push_back(i);
    else if (p->geometry.probation > 0 || heldForMask(*p))
      held.push_back(i);
    else if (map_->hasLoadedMap() && !map_->fromLoadedMap(*p))
      own.push_back(i);
    else
      ++trusted;
  }
  // The place is the last frame's: this frame has no final pose yet.
  if (trusted >= kMapMatchesWithoutTemporary && (options_.localisation || on_loaded_map_)) {
    held.insert(held.end(), temporary.begin(), temporary.end());
    held.insert(held.end(), own.begin(), own.end());
  } else {
    trusted += static_cast<int>(own.size());
    if (!detector_ && map_->segmenting() && trusted >= min_trusted)
      held.insert(held.end(), temporary.begin(), temporary.end());
    else
      trusted += static_cast<int>(temporary.size());
  }
  if (!held.empty() && trusted < min_trusted) {
    std::erase_if(held, [&](int i) {
      if (current_.points[i]->geometry.on_mover) return false;
      ++trusted;
      return true;
    });
    std::stable_sort(held.begin(), held.end(), [this](int a, int b) {
      return current_.points[a]->geometry.probation < current_.points[b]->geometry.probation;
    });
    const int join = std::clamp(min_trusted - trusted, 0, static_cast<int>(held.size()));
    held.erase(held.begin(), held.begin() + join);
  }
  if (held.empty()) return optimise();
  std::vector<std::shared_ptr<MapPoint>> aside;
  aside.reserve(held.size());
  for (int i : held) aside.push_back(std::move(current_.points[i]));
  const int inliers = optimise();
  for (std::size_t k = 0; k < held.size(); ++k) {
    const int i = held[k];
    current_.points[i] = std::move(aside[k]);
    const Observation o = observationOf(current_, i);
    const double chi2 = reprojectionChi2(camera_, current_.T_c_w, current_.points[i]->position, o);
    current_.outlier[i] = chi2 > (o.u_right >= 0 ? kChi2Stereo : kChi2Mono);
  }
  return inliers;
}

bool Tracker::plausibleMotion() {
  // The pose is compared with the last steady frame's motion carried on,
  // and with the motion of the frame before carried on from there: a pose
  // that is wrong by less than the bounds passes, and the right pose after
  // it departs from the first prediction but not from the second. The check
  // trusts the motion only once it has predicted kTrustedFrames frames in a
  // row: the first frames of a map, or those after a frame starved by
  // movers, may carry a pose error into it.
  constexpr int kTrustedFrames = 3;
  const TrackingOptions& t = options_.tracking;
  followMapUnderSteadyPoses();
  const auto& h = steady_poses_;
  last_pose_departed_ = false;
  if (t.max_acceleration <= 0 || state_ != TrackingState::kOk || h.size() < 3 || h.back().stamp != last_.stamp) {
    predicted_frames_ = 0;
    return true;
  }
  double worst_m = 0, worst_deg = 0;
  bool plausible = false;
  for (std::size_t from = 1; from <= 2 && !plausible; ++from) {
    const StampedPose& f = h[h.size() - from];
    const SE3 predicted = extrapolate(h[h.size() - from - 1], f, current_.stamp);
    const double dt = secondsBetween(current_.stamp, f.stamp);
    const double moved = (current_.T_c_w.inverse().translation() - predicted.inverse().translation()).norm();
    const double turned = rotationAngle(current_.T_c_w.linear() * predicted.linear().transpose()) * 180.0 / M_PI;
    plausible = moved <= t.max_jump_m + 0.5 * t.max_acceleration * dt * dt &&
                turned <= t.max_jump_deg + 0.5 * t.max_angular_acceleration * dt * dt;
    if (from == 1) worst_m = moved, worst_deg = turned;
    // Right by the frame before the last only, and the last frame's pose
    // departs further from that motion than this one: the last pose was the
    // one off, and predicting from it would reject the next right pose.
    if (plausible && from == 2) {
      const SE3 last_predicted = extrapolate(h[h.size() - 3], f, h.back().stamp);
      last_pose_departed_ =
          (h.back().T_c_w.inverse().translation() - last_predicted.inverse().translation()).norm() > moved;
    }
  }
  if (plausible || predicted_frames_ < kTrustedFrames) {
    predicted_frames_ = plausible ? predicted_frames_ + 1 : 0;
    return true;
  }
  SP_DEBUG(logger, "frame " << current_.id << ": the pose departs from the motion model's by " << worst_m << " m and "
                            << worst_deg << " degrees: implausible, no pose");
  return false;
}

void Tracker::followMapUnderSteadyPoses() {
  // Local BA moves keyframes by centimetres between frames: a pose kept in
  // the world as it was would depart from the motion by as much.
  for (StampedPose& p : steady_poses_)
    if (p.reference) p.T_c_w = renormalized(p.T_c_ref * p.reference->T_c_w());
}

SE3 Tracker::predictedPose(const SE3& last) const {
  // Constant velocity per frame, but a frame that comes after a gap (a frame
  // skipped for bad input, dropped by the camera) is predicted further.
  // Intervals within a factor 1.5 count as one frame: TUM's colour stamps
  // alternate between 32 and 36 ms around a steady 30 Hz, and scaling the
  // velocity by that jitter made the prediction worse (6-run sweeps on
  // tum_fr3_teddy_200: 0.0092 m against 0.0083 m).
  const double dt = secondsBetween(current_.stamp, last_.stamp);
  const double ratio = velocity_dt_ > 0 && dt > 0 ? dt / velocity_dt_ : 1.0;
  if (ratio < 1.5 && ratio > 1.0 / 1.5) return renormalized(velocity_ * last);
  return renormalized(scaledMotion(velocity_, std::clamp(ratio, 0.25, 4.0)) * last);
}

void Tracker::updateProbation() {
  // A point on probation matched consistently with the final pose (which it
  // did not influence), outside any dynamic cluster, has one frame less to go.
  for (int i = 0; i < current_.size(); ++i) {
    const auto& p = current_.points[i];
    if (!p || p->bad || p->isTemporary() || p->geometry.probation <= 0 || current_.outlier[i] || current_.dynamic[i]) continue;
    --p->geometry.probation;
  }
}

bool Tracker::initialise(const std::vector<int>* only, const SE3& start) {
  int with_depth = 0;
  for (float d : current_.depth) with_depth += d > 0;
  if (with_depth < options_.tracking.min_init_features) {
    SP_INFO(logger, "frame " << current_.id << ": " << with_depth << " features with depth, need "
                             << options_.tracking.min_init_features << " to initialise");
    return false;
  }
  current_.T_c_w = start;
  map_id_ = map_->beginMap();
  auto kf = std::make_unique<KeyFrame>(map_->nextKeyFrameId(), current_);
  kf->origin = true;
  KeyFrame* k = map_->addKeyFrame(std::move(kf));
  std::vector<char> allowed(k->frame.size(), only ? 0 : 1);
  if (only)
    for (int i : *only) allowed[i] = 1;
  for (int i = 0; i < k->frame.size(); ++i) {
    // Movers (known or masked) make no points; a person model's suspects
    // make points on a mover's probation (that model also paints what stands).
    const bool suspect = i < static_cast<int>(k->frame.suspect.size()) && k->frame.suspect[i];
    if (k->frame.depth[i] <= 0 || (k->frame.dynamic[i] && !suspect) || !allowed[i]) continue;
    auto p = map_->createPoint(k->frame.unprojectToWorld(i), k);
    if (suspect) {
      p->geometry.on_mover = true;
      p->geometry.probation = options_.geometry.mover_probation_frames;
    }
    k->addObservation(p, i);
    p->updateFromObservations();
    current_.points[i] = p;
  }
  reference_ = k;
  last_keyframe_stamp_ = current_.stamp;
  last_keyframe_frame_id_ = current_.id;
  local_keyframes_ = {k};
  inliers_ = k->trackedPoints(1);
  state_ = TrackingState::kOk;
  SP_INFO(logger, "map " << map_id_ << " initialised with " << inliers_ << " points");
  return true;
}

void Tracker::markMoverCells(bool tracked) {
  const TrackingOptions& t = options_.tracking;
  mover_cells_.release();
  if (!tracked || t.mover_cells_every <= 1 || current_.size() == 0) return;
  const auto dynamic = std::count_if(current_.dynamic.begin(), current_.dynamic.end(), [](char d) { return d != 0; });
  if (dynamic == 0 || dynamic < t.mover_cells_min_share * current_.size()) return;
  constexpr int kScale = 8;  // the extractor samples one point per grid cell (32 px and up)
  mover_cells_ = cv::Mat::zeros((camera_.height + kScale - 1) / kScale, (camera_.width + kScale - 1) / kScale, CV_8UC1);
  const int radius = std::max(1, static_cast<int>(std::lround(t.mover_cells_radius_px * camera_.width / 640.0 / kScale)));
  for (int i = 0; i < current_.size(); ++i)
    if (current_.dynamic[i])
      cv::circle(mover_cells_, cv::Point(cvRound(current_.keys[i].pt.x / kScale), cvRound(current_.keys[i].pt.y / kScale)),
                 radius, cv::Scalar(255), cv::FILLED);
}

}  // namespace stillpoint::slam
