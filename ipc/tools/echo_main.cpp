// stillpoint-echo: subscribe to stillpoint's pose output and print poses and rates.
#include <pwd.h>

#include <chrono>
#include <cstdio>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>

#include "stillpoint/core/covariance.hpp"
#include "stillpoint/core/program.hpp"
#include "stillpoint/ipc/options.hpp"
#include "stillpoint/ipc/transport.hpp"

using namespace stillpoint;
using namespace stillpoint::ipc;
using Clock = std::chrono::steady_clock;

namespace {

constexpr const char* kUsage =
    "usage: stillpoint-echo --shm|--lcm|--dds [--config IPC.yaml] [--name RING] [--url URL]\n"
    "                       [--domain ID] [--dds-config XML|URI] [--count N] [--seconds S]\n"
    "                       [--rates-only] [--from-oldest] [--owner USER|UID]\n"
    "Prints one line per pose (and status), and a rate line every second.\n"
    "  --shm         read the shared-memory ring /dev/shm/RING (default stillpoint_pose)\n"
    "  --owner U     the ring must belong to user U (default: the user running this)\n"
    "  --lcm         subscribe on the LCM URL (default udpm://239.255.76.67:7667?ttl=0)\n"
    "  --dds         subscribe on Cyclone DDS domain ID (default 0) with the given config\n"
    "  --config F    take names, URL, domain and DDS config from the ipc: section of F\n"
    "  --count N     exit after N poses;  --seconds S  exit after S seconds\n"
    "Exit status: 0 ok, 1 error (missing ring, writer gone, bad URL, receive failure),\n"
    "2 usage error.\n";

int usageError(const std::string& why) {
  std::cerr << "stillpoint-echo: " << why << "\n" << kUsage;
  return 2;
}

// A user name or a numeric uid; -1 when neither.
std::int64_t parseOwner(const std::string& text) {
  if (!text.empty() && text.find_first_not_of("0123456789") == std::string::npos && text.size() <= 10) {
    const unsigned long long uid = std::stoull(text);
    return uid <= 0xFFFFFFFEull ? static_cast<std::int64_t>(uid) : -1;
  }
  const struct passwd* pw = ::getpwnam(text.c_str());
  return pw != nullptr ? static_cast<std::int64_t>(pw->pw_uid) : -1;
}

double wallNowNs() {
  return static_cast<double>(
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch()).count());
}

}  // namespace

static int echoMain(int argc, char** argv) {
  std::string transport, config, name, url, dds_config;
  std::int64_t owner = -1;
  long long domain = -1;
  long count = -1;
  double seconds = -1;
  bool rates_only = false, from_oldest = false;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto val = [&](std::string& out) -> bool {
      if (i + 1 >= argc) return false;
      out = argv[++i];
      return true;
    };
    std::string v;
    if (k == "--help" || k == "-h") {
      std::cout << kUsage;
      return 0;
    } else if (k == "--shm" || k == "--lcm" || k == "--dds") {
      if (!transport.empty()) return usageError("choose one of --shm, --lcm, --dds");
      transport = k.substr(2);
    } else if (k == "--rates-only") {
      rates_only = true;
    } else if (k == "--from-oldest") {
      from_oldest = true;
    } else if (k == "--owner") {
      if (!val(v)) return usageError(k + " needs a value");
      owner = parseOwner(v);
      if (owner < 0) return usageError("no user '" + v + "' for --owner");
    } else if (k == "--config" || k == "--name" || k == "--url" || k == "--dds-config" || k == "--domain" ||
               k == "--count" || k == "--seconds") {
      if (!val(v)) return usageError(k + " needs a value");
      try {
        std::size_t used = 0;
        if (k == "--config") config = v;
        else if (k == "--name") name = v;
        else if (k == "--url") url = v;
        else if (k == "--dds-config") dds_config = v;
        else if (k == "--domain") domain = std::stoll(v, &used);
        else if (k == "--count") count = std::stol(v, &used);
        else seconds = std::stod(v, &used);
        if (used != 0 && used != v.size()) throw std::invalid_argument(v);
      } catch (const std::exception&) {
        return usageError("bad number '" + v + "' for " + k);
      }
      if ((k == "--count" && count <= 0) || (k == "--seconds" && seconds <= 0) ||
          (k == "--domain" && (domain < 0 || domain > 230)))
        return usageError(k + " out of range: " + v);
    } else {
      return usageError("unknown argument '" + k + "'");
    }
  }
  if (transport.empty()) return usageError("choose a transport: --shm, --lcm or --dds");

  IpcOptions o;
  if (!config.empty()) {
    auto loaded = loadIpcOptions(config);
    if (!loaded) {
      std::cerr << "stillpoint-echo: " << loaded.error() << "\n";
      return 1;
    }
    o = *loaded;
  }
  if (!name.empty()) o.shm.name = name;
  if (!url.empty()) o.lcm.url = url;
  if (domain >= 0) o.dds.domain_id = static_cast<std::uint32_t>(domain);
  if (!dds_config.empty()) o.dds.config = dds_config;
  if (Status s = o.validate(); !s) {
    std::cerr << "stillpoint-echo: " << s.error() << "\n";
    return 1;
  }

  Result<std::unique_ptr<Subscriber>> sub = Error{"unreachable"};
  if (transport == "shm") {
    ShmSubscriberOptions so;
    so.from_oldest = from_oldest;
    so.owner_uid = owner;
    sub = makeShmSubscriber(o.shm, so);
  } else if (transport == "lcm") {
    sub = makeLcmSubscriber(o.lcm);
  } else {
    sub = makeDdsSubscriber(o.dds);
  }
  if (!sub) {
    std::cerr << "stillpoint-echo: " << sub.error() << "\n";
    return 1;
  }

  long poses = 0, statuses = 0, window_poses = 0, window_statuses = 0, restarts = 0;
  (*sub)->onPose([&](const PoseMessage& p) {
    ++poses;
    ++window_poses;
    if (rates_only) return;
    std::ostringstream line;
    line << std::fixed << std::setprecision(6) << "pose frame=" << p.frame_counter
         << " t=" << p.sensor_stamp.toSecondsString() << " state=" << toString(p.state) << " p=[" << p.position[0]
         << " " << p.position[1] << " " << p.position[2] << "] q=[" << p.orientation[0] << " " << p.orientation[1]
         << " " << p.orientation[2] << " " << p.orientation[3] << "] tracked=" << p.tracked_features
         << " rejected=" << p.dynamic_rejected_features << " keyframes=" << p.keyframes << " map=" << std::hex
         << p.map_id << std::dec << " health=" << toString(p.health) << std::setprecision(3)
         << " dynamic_share=" << p.dynamic_share << " rms_px=" << p.reprojection_rms_px
         << " conditioning=" << p.conditioning << " causes=" << health_cause::toString(p.health_causes)
         << " mask_age_s=" << p.mask_age_s;
    // The covariance's standard deviations per axis (0 without a pose).
    const Eigen::Matrix<double, 6, 1> sigma = fromUpperTriangle(p.covariance).diagonal().cwiseMax(0.0).cwiseSqrt();
    line << std::setprecision(4) << " sigma_m=[" << sigma(0) << " " << sigma(1) << " " << sigma(2)
         << "] sigma_rad=[" << sigma(3) << " " << sigma(4) << " " << sigma(5) << "]"
         << std::setprecision(1) << " latency_us=" << (wallNowNs() - static_cast<double>(p.publish_stamp.nanoseconds())) * 1e-3;
    std::cout << line.str() << "\n";
  });
  (*sub)->onStatus([&](const StatusMessage& s) {
    ++statuses;
    ++window_statuses;
    if (rates_only) return;
    std::ostringstream line;
    line << std::fixed << std::setprecision(2) << "status uptime_s=" << s.uptime_s
         << " frames=" << s.frames_received << " dropped=" << s.frames_dropped << " state=" << toString(s.tracking_state)
         << " health=" << toString(s.health) << " causes=" << health_cause::toString(s.health_causes);
    for (const auto& t : s.threads)
      line << " " << t.name << "=" << t.loop_rate_hz << "Hz/" << t.latency_ms_median << "ms";
    for (const auto& q : s.queues) line << " q." << q.name << "=" << q.depth << "/" << q.capacity;
    std::cout << line.str() << "\n";
  });
  (*sub)->onRestart([&] {
    ++restarts;
    std::cout << "writer restarted (ring reattached)\n";
  });

  const auto start = Clock::now();
  auto window_start = start;
  for (;;) {
    auto r = (*sub)->poll(std::chrono::milliseconds(100));
    if (!r) {
      std::cerr << "stillpoint-echo: " << r.error() << "\n";
      return 1;
    }
    const auto now = Clock::now();
    const double window = std::chrono::duration<double>(now - window_start).count();
    if (window >= 1.0) {
      std::cout << std::fixed << std::setprecision(1) << "rate pose_hz=" << window_poses / window
                << " status_hz=" << window_statuses / window << " poses=" << poses << " lost=" << (*sub)->lost()
                << std::endl;
      window_poses = window_statuses = 0;
      window_start = now;
    }
    if (count > 0 && poses >= count) break;
    if (seconds > 0 && std::chrono::duration<double>(now - start).count() >= seconds) break;
  }
  std::cout << std::flush;
  return 0;
}

int main(int argc, char** argv) { return stillpoint::runProgram("stillpoint-echo", echoMain, argc, argv); }
