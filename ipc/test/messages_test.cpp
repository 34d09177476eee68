#include <gtest/gtest.h>

#include <cmath>

#include "stillpoint/ipc/messages.hpp"

namespace stillpoint::ipc {

TEST(Messages, TrackingStateNamesAndRange) {
  EXPECT_STREQ(toString(TrackingState::kRelocalised), "relocalised");
  for (int i = 0; i < 6; ++i) EXPECT_TRUE(trackingStateFromInt(i).ok());
  EXPECT_FALSE(trackingStateFromInt(6).ok());
  EXPECT_FALSE(trackingStateFromInt(-1).ok());
}

TEST(Messages, PoseValidation) {
  PoseMessage p;
  EXPECT_TRUE(validate(p).ok());  // no pose, NaN pose fields
  p.position = {0.0, 0.0, 0.0};
  EXPECT_FALSE(validate(p).ok());  // no pose, but numbers a consumer could take for one
  p.orientation = {0.0, 0.0, 0.0, 1.0};
  p.state = TrackingState::kOk;
  EXPECT_TRUE(validate(p).ok());
  p.orientation = {0.0, 0.0, 0.0, 2.0};
  EXPECT_FALSE(validate(p).ok());
  p.orientation = {0.0, 0.0, 0.0, 1.0};
  p.position[1] = std::nan("");
  EXPECT_FALSE(validate(p).ok());
}

TEST(Messages, StatusValidationNamesTheProblem) {
  StatusMessage s;
  s.threads.push_back({"tracking", 30.0, 12.0, 15.0});
  EXPECT_TRUE(validate(s).ok());
  s.threads.push_back({std::string(32, 'x'), 1.0, 1.0, 1.0});
  const Status bad = validate(s);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().find("thread name"), std::string::npos) << bad.error();
  s.threads.pop_back();
  s.queues.assign(StatusMessage::kMaxQueues + 1, QueueStats{"q", 0, 1, 0});
  EXPECT_FALSE(validate(s).ok());
}

}  // namespace stillpoint::ipc
