// Maps started after a loss (Tracker::startNewMap) rejoin the map they lost.
// While tracking in a map that is not the only one, every kMergeEvery-th frame
// is looked up in the older maps' keyframes whose views look most like it
// (Frame::thumbnail), by descriptor matches, PnP and a pose refit against the
// older map's points. Two lookups within a few seconds
// that agree on where the current map lies in the older one's frame move
// every keyframe and point of the current map into that frame; the two maps
// are one from then on, and so is the trajectory (its records follow their
// keyframes). Movers stay out: features flagged dynamic take no part.
#include <algorithm>
#include <cmath>
#include <unordered_set>
#include <vector>

#include "matcher.hpp"
#include "optimizer.hpp"
#include "stillpoint/core/log.hpp"
#include "tracking.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("maps");

constexpr int kMergeEvery = 5;        // frames between lookups
constexpr std::size_t kCandidates = 4;  // older keyframes tried per lookup, the most alike views first
constexpr double kAgreeM = 0.05, kAgreeDeg = 3.0;  // two lookups agree within
constexpr double kConfirmWithinS = 3.0;            // the second lookup comes within this of the first

double angleDeg(const SE3& T) {
  const double c = std::clamp((T.linear().trace() - 1.0) / 2.0, -1.0, 1.0);
  return std::acos(c) * 180.0 / M_PI;
}
}  // namespace

void Tracker::lookForOlderMaps() {
  if (map_->mapsStarted() < 2 || current_.id % kMergeEvery != 0) return;
  KeyFrame* found_kf = nullptr;
  SE3 T_older_newer = SE3::Identity();
  {
    std::shared_lock lock(map_->mutex());
    catchUpWithWorld();
    // The older maps' keyframes whose view looks most like this one: by
    // their words, or without a vocabulary by their small views.
    std::vector<KeyFrame*> candidates;
    if (vocabulary_) {
      for (const Map::PlaceMatch& m : map_->similarKeyFrames(
               staticWords(current_), [this](const KeyFrame* kf) { return kf->map_id != map_id_; }, 0.0, kCandidates))
        candidates.push_back(m.keyframe);
    } else {
      std::vector<std::pair<double, KeyFrame*>> ranked;
      for (const auto& kf : map_->keyframes()) {
        if (kf->bad || kf->map_id == map_id_ || kf->frame.thumbnail.empty() || current_.thumbnail.empty()) continue;
        ranked.emplace_back(current_.thumbnail.dot(kf->frame.thumbnail), kf.get());
      }
      const std::size_t n = std::min(kCandidates, ranked.size());
      std::partial_sort(ranked.begin(), ranked.begin() + n, ranked.end(), [](const auto& a, const auto& b) {
        return a.first != b.first ? a.first > b.first : a.second->id < b.second->id;
      });
      for (std::size_t k = 0; k < n; ++k) candidates.push_back(ranked[k].second);
    }
    if (candidates.empty()) return;  // nothing of the older maps is left in memory
    for (KeyFrame* kf : candidates) {
      Frame probe = current_;
      probe.clearMatches();
      if (searchByDescriptor(&probe, *kf, 0.75f) < 20) continue;
      for (int i = 0; i < probe.size(); ++i)
        if (probe.dynamic[i]) probe.points[i] = nullptr;
      if (!poseFromMatches(&probe)) continue;
      if (optimizeFramePose(&probe) < options_.tracking.min_inliers_after_reloc) continue;
      if (offAlongView(depthOffset(probe))) continue;  // as relocalisation refuses it (relocalisation.cpp)
      // T_c_older^-1 * T_c_newer: the current map's world in the older one's.
      T_older_newer = renormalized(probe.T_c_w.inverse() * current_.T_c_w);
      found_kf = kf;
      break;
    }
  }
  if (!found_kf) return;
  const std::uint32_t older = found_kf->map_id;
  const bool confirms = merge_candidate_ && merge_candidate_->older == older &&
                        secondsBetween(current_.stamp, merge_candidate_->stamp) <= kConfirmWithinS &&
                        (merge_candidate_->T_older_newer.translation() - T_older_newer.translation()).norm() <= kAgreeM &&
                        angleDeg(merge_candidate_->T_older_newer.inverse() * T_older_newer) <= kAgreeDeg;
  if (!confirms) {
    merge_candidate_ = MergeCandidate{older, T_older_newer, current_.stamp};
    SP_DEBUG(logger, "frame " << current_.id << ": map " << map_id_ << " seen in map " << older
                              << " (keyframe " << found_kf->id << "), waiting for a second sighting");
    return;
  }
  std::unique_lock lock(map_->mutex());
  if (found_kf->bad) return;
  mergeInto(older, T_older_newer, found_kf);
  merge_candidate_.reset();
}

void Tracker::mergeInto(std::uint32_t older, const SE3& T_older_newer, KeyFrame* older_keyframe) {
  const std::uint32_t newer = map_id_;
  const SE3 T_newer_older = T_older_newer.inverse();
  std::unordered_set<const MapPoint*> moved;
  std::vector<MapPoint*> points;
  KeyFrame* origin = nullptr;
  std::size_t keyframes = 0;
  for (const auto& kf : map_->keyframes()) {
    if (kf->map_id != newer) continue;
    kf->map_id = older;
    ++keyframes;
    if (kf->origin) origin = kf.get();
    if (kf->bad) continue;  // its anchor follows its parent's
    kf->T_c_w() = renormalized(kf->T_c_w() * T_newer_older);
    for (const auto& p : kf->frame.points) {
      if (!p || p->bad || !moved.insert(p.get()).second) continue;
      p->position = T_older_newer * p->position;
      points.push_back(p.get());
    }
  }
  // Normals and distance ranges once every keyframe has moved.
  for (MapPoint* p : points) p->updateFromObservations();
  // The newer map's origin hangs under the keyframe it was found from.
  if (origin) {
    origin->origin = false;
    origin->parent = older_keyframe;
    older_keyframe->children.push_back(origin);
  }
  map_->staticSightings().moveMap(newer, older, T_older_newer);
  current_.T_c_w = renormalized(current_.T_c_w * T_newer_older);
  if (has_last_) last_.T_c_w = renormalized(last_.T_c_w * T_newer_older);
  map_->activate(older);
  notePoseWorld();
  map_id_ = older;
  trajectory_.relabel(newer, older);
  if (detector_) detector_->forgetHistory();
  SP_WARN(logger, "frame " << current_.id << ": map " << newer << " (" << keyframes << " keyframes, " << moved.size()
                           << " points) merged into map " << older << " at keyframe " << older_keyframe->id);
}

}  // namespace stillpoint::slam
