// Pose health: what a consumer of the pose needs to know to trust it, from
// the final pose's own evidence. See docs/pose-health.md.
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <vector>

#include "optimizer.hpp"
#include "tracking.hpp"

namespace stillpoint::slam {
namespace {

// Raw levels (before hysteresis). An unreliable pose rests on too little or
// on evidence that leaves a direction free; a degraded one on less than a
// static scene gives, or on a view that movers fill.
constexpr int kUnreliableInliers = 30, kDegradedInliers = 80;
constexpr float kUnreliableDynamicShare = 0.5f, kDegradedDynamicShare = 0.25f;
constexpr float kUnreliableConditioning = 0.02f, kDegradedConditioning = 0.05f;
constexpr float kDegradedRmsPx = 2.0f;
// The inliers' information takes the map points for exact. Their own error
// makes the pose's drift over 1/3 s 8 times the position's standard deviation
// that information predicts and 13 times the rotation's (median over 19
// sequences with movers, docs/pose-health.md, "The covariance").
constexpr double kPositionSigmaScale = 8, kRotationSigmaScale = 13;
// An unreliable pose may follow a mover, which its inliers cannot show: its
// covariance gains the spread of such poses' drift over 1/3 s (per axis).
constexpr double kUnreliablePositionSigmaM = 0.05, kUnreliableRotationSigmaRad = 0.03;
// With the semantic module as the only judge of what moves, masks whose image
// is old no longer say where the movers are, and the keyframes waiting for
// theirs hold their points back (infinity: none near the camera has any):
// PoseQuality::kDegradedMaskAgeS and kUnreliableMaskAgeS.

// The frame's own level, and every measure that lowered it.
PoseHealth rawHealth(const PoseQuality& q, bool masks_alone, bool starved, std::uint16_t* causes) {
  const bool masks_known = masks_alone && q.mask_age_s >= 0;
  PoseHealth level = PoseHealth::kGood;
  std::uint16_t why = 0;
  auto lower = [&](bool unreliable, bool degraded, std::uint16_t cause) {
    if (!unreliable && !degraded) return;
    why |= cause;
    level = std::max(level, unreliable ? PoseHealth::kUnreliable : PoseHealth::kDegraded);
  };
  lower(q.inliers < kUnreliableInliers, q.inliers < kDegradedInliers, health_cause::kFewInliers);
  lower(q.dynamic_share > kUnreliableDynamicShare, q.dynamic_share > kDegradedDynamicShare,
        health_cause::kViewMoving);
  lower(q.conditioning < kUnreliableConditioning, q.conditioning < kDegradedConditioning,
        health_cause::kPoorConditioning);
  lower(false, q.reprojection_rms_px > kDegradedRmsPx, health_cause::kHighReprojection);
  lower(starved, false, health_cause::kFallbackEvidence);
  lower(masks_known && q.mask_age_s > PoseQuality::kUnreliableMaskAgeS,
        masks_known && q.mask_age_s > PoseQuality::kDegradedMaskAgeS, health_cause::kMasksLate);
  *causes = why;
  return level;
}

}  // namespace

const char* toString(PoseHealth health) {
  switch (health) {
    case PoseHealth::kGood: return "good";
    case PoseHealth::kDegraded: return "degraded";
    case PoseHealth::kUnreliable: return "unreliable";
    case PoseHealth::kLost: return "lost";
  }
  return "?";
}

PoseQuality Tracker::measureQuality(bool ok) {
  PoseQuality q;
  q.mask_age_s = mask_age_s_;
  q.masks_found_movers = masks_found_movers_;
  if (!ok) {
    health_ = PoseHealth::kLost;
    better_frames_ = 0;
    return q;
  }
  int dynamic = 0, outliers = 0;
  double sum_sq = 0;
  std::vector<double> depths;
  Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
  std::vector<Eigen::Matrix<double, 2, 6>> jacobians;
  PoseProblem evidence;
  evidence.camera = &camera_;
  for (int i = 0; i < current_.size(); ++i) {
    if (current_.dynamic[i]) ++dynamic;
    const auto& p = current_.points[i];
    if (!p || p->isTemporary()) continue;
    if (current_.outlier[i]) {
      ++outliers;
      continue;
    }
    const Vec3 pc = current_.T_c_w * p->position;
    if (pc.z() <= 1e-6) continue;
    const Vec2 uv = camera_.project(pc);
    // In level-0 pixels: a coarse level's feature is located as much less precisely.
    const double scale = levels_.scales[current_.keys[i].octave];
    sum_sq += (uv - Vec2(current_.un[i].x, current_.un[i].y)).squaredNorm() / (scale * scale);
    ++q.inliers;
    depths.push_back(pc.z());
    evidence.points_w.push_back(p->position);
    evidence.observations.push_back(observationOf(current_, i));
    // d(u, v) / d(translation, rotation) of a left perturbation of T_c_w.
    const double x = pc.x(), y = pc.y(), z = pc.z(), iz = 1.0 / z, iz2 = iz * iz;
    Eigen::Matrix<double, 2, 6> J;
    J << camera_.fx * iz, 0, -camera_.fx * x * iz2, -camera_.fx * x * y * iz2, camera_.fx * (1 + x * x * iz2),
        -camera_.fx * y * iz, 0, camera_.fy * iz, -camera_.fy * y * iz2, -camera_.fy * (1 + y * y * iz2),
        camera_.fy * x * y * iz2, camera_.fy * x * iz;
    jacobians.push_back(J);
  }
  q.dynamic_share = static_cast<float>(dynamic) / static_cast<float>(std::max(1, dynamic + q.inliers));
  q.outlier_share = static_cast<float>(outliers) / static_cast<float>(std::max(1, outliers + q.inliers));
  if (q.inliers > 0) q.reprojection_rms_px = static_cast<float>(std::sqrt(sum_sq / q.inliers));
  if (q.inliers >= 3) {
    // Translation in units of the median depth, so a metre and a radian weigh alike there.
    std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
    const double scale = depths[depths.size() / 2];
    for (auto& J : jacobians) {
      J.leftCols<3>() *= scale;
      H += J.transpose() * J;
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(H, Eigen::EigenvaluesOnly);
    const double lo = eig.eigenvalues()(0), hi = eig.eigenvalues()(5);
    q.conditioning = hi > 0 ? static_cast<float>(std::sqrt(std::max(0.0, lo) / hi)) : 0.0f;
    Eigen::Matrix<double, 6, 1> calibration;
    calibration << kPositionSigmaScale, kPositionSigmaScale, kPositionSigmaScale, kRotationSigmaScale,
        kRotationSigmaScale, kRotationSigmaScale;
    q.covariance = calibration.asDiagonal() *
                   poseCovarianceInMap(poseInformation(evidence, current_.T_c_w), current_.T_c_w, 1.0) *
                   calibration.asDiagonal();
  }
  // Hysteresis: worse at once, better only when it has held a while. A pose
  // kept on fallback evidence (movers starved the frame) is unreliable.
  const bool masks_alone = options_.semantic.enabled && !detector_;
  std::uint16_t causes = 0;
  const PoseHealth raw = rawHealth(q, masks_alone, starved_, &causes);
  if (raw >= health_ || health_ == PoseHealth::kLost) {  // lost -> a pose: its own level at once
    health_ = raw;
    better_frames_ = 0;
  } else if (++better_frames_ >= PoseQuality::kRecoveryFrames) {
    health_ = raw;
    better_frames_ = 0;
  }
  q.health = health_;
  if (q.health == PoseHealth::kUnreliable) {
    q.covariance.diagonal().head<3>().array() += kUnreliablePositionSigmaM * kUnreliablePositionSigmaM;
    q.covariance.diagonal().tail<3>().array() += kUnreliableRotationSigmaRad * kUnreliableRotationSigmaRad;
  }
  q.causes = health_ == raw ? causes : static_cast<std::uint16_t>(causes | health_cause::kRecovering);
  return q;
}

}  // namespace stillpoint::slam
