#include "stillpoint/core/health_causes.hpp"

#include <gtest/gtest.h>

namespace stillpoint::health_cause {
namespace {

TEST(HealthCauses, EveryBitHasItsOwnName) {
  std::string all;
  for (int bit = 0; bit < kCount; ++bit) {
    const char* n = name(static_cast<std::uint16_t>(1u << bit));
    ASSERT_NE(n, nullptr) << "bit " << bit;
    EXPECT_EQ(all.find(n), std::string::npos) << n << " twice";
    all += std::string(n) + " ";
  }
  EXPECT_EQ(name(1u << kCount), nullptr);
  EXPECT_EQ(name(kViewMoving | kMasksLate), nullptr) << "one bit at a time";
}

TEST(HealthCauses, SetsReadInBitOrder) {
  EXPECT_EQ(toString(0), "none");
  EXPECT_EQ(toString(kMasksLate | kViewMoving), "view_moving+masks_late");
  EXPECT_EQ(toString(kFallbackEvidence | kRecovering), "fallback_evidence+recovering");
  EXPECT_EQ(toString(kFewInliers | (1u << 12)), "few_inliers+bit12") << "a newer writer's bit";
}

}  // namespace
}  // namespace stillpoint::health_cause
