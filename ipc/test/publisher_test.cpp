#include <gtest/gtest.h>

#include <atomic>
#include <mutex>
#include <thread>

#include "stillpoint/ipc/publisher.hpp"

namespace stillpoint::ipc {
namespace {

// Records what it is asked to send; can be held closed to simulate a stalled transport.
struct Recorder {
  std::mutex mutex;
  std::vector<std::uint64_t> frames;
  std::vector<Timestamp> publish_stamps;
  int statuses = 0;
  std::atomic<bool> block{false};
};

class FakeTransport : public Transport {
 public:
  explicit FakeTransport(Recorder* r, bool fail = false) : r_(r), fail_(fail) {}
  std::string_view name() const override { return "fake"; }
  Status publishPose(const PoseMessage& p) override {
    while (r_->block) std::this_thread::yield();
    std::lock_guard lock(r_->mutex);
    r_->frames.push_back(p.frame_counter);
    r_->publish_stamps.push_back(p.publish_stamp);
    return fail_ ? Status(Error{"broken"}) : Status::success();
  }
  Status publishStatus(const StatusMessage&) override {
    std::lock_guard lock(r_->mutex);
    ++r_->statuses;
    return Status::success();
  }

 private:
  Recorder* r_;
  bool fail_;
};

std::vector<std::unique_ptr<Transport>> one(Recorder* r, bool fail = false) {
  std::vector<std::unique_ptr<Transport>> v;
  v.push_back(std::make_unique<FakeTransport>(r, fail));
  return v;
}

PoseMessage pose(std::uint64_t k) {
  PoseMessage p;
  p.frame_counter = k;
  return p;
}

}  // namespace

TEST(Publisher, InlineModeSendsInOrderAndStampsPublishTime) {
  Recorder r;
  Publisher pub(one(&r), 4, Publisher::Mode::kInline);
  for (std::uint64_t k = 1; k <= 10; ++k) pub.publishPose(pose(k));
  pub.publishStatus(StatusMessage{});
  EXPECT_EQ(r.frames, (std::vector<std::uint64_t>{1, 2, 3, 4, 5, 6, 7, 8, 9, 10}));
  EXPECT_EQ(r.statuses, 1);
  for (const auto& t : r.publish_stamps) EXPECT_GT(t.nanoseconds(), 0);
  const auto st = pub.stats();
  EXPECT_EQ(st.sent, 11u);
  EXPECT_EQ(st.dropped, 0u);
}

TEST(Publisher, StalledTransportDropsOldestNotNewest) {
  Recorder r;
  r.block = true;
  {
    Publisher pub(one(&r), 3);
    pub.publishPose(pose(1));
    // Wait until the thread holds pose 1 inside the (blocked) transport.
    while (pub.stats().queue_depth != 0) std::this_thread::yield();
    for (std::uint64_t k = 2; k <= 10; ++k) pub.publishPose(pose(k));  // never blocks
    const auto st = pub.stats();
    EXPECT_EQ(st.queue_depth, 3u);
    EXPECT_EQ(st.dropped, 6u);
    r.block = false;
  }  // destructor drains and joins
  EXPECT_EQ(r.frames, (std::vector<std::uint64_t>{1, 8, 9, 10}));
}

TEST(Publisher, CloseStopsAcceptingAndDestructorDrains) {
  Recorder r;
  auto pub = std::make_unique<Publisher>(one(&r), 64);
  for (std::uint64_t k = 1; k <= 20; ++k) pub->publishPose(pose(k));
  pub->close();
  pub->publishPose(pose(99));  // ignored after close
  pub.reset();
  EXPECT_EQ(r.frames.size(), 20u);
  EXPECT_EQ(r.frames.back(), 20u);
}

TEST(Publisher, TransportErrorsAreCountedNotFatal) {
  Recorder r;
  Publisher pub(one(&r, /*fail=*/true), 4, Publisher::Mode::kInline);
  pub.publishPose(pose(1));
  pub.publishPose(pose(2));
  EXPECT_EQ(pub.stats().send_errors, 2u);
  EXPECT_EQ(pub.stats().sent, 2u);
}

// A network transport that cannot come up (no route yet) is down, not fatal:
// the publisher skips it, counts what it missed, names it in its stats, and
// takes it up once it can be made.
TEST(Publisher, ATransportThatCannotComeUpIsRetriedUntilItIsUp) {
  Recorder r;
  int attempts = 0;
  std::vector<std::unique_ptr<Transport>> transports;
  transports.push_back(makeRetryingTransport(
      "late",
      [&]() -> Result<std::unique_ptr<Transport>> {
        if (++attempts < 3) return Error{"no route to host"};
        return std::unique_ptr<Transport>(std::make_unique<FakeTransport>(&r));
      },
      std::chrono::seconds(0)));
  EXPECT_EQ(attempts, 1);
  EXPECT_FALSE(transports[0]->up());
  Publisher pub(std::move(transports), 4, Publisher::Mode::kInline);
  pub.publishPose(pose(1));  // second attempt fails: still down
  PublisherStats s = pub.stats();
  ASSERT_EQ(s.down.size(), 1u);
  EXPECT_EQ(s.down[0], "late");
  EXPECT_EQ(s.unsent_down, 1u);
  EXPECT_EQ(s.send_errors, 0u);
  pub.publishPose(pose(2));  // third attempt: up, and this one is sent
  s = pub.stats();
  EXPECT_TRUE(s.down.empty());
  EXPECT_EQ(attempts, 3);
  std::lock_guard lock(r.mutex);
  EXPECT_EQ(r.frames, std::vector<std::uint64_t>{2});
}

TEST(Publisher, ATransportIsNotRetriedBeforeItsPeriod) {
  int attempts = 0;
  auto t = makeRetryingTransport(
      "late", [&]() -> Result<std::unique_ptr<Transport>> { ++attempts; return Error{"no route"}; },
      std::chrono::hours(1));
  for (int k = 0; k < 5; ++k) t->retry();
  EXPECT_EQ(attempts, 1);
  EXPECT_FALSE(t->up());
  EXPECT_FALSE(t->publishPose(pose(1)));
}

TEST(Publisher, CreateRejectsInvalidOptions) {
  IpcOptions o;
  o.shm.capacity = 3;
  auto p = Publisher::create(o);
  ASSERT_FALSE(p.ok());
  EXPECT_NE(p.error().find("ipc.shm.capacity"), std::string::npos);
}

}  // namespace stillpoint::ipc
