#include "stillpoint/core/health_causes.hpp"

namespace stillpoint::health_cause {

const char* name(std::uint16_t cause) {
  switch (cause) {
    case kFewInliers: return "few_inliers";
    case kViewMoving: return "view_moving";
    case kPoorConditioning: return "poor_conditioning";
    case kHighReprojection: return "high_reprojection";
    case kFallbackEvidence: return "fallback_evidence";
    case kMasksLate: return "masks_late";
    case kRecovering: return "recovering";
    default: return nullptr;
  }
}

std::string toString(std::uint16_t causes) {
  std::string out;
  for (int bit = 0; bit < 16; ++bit) {
    const auto cause = static_cast<std::uint16_t>(1u << bit);
    if (!(causes & cause)) continue;
    if (!out.empty()) out += '+';
    const char* known = name(cause);
    out += known ? std::string(known) : "bit" + std::to_string(bit);
  }
  return out.empty() ? "none" : out;
}

}  // namespace stillpoint::health_cause
