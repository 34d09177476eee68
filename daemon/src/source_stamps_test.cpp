#include "source_stamps.hpp"

#include <gtest/gtest.h>

namespace stillpoint::daemon {
namespace {

using namespace std::chrono_literals;

Timestamp ms(std::int64_t v) { return Timestamp::fromNanoseconds(v * 1'000'000); }

// A camera's stamps pass unchanged while they increase; one at or before the
// last is skipped; after a reconnect whose camera clock started again, the
// stamps go on from the last one by the time that passed, and keep going.
TEST(SourceStamps, GoOnFromTheLastStampWhenTheCameraClockStartsAgain) {
  SourceStamps stamps;
  const auto t0 = SourceStamps::Clock::now();
  EXPECT_EQ(stamps.next(ms(5000), t0), ms(5000));
  EXPECT_EQ(stamps.next(ms(5033), t0 + 33ms), ms(5033));
  EXPECT_FALSE(stamps.next(ms(5033), t0 + 40ms)) << "a repeated frame";
  EXPECT_FALSE(stamps.next(ms(5000), t0 + 50ms)) << "back in time without a reconnect";

  stamps.reconnected();  // plugged back in 1.2 s later; its clock starts at 0
  bool rebased = false;
  EXPECT_EQ(stamps.next(ms(0), t0 + 1233ms, &rebased), ms(5033 + 1200));
  EXPECT_TRUE(rebased);
  EXPECT_EQ(stamps.next(ms(33), t0 + 1266ms, &rebased), ms(5033 + 1233));
  EXPECT_FALSE(rebased);

  // A reconnect whose clock did not start again (V4L2: the kernel's clock)
  // keeps its stamps.
  stamps.reconnected();
  EXPECT_EQ(stamps.next(ms(2000), t0 + 3000ms, &rebased), ms(5033 + 1200 + 2000));
  EXPECT_FALSE(rebased);
}

}  // namespace
}  // namespace stillpoint::daemon
