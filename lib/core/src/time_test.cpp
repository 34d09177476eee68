#include "stillpoint/core/time.hpp"

#include <gtest/gtest.h>

#include <limits>

namespace stillpoint {
namespace {

TEST(Timestamp, ParsesTumSecondsExactly) {
  auto t = Timestamp::parseSeconds("1341841873.273798");
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->nanoseconds(), 1341841873273798000LL);
  EXPECT_EQ(t->toSecondsString(), "1341841873.273798");
}

// Any stamp a message may carry prints, rounded to microseconds: the
// extremes of int64 too (a sender's garbage must not overflow the printer).
TEST(Timestamp, EveryStampPrints) {
  EXPECT_EQ(Timestamp::fromNanoseconds(-1'500).toSecondsString(), "-0.000002");
  EXPECT_EQ(Timestamp::fromNanoseconds(1'499).toSecondsString(), "0.000001");
  EXPECT_EQ(Timestamp::fromNanoseconds(std::numeric_limits<std::int64_t>::max()).toSecondsString(),
            "9223372036.854776");
  EXPECT_EQ(Timestamp::fromNanoseconds(std::numeric_limits<std::int64_t>::min()).toSecondsString(),
            "-9223372036.854776");
}

TEST(Timestamp, RejectsMalformed) {
  EXPECT_FALSE(Timestamp::parseSeconds("").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds("12.3.4").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds("abc").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds(".").has_value());
}

// Stamps beyond kMaxSeconds would overflow int64 nanoseconds (they used to
// wrap around: 9341841873 s came back as a negative stamp).
TEST(Timestamp, RejectsStampsBeyondTheRange) {
  const auto last = Timestamp::parseSeconds("9000000000.999999999");
  ASSERT_TRUE(last.has_value());
  EXPECT_EQ(last->nanoseconds(), 9'000'000'000'999'999'999LL);
  EXPECT_FALSE(Timestamp::parseSeconds("9000000001").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds("9341841873.273798").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds("9999999999.0").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds("-9341841873.2").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds("99999999999999999999999999").has_value());
  const auto negative = Timestamp::parseSeconds("-9000000000");
  ASSERT_TRUE(negative.has_value());
  EXPECT_LT(negative->nanoseconds(), 0);
}

TEST(Timestamp, OrdersAndSubtracts) {
  const auto a = Timestamp::fromNanoseconds(1'000'000'000);
  const auto b = Timestamp::fromSeconds(1.5);
  EXPECT_LT(a, b);
  EXPECT_DOUBLE_EQ(secondsBetween(b, a), 0.5);
}

}  // namespace
}  // namespace stillpoint
