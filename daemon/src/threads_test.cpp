#include "threads.hpp"

#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <unistd.h>

#include <fstream>
#include <string>
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

TEST(ThreadsTest, NiceIsPerThread) {
  const std::vector<int> available = availableCores();
  const int process_nice = getpriority(PRIO_PROCESS, 0);
  if (process_nice > 14) GTEST_SKIP() << "process already at nice " << process_nice;
  std::thread t([&] {
    ThreadPlacement p;
    p.nice = process_nice + 5;
    EXPECT_TRUE(placeCurrentThread("sp-nice", p, available, "threads.semantic").empty());
    EXPECT_EQ(getpriority(PRIO_PROCESS, static_cast<id_t>(::gettid())), process_nice + 5);
    if (geteuid() != 0) {  // a negative value needs CAP_SYS_NICE: a warning, the value kept
      p.nice = -5;
      const auto warnings = placeCurrentThread("sp-nice", p, available, "threads.semantic");
      ASSERT_EQ(warnings.size(), 1u);
      EXPECT_NE(warnings[0].find("threads.semantic.nice"), std::string::npos) << warnings[0];
      EXPECT_NE(warnings[0].find("CAP_SYS_NICE"), std::string::npos) << warnings[0];
      EXPECT_EQ(getpriority(PRIO_PROCESS, static_cast<id_t>(::gettid())), process_nice + 5);
    }
  });
  t.join();
  EXPECT_EQ(getpriority(PRIO_PROCESS, static_cast<id_t>(::gettid())), process_nice);  // other threads untouched
}

long lockedKb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind("VmLck:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}

TEST(ThreadsTest, MemoryIsLockedOnlyWithTheCapabilityOrAnUnlimitedLimit) {
  rlimit saved{};
  ASSERT_EQ(getrlimit(RLIMIT_MEMLOCK, &saved), 0);
  // A finite limit: locked only with CAP_IPC_LOCK; otherwise a warning says what to set.
  rlimit finite = saved;
  finite.rlim_cur = 64 * 1024;
  if (finite.rlim_max != RLIM_INFINITY && finite.rlim_max < finite.rlim_cur) finite.rlim_cur = finite.rlim_max;
  ASSERT_EQ(setrlimit(RLIMIT_MEMLOCK, &finite), 0);
  bool locked = false;
  std::vector<std::string> warnings = lockMemory(&locked);
  EXPECT_EQ(locked, hasIpcLockCapability());
  if (locked) {
    EXPECT_GT(lockedKb(), 64);  // all of the test's pages, past the finite limit
    munlockall();
  } else {
    ASSERT_EQ(warnings.size(), 1u);
    EXPECT_NE(warnings[0].find("LimitMEMLOCK=infinity"), std::string::npos) << warnings[0];
  }
  // Unlimited (raising it needs CAP_SYS_RESOURCE): locked.
  rlimit unlimited{RLIM_INFINITY, RLIM_INFINITY};
  if (setrlimit(RLIMIT_MEMLOCK, &unlimited) == 0) {
    warnings = lockMemory(&locked);
    EXPECT_TRUE(locked) << (warnings.empty() ? "" : warnings[0]);
    EXPECT_GT(lockedKb(), 0);
    munlockall();
  }
  setrlimit(RLIMIT_MEMLOCK, &saved);
}

}  // namespace
}  // namespace stillpoint::daemon
