// ipc_probe: publisher and subscriber processes for the ipc integration tests.
//
//   ipc_probe pub --transport lcm|dds|shm --count N [--rate HZ] [--status-every K]
//                 [--ready-file F] [--hold-file F] [--timeout S] [transport options]
//   ipc_probe sub --transport lcm|dds --count N [--statuses M] [--last-status K]
//                 [--ready-file F] [--timeout S] [transport options]
//   ipc_probe shm-writer NAME RATE_HZ SECONDS [CAPACITY]
//                 (stress-test writer: shm_pattern.h records, paced at RATE_HZ; prints the rate reached)
//   transport options (shm ring: sp_probe<suffix>): --url URL  --domain ID  --dds-config XML|URI  --suffix S
//
// Message k is probe::testPose(k) (frame_counter k = 1..N); the subscriber checks every
// field bit for bit and that each arrives exactly once (order is reported, see runSub). Status messages are
// testStatus(j), j = 1, 2, ... Exit status: 0 all good, 1 check failed or error, 2 usage.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <thread>
#include <vector>

#include "probe_messages.hpp"
#include "shm_pattern.h"
#include "stillpoint/core/program.hpp"
#include "stillpoint/ipc/publisher.hpp"
#include "stillpoint/ipc/shm_writer.hpp"

using namespace stillpoint;
using namespace stillpoint::ipc;
using Clock = std::chrono::steady_clock;

namespace {

struct Args {
  std::string role, transport, url = LcmOptions().url, dds_config, suffix, ready_file, hold_file;
  std::uint32_t domain = 0;
  long count = 100, status_every = 0, statuses = -1, last_status = -1;
  double rate = 500.0, timeout = 10.0;
  bool objects = false;  // pub: each pose's testObjects too; sub: expect them all
};

[[noreturn]] void usage(const std::string& why) {
  std::cerr << "ipc_probe: " << why << "\n"
            << "usage: ipc_probe pub|sub --transport lcm|dds --count N [--rate HZ] [--status-every K]\n"
            << "       [--statuses M] [--last-status K] [--ready-file F] [--hold-file F] [--timeout S]\n"
            << "       [--url URL] [--domain ID] [--dds-config XML|URI] [--suffix S] [--objects]\n";
  std::exit(2);
}

Args parse(int argc, char** argv) {
  Args a;
  if (argc < 2) usage("missing role");
  a.role = argv[1];
  if (a.role != "pub" && a.role != "sub") usage("role must be pub, sub or shm-writer");
  for (int i = 2; i < argc; ++i) {
    const std::string k = argv[i];
    auto val = [&]() -> std::string {
      if (i + 1 >= argc) usage(k + " needs a value");
      return argv[++i];
    };
    try {
      if (k == "--transport") a.transport = val();
      else if (k == "--url") a.url = val();
      else if (k == "--dds-config") a.dds_config = val();
      else if (k == "--suffix") a.suffix = val();
      else if (k == "--ready-file") a.ready_file = val();
      else if (k == "--hold-file") a.hold_file = val();
      else if (k == "--domain") a.domain = static_cast<std::uint32_t>(std::stoul(val()));
      else if (k == "--count") a.count = std::stol(val());
      else if (k == "--status-every") a.status_every = std::stol(val());
      else if (k == "--statuses") a.statuses = std::stol(val());
      else if (k == "--last-status") a.last_status = std::stol(val());
      else if (k == "--rate") a.rate = std::stod(val());
      else if (k == "--timeout") a.timeout = std::stod(val());
      else if (k == "--objects") a.objects = true;
      else usage("unknown option " + k);
    } catch (const std::exception&) {
      usage("bad value for " + k);
    }
  }
  if (a.transport != "lcm" && a.transport != "dds" && a.transport != "shm") usage("--transport must be lcm, dds or shm");
  if (a.count < 0 || a.rate <= 0 || a.timeout <= 0) usage("--count, --rate and --timeout must be positive");
  return a;
}

IpcOptions optionsFor(const Args& a) {
  IpcOptions o;
  o.shm.enabled = a.transport == "shm";
  o.shm.name = "sp_probe" + a.suffix;
  o.queue_capacity = 4096;  // the test wants every message: never drop at the hand-off
  if (a.transport == "lcm") {
    o.lcm.enabled = true;
    o.lcm.url = a.url;
    o.lcm.pose_channel += a.suffix;
    o.lcm.status_channel += a.suffix;
    o.lcm.objects_channel += a.suffix;
  } else if (a.transport == "dds") {
    o.dds.enabled = true;
    o.dds.domain_id = a.domain;
    o.dds.config = a.dds_config;
    o.dds.pose_topic += a.suffix;
    o.dds.status_topic += a.suffix;
    o.dds.objects_topic += a.suffix;
  }
  return o;
}

bool waitForFile(const std::string& path, Clock::time_point deadline) {
  while (!std::filesystem::exists(path)) {
    if (Clock::now() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return true;
}

int runPub(const Args& a) {
  const IpcOptions o = optionsFor(a);
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(a.timeout));
  auto transports = makeTransports(o);
  if (!transports) {
    std::cerr << "ipc_probe pub: " << transports.error() << "\n";
    return 1;
  }
  if (!a.ready_file.empty() && !waitForFile(a.ready_file, deadline)) {
    std::cerr << "ipc_probe pub: subscriber never became ready (" << a.ready_file << ")\n";
    return 1;
  }
  // DDS best-effort writers only send to readers they have matched. Without a ready
  // file nobody is waiting yet (the late-joiner test): publish at once.
  for (const auto& t : transports.value()) {
    if (a.ready_file.empty()) break;
    while (t->matchedReaders() == 0) {
      if (Clock::now() > deadline) {
        std::cerr << "ipc_probe pub: no " << t->name() << " reader matched\n";
        return 1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  }
  Publisher pub(std::move(transports.value()), o.queue_capacity);
  const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / a.rate));
  auto next = Clock::now();
  long statuses = 0;
  for (long k = 1; k <= a.count; ++k) {
    pub.publishPose(probe::testPose(static_cast<std::uint64_t>(k)));
    if (a.objects) pub.publishObjects(probe::testObjects(static_cast<std::uint64_t>(k)));
    if (a.status_every > 0 && k % a.status_every == 0) pub.publishStatus(probe::testStatus(static_cast<std::uint64_t>(++statuses)));
    next += period;
    std::this_thread::sleep_until(next);
  }
  pub.flush();
  // Give the last datagrams time to leave before the sockets close.
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  const PublisherStats st = pub.stats();
  std::cout << "pub sent=" << st.sent << " dropped=" << st.dropped << " errors=" << st.send_errors
            << " statuses=" << statuses << std::endl;
  if (!a.hold_file.empty() && !waitForFile(a.hold_file, deadline)) {
    std::cerr << "ipc_probe pub: hold file " << a.hold_file << " never appeared\n";
    return 1;
  }
  return st.dropped == 0 && st.send_errors == 0 ? 0 : 1;
}

int runSub(const Args& a) {
  const IpcOptions o = optionsFor(a);
  ShmSubscriberOptions shm;
  shm.from_oldest = shm.wait_for_ring = true;
  shm.objects = a.objects;
  auto sub = a.transport == "lcm"   ? makeLcmSubscriber(o.lcm)
             : a.transport == "shm" ? makeShmSubscriber(o.shm, shm)
                                    : makeDdsSubscriber(o.dds, 4096);
  if (!sub) {
    std::cerr << "ipc_probe sub: " << sub.error() << "\n";
    return 1;
  }
  std::vector<int> seen(static_cast<std::size_t>(a.count) + 1, 0), seen_objects(seen.size(), 0);
  long objects = 0, bad_objects = 0;
  std::string first_problem;
  (*sub)->onObjects([&](const ObjectsMessage& m) {
    ++objects;
    if (m.frame_counter < 1 || m.frame_counter > static_cast<std::uint64_t>(a.count) || seen_objects[m.frame_counter]++) {
      ++bad_objects;
      return;
    }
    if (std::string d = probe::diff(probe::testObjects(m.frame_counter), m); !d.empty()) {
      ++bad_objects;
      if (first_problem.empty()) first_problem = "objects " + std::to_string(m.frame_counter) + ": " + d;
    }
  });
  long received = 0, mismatched = 0, duplicates = 0, out_of_order = 0, unexpected = 0, statuses = 0,
       bad_status = 0;
  std::uint64_t last = 0;
  (*sub)->onPose([&](const PoseMessage& p) {
    ++received;
    if (p.frame_counter < 1 || p.frame_counter > static_cast<std::uint64_t>(a.count)) {
      ++unexpected;
      return;
    }
    if (p.frame_counter <= last) ++out_of_order;
    last = p.frame_counter;
    if (seen[p.frame_counter]++) ++duplicates;
    if (std::string d = probe::diff(probe::testPose(p.frame_counter), p); !d.empty()) {
      ++mismatched;
      if (first_problem.empty()) first_problem = "pose " + std::to_string(p.frame_counter) + ": " + d;
    }
  });
  (*sub)->onStatus([&](const StatusMessage& s) {
    ++statuses;
    // Status j has frames_received == 30 j; check the whole message against testStatus(j).
    const std::uint64_t j = s.frames_received / 30;
    if (a.last_status >= 0 && statuses == 1 && j != static_cast<std::uint64_t>(a.last_status)) {
      ++bad_status;
      first_problem = "first status is #" + std::to_string(j) + ", expected the last one #" + std::to_string(a.last_status);
    }
    if (std::string d = probe::diff(probe::testStatus(j), s); !d.empty()) {
      ++bad_status;
      if (first_problem.empty()) first_problem = "status " + std::to_string(j) + ": " + d;
    }
  });
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(a.timeout));
  bool ready = a.ready_file.empty();
  const bool want_status = a.statuses > 0 || a.last_status >= 0;
  std::string error;
  while (Clock::now() < deadline) {
    if (!ready && (*sub)->matchedWriters() != 0) {  // LCM: -1, ready at once; DDS: once matched
      std::ofstream(a.ready_file) << "ready\n";
      ready = true;
    }
    if (received >= a.count && (!want_status || statuses >= std::max(1L, a.statuses)) &&
        (!a.objects || objects >= a.count))
      break;
    auto r = (*sub)->poll(std::chrono::milliseconds(20));
    if (!r) {
      error = r.error();
      break;
    }
  }
  long missing = 0;
  for (long k = 1; k <= a.count; ++k) missing += seen[static_cast<std::size_t>(k)] == 0;
  std::cout << "sub received=" << received << " missing=" << missing << " mismatched=" << mismatched
            << " duplicates=" << duplicates << " out_of_order=" << out_of_order << " unexpected=" << unexpected
            << " statuses=" << statuses << " bad_status=" << bad_status;
  if (a.objects) std::cout << " objects=" << objects << " bad_objects=" << bad_objects;
  std::cout << std::endl;
  if (!first_problem.empty()) std::cout << "first problem: " << first_problem << std::endl;
  if (!error.empty()) std::cout << "receive error: " << error << std::endl;
  const bool statuses_ok = a.statuses < 0 || statuses == a.statuses;
  const bool last_ok = a.last_status < 0 || statuses >= 1;
  // out_of_order is reported, not a failure: UDP gives no ordering guarantee even on
  // loopback (two datagrams can sit in different CPUs' backlogs when the sender migrates).
  return missing == 0 && mismatched == 0 && duplicates == 0 && unexpected == 0 &&
                 bad_status == 0 && statuses_ok && last_ok && (error.empty() || received == a.count) &&
                 (!a.objects || (objects == a.count && bad_objects == 0))
             ? 0
             : 1;
}

}  // namespace

int runShmWriter(int argc, char** argv) {
  if (argc < 5) usage("shm-writer needs NAME RATE_HZ SECONDS [CAPACITY]");
  double rate = 0, seconds = 0;
  std::uint32_t capacity = 1024;
  try {
    rate = std::stod(argv[3]);
    seconds = std::stod(argv[4]);
    if (argc > 5) capacity = static_cast<std::uint32_t>(std::stoul(argv[5]));
  } catch (const std::exception&) {
    usage("bad shm-writer number");
  }
  auto writer = ShmPoseWriter::create(argv[2], capacity);
  if (!writer) {
    std::cerr << "ipc_probe shm-writer: " << writer.error() << "\n";
    return 1;
  }
  const std::uint64_t g = (*writer)->generation();
  const auto start = Clock::now();
  const auto end = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  sp_pose_record rec;
  // Paced by count, not by sleeping a period: a late wake-up is caught up at once.
  for (auto now = start; now < end; now = Clock::now()) {
    const auto due = static_cast<std::uint64_t>(std::chrono::duration<double>(now - start).count() * rate) + 1;
    while ((*writer)->written() < due) {
      sp_test_fill(&rec, g, (*writer)->written() + 1);
      (*writer)->write(rec);
    }
    std::this_thread::sleep_for(std::chrono::microseconds(20));
  }
  const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
  std::cout << "writer generation=" << g << " records=" << (*writer)->written()
            << " rate_hz=" << static_cast<long>((*writer)->written() / elapsed) << std::endl;
  return 0;
}

static int probeMain(int argc, char** argv) {
  if (argc >= 2 && std::string(argv[1]) == "shm-writer") return runShmWriter(argc, argv);
  const Args a = parse(argc, argv);
  return a.role == "pub" ? runPub(a) : runSub(a);
}

int main(int argc, char** argv) { return stillpoint::runProgram("ipc_probe", probeMain, argc, argv); }
