#include "stillpoint/eval/metrics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>
#include <random>

namespace stillpoint::eval {
namespace {

constexpr double kDegToRad = std::numbers::pi / 180.0;

Timestamp at(double seconds) { return Timestamp::fromSeconds(1000.0 + seconds); }

SE3 pose(const Mat3& R, const Vec3& t) {
  SE3 T = SE3::Identity();
  T.linear() = R;
  T.translation() = t;
  return T;
}

// A wandering, non-planar camera path at `rate_hz` for `duration_s`.
Trajectory randomTrajectory(std::mt19937& rng, double rate_hz, double duration_s) {
  std::normal_distribution<double> step(0.0, 0.05);
  Trajectory trajectory;
  Vec3 p = Vec3::Zero();
  Vec3 w = Vec3::Zero();
  const int n = static_cast<int>(rate_hz * duration_s);
  for (int k = 0; k < n; ++k) {
    p += Vec3(0.02, 0.01, 0.005) + Vec3(step(rng), step(rng), step(rng));
    w += 0.1 * Vec3(step(rng), step(rng), step(rng));
    trajectory.push_back({at(k / rate_hz), pose(expSO3(w), p)});
  }
  return trajectory;
}

SE3 knownTransform() {
  return pose(expSO3(Vec3(0.3, -1.2, 2.0)), Vec3(4.0, -2.5, 1.25));
}

TEST(Associate, PicksNearestWithinWindowAndRejectsFarther) {
  Trajectory gt;
  for (int k = 0; k < 10; ++k) gt.push_back({at(0.1 * k), SE3::Identity()});
  const Trajectory est = {
      {at(0.105), SE3::Identity()},  // 5 ms after gt[1]
      {at(0.215), SE3::Identity()},  // 15 ms after gt[2]
      {at(0.3249), SE3::Identity()}, // 24.9 ms after gt[3]: too far
      {at(0.48), SE3::Identity()},   // 20 ms before gt[5]: inside (inclusive)
  };
  const auto matches = associate(est, gt, 0.02);
  ASSERT_EQ(matches.size(), 3u);
  EXPECT_EQ(matches[0].est_index, 0u);
  EXPECT_EQ(matches[0].gt_index, 1u);
  EXPECT_EQ(matches[1].est_index, 1u);
  EXPECT_EQ(matches[1].gt_index, 2u);
  EXPECT_EQ(matches[2].est_index, 3u);
  EXPECT_EQ(matches[2].gt_index, 5u);
}

TEST(Associate, IsOneToOneGreedyBySmallestDifference) {
  // gt at 0 and 10 ms; estimates at 4 ms and 6 ms. 4 ms takes gt 0 (diff 4),
  // 6 ms then takes gt 10 (diff 4) — not gt 0 again.
  const Trajectory gt = {{at(0.0), SE3::Identity()}, {at(0.010), SE3::Identity()}};
  const Trajectory est = {{at(0.004), SE3::Identity()}, {at(0.006), SE3::Identity()}};
  const auto matches = associate(est, gt, 0.02);
  ASSERT_EQ(matches.size(), 2u);
  EXPECT_EQ(matches[0].gt_index, 0u);
  EXPECT_EQ(matches[1].gt_index, 1u);

  // A third estimate near gt 0 stays unmatched once both gt poses are used.
  const Trajectory est3 = {{at(-0.001), SE3::Identity()},
                           {at(0.004), SE3::Identity()},
                           {at(0.009), SE3::Identity()}};
  const auto matches3 = associate(est3, gt, 0.02);
  ASSERT_EQ(matches3.size(), 2u);
  EXPECT_EQ(matches3[0].est_index, 0u);  // |-1 ms| beats |4 ms| for gt 0
  EXPECT_EQ(matches3[1].est_index, 2u);  // 1 ms beats 6 ms for gt 10 ms
}

TEST(Align, RecoversKnownRigidTransformExactly) {
  std::mt19937 rng(1);
  for (int trial = 0; trial < 5; ++trial) {
    const Trajectory gt = randomTrajectory(rng, 30.0, 5.0);
    const SE3 T_est_gt = knownTransform();
    Trajectory est;
    for (const StampedPose& p : gt) est.push_back({p.stamp, T_est_gt * p.T_w_c});

    const auto result = evaluate(gt, est);
    ASSERT_TRUE(result.ok()) << result.error();
    EXPECT_EQ(result->matched, gt.size());
    EXPECT_LT(result->ate_rmse_m, 1e-9);
    EXPECT_LT(result->ate_max, 1e-9);
    EXPECT_LT(result->rpe_trans_m_s, 1e-9);
    EXPECT_LT(result->rpe_rot_deg_s, 1e-6);
    EXPECT_TRUE(result->alignment.T_gt_est.isApprox(T_est_gt.inverse(), 1e-9));
    EXPECT_DOUBLE_EQ(result->alignment.scale, 1.0);
  }
}

TEST(Align, RecoversScaleWhenAsked) {
  std::mt19937 rng(2);
  const Trajectory gt = randomTrajectory(rng, 30.0, 4.0);
  std::vector<Vec3> gt_positions;
  std::vector<Vec3> est_positions;
  const SE3 T_est_gt = knownTransform();
  for (const StampedPose& p : gt) {
    gt_positions.push_back(p.T_w_c.translation());
    est_positions.push_back(0.4 * (T_est_gt * p.T_w_c.translation()));
  }
  const auto with_scale = alignUmeyama(est_positions, gt_positions, true);
  ASSERT_TRUE(with_scale.ok()) << with_scale.error();
  EXPECT_NEAR(with_scale->scale, 2.5, 1e-9);
  for (std::size_t k = 0; k < gt_positions.size(); ++k) {
    EXPECT_LT((with_scale->apply(est_positions[k]) - gt_positions[k]).norm(), 1e-9);
  }
  const auto rigid = alignUmeyama(est_positions, gt_positions, false);
  ASSERT_TRUE(rigid.ok());
  EXPECT_EQ(rigid->scale, 1.0);
  EXPECT_TRUE(rigid->T_gt_est.linear().isApprox(T_est_gt.linear().transpose(), 1e-9));
}

TEST(Align, NeverReturnsAReflection) {
  // Mirror-image point sets: the best proper rotation, not the mirror.
  const std::vector<Vec3> gt = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
  std::vector<Vec3> est;
  for (const Vec3& p : gt) est.emplace_back(p.x(), p.y(), -p.z());
  const auto alignment = alignUmeyama(est, gt, false);
  ASSERT_TRUE(alignment.ok());
  EXPECT_NEAR(alignment->T_gt_est.linear().determinant(), 1.0, 1e-12);
}

TEST(Ate, AlternatingOffsetGivesThatOffset) {
  // Each position appears twice; the estimate is +d then -d along x. The
  // offsets cancel in the cross-covariance, so the alignment is the identity
  // (after undoing a known transform) and every error is exactly d.
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> uniform(-2.0, 2.0);
  const double d = 0.037;
  const SE3 T_est_gt = knownTransform();
  Trajectory gt;
  Trajectory est;
  for (int k = 0; k < 40; ++k) {
    const Vec3 p(uniform(rng), uniform(rng), uniform(rng));
    for (int s : {+1, -1}) {
      const Timestamp t = at(0.01 * static_cast<double>(gt.size()));
      gt.push_back({t, pose(Mat3::Identity(), p)});
      est.push_back({t, T_est_gt * pose(Mat3::Identity(), p + Vec3(s * d, 0, 0))});
    }
  }
  const auto result = evaluate(gt, est);
  ASSERT_TRUE(result.ok()) << result.error();
  EXPECT_NEAR(result->ate_rmse_m, d, 1e-12);
  EXPECT_NEAR(result->ate_mean, d, 1e-12);
  EXPECT_NEAR(result->ate_median, d, 1e-12);
  EXPECT_NEAR(result->ate_max, d, 1e-12);
  ASSERT_EQ(result->pose_errors.size(), gt.size());
  EXPECT_NEAR(result->pose_errors[5].ate_m, d, 1e-12);
}

TEST(Rpe, ConstantVelocityErrorGivesThatRate) {
  // Ground truth moves at v_gt, the estimate at v_gt + dv, both with the same
  // fixed (non-identity) orientation; every 1 s pair is off by |dv| * dt.
  const Vec3 v_gt(0.3, -0.1, 0.05);
  const Vec3 dv(0.04, 0.0, -0.03);  // |dv| = 0.05 m/s
  const Mat3 R = expSO3(Vec3(0.2, 0.4, -0.7));
  Trajectory gt;
  Trajectory est;
  for (int k = 0; k < 300; ++k) {
    const double t = k / 30.0;
    gt.push_back({at(t), pose(R, v_gt * t)});
    est.push_back({at(t), knownTransform() * pose(R, (v_gt + dv) * t)});
  }
  const auto result = evaluate(gt, est);
  ASSERT_TRUE(result.ok()) << result.error();
  EXPECT_NEAR(result->rpe_trans_m_s, 0.05, 1e-9);
  EXPECT_NEAR(result->rpe_rot_deg_s, 0.0, 1e-6);
  // Pairs start at every pose up to 1 s before the end.
  EXPECT_EQ(result->rpe_pairs, 300u - 30u);
  for (const RelativeError& pair : result->relative_errors) {
    EXPECT_NEAR(pair.dt_s, 1.0, 1e-6);
  }
}

TEST(Rpe, RotationDriftGivesDegreesPerSecond) {
  // Same positions; the estimate's orientation drifts at 2 deg/s about a
  // fixed world axis on top of a rotating ground truth. With the drift D on the
  // world side, E_ij = R_j^T D(t_j - t_i) R_j, whose angle is exactly the drift.
  const double drift_deg_s = 2.0;
  const Vec3 axis = Vec3(1.0, 2.0, 2.0) / 3.0;
  Trajectory gt;
  Trajectory est;
  for (int k = 0; k < 300; ++k) {
    const double t = k / 30.0;
    const Vec3 p(std::cos(t), std::sin(t), 0.2 * t);  // non-planar helix
    const Mat3 R_gt = expSO3(Vec3(0.0, 0.0, 0.3 * t));
    gt.push_back({at(t), pose(R_gt, p)});
    est.push_back({at(t), pose(expSO3(axis * drift_deg_s * kDegToRad * t) * R_gt, p)});
  }
  const auto result = evaluate(gt, est);
  ASSERT_TRUE(result.ok()) << result.error();
  EXPECT_LT(result->ate_rmse_m, 1e-9);
  EXPECT_NEAR(result->rpe_rot_deg_s, drift_deg_s, 1e-6);
}

TEST(Rpe, IsNanWhenShorterThanDelta) {
  std::mt19937 rng(4);
  const Trajectory gt = randomTrajectory(rng, 30.0, 0.5);
  const auto result = evaluate(gt, gt);
  ASSERT_TRUE(result.ok()) << result.error();
  EXPECT_EQ(result->rpe_pairs, 0u);
  EXPECT_TRUE(std::isnan(result->rpe_trans_m_s));
}

TEST(Evaluate, FailsWithFewerThanThreeMatches) {
  std::mt19937 rng(5);
  const Trajectory gt = randomTrajectory(rng, 30.0, 2.0);
  Trajectory est;
  for (std::size_t k = 0; k < 2; ++k) est.push_back(gt[k]);
  for (std::size_t k = 0; k < 5; ++k) {
    est.push_back({Timestamp::fromNanoseconds(gt.back().stamp.nanoseconds() + 1'000'000'000 +
                                              static_cast<std::int64_t>(k)),
                   SE3::Identity()});
  }
  const auto result = evaluate(gt, est);
  ASSERT_FALSE(result.ok());
  EXPECT_NE(result.error().find("only 2 of 7"), std::string::npos) << result.error();
}

TEST(Evaluate, AlignsEachMapOnItsOwn) {
  // The second half of the estimate is a new map: the same path in another
  // frame. Each map aligned on its own matches exactly; one alignment of both
  // could not.
  std::mt19937 rng(11);
  const Trajectory gt = randomTrajectory(rng, 30.0, 6.0);
  Trajectory est = gt;
  const SE3 second_frame = knownTransform();
  for (std::size_t k = est.size() / 2; k < est.size(); ++k) {
    est[k].T_w_c = second_frame * est[k].T_w_c;
    est[k].map_id = 1;
  }
  const auto result = evaluate(gt, est);
  ASSERT_TRUE(result.ok()) << result.error();
  EXPECT_EQ(result->maps, 2u);
  EXPECT_EQ(result->matched, gt.size());
  EXPECT_EQ(result->unaligned, 0u);
  EXPECT_LT(result->ate_rmse_m, 1e-9);
  EXPECT_LT(result->rpe_trans_m_s, 1e-9);  // no relative error spans the two maps
  // Taken in one frame, as a consumer that ignores the map id would, the
  // second map is far off.
  EXPECT_GT(result->ate_one_frame_rmse_m, 0.1);
  ASSERT_EQ(result->pose_errors.size(), gt.size());
  for (std::size_t k = 1; k < result->pose_errors.size(); ++k)
    EXPECT_LT(result->pose_errors[k - 1].stamp, result->pose_errors[k].stamp);

  // Marked as one map, the same poses are far off.
  for (StampedPose& p : est) p.map_id = 0;
  const auto merged = evaluate(gt, est);
  ASSERT_TRUE(merged.ok()) << merged.error();
  EXPECT_EQ(merged->maps, 1u);
  EXPECT_GT(merged->ate_rmse_m, 0.1);
  EXPECT_EQ(merged->ate_one_frame_rmse_m, merged->ate_rmse_m);
}

TEST(Evaluate, OneFrameErrorOfAMapStartedWhereTheLastLeftOff) {
  // The second map starts in the first one's frame, 10 cm off along x (what
  // the camera moved while lost): each map alone is exact, and in one frame
  // the error is that offset, shared out by the alignment.
  std::mt19937 rng(13);
  const Trajectory gt = randomTrajectory(rng, 30.0, 6.0);
  Trajectory est = gt;
  const std::size_t half = est.size() / 2;
  for (std::size_t k = half; k < est.size(); ++k) {
    est[k].T_w_c.translation() += Vec3(0.1, 0, 0);
    est[k].map_id = 1;
  }
  const auto result = evaluate(gt, est);
  ASSERT_TRUE(result.ok()) << result.error();
  EXPECT_LT(result->ate_rmse_m, 1e-9);
  // A shift alone splits the offset between the halves (5 cm each way); the
  // best rigid alignment does no worse, and cannot undo it.
  EXPECT_GT(result->ate_one_frame_rmse_m, 0.02);
  EXPECT_LE(result->ate_one_frame_rmse_m, 0.05 + 1e-9);
}

TEST(Evaluate, LeavesOutMapsTooShortToAlign) {
  std::mt19937 rng(12);
  const Trajectory gt = randomTrajectory(rng, 30.0, 3.0);
  Trajectory est = gt;
  est[est.size() - 2].map_id = 1;
  est[est.size() - 1].map_id = 1;
  est[est.size() - 1].T_w_c.translation() += Vec3(5, 5, 5);
  const auto result = evaluate(gt, est);
  ASSERT_TRUE(result.ok()) << result.error();
  EXPECT_EQ(result->maps, 2u);
  EXPECT_EQ(result->unaligned, 2u);
  EXPECT_EQ(result->matched, gt.size() - 2);
  EXPECT_LT(result->ate_rmse_m, 1e-9);
}

TEST(Evaluate, RejectsBadOptions) {
  EvalOptions options;
  options.max_dt_s = -1.0;
  EXPECT_NE(options.validate().error().find("max_dt_s"), std::string::npos);
  options = EvalOptions{};
  options.rpe_delta_s = 0.0;
  EXPECT_NE(options.validate().error().find("rpe_delta_s"), std::string::npos);
  options = EvalOptions{};
  options.max_dt_s = 1e10;  // finite, but overflows a stamp in nanoseconds
  EXPECT_NE(options.validate().error().find("max_dt_s"), std::string::npos);
  options = EvalOptions{};
  options.rpe_delta_s = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(options.validate().error().find("rpe_delta_s"), std::string::npos);
  options = EvalOptions{};
  options.min_matches = 2;
  EXPECT_FALSE(options.validate().ok());
  EXPECT_TRUE(EvalOptions{}.validate().ok());
}

TEST(Quantile, NearestRankAndTheMedianOfAnEvenCount) {
  const std::vector<double> v = {10, 3, 7, 1, 9, 2, 8, 4, 6, 5};
  EXPECT_DOUBLE_EQ(quantile(v, 0.5), 5.5);
  EXPECT_DOUBLE_EQ(quantile(v, 0.9), 9.0);
  EXPECT_DOUBLE_EQ(quantile(v, 0.95), 10.0);
  EXPECT_DOUBLE_EQ(quantile(v, 1.0), 10.0);
  EXPECT_DOUBLE_EQ(quantile({4, 1, 3}, 0.5), 3.0);
  EXPECT_TRUE(std::isnan(quantile({}, 0.5)));
}

// The estimate is the ground truth but for a 5 cm jump at frame 40 that it
// keeps (a pose following a mover for a moment); frames 40-49 are labelled
// "unreliable", the rest "good", and the second half is a new map.
TEST(DriftByLabel, GivesEachLabelTheErrorItsPosesAdded) {
  std::mt19937 rng(13);
  const Trajectory gt = randomTrajectory(rng, 30.0, 4.0);
  Trajectory est = gt;
  for (std::size_t k = 40; k < est.size(); ++k) est[k].T_w_c.translation() += Vec3(0.05, 0, 0);
  for (std::size_t k = est.size() / 2; k < est.size(); ++k) {
    est[k].T_w_c = knownTransform() * est[k].T_w_c;
    est[k].map_id = 1;
  }
  std::vector<StampedLabel> labels;
  for (std::size_t k = 0; k < gt.size(); ++k)
    labels.push_back({gt[k].stamp, k >= 40 && k < 50 ? "unreliable" : "good"});
  const auto result = evaluate(gt, est);
  ASSERT_TRUE(result.ok()) << result.error();

  const auto drift = driftByLabel(*result, labels, poseHealthDriftOptions());
  ASSERT_TRUE(drift.ok()) << drift.error();
  ASSERT_EQ(drift->size(), 2u);
  const LabelDrift& good = (*drift)[0];
  const LabelDrift& unreliable = (*drift)[1];
  EXPECT_EQ(good.label, "good");
  EXPECT_EQ(unreliable.label, "unreliable");
  // 10 frames back: frames 10..119 have a pose that far back in their map,
  // but the new map's first 10 (60..69) do not.
  EXPECT_EQ(good.poses + unreliable.poses, gt.size() - 10 - 10);
  EXPECT_EQ(unreliable.poses, 10u);
  // Every unreliable frame spans the jump; the good frames after it carry it
  // until their window starts past it (frames 50-59: 10 frames back is 40-49).
  EXPECT_NEAR(unreliable.median_m, 0.05, 1e-9);
  EXPECT_NEAR(unreliable.max_m, 0.05, 1e-9);
  EXPECT_DOUBLE_EQ(unreliable.share_over_bound, 1.0);
  EXPECT_NEAR(good.median_m, 0.0, 1e-9);
  EXPECT_NEAR(good.max_m, 0.0, 1e-9);  // frames 50-59 start their window at 40-49, past the jump
  EXPECT_DOUBLE_EQ(good.share_over_bound, 0.0);
}

TEST(DriftByLabel, ASetLabelCountsItsPoseUnderEachPart) {
  const std::vector<LabelledDrift> poses = {
      {"none", 0.001}, {"view_moving+masks_late", 0.03}, {"masks_late", 0.01}, {"recovering", 0.002}};
  const std::vector<LabelledDrift> split = splitLabels(poses);
  ASSERT_EQ(split.size(), 5u);
  const auto summary = summariseDrift(split, healthCauseDriftOptions());
  std::vector<std::string> names;
  for (const LabelDrift& d : summary) names.push_back(d.label);
  // none first, then the causes in the order of their bits.
  EXPECT_EQ(names, (std::vector<std::string>{"none", "view_moving", "masks_late", "recovering"}));
  EXPECT_EQ(summary[1].poses, 1u);
  EXPECT_DOUBLE_EQ(summary[1].max_m, 0.03);
  EXPECT_EQ(summary[2].poses, 2u);
  EXPECT_DOUBLE_EQ(summary[2].max_m, 0.03);
  EXPECT_DOUBLE_EQ(summary[2].share_over_bound, 0.5);
  EXPECT_EQ(splitLabels({{"a+", 1.0}}).size(), 2u) << "an empty part is a label too";
}

TEST(DriftByLabel, PosesWithoutALabelNearbyAreCountedApart) {
  std::mt19937 rng(14);
  const Trajectory gt = randomTrajectory(rng, 30.0, 2.0);
  const auto result = evaluate(gt, gt);
  ASSERT_TRUE(result.ok()) << result.error();
  std::vector<StampedLabel> labels;
  for (std::size_t k = 0; k < 30; ++k) labels.push_back({gt[k].stamp, "good"});
  const auto drift = driftByLabel(*result, labels);
  ASSERT_TRUE(drift.ok()) << drift.error();
  ASSERT_EQ(drift->size(), 2u);
  EXPECT_EQ((*drift)[0].label, "-");
  EXPECT_EQ((*drift)[0].poses, 30u);
  EXPECT_EQ((*drift)[1].label, "good");
  EXPECT_EQ((*drift)[1].poses, 20u);

  DriftOptions bad;
  bad.window_s = 0.0;
  EXPECT_NE(driftByLabel(*result, labels, bad).error().find("window_s"), std::string::npos);
  bad.window_s = 1e10;
  EXPECT_NE(driftByLabel(*result, labels, bad).error().find("window_s"), std::string::npos);
}

// Poses drawn about the truth with known covariances (position, then rotation
// about the map's axes, in an estimate's map that is turned and shifted from
// the ground truth's), each pose's own, some much weaker along one axis: the
// normalised drifts are chi-square with 3 degrees of freedom, so about 95 %
// lie within the ellipsoid and their median is a chi-square's. Covariances
// four times too small read as too narrow.
TEST(CovarianceCoverage, CovariancesThatDescribeTheNoiseCoverItsDrift) {
  std::mt19937 rng(21);
  const Trajectory gt = randomTrajectory(rng, 30.0, 60.0);
  std::normal_distribution<double> unit(0.0, 1.0);
  Trajectory est;
  std::vector<StampedCovariance> covariances, too_small;
  std::vector<StampedLabel> labels;
  for (std::size_t k = 0; k < gt.size(); ++k) {
    Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Zero();
    A.diagonal() << 0.003, 0.002, k % 2 ? 0.02 : 0.004, 0.002, 0.004, k % 3 ? 0.001 : 0.01;
    A(1, 3) = 0.002;
    Eigen::Matrix<double, 6, 1> n;
    for (int i = 0; i < 6; ++i) n(i) = unit(rng);
    const Eigen::Matrix<double, 6, 1> e = A * n;
    SE3 T = knownTransform().inverse() * gt[k].T_w_c;  // in the estimate's map
    T.translation() += e.head<3>();
    T.linear() = expSO3(e.tail<3>()) * T.linear();
    est.push_back({gt[k].stamp, T});
    covariances.push_back({gt[k].stamp, A * A.transpose()});
    too_small.push_back({gt[k].stamp, A * A.transpose() / 16.0});
    labels.push_back({gt[k].stamp, k % 2 ? "degraded" : "good"});
  }
  covariances[5].covariance.setZero();  // a frame without a pose
  const auto result = evaluate(gt, est);
  ASSERT_TRUE(result.ok()) << result.error();
  const auto poses = normalisedDriftPerPose(*result, est, covariances, labels, poseHealthDriftOptions());
  ASSERT_TRUE(poses.ok()) << poses.error();
  EXPECT_EQ(poses->size(), gt.size() - 10 - 1);  // a window back, and frame 15's pair starts at frame 5
  const auto coverage = summariseCoverage(*poses, poseHealthDriftOptions());
  ASSERT_EQ(coverage.size(), 3u);
  EXPECT_EQ(coverage[0].label, "good");
  EXPECT_EQ(coverage[1].label, "degraded");
  EXPECT_EQ(coverage[2].label, "all");
  EXPECT_EQ(coverage[2].poses, poses->size());
  for (const CovarianceCoverage& c : coverage) {
    EXPECT_NEAR(c.position_within, 0.95, 0.025) << c.label;
    EXPECT_NEAR(c.rotation_within, 0.95, 0.025) << c.label;
    EXPECT_NEAR(c.position_median, 1.0, 0.12) << c.label;
    EXPECT_NEAR(c.rotation_median, 1.0, 0.12) << c.label;
  }
  const auto narrow = normalisedDriftPerPose(*result, est, too_small, labels);
  ASSERT_TRUE(narrow.ok()) << narrow.error();
  const CovarianceCoverage all = summariseCoverage(*narrow).back();
  EXPECT_NEAR(all.position_median, 16.0, 2.0);
  EXPECT_LT(all.position_within, 0.5);
}

}  // namespace
}  // namespace stillpoint::eval
