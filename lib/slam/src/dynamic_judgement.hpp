#pragma once
// The dynamic-object detector's per-frame working state, shared by its
// pipeline (dynamic_detector.cpp) and its dense cues (dynamic_cues.cpp).
#include <memory>
#include <utility>
#include <vector>

#include "dynamic_detector.hpp"

namespace stillpoint::slam {

// What one feature of the current frame says about its own motion.
struct FeatureEvidence {
  // Its stage-1 map point, else a carried or reference-keyframe match (null:
  // none, or an ambiguous projection match).
  std::shared_ptr<MapPoint> point;
  bool from_map = false;   // `point` is its stage-1 map point
  bool ambiguous = false;  // its projection match had a close second
  int links = 1;           // carried chain: links to its oldest position
  // Its match to an anchor frame (fixed baseline, the strongest evidence).
  bool has_anchor = false;
  Vec3 anchor_point = Vec3::Zero();
  int anchor_distance = 0;  // Hamming distance of that match
  const std::uint8_t* anchor_descriptor = nullptr;
  int anchor_baseline = 0;  // frames back
  // Matched to a feature that was moving before (carried from the last
  // frame's flagged ones, or an anchor's geometry-dynamic feature; a semantic
  // mask's mark alone is not motion): its cluster's memory.
  bool inherited = false;
  // Matched to a feature this module found moving (carried, or an anchor's
  // geometry-dynamic feature): a mask's movable class is not motion.
  bool seen_moving = false;
  Vec3 residual = Vec3::Zero();  // of its last judgement, over the level sigma
  double carried_chi2 = 0;       // judged by carried evidence: its chi2 (lone_moving_chi2)
  bool released = false;         // in a dynamic cluster but static (moved-surface split, photometric test)
};

// A feature that took part in the verdict.
struct JudgedEvidence {
  int feature;
  JudgedFeature::Evidence kind;
};

// A feature whose evidence disagreed but which the static hypothesis explains
// as well (another copy of a repeating pattern): out of the verdict, reported.
struct ExplainedEvidence {
  int feature;
  double chi2;
  JudgedFeature::Evidence kind;
};

struct DynamicDetector::FrameJudgement {
  Frame& frame;
  const StageOneMatches& stage_one;
  std::shared_ptr<const geometry::DepthClusters> clusters{};
  GeometryOutput out{};
  std::vector<FeatureEvidence> ev{};
  // Map points of ambiguous matches: they still learn their cluster's verdict.
  std::vector<std::pair<int, std::shared_ptr<MapPoint>>> ambiguous_points{};
  std::vector<int> anchored_in_cluster{};  // anchor matches per cluster
  // Per cluster: most of its anchor matches were seen moving (knownMovers()).
  std::vector<char> known_mover{};
  bool anchored = false;                 // judged by the anchor evidence (else stage-1 matches)
  // The latest judgement: residuals (lib/geometry's input) and, per entry, who.
  std::vector<geometry::FeatureResidual> residuals{};
  std::vector<JudgedEvidence> judged{};
  std::vector<ExplainedEvidence> explained{};
  geometry::FreeSpace free{};
  geometry::ClusterVerdict verdict{};
  // Stage 1's matches, restored for features the photometric test frees.
  std::vector<std::shared_ptr<MapPoint>> stage_one_points{};
  bool refitted = false;  // the pose is fitted without the dropped features
  // Frame indices into seen_ per photometric try, nearest baseline last.
  std::vector<std::vector<std::size_t>> photo_tries{};
};

}  // namespace stillpoint::slam
