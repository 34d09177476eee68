#pragma once
// Real processes for the ring tests: a body run in a forked child under a time limit. A
// step that a regression could block (an open() of a FIFO) runs in a child that is killed
// after the limit, so a hang fails the test instead of stalling it.
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <functional>
#include <string>
#include <thread>

#include "stillpoint/ipc/shm_writer.hpp"
#include "stillpoint_shm.h"

namespace stillpoint::ipc::shm_test {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

inline std::string ringPath(const std::string& name) { return std::string(SP_SHM_DIR) + name; }

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

}  // namespace stillpoint::ipc::shm_test
