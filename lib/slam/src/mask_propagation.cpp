#include <algorithm>

#include "matcher.hpp"
#include "stillpoint/core/log.hpp"
#include "tracking.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("tracking");
}  // namespace

void Tracker::markSemanticMovers() {
  // The newest segmented keyframe near the camera: features inside its
  // movable masks are looked up in this frame by descriptor alone (the
  // object may have moved anywhere since) and kept out of the pose, so a
  // masked object does not pull the pose between keyframes.
  const KeyFrame* source = nullptr;
  const auto consider = [&](const KeyFrame* kf) {
    if (kf && !kf->bad && kf->segmented && (!source || kf->id > source->id)) source = kf;
  };
  consider(reference_);
  for (const KeyFrame* kf : local_keyframes_) consider(kf);
  if (!source) return;
  const auto has_flags = [](const Frame& other) {
    return std::find(other.dynamic.begin(), other.dynamic.end(), kSemanticDynamic) != other.dynamic.end();
  };
  // Most keyframes mask nothing: skip the brute-force pass then.
  if (!has_flags(source->frame)) return;
  const Frame& f = source->frame;
  // Mutual nearest neighbours over all the keyframe's features, ratio 0.7 and
  // rotation consistency: window-free matching on repetitive texture
  // mismatches, and a static feature marked here is lost to the pose.
  for (const auto& [j, i] : matchByDescriptor(current_, f, 0.7f, false, true)) {
    if (f.dynamic[i] != kSemanticDynamic) continue;
    current_.dynamic[j] = kSemanticDynamic, ++semantic_marked_;
  }
  if (options_.semantic.propagate_from_last && has_last_ && has_flags(last_)) {
    // The last frame's flagged features, looked up here: from frame to frame
    // an object changes less than since its keyframe. (Features the geometry
    // module flagged carry its flag instead and are not followed.)
    int chained = 0;
    for (const auto& [j, i] : matchByDescriptor(current_, last_, 0.7f, false, true))
      if (last_.dynamic[i] == kSemanticDynamic && !current_.dynamic[j]) current_.dynamic[j] = kSemanticDynamic, ++chained;
    semantic_marked_ += chained;
    SP_DEBUG(logger, "frame " << current_.id << ": " << chained << " flagged from the last frame");
  }
  const float grow = options_.semantic.propagate_grow_px;
  for (int pass = 0; grow > 0 && semantic_marked_ >= 5 && pass < options_.semantic.propagate_grow_passes; ++pass) {
    // Region growing from the matches, then (more passes) from what it added.
    std::vector<int> grown;
    for (int j = 0; j < current_.size(); ++j) {
      const float z = current_.depth[j];
      if (current_.dynamic[j] || z <= 0) continue;
      if (maskedNeighbours(current_, current_.un[j], z, grow) >= 2) grown.push_back(j);
    }
    for (int j : grown) current_.dynamic[j] = kSemanticDynamic;
    semantic_marked_ += static_cast<int>(grown.size());
    if (grown.empty()) break;
  }
  SP_DEBUG(logger, "frame " << current_.id << ": " << semantic_marked_ << " features matched to masks of keyframe " << source->id);
}

}  // namespace stillpoint::slam
