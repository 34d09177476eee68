#pragma once
// Scores dynamic-feature flags against ground-truth mover masks.
//
// Feature file (written by the SLAM side), one feature per line:
//   timestamp u v flagged
// timestamp as in rgb.txt (the colour frame), u v pixel coordinates in that
// image, flagged 1 when the feature was classified dynamic, else 0. Lines
// starting with '#' and blank lines are ignored. A feature lies on a mover when
// the mask pixel nearest to (u, v) is non-zero.
#include <cstdint>
#include <map>
#include <span>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"

namespace stillpoint::synth {

struct FlaggedFeature {
  double u = 0, v = 0;
  bool flagged = false;
};

struct MoverFeatureCount {
  std::uint16_t id = 0;
  int features = 0;  // features on this mover
  int flagged = 0;   // of which flagged dynamic
};

struct FrameScore {
  int features = 0;         // inside the image
  int outside = 0;          // ignored: outside the image
  int flagged = 0;
  int on_movers = 0;        // on a moving mover (every mover when no speeds are given)
  int true_positives = 0;   // flagged and on a moving mover
  // On movers that stand still in this frame (slower than the scorer's
  // min_speed): not required to be found, not wrong when flagged.
  int on_still = 0, still_flagged = 0;
  std::vector<MoverFeatureCount> movers;  // movers carrying features, by id
  // Movers with at least min_mover_features features ("eligible").
  int eligible_movers = 0, eligible_features = 0, eligible_flagged = 0;

  // NaN when undefined (nothing flagged / no feature on a mover / no eligible mover).
  // precision = (true_positives + still_flagged) / flagged.
  double precision() const;
  double recall() const;
  double eligibleRecall() const;
};

// mask: CV_16UC1 (0 = static, otherwise mover id). still: ids of the movers
// standing still in this frame (their features count for neither recall nor
// eligibility, and a flag on them is no false positive).
FrameScore scoreFrame(const cv::Mat& mask, std::span<const FlaggedFeature> features,
                      int min_mover_features = 10, std::span<const std::uint16_t> still = {});

struct SequenceScore {
  int frames = 0;  // frames scored
  // Per-frame values averaged over the frames where they are defined.
  double precision_mean = 0, recall_mean = 0;
  int precision_frames = 0, recall_frames = 0;
  // The criterion of the detection bars: frames with at least one mover carrying
  // >= min_mover_features features; recall over those movers' features,
  // precision over all flags of those frames.
  double eligible_recall_mean = 0, eligible_precision_mean = 0;
  int eligible_frames = 0, eligible_precision_frames = 0;
  // Pooled over all frames.
  long features = 0, flagged = 0, on_movers = 0, true_positives = 0, on_still = 0, still_flagged = 0;
  // Frames without any feature on a mover that still have flags (false alarms).
  int static_frames_with_flags = 0;
  // Per mover id: features and flags summed over frames, and frames eligible.
  std::map<std::uint16_t, MoverFeatureCount> movers;
  std::map<std::uint16_t, int> mover_eligible_frames;
};

SequenceScore averageScores(std::span<const FrameScore> frames, int min_mover_features = 10);

// A generated sequence's mask list (SEQUENCE_DIR/mask.txt): each colour
// frame's timestamp and the path of its mask (CV_16UC1, 0 = static).
Result<std::map<Timestamp, std::string>> readMaskList(const std::string& sequence_dir);

// Reads a feature file; errors name the file and line.
Result<std::map<Timestamp, std::vector<FlaggedFeature>>> readFlaggedFeatures(const std::string& path);

struct SequenceScoreReport {
  SequenceScore score;
  std::vector<std::pair<Timestamp, FrameScore>> frames;
  int frames_without_features = 0;  // in mask.txt but not in the feature file
};

// Scores a feature file against a generated sequence (its mask.txt and masks).
// A feature stamp missing from mask.txt is an error naming the line.
// min_speed_m_s > 0: a mover counts as moving in a frame only when its speed
// in movers.txt is at least this; a still mover is scored as still (above).
// A geometric detector cannot see a mover that does not move: the walking
// presets ease to a stop at each end of their path.
Result<SequenceScoreReport> scoreSequence(const std::string& sequence_dir, const std::string& features_path,
                                          int min_mover_features = 10, double min_speed_m_s = 0.0);

}  // namespace stillpoint::synth
