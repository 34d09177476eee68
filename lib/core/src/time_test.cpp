#include "stillpoint/core/time.hpp"

#include <gtest/gtest.h>

namespace stillpoint {
namespace {

TEST(Timestamp, ParsesTumSecondsExactly) {
  auto t = Timestamp::parseSeconds("1341841873.273798");
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->nanoseconds(), 1341841873273798000LL);
  EXPECT_EQ(t->toSecondsString(), "1341841873.273798");
}

TEST(Timestamp, RejectsMalformed) {
  EXPECT_FALSE(Timestamp::parseSeconds("").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds("12.3.4").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds("abc").has_value());
  EXPECT_FALSE(Timestamp::parseSeconds(".").has_value());
}

TEST(Timestamp, OrdersAndSubtracts) {
  const auto a = Timestamp::fromNanoseconds(1'000'000'000);
  const auto b = Timestamp::fromSeconds(1.5);
  EXPECT_LT(a, b);
  EXPECT_DOUBLE_EQ(secondsBetween(b, a), 0.5);
}

}  // namespace
}  // namespace stillpoint
