// TaskThread: the tracker's long-lived helper for jobs it overlaps with its
// own work (the anchor matches while stage 1 runs).
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>
#include <vector>

#include "task_thread.hpp"

namespace stillpoint::slam {
namespace {

TEST(TaskThread, RunsJobsInOrderOnOneOtherThread) {
  TaskThread helper;
  std::vector<int> order;  // written by the helper only, read after the futures
  std::vector<std::future<std::thread::id>> ids;
  for (int k = 0; k < 20; ++k)
    ids.push_back(helper.run([&order, k] {
      order.push_back(k);
      return std::this_thread::get_id();
    }));
  const std::thread::id first = ids.front().get();
  EXPECT_NE(first, std::this_thread::get_id());
  for (std::size_t k = 1; k < ids.size(); ++k) EXPECT_EQ(ids[k].get(), first) << "job " << k;
  ASSERT_EQ(order.size(), 20u);
  for (int k = 0; k < 20; ++k) EXPECT_EQ(order[k], k);
}

TEST(TaskThread, ReturnsResultsAndRethrowsAJobsException) {
  TaskThread helper;
  auto value = helper.run([] { return std::vector<int>{1, 2, 3}; });
  auto failing = helper.run([]() -> int { throw std::runtime_error("job failed"); });
  auto after = helper.run([] { return 7; });
  EXPECT_EQ(value.get(), (std::vector<int>{1, 2, 3}));
  EXPECT_THROW(failing.get(), std::runtime_error);
  EXPECT_EQ(after.get(), 7);  // the thread survives a throwing job
}

TEST(TaskThread, DestructionFinishesTheQueuedJobs) {
  std::atomic<int> done{0};
  {
    TaskThread helper;
    for (int k = 0; k < 5; ++k)
      (void)helper.run([&done] {
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
        ++done;
      });
  }
  EXPECT_EQ(done.load(), 5);
}

}  // namespace
}  // namespace stillpoint::slam
