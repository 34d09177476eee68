#include <algorithm>

#include "stillpoint/core/log.hpp"
#include "tracking.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("tracking");
}  // namespace

bool Tracker::needNewKeyFrame(bool mapping_idle) const {
  const KeyframeOptions& o = options_.keyframes;
  if (!reference_ || options_.localisation) return false;
  // A map started on the view's static support while a mover still hides
  // much of it stands on a slice of the view: the frames right after are
  // poorly conditioned (in rotation above all), and keyframes made from
  // them bend the map for good. They track against the first keyframe
  // until the geometry module has its full baseline in the new map.
  if (current_.id <= young_map_until_frame_) return false;
  // A place a loaded map holds is mapped already: keyframes there would map
  // only what hides it (a mover near the camera) or what changed, and the
  // map would grow on every run through the same rooms. New ground, outside
  // the loaded keyframes' views, is mapped as ever.
  if (known_place_) return false;
  const std::size_t keyframes = map_->goodKeyFrameCount(map_->activeMapId());
  if (current_.id < last_reloc_frame_id_ + 30 && keyframes > 30) return false;
  // Every map point of the reference keyframe counts: a point seen by one
  // keyframe is as useful to tracking as one seen by many (requiring several
  // observations starves young maps of keyframes, and then of observations).
  const int ref_matches = reference_->trackedPoints(1);
  // "Close" in ORB-SLAM2's sense is "can be mapped from depth". Keyframes
  // map far points too (keyframes.min_new_points), so every keypoint with
  // depth counts: counting only those nearer than close_depth_ fired this
  // rule where the map was already complete, because far matches take a
  // share of the pose's inliers, and the map grew on every lap of a looped
  // replay (test/looped_replay_test.cpp).
  int close_tracked = 0, close_untracked = 0;
  for (int i = 0; i < current_.size(); ++i) {
    if (current_.depth[i] <= 0) continue;
    const auto& p = current_.points[i];
    if (p && !current_.outlier[i] && !p->isTemporary())
      ++close_tracked;
    else
      ++close_untracked;
  }
  const bool need_close = close_tracked < o.close_tracked_min && close_untracked > o.close_untracked_min;
  const double ratio = keyframes < 2 ? 0.4 : o.tracked_ratio;
  const double since_s = secondsBetween(current_.stamp, last_keyframe_stamp_);
  const bool c1a = since_s >= o.max_interval_s;
  const bool c1b = current_.id >= last_keyframe_frame_id_ + o.min_interval_frames && mapping_idle;
  const bool c1c = inliers_ < 0.25 * ref_matches || need_close;
  const bool c2 = (inliers_ < ratio * ref_matches || need_close) && inliers_ > 15;
  return (c1a || c1b || c1c) && c2;
}

KeyFrame* Tracker::createKeyFrame() {
  catchUpWithWorld();  // a loop closure may have moved the map since the pose
  releaseCulledKeyFrames();  // the exclusive lock is held anyway
  const std::int64_t id = map_->nextKeyFrameId();
  Frame copy = current_;
  for (int i = 0; i < copy.size(); ++i) {
    const auto& p = copy.points[i];
    if (!p || p->bad || p->isTemporary() || copy.outlier[i]) {
      copy.points[i] = nullptr;
      copy.outlier[i] = 0;
    }
  }
  auto made = std::make_unique<KeyFrame>(id, copy);
  made->bow = staticWords(made->frame);
  KeyFrame* kf = map_->addKeyFrame(std::move(made));
  for (int i = 0; i < kf->frame.size(); ++i) {
    const auto p = kf->frame.points[i];
    if (!p) continue;
    if (p->observations.count(kf)) {
      // The same point matched twice in one frame keeps only its first match.
      kf->frame.points[i] = nullptr;
      continue;
    }
    kf->addObservation(p, i);
    p->updateFromObservations();
  }
  // New points from depth: all close ones, and at least the nearest N
  // (keyframes.min_new_points, 500). In the virtual-stereo coordinate a depth
  // error dz counts bf dz / z^2 px, and a structured-light sensor's depth
  // noise grows as z^2, so a far point's depth is as good there as a near
  // one's; far structure is what pins the rotation. 100 (ORB-SLAM2's) left
  // the background mostly unmapped: ATE on the real excerpt 0.0082 -> 0.0049 m
  // (docs/decisions.md).
  std::vector<std::pair<float, int>> by_depth;
  for (int i = 0; i < kf->frame.size(); ++i)
    if (kf->frame.depth[i] > 0 && !kf->frame.points[i] && !kf->frame.dynamic[i])
      by_depth.emplace_back(kf->frame.depth[i], i);
  std::sort(by_depth.begin(), by_depth.end());
  int created = 0, lately = 0;
  const std::unordered_set<std::uint64_t> masked_lately =
      detector_ ? recentlyMasked() : std::unordered_set<std::uint64_t>();
  for (const auto& [z, i] : by_depth) {
    if (z > close_depth_ && created >= options_.keyframes.min_new_points) break;
    auto p = map_->createPoint(kf->frame.unprojectToWorld(i), kf);
    const bool where_masked = !masked_lately.empty() && nearPlace(masked_lately, p->position);
    if (detector_) {
      p->geometry.on_mover = detector_->onKnownMover(i) || where_masked;
      p->geometry.probation =
          p->geometry.on_mover ? options_.geometry.mover_probation_frames : options_.geometry.probation_frames;
    }
    kf->addObservation(p, i);
    p->updateFromObservations();
    current_.points[i] = p;
    current_.outlier[i] = 0;
    ++created;
    lately += where_masked;
  }
  if (lately > 0)
    SP_DEBUG(logger, "frame " << current_.id << ": " << lately << " of " << created
                              << " new points where masks ended serve a mover's probation");
  kf->updateConnections();
  if (detector_) kf->dynamic_suspects = detector_->takeSuspects();
  reference_ = kf;
  last_keyframe_stamp_ = current_.stamp;
  last_keyframe_frame_id_ = current_.id;
  return kf;
}

void Tracker::releaseCulledKeyFrames() {
  if (options_.mapping.keep_culled_keyframes) return;
  // Our pointers to keyframes: the reference (its record holds the anchor;
  // a culled reference is only ever tested for `bad`, which null equals) and
  // the local keyframes (rebuilt for every frame).
  if (reference_ && reference_->bad) reference_ = nullptr;
  std::erase_if(local_keyframes_, [](KeyFrame* kf) { return kf->bad; });
  const std::size_t released = map_->releaseCulledKeyFrames();
  if (released > 0) SP_DEBUG(logger, "freed " << released << " culled keyframes");
}

}  // namespace stillpoint::slam
