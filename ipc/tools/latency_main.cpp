// ipc_latency: publish -> receive latency between two processes, per transport.
//
//   ipc_latency --transport shm|lcm|dds [--count N] [--rate HZ] [--busy-poll]
//               [--url URL] [--domain ID] [--dds-config XML|URI]
//
// The parent publishes N poses through a threaded Publisher (as the daemon does); a
// child process (this program again, --role sub) subscribes and, for each pose, takes
// CLOCK_REALTIME on arrival. It prints two distributions:
//   transport: arrival - publish_stamp (stamped by the publisher thread just before send)
//   end_to_end: arrival - the time publishPose() was called (includes the queue hand-off)
// LCM needs multicast: run it inside a network namespace (ipc/tools/latency-bench.sh).
#include <spawn.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <thread>
#include <vector>

#include "probe_messages.hpp"
#include "stillpoint/core/program.hpp"
#include "stillpoint/ipc/publisher.hpp"
#include "stillpoint/ipc/shm_writer.hpp"

extern char** environ;

using namespace stillpoint;
using namespace stillpoint::ipc;
using Clock = std::chrono::steady_clock;

namespace {

std::int64_t wallNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

struct Args {
  std::string role = "pub", transport, url = LcmOptions().url, dds_config, ready_file, tag;
  std::uint32_t domain = 0;
  long count = 1000;
  double rate = 200.0;
  bool busy_poll = false;
};

IpcOptions optionsFor(const Args& a) {
  IpcOptions o;
  o.shm.enabled = a.transport == "shm";
  o.shm.name = "sp_latency_" + a.tag;
  o.lcm.enabled = a.transport == "lcm";
  o.lcm.url = a.url;
  o.lcm.pose_channel += "_LAT_" + a.tag;
  o.lcm.status_channel += "_LAT_" + a.tag;
  o.dds.enabled = a.transport == "dds";
  o.dds.domain_id = a.domain;
  o.dds.config = a.dds_config;
  o.dds.pose_topic += "_lat_" + a.tag;
  o.dds.status_topic += "_lat_" + a.tag;
  return o;
}

void printStats(const char* what, std::vector<double> us) {
  if (us.empty()) {
    std::cout << what << ": no samples\n";
    return;
  }
  std::sort(us.begin(), us.end());
  auto q = [&](double f) { return us[std::min(us.size() - 1, static_cast<std::size_t>(f * (us.size() - 1) + 0.5))]; };
  std::printf("%-10s n=%zu median_us=%.1f p99_us=%.1f max_us=%.1f\n", what, us.size(), q(0.5), q(0.99), us.back());
}

int runSub(const Args& a) {
  // 1 us timer slack instead of the default 50 us: the shm reader's 50 us naps then
  // last 50 us, which is what a polling controller would configure too.
  ::prctl(PR_SET_TIMERSLACK, 1000UL, 0UL, 0UL, 0UL);
  const IpcOptions o = optionsFor(a);
  Result<std::unique_ptr<Subscriber>> sub = Error{""};
  if (a.transport == "shm") {
    ShmSubscriberOptions so;
    so.busy_poll = a.busy_poll;
    sub = makeShmSubscriber(o.shm, so);
  } else if (a.transport == "lcm") {
    sub = makeLcmSubscriber(o.lcm);
  } else {
    sub = makeDdsSubscriber(o.dds, 256);
  }
  if (!sub) {
    std::cerr << "ipc_latency sub: " << sub.error() << "\n";
    return 1;
  }
  std::vector<double> transport_us, e2e_us;
  long received = 0;
  (*sub)->onPose([&](const PoseMessage& p) {
    const std::int64_t now = wallNs();
    ++received;
    transport_us.push_back(static_cast<double>(now - p.publish_stamp.nanoseconds()) * 1e-3);
    e2e_us.push_back(static_cast<double>(now - p.sensor_stamp.nanoseconds()) * 1e-3);
  });
  const auto deadline = Clock::now() + std::chrono::seconds(30) + std::chrono::milliseconds(static_cast<long>(1000 * a.count / a.rate));
  bool ready = false;
  while (received < a.count && Clock::now() < deadline) {
    if (!ready && (*sub)->matchedWriters() != 0) {
      std::ofstream(a.ready_file) << "ready\n";
      ready = true;
    }
    auto r = (*sub)->poll(std::chrono::milliseconds(a.busy_poll ? 0 : 50));
    if (!r) {
      std::cerr << "ipc_latency sub: " << r.error() << "\n";
      return 1;
    }
  }
  std::printf("transport=%s%s received=%ld of %ld at %.0f Hz\n", a.transport.c_str(),
              a.transport == "shm" ? (a.busy_poll ? " (busy poll)" : " (50 us sleep poll)") : "", received, a.count,
              a.rate);
  printStats("transport", transport_us);
  printStats("end_to_end", e2e_us);
  return received == a.count ? 0 : 1;
}

int runPub(Args a, char* self) {
  a.tag = std::to_string(::getpid());
  a.ready_file = (std::filesystem::temp_directory_path() / ("sp_latency_ready_" + a.tag)).string();
  std::filesystem::remove(a.ready_file);
  const IpcOptions o = optionsFor(a);
  auto transports = makeTransports(o);
  if (!transports) {
    std::cerr << "ipc_latency: " << transports.error() << "\n";
    return 1;
  }
  std::vector<std::string> args = {self, "--role", "sub", "--transport", a.transport, "--count", std::to_string(a.count),
                                   "--rate", std::to_string(a.rate), "--url", a.url, "--domain", std::to_string(a.domain),
                                   "--tag", a.tag, "--ready-file", a.ready_file};
  if (!a.dds_config.empty()) args.insert(args.end(), {"--dds-config", a.dds_config});
  if (a.busy_poll) args.push_back("--busy-poll");
  std::vector<char*> argv;
  for (auto& s : args) argv.push_back(s.data());
  argv.push_back(nullptr);
  pid_t child = 0;
  if (posix_spawn(&child, "/proc/self/exe", nullptr, nullptr, argv.data(), environ) != 0) {
    std::cerr << "ipc_latency: cannot start the subscriber process\n";
    return 1;
  }
  const auto deadline = Clock::now() + std::chrono::seconds(20);
  bool ok = true;
  while (!std::filesystem::exists(a.ready_file) || transports.value().front()->matchedReaders() == 0) {
    if (Clock::now() > deadline) {
      std::cerr << "ipc_latency: subscriber not ready\n";
      ok = false;
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  if (ok) {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));  // let discovery settle on both sides
    Publisher pub(std::move(transports.value()), 64);
    const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / a.rate));
    auto next = Clock::now();
    for (long k = 1; k <= a.count; ++k) {
      PoseMessage p = probe::testPose(static_cast<std::uint64_t>(k));
      p.sensor_stamp = Timestamp::fromNanoseconds(wallNs());  // "handed over now"
      pub.publishPose(p);
      next += period;
      std::this_thread::sleep_until(next);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
  }
  int status = 0;
  ::waitpid(child, &status, 0);
  std::filesystem::remove(a.ready_file);
  transports.value().clear();  // the writer goes first: remove() refuses a ring that has one
  if (a.transport == "shm") (void)ShmPoseWriter::remove(o.shm.name);
  return ok && WIFEXITED(status) && WEXITSTATUS(status) == 0 ? 0 : 1;
}

}  // namespace

static int latencyMain(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    const bool has = i + 1 < argc;
    if (k == "--busy-poll") a.busy_poll = true;
    else if (k == "--role" && has) a.role = argv[++i];
    else if (k == "--transport" && has) a.transport = argv[++i];
    else if (k == "--url" && has) a.url = argv[++i];
    else if (k == "--dds-config" && has) a.dds_config = argv[++i];
    else if (k == "--ready-file" && has) a.ready_file = argv[++i];
    else if (k == "--tag" && has) a.tag = argv[++i];
    else if (k == "--domain" && has) a.domain = static_cast<std::uint32_t>(std::atoi(argv[++i]));
    else if (k == "--count" && has) a.count = std::atol(argv[++i]);
    else if (k == "--rate" && has) a.rate = std::atof(argv[++i]);
    else {
      std::cerr << "usage: ipc_latency --transport shm|lcm|dds [--count N] [--rate HZ] [--busy-poll]\n"
                   "                   [--url URL] [--domain ID] [--dds-config XML|URI]\n";
      return 2;
    }
  }
  if ((a.transport != "shm" && a.transport != "lcm" && a.transport != "dds") || a.count <= 0 || a.rate <= 0) {
    std::cerr << "ipc_latency: --transport must be shm, lcm or dds; --count and --rate positive\n";
    return 2;
  }
  return a.role == "sub" ? runSub(a) : runPub(a, argv[0]);
}

int main(int argc, char** argv) { return stillpoint::runProgram("ipc_latency", latencyMain, argc, argv); }
