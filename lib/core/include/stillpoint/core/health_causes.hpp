#pragma once
// What lowered a pose's health (docs/pose-health.md): the bits of
// slam::PoseQuality::causes and of the pose and status messages'
// health_causes, one definition for the library and every wire format.
#include <cstdint>
#include <string>

namespace stillpoint::health_cause {

constexpr std::uint16_t kFewInliers = 1u << 0;         // under 80 map points in the pose (30: unreliable)
constexpr std::uint16_t kViewMoving = 1u << 1;         // over a quarter of the view moving (half: unreliable)
constexpr std::uint16_t kPoorConditioning = 1u << 2;   // conditioning under 0.05 (0.02: unreliable)
constexpr std::uint16_t kHighReprojection = 1u << 3;   // the inliers' RMS over 2 px
constexpr std::uint16_t kFallbackEvidence = 1u << 4;   // kept on fallback evidence: unreliable
constexpr std::uint16_t kMasksLate = 1u << 5;          // the semantic module alone, masks over 0.6 s old (2 s: unreliable)
constexpr std::uint16_t kRecovering = 1u << 6;         // the frame's own level is better, not held long enough yet
constexpr int kCount = 7;

// The name of one bit ("few_inliers", "view_moving", ...); nullptr for a bit not defined here.
const char* name(std::uint16_t cause);
// The set bits' names joined by '+' ("view_moving+masks_late"), "none" for 0;
// a bit not defined here (a newer writer's) as "bitN".
std::string toString(std::uint16_t causes);

}  // namespace stillpoint::health_cause
