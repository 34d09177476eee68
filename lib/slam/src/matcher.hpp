#pragma once
// Descriptor matching between frames, keyframes and map points.
#include <memory>
#include <utility>
#include <vector>

#include "map.hpp"

namespace stillpoint::slam {

constexpr int kMatchThresholdHigh = 100;
constexpr int kMatchThresholdLow = 50;

// Projects the matched points of `last` into `current` (pose already
// predicted) and matches in a window of `radius` x scale pixels. `ratio_out`
// (optional, sized to `current`) receives per matched keypoint the ratio of
// the best Hamming distance to the second best among all keypoints in the
// window (a lone candidate: against kMatchThresholdLow): a match on
// repetitive texture has a close second. `max_ratio` > 0 rejects matches above that ratio.
int searchByProjection(Frame* current, const Frame& last, float radius, std::vector<float>* ratio_out = nullptr,
                       float max_ratio = 0);

// Projects local map points into `current`; `radius_factor` widens windows.
int searchLocalPoints(Frame* current, const std::vector<std::shared_ptr<MapPoint>>& points,
                      float radius_factor, std::vector<char>* in_view_out = nullptr);

// Matches the keyframe's map points to `current` by descriptor only (no pose
// needed): nearest neighbour with ratio test and orientation consistency.
// Returns matches as pairs (frame keypoint, map point) written into current->points.
int searchByDescriptor(Frame* current, const KeyFrame& keyframe, float ratio);
// The same matching, returned as (frame keypoint, keyframe keypoint) pairs
// without touching the frame.
std::vector<std::pair<int, int>> matchByDescriptor(const Frame& current, const KeyFrame& keyframe, float ratio);
// The same between two frames: keypoints of `other` take part when they hold
// a map point (`need_point`) or a depth (otherwise). `mutual` also asks that
// the frame keypoint's own nearest neighbour in `other` is its match (fewer
// mismatches on repetitive texture, at the cost of a second pass). Frame
// keypoints already flagged dynamic take part only when no map point is needed
// (evidence, not pose).
std::vector<std::pair<int, int>> matchByDescriptor(const Frame& current, const Frame& other, float ratio,
                                                   bool need_point, bool mutual = false);

// The mutual matches of matchByDescriptor(current, other, ratio, false, true)
// that fall on `features` (frame keypoint indices, ascending), found by
// scanning `other` once per listed keypoint, and `current` once per
// keypoint of `other` that may own it, instead of `current` once per
// keypoint of `other`: a few clusters' features cost a few per cent of a
// whole frame's matching. The orientation filter sees only these matches.
std::vector<std::pair<int, int>> matchSomeByDescriptor(const Frame& current, const Frame& other, float ratio,
                                                       const std::vector<int>& features);
// The same from the other side: the mutual matches of matchByDescriptor(
// current, other, ratio, false, true) whose keypoint of `other` is among
// `from` (its indices, ascending), found by scanning `current` once per
// listed keypoint and `other` once per keypoint of `current` that one of them
// claims (and `current` again for a keypoint of `other` that ties it). The
// orientation filter sees only these matches.
std::vector<std::pair<int, int>> matchFromSomeByDescriptor(const Frame& current, const Frame& other, float ratio,
                                                           const std::vector<int>& from);


// Keeps only matches whose rotation change agrees with the dominant ones.
void filterByOrientation(const std::vector<float>& rotation_deg, std::vector<int>* match_indices);

}  // namespace stillpoint::slam
