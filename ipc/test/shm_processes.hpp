#pragma once
// Real processes for the ring tests: a body run in a forked child under a time limit, and
// a writer in its own process. Locks, FIFOs and SIGKILL act on processes, so the tests
// use them; a step that a regression could block runs in a child that is killed after
// the limit, so a hang fails the test instead of stalling it.
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <functional>
#include <string>
#include <thread>

#include "stillpoint/ipc/shm_writer.hpp"
#include "stillpoint_shm.h"

namespace stillpoint::ipc::shm_test {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

inline std::string ringPath(const std::string& name) { return std::string(SP_SHM_DIR) + name; }
inline std::string lockPath(const std::string& name) { return ringPath(name) + SP_SHM_LOCK_SUFFIX; }

inline std::string readAll(int fd) {
  std::string text;
  char buf[4096];
  for (ssize_t n; (n = ::read(fd, buf, sizeof(buf))) > 0;) text.append(buf, static_cast<std::size_t>(n));
  return text;
}

struct ChildOutcome {
  bool finished = false;  // false: still running at the limit, killed
  int exit_code = -1;
  std::string output;
};

// Runs `body` in a forked child: its return value becomes the exit status and the text
// it leaves in `out` comes back. The child is SIGKILLed after `limit`.
inline ChildOutcome runInChild(const std::function<int(std::string& out)>& body, std::chrono::milliseconds limit = 5s) {
  int fds[2];
  if (::pipe(fds) != 0) return {};
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(fds[0]);
    std::string out;
    const int code = body(out);
    (void)!::write(fds[1], out.data(), out.size());
    ::_exit(code);
  }
  ::close(fds[1]);
  ChildOutcome outcome;
  const auto until = Clock::now() + limit;
  int status = 0;
  while (::waitpid(pid, &status, WNOHANG) == 0) {
    if (Clock::now() > until) {
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      ::close(fds[0]);
      outcome.output = "still running after " + std::to_string(limit.count()) + " ms (killed)";
      return outcome;
    }
    std::this_thread::sleep_for(2ms);
  }
  outcome.finished = true;
  outcome.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  outcome.output = readAll(fds[0]);
  ::close(fds[0]);
  return outcome;
}

// Child body: tries to become the ring's writer; exit 0 and the error when refused.
inline int expectRefused(const std::string& name, std::string& out) {
  auto w = ShmPoseWriter::create(name, 8);
  if (w) {
    out = "writer created";
    return 1;
  }
  out = w.error();
  return 0;
}

inline volatile std::sig_atomic_t g_stop = 0;
inline void onTerm(int) { g_stop = 1; }

// A writer in its own process that publishes a record every millisecond until SIGTERM
// (clean close) or SIGKILL. Its first line on the pipe says whether it got the ring.
class WriterProcess {
 public:
  // `gate` (a pipe) given: wait until its write end is closed before creating the writer.
  WriterProcess(const std::string& name, std::uint32_t capacity, const int* gate = nullptr) {
    int fds[2];
    if (::pipe(fds) != 0) return;
    pid_ = ::fork();
    if (pid_ == 0) {
      ::close(fds[0]);
      std::signal(SIGTERM, onTerm);
      if (gate != nullptr) {
        ::close(gate[1]);
        (void)readAll(gate[0]);
      }
      auto w = ShmPoseWriter::create(name, capacity);
      const std::string line = w ? "ok\n" : "refused: " + w.error() + "\n";
      (void)!::write(fds[1], line.data(), line.size());
      ::close(fds[1]);
      if (!w) ::_exit(1);
      sp_pose_record r{};  // a pose at the origin, as subscribers accept it
      r.orientation[3] = 1.0;
      r.tracking_state = SP_TRACKING_OK;
      while (!g_stop) {
        (*w)->write(r);
        ::usleep(1000);
      }
      w->reset();
      ::_exit(0);
    }
    ::close(fds[1]);
    out_fd_ = fds[0];
  }
  ~WriterProcess() {
    stop(SIGKILL);
    if (out_fd_ >= 0) ::close(out_fd_);
  }
  WriterProcess(const WriterProcess&) = delete;
  WriterProcess& operator=(const WriterProcess&) = delete;

  pid_t pid() const { return pid_; }
  // The child's report: "ok" or "refused: <error>"; "" if it said nothing within `limit`.
  std::string report(std::chrono::milliseconds limit = 5s) {
    if (report_.empty() && out_fd_ >= 0) {
      const auto until = Clock::now() + limit;
      ::fcntl(out_fd_, F_SETFL, O_NONBLOCK);
      char buf[1024];
      while (report_.find('\n') == std::string::npos && Clock::now() < until) {
        const ssize_t n = ::read(out_fd_, buf, sizeof(buf));
        if (n > 0) report_.append(buf, static_cast<std::size_t>(n));
        else if (n == 0) break;
        else std::this_thread::sleep_for(1ms);
      }
      if (!report_.empty() && report_.back() == '\n') report_.pop_back();
    }
    return report_;
  }
  // Sends `sig` and reaps the child; returns its wait status.
  int stop(int sig) {
    if (pid_ <= 0) return -1;
    ::kill(pid_, sig);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
    return status;
  }

 private:
  pid_t pid_ = -1;
  int out_fd_ = -1;
  std::string report_;
};

// A ring name of the test's own (prefix, test name, pid), with its ring and
// lock files removed before and after the test.
class RingNameTest : public testing::Test {
 protected:
  explicit RingNameTest(const char* prefix) : prefix_(prefix) {}
  void SetUp() override {
    name_ = prefix_ + testing::UnitTest::GetInstance()->current_test_info()->name() + "_" + std::to_string(::getpid());
    clear();
  }
  void TearDown() override { clear(); }
  void clear() {
    for (const std::string& p : {ringPath(name_), lockPath(name_)}) {
      if (::unlink(p.c_str()) != 0) ::rmdir(p.c_str());
    }
  }
  std::string prefix_, name_;
};

}  // namespace stillpoint::ipc::shm_test
