// Who may write a ring, and what a reader can tell about its writer, with writer
// processes and real files in /dev/shm: writers racing for one name, a second writer
// while the first publishes, a writer killed with SIGKILL, another user's read lock, a
// stale ring recording the pid of a live process.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstddef>
#include <cstring>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "shm_processes.hpp"
#include "stillpoint/ipc/shm_writer.hpp"
#include "stillpoint/ipc/transport.hpp"
#include "stillpoint_shm.h"

namespace stillpoint::ipc {
namespace {

using namespace shm_test;

// The header of the ring file at `name`, copied; zeroed when there is none.
sp_shm_header readHeader(const std::string& name) {
  sp_shm_header h{};
  const int fd = ::open(ringPath(name).c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) return h;
  if (::pread(fd, &h, sizeof(h), 0) != static_cast<ssize_t>(sizeof(h))) h = sp_shm_header{};
  ::close(fd);
  return h;
}

std::uint64_t writeCount(const std::string& name) {
  sp_shm_header h = readHeader(name);
  return h.write_count;
}

// Records `pid` as the ring's writer, as a crashed writer whose pid was reused leaves it.
void recordWriterPid(const std::string& name, std::uint32_t pid) {
  const int fd = ::open(ringPath(name).c_str(), O_RDWR | O_CLOEXEC);
  ASSERT_GE(fd, 0) << std::strerror(errno);
  ASSERT_EQ(::pwrite(fd, &pid, sizeof(pid), offsetof(sp_shm_header, writer_pid)), static_cast<ssize_t>(sizeof(pid)));
  ::close(fd);
}

bool waitUntil(const std::function<bool()>& condition, std::chrono::milliseconds limit) {
  const auto until = Clock::now() + limit;
  while (!condition()) {
    if (Clock::now() > until) return false;
    std::this_thread::sleep_for(2ms);
  }
  return true;
}

class RingOwnership : public RingNameTest {
 protected:
  RingOwnership() : RingNameTest("sp_own_") {}
};

TEST_F(RingOwnership, AnotherUserReadsTheRingButCannotBlockWriters) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root to act as another user";
  constexpr uid_t kOther = 65534;
  auto becomeOther = [] { return ::setgid(kOther) == 0 && ::setuid(kOther) == 0; };
  ::umask(022);  // the ring readable by everyone, as under systemd's default
  WriterProcess writer(name_, 8);
  ASSERT_EQ(writer.report(), "ok");
  struct stat st {};
  ASSERT_EQ(::stat(lockPath(name_).c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);

  const ChildOutcome reader = runInChild([&](std::string& out) {
    if (!becomeOther()) return 2;
    sp_shm_reader r;
    sp_shm_reader_init(&r);
    r.owner_uid = 0;  // the writer's user
    const int rc = sp_shm_reader_open(&r, name_.c_str(), SP_SHM_START_LATEST);
    if (rc != SP_SHM_OK) out = std::string("open: ") + sp_shm_strerror(rc);
    else if (sp_shm_writer_alive(&r) != 1) out = "the running writer is not seen alive";
    struct flock lock {};
    lock.l_type = F_RDLCK;
    lock.l_whence = SEEK_SET;
    if (rc == SP_SHM_OK && ::fcntl(r.fd, F_OFD_SETLK, &lock) == 0) out = "read-locked a running writer's ring";
    if (::open(lockPath(name_).c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC) >= 0) out = "opened the writers' lock file";
    sp_shm_reader_close(&r);
    return out.empty() ? 0 : 1;
  });
  ASSERT_TRUE(reader.finished) << reader.output;
  EXPECT_EQ(reader.exit_code, 0) << reader.output;

  // With the writer killed, another user's read lock on its ring neither looks like a
  // live writer nor keeps a new writer from starting.
  writer.stop(SIGKILL);
  int locked[2];
  ASSERT_EQ(::pipe(locked), 0);
  const pid_t holder = ::fork();
  if (holder == 0) {
    const int fd = becomeOther() ? ::open(ringPath(name_).c_str(), O_RDONLY | O_CLOEXEC) : -1;
    struct flock lock {};
    lock.l_type = F_RDLCK;
    lock.l_whence = SEEK_SET;
    if (fd < 0 || ::fcntl(fd, F_OFD_SETLK, &lock) != 0) ::_exit(1);
    (void)!::write(locked[1], "L", 1);
    ::pause();
    ::_exit(0);
  }
  ::close(locked[1]);
  char c = 0;
  const bool holding = ::read(locked[0], &c, 1) == 1;
  ::close(locked[0]);
  sp_shm_reader r;
  sp_shm_reader_init(&r);
  const int opened = sp_shm_reader_open(&r, name_.c_str(), SP_SHM_START_LATEST);
  const int alive = sp_shm_writer_alive(&r);
  const int died = sp_shm_reader_writer_died(&r);
  sp_shm_reader_close(&r);
  const ChildOutcome next = runInChild([&](std::string& out) {
    auto w = ShmPoseWriter::create(name_, 8);
    out = w ? "" : w.error();
    return w ? 0 : 1;
  });
  ::kill(holder, SIGKILL);
  ::waitpid(holder, nullptr, 0);
  ASSERT_TRUE(holding) << "the other user could not read-lock the dead ring";
  EXPECT_EQ(opened, SP_SHM_OK);
  EXPECT_EQ(alive, 0);
  EXPECT_EQ(died, 1);
  ASSERT_TRUE(next.finished) << next.output;
  EXPECT_EQ(next.exit_code, 0) << next.output;
}

TEST_F(RingOwnership, SecondWriterFailsAtOnceWhileTheFirstKeepsPublishing) {
  WriterProcess first(name_, 8);
  ASSERT_EQ(first.report(), "ok");

  const auto started = Clock::now();
  const ChildOutcome second = runInChild([&](std::string& out) { return expectRefused(name_, out); });
  ASSERT_TRUE(second.finished) << second.output;
  EXPECT_LT(Clock::now() - started, 2s);
  EXPECT_EQ(second.exit_code, 0) << second.output;
  EXPECT_NE(second.output.find("ring " + name_ + " is owned by a running writer, pid " + std::to_string(first.pid())),
            std::string::npos)
      << second.output;

  // The first writer still owns the file at the ring's name and keeps adding records.
  EXPECT_EQ(readHeader(name_).writer_pid, static_cast<std::uint32_t>(first.pid()));
  EXPECT_EQ(readHeader(name_).generation, 1u);
  const std::uint64_t before = writeCount(name_);
  EXPECT_TRUE(waitUntil([&] { return writeCount(name_) > before + 5; }, 5s));
}

TEST_F(RingOwnership, WritersStartingTogetherLeaveExactlyOneOwner) {
  // Large rings: building one takes milliseconds, which is the window in which a check
  // of the old owner followed by a rename lets several writers through.
  constexpr std::uint32_t kCapacity = 1u << 16;
  constexpr int kWriters = 4;
  for (int round = 0; round < 4; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    int gate[2];
    ASSERT_EQ(::pipe(gate), 0);
    std::vector<std::unique_ptr<WriterProcess>> writers;
    for (int k = 0; k < kWriters; ++k) writers.push_back(std::make_unique<WriterProcess>(name_, kCapacity, gate));
    ::close(gate[0]);
    std::this_thread::sleep_for(20ms);  // all of them waiting at the gate
    ::close(gate[1]);                   // go

    int owners = 0;
    pid_t owner = -1;
    for (auto& w : writers) {
      const std::string report = w->report();
      if (report == "ok") {
        ++owners;
        owner = w->pid();
      } else {
        EXPECT_NE(report.find("is owned by a running writer"), std::string::npos) << report;
      }
    }
    ASSERT_EQ(owners, 1);
    // The owner publishes into the file the name refers to, not into an unlinked one.
    EXPECT_EQ(readHeader(name_).writer_pid, static_cast<std::uint32_t>(owner));
    const std::uint64_t before = writeCount(name_);
    EXPECT_TRUE(waitUntil([&] { return writeCount(name_) > before + 5; }, 5s));
    writers.clear();  // SIGKILL: the next round starts on a stale ring
  }
}

TEST_F(RingOwnership, KilledWriterIsSeenGoneByReaders) {
  WriterProcess writer(name_, 8);
  ASSERT_EQ(writer.report(), "ok");
  sp_shm_reader r;
  sp_shm_reader_init(&r);
  ASSERT_EQ(sp_shm_reader_open(&r, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_OK);
  EXPECT_EQ(sp_shm_writer_alive(&r), 1);
  EXPECT_EQ(sp_shm_reader_writer_died(&r), 0);
  sp_pose_record pose;
  EXPECT_TRUE(waitUntil([&] { return sp_shm_reader_next(&r, &pose) == SP_SHM_OK; }, 5s));

  ShmOptions o;
  o.name = name_;
  auto sub = makeShmSubscriber(o);
  ASSERT_TRUE(sub.ok()) << sub.error();
  auto polled = (*sub)->poll(200ms);
  ASSERT_TRUE(polled.ok()) << polled.error();

  const int status = writer.stop(SIGKILL);
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL);
  EXPECT_EQ(sp_shm_writer_alive(&r), 0);
  EXPECT_EQ(sp_shm_reader_writer_closed(&r), 0);  // the ring itself still says "running"
  EXPECT_EQ(sp_shm_reader_writer_died(&r), 1);

  // The subscriber drains what is left, then says the writer is gone instead of waiting.
  Result<int> after = 0;
  for (int k = 0; k < 20 && after.ok(); ++k) after = (*sub)->poll(100ms);
  ASSERT_FALSE(after.ok()) << "the subscriber kept waiting on a ring whose writer was killed";
  EXPECT_NE(after.error().find("writer gone"), std::string::npos) << after.error();
  EXPECT_NE(after.error().find(ringPath(name_)), std::string::npos) << after.error();

  // A new writer takes over: the reader still on the dead ring is told it did not just
  // die, and reattaches.
  WriterProcess next(name_, 8);
  ASSERT_EQ(next.report(), "ok");
  EXPECT_EQ(sp_shm_reader_writer_died(&r), 0);
  EXPECT_TRUE(waitUntil([&] { return sp_shm_reader_next(&r, &pose) == SP_SHM_RESTARTED; }, 5s));
  EXPECT_EQ(sp_shm_writer_alive(&r), 1);
  sp_shm_reader_close(&r);
}

TEST_F(RingOwnership, CleanlyStoppedWriterIsNotAlive) {
  WriterProcess writer(name_, 8);
  ASSERT_EQ(writer.report(), "ok");
  sp_shm_reader r;
  sp_shm_reader_init(&r);
  ASSERT_EQ(sp_shm_reader_open(&r, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_OK);
  EXPECT_EQ(sp_shm_writer_alive(&r), 1);
  const int status = writer.stop(SIGTERM);
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  EXPECT_EQ(sp_shm_writer_alive(&r), 0);
  EXPECT_EQ(sp_shm_reader_writer_closed(&r), 1);
  EXPECT_EQ(sp_shm_reader_writer_died(&r), 0);
  sp_shm_reader_close(&r);
  // A ring closed cleanly is not an error for a subscriber: it waits for the next writer.
  ShmOptions o;
  o.name = name_;
  auto sub = makeShmSubscriber(o);
  ASSERT_TRUE(sub.ok()) << sub.error();
  auto polled = (*sub)->poll(300ms);
  EXPECT_TRUE(polled.ok()) << polled.error();
}

TEST_F(RingOwnership, StaleRingRecordingALivePidIsTakenOver) {
  // A writer that dies holding the ring (no clean close), whose recorded pid then
  // belongs to a live, unrelated process: this test process, then init.
  const ChildOutcome crashed = runInChild([&](std::string& out) {
    auto w = ShmPoseWriter::create(name_, 8);
    if (!w) {
      out = w.error();
      return 1;
    }
    ::_exit(0);  // no destructor: the ring keeps saying "running"
  });
  ASSERT_TRUE(crashed.finished && crashed.exit_code == 0) << crashed.output;
  std::uint64_t generation = 1;
  for (const std::uint32_t live_pid : {static_cast<std::uint32_t>(::getpid()), 1u}) {
    SCOPED_TRACE("recorded pid " + std::to_string(live_pid));
    recordWriterPid(name_, live_pid);
    ASSERT_EQ(readHeader(name_).writer_state, static_cast<std::uint64_t>(SP_SHM_WRITER_RUNNING));
    const ChildOutcome next = runInChild([&](std::string& out) {
      auto w = ShmPoseWriter::create(name_, 8);
      if (!w) {
        out = w.error();
        return 1;
      }
      out = std::to_string((*w)->generation());
      ::_exit(w.value()->generation() == generation + 1 ? 0 : 2);  // crashes too: the next round is stale again
    });
    ASSERT_TRUE(next.finished) << next.output;
    EXPECT_EQ(next.exit_code, 0) << "the stale ring blocked the new writer: " << next.output;
    ++generation;
    EXPECT_EQ(readHeader(name_).generation, generation);
  }
}
}  // namespace
}  // namespace stillpoint::ipc
