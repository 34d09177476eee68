#include "threads.hpp"

#include <pthread.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sched.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>

namespace stillpoint::daemon {

std::vector<int> availableCores() {
  std::vector<int> cores;
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) != 0) return cores;
  for (int c = 0; c < CPU_SETSIZE; ++c)
    if (CPU_ISSET(c, &set)) cores.push_back(c);
  return cores;
}

namespace {
std::string list(const std::vector<int>& cores) {
  std::string s;
  for (int c : cores) {
    if (!s.empty()) s += ',';
    s += std::to_string(c);
  }
  return s;
}
}  // namespace

std::vector<std::string> placeCurrentThread(const std::string& name, const ThreadPlacement& placement,
                                            const std::vector<int>& available, const std::string& what) {
  std::vector<std::string> warnings;
  const std::string short_name = name.substr(0, 15);
  pthread_setname_np(pthread_self(), short_name.c_str());

  if (!placement.cores.empty()) {
    cpu_set_t set;
    CPU_ZERO(&set);
    std::vector<int> used, missing;
    for (int c : placement.cores) {
      bool ok = false;
      for (int a : available) ok |= a == c;
      (ok ? used : missing).push_back(c);
      if (ok) CPU_SET(c, &set);
    }
    if (!missing.empty())
      warnings.push_back(what + ".cores: core(s) " + list(missing) + " not available on this machine (available: " +
                         list(available) + ")" + (used.empty() ? "; thread left unpinned" : "; pinned to " + list(used)));
    if (!used.empty()) {
      const int rc = pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
      if (rc != 0) warnings.push_back(what + ".cores: cannot pin to " + list(used) + ": " + std::strerror(rc));
    }
  }
  if (placement.priority > 0) {
    sched_param param{};
    param.sched_priority = placement.priority;
    const int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
    if (rc != 0)
      warnings.push_back(what + ".priority: SCHED_FIFO " + std::to_string(placement.priority) +
                         " not permitted (" + std::strerror(rc) +
                         "; needs CAP_SYS_NICE or RLIMIT_RTPRIO); normal scheduling kept");
  }
  if (placement.nice != 0 && placement.priority == 0) {
    // Linux keeps a nice value per thread: PRIO_PROCESS with the thread id.
    const auto tid = static_cast<id_t>(::gettid());
    errno = 0;
    if (setpriority(PRIO_PROCESS, tid, placement.nice) != 0)
      warnings.push_back(what + ".nice: " + std::to_string(placement.nice) + " not permitted (" +
                         std::strerror(errno) + (placement.nice < 0 ? "; a negative value needs CAP_SYS_NICE" : "") +
                         "); nice " + std::to_string(getpriority(PRIO_PROCESS, tid)) + " kept");
  }
  return warnings;
}

void clearInheritedPlacement(const std::vector<int>& available) {
  if (!available.empty()) {
    cpu_set_t set;
    CPU_ZERO(&set);
    for (int c : available) CPU_SET(c, &set);
    pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
  }
  int policy = SCHED_OTHER;
  sched_param param{};
  if (pthread_getschedparam(pthread_self(), &policy, &param) == 0 && policy != SCHED_OTHER) {
    param.sched_priority = 0;
    pthread_setschedparam(pthread_self(), SCHED_OTHER, &param);
  }
}

bool hasIpcLockCapability() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind("CapEff:", 0) == 0) return (std::stoull(line.substr(7), nullptr, 16) >> 14) & 1;  // CAP_IPC_LOCK
  return false;
}

std::vector<std::string> lockMemory(bool* locked) {
  *locked = false;
  rlimit limit{};
  if (getrlimit(RLIMIT_MEMLOCK, &limit) != 0)
    return {std::string("lock_memory: getrlimit(RLIMIT_MEMLOCK) failed: ") + std::strerror(errno) + "; not locked"};
  if (limit.rlim_cur != RLIM_INFINITY && !hasIpcLockCapability())
    return {"lock_memory: RLIMIT_MEMLOCK is " + std::to_string(limit.rlim_cur) +
            " bytes, not unlimited (systemd: LimitMEMLOCK=infinity); memory not locked"};
  if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0)
    return {std::string("lock_memory: mlockall failed: ") + std::strerror(errno) + "; memory not locked"};
  *locked = true;
  return {};
}

}  // namespace stillpoint::daemon
