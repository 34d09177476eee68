#pragma once
// Trajectory error metrics as defined by the TUM RGB-D benchmark
// (Sturm et al., IROS 2012): absolute trajectory error (ATE) after a
// closed-form rigid alignment, and relative pose error (RPE) over 1 s.
#include <cstddef>
#include <string>
#include <vector>

#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"
#include "stillpoint/eval/trajectory.hpp"

namespace stillpoint::eval {

struct EvalOptions {
  double max_dt_s = 0.02;      // association window: |t_est - t_gt| <= max_dt_s
  double rpe_delta_s = 1.0;    // RPE pose distance in time
  bool estimate_scale = false; // Umeyama similarity instead of a rigid transform
  std::size_t min_matches = 3;

  // Names the first bad field, or succeeds.
  Status validate() const;
};

// One matched pair: indices into the estimate and the ground truth.
struct Match {
  std::size_t est_index = 0;
  std::size_t gt_index = 0;
};

// One-to-one association as TUM's associate.py does it: every pair with
// |t_est - t_gt| <= max_dt_s is a candidate; candidates are taken greedily by
// smallest time difference (ties: earlier estimate, then earlier ground truth),
// skipping poses already used. Returned sorted by estimate time. Both inputs
// must be sorted by time.
std::vector<Match> associate(const Trajectory& est, const Trajectory& gt, double max_dt_s);

// Similarity transform p_gt ~ scale * (R * p_est) + t, with R and t in T_gt_est.
struct Alignment {
  SE3 T_gt_est = SE3::Identity();
  double scale = 1.0;

  Vec3 apply(const Vec3& p_est) const;
  // Maps a pose of the estimate's world into the ground truth's world; the
  // scale multiplies the position only.
  SE3 apply(const SE3& T_w_c) const;
};

// Closed-form least-squares alignment of est onto gt positions (Horn 1987 /
// Umeyama 1991, via SVD of the cross-covariance with the reflection fix).
// Minimises sum |gt_k - (s R est_k + t)|^2 with s = 1 unless estimate_scale.
// Needs equal sizes, >= 3 points, and spread points when scale is estimated.
Result<Alignment> alignUmeyama(const std::vector<Vec3>& est_positions,
                               const std::vector<Vec3>& gt_positions, bool estimate_scale);

// Absolute error of one matched estimate pose after alignment.
struct PoseError {
  Timestamp stamp;  // estimate time
  double ate_m = 0.0;
};

// One RPE pair (i, j) of matched estimate poses.
struct RelativeError {
  Timestamp from;  // t_i (estimate time)
  Timestamp to;    // t_j (estimate time)
  double dt_s = 0.0;       // t_j - t_i
  double trans_m = 0.0;    // |translation(E)|
  double rot_deg = 0.0;    // rotation angle of E
};

struct EvalResult {
  std::size_t matched = 0;  // matched poses in the maps aligned
  // Maps in the estimate (StampedPose::map_id), each aligned on its own;
  // `unaligned`: matched poses of maps too short to align (left out).
  std::size_t maps = 1;
  std::size_t unaligned = 0;
  std::size_t matched_in_largest_map = 0;  // `alignment` is that map's
  Alignment alignment;
  // ATE over the matched poses, metres.
  double ate_rmse_m = 0.0;
  double ate_mean = 0.0;
  double ate_median = 0.0;
  double ate_max = 0.0;
  // ATE of every matched pose, the short maps' too, under one alignment for
  // all maps: the error a consumer that takes every pose in one frame sees
  // (a new map's poses are only as good as where it was started). Equal to
  // ate_rmse_m for one map.
  double ate_one_frame_rmse_m = 0.0;
  // RPE rates; NaN when no pair spans rpe_delta_s (trajectory too short).
  double rpe_trans_m_s = 0.0;
  double rpe_rot_deg_s = 0.0;
  std::size_t rpe_pairs = 0;
  // Per matched pose, in estimate time order; the three vectors line up.
  std::vector<PoseError> pose_errors;
  Trajectory est_aligned;  // matched estimate poses mapped by `alignment`
  Trajectory gt_matched;   // their associated ground-truth poses
  std::vector<RelativeError> relative_errors;
};

// RPE over already matched pose pairs (est[k] belongs with gt[k], both in
// estimate time order), following the benchmark's definition for a time delta:
//   for each i, j = the matched estimate pose whose time is closest to
//   t_i + delta_s (pairs whose target time lies past the last pose, or with
//   j == i, are skipped);
//   E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j), P = estimate, Q = ground truth;
//   trans_m = |t(E_ij)|, rot_deg = angle(R(E_ij)) in degrees.
// The rates are RMSE over pairs of trans_m / dt and rot_deg / dt with
// dt = t_j - t_i the actual estimate time difference (m/s and deg/s).
// Relative motions do not change under a rigid alignment, so P may be the raw
// or the aligned estimate.
struct RpeSummary {
  double trans_m_s = 0.0;
  double rot_deg_s = 0.0;
  std::vector<RelativeError> pairs;
};
RpeSummary computeRpe(const Trajectory& est, const Trajectory& gt, double delta_s);

// Associates, aligns and computes ATE and RPE. Fails on invalid options or
// fewer than options.min_matches associated poses.
Result<EvalResult> evaluate(const Trajectory& gt, const Trajectory& est,
                            const EvalOptions& options = {});

// The q-quantile (0 < q <= 1) of `values` by nearest rank, the smallest value
// with at least a share q of them at or below it; for q = 0.5 the median (the
// mean of the middle two of an even count). NaN when there are none.
double quantile(std::vector<double> values, double q);

// How far off the poses of each label were (a label per pose: its pose health,
// or any other class): for every matched pose j of an evaluation, the
// translation error [m] of the motion over the last `window_s`, from the
// newest matched pose i of the same map with t_i <= t_j - window_s + max_dt_s
// (none when that is more than two windows back):
// |t((Q_i^-1 Q_j)^-1 (P_i^-1 P_j))|.
// That is the error a pose added over a moment, which a consumer trusting
// the label would take in; unlike the ATE it does not depend on how the whole
// trajectory aligns. A pose takes the label nearest in time within
// max_dt_s ("-" when none).
struct LabelDrift {
  std::string label;
  std::size_t poses = 0;  // poses of the label with a pose window_s before them
  double median_m = 0.0;
  double p90_m = 0.0;
  double max_m = 0.0;
  double share_over_bound = 0.0;  // share of those poses whose error exceeds the bound
};

struct DriftOptions {
  double window_s = 1.0 / 3.0;  // 10 frames at 30 Hz
  double bound_m = 0.02;
  double max_dt_s = 0.02;
  // Labels reported first, in this order (each only if some pose has it);
  // the others follow in alphabetical order.
  std::vector<std::string> order;

  // Names the first bad field, or succeeds.
  Status validate() const;
};

// The options for stillpoint's pose health (the frame log's `health`): its
// levels reported best first, good, degraded, unreliable.
DriftOptions poseHealthDriftOptions();
// The options for what lowered the pose health (the frame log's
// `health_causes`, split by splitLabels): none first, then the causes in the
// order of their bits (stillpoint/core/health_causes.hpp).
DriftOptions healthCauseDriftOptions();

Result<std::vector<LabelDrift>> driftByLabel(const EvalResult& result, const std::vector<StampedLabel>& labels,
                                             const DriftOptions& options = {});

// The same in two steps, to pool poses of several runs: each pose's label
// and drift, and their summary per label.
struct LabelledDrift {
  std::string label;
  double drift_m = 0.0;
};
Result<std::vector<LabelledDrift>> driftPerPose(const EvalResult& result, const std::vector<StampedLabel>& labels,
                                                const DriftOptions& options = {});
std::vector<LabelDrift> summariseDrift(const std::vector<LabelledDrift>& poses, const DriftOptions& options = {});
// Each pose once under every part of its label ("view_moving+masks_late":
// once under each), for labels that name a set.
std::vector<LabelledDrift> splitLabels(const std::vector<LabelledDrift>& poses, char separator = '+');

// How well pose covariances cover the drift (docs/pose-health.md, "The
// covariance"): for every pose j that driftPerPose pairs with a pose i, the
// drift's translation and rotation (of E_ij, in camera j's axes), each
// normalised by the covariance the two poses' covariances give it to first
// order (`estimate`: the unaligned trajectory they belong to; pose i's
// rotation error swings the way from i to j, so it adds to the translation's):
// d^T S^-1 d, chi-square with 3 degrees of freedom where the covariances are
// right. Poses without a covariance (all zero, or none within
// max_dt_s) are left out; a pose takes the label nearest in time ("-": none).
struct NormalisedDrift {
  std::string label;
  double position = 0.0;
  double rotation = 0.0;
};
Result<std::vector<NormalisedDrift>> normalisedDriftPerPose(const EvalResult& result, const Trajectory& estimate,
                                                            const std::vector<StampedCovariance>& covariances,
                                                            const std::vector<StampedLabel>& labels,
                                                            const DriftOptions& options = {});

// Per label (options.order first, as summariseDrift), then "all": the share of
// normalised drifts within the 95 % ellipsoid (under 7.815) and their median
// over a chi-square's (2.366): 1 when the covariances are as wide as they
// should be, above 1 when too narrow.
struct CovarianceCoverage {
  std::string label;
  std::size_t poses = 0;
  double position_within = 0.0, position_median = 0.0;
  double rotation_within = 0.0, rotation_median = 0.0;
};
std::vector<CovarianceCoverage> summariseCoverage(const std::vector<NormalisedDrift>& poses,
                                                  const DriftOptions& options = {});

}  // namespace stillpoint::eval
