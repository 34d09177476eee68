#include "threads.hpp"

#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>

#include <thread>

namespace stillpoint::daemon {
namespace {

TEST(ThreadsTest, NamesAndPinsToAnAvailableCore) {
  const std::vector<int> available = availableCores();
  ASSERT_FALSE(available.empty());
  std::thread t([&] {
    ThreadPlacement p;
    p.cores = {available.back()};
    auto warnings = placeCurrentThread("sp-test-thread-long-name", p, available, "threads.tracking");
    EXPECT_TRUE(warnings.empty());
    char name[32] = {};
    pthread_getname_np(pthread_self(), name, sizeof name);
    EXPECT_STREQ(name, "sp-test-thread-");  // 15 characters: the kernel's limit
    cpu_set_t set;
    CPU_ZERO(&set);
    ASSERT_EQ(sched_getaffinity(0, sizeof set, &set), 0);
    EXPECT_EQ(CPU_COUNT(&set), 1);
    EXPECT_TRUE(CPU_ISSET(available.back(), &set));
  });
  t.join();
}

TEST(ThreadsTest, AbsentCoreDegradesWithAWarning) {
  const std::vector<int> available = availableCores();
  std::thread t([&] {
    cpu_set_t before;
    CPU_ZERO(&before);
    sched_getaffinity(0, sizeof before, &before);
    ThreadPlacement p;
    p.cores = {1000};
    auto warnings = placeCurrentThread("sp-x", p, available, "threads.mapping");
    ASSERT_EQ(warnings.size(), 1u);
    EXPECT_NE(warnings[0].find("threads.mapping.cores"), std::string::npos) << warnings[0];
    EXPECT_NE(warnings[0].find("1000"), std::string::npos) << warnings[0];
    EXPECT_NE(warnings[0].find("unpinned"), std::string::npos) << warnings[0];
    cpu_set_t after;
    CPU_ZERO(&after);
    sched_getaffinity(0, sizeof after, &after);
    EXPECT_TRUE(CPU_EQUAL(&before, &after));  // left as it was

    p.cores = {available.front(), 1000};
    warnings = placeCurrentThread("sp-x", p, available, "threads.mapping");
    ASSERT_EQ(warnings.size(), 1u);
    EXPECT_NE(warnings[0].find("pinned to " + std::to_string(available.front())), std::string::npos) << warnings[0];
  });
  t.join();
}

TEST(ThreadsTest, ClearingTheInheritedPlacementUnpins) {
  const std::vector<int> available = availableCores();
  ASSERT_FALSE(available.empty());
  std::thread parent([&] {
    ThreadPlacement p;
    p.cores = {available.front()};
    EXPECT_TRUE(placeCurrentThread("sp-parent", p, available, "threads.mapping").empty());
    std::thread child([&] {  // inherits the parent's single core...
      cpu_set_t set;
      CPU_ZERO(&set);
      sched_getaffinity(0, sizeof set, &set);
      EXPECT_EQ(CPU_COUNT(&set), 1);
      clearInheritedPlacement(available);  // ...until it clears it
      CPU_ZERO(&set);
      sched_getaffinity(0, sizeof set, &set);
      EXPECT_EQ(CPU_COUNT(&set), static_cast<int>(available.size()));
    });
    child.join();
  });
  parent.join();
}

}  // namespace
}  // namespace stillpoint::daemon
