// stillpointd: the long-running SLAM service. Reads one YAML config, opens the
// camera, tracks and publishes poses until SIGTERM/SIGINT (or the end of a
// recording). See docs/daemon.md.
#include <signal.h>
#include <unistd.h>

#include <opencv2/core.hpp>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>

#include "config.hpp"
#include "daemon.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/core/program.hpp"

namespace {

using namespace stillpoint;

constexpr const char* kUsage =
    "usage: stillpointd [--config PATH] [--print-config] [--max-frames N] [--log-level LEVEL]\n"
    "       stillpointd --help | --version\n"
    "\n"
    "Runs stillpoint as a service: opens the camera named in the config, tracks and publishes\n"
    "poses until SIGTERM/SIGINT (a second signal forces exit) or the end of a recording.\n"
    "SIGUSR1 writes the map to map.save (it is also written on stop).\n"
    "--config defaults to /etc/stillpoint/stillpointd.yaml. --print-config prints the effective\n"
    "configuration (every field, SLAM options included) and exits. --max-frames overrides\n"
    "source.replay.max_frames, --log-level overrides log_level.\n"
    "Exit status: 0 clean stop, 1 start-up or runtime error (or a stop that overran\n"
    "shutdown_timeout_s), 2 usage error, 130 forced by a second signal.\n";

void writeAll(const char* text) {
  // Async-signal-safe enough for the forced-exit path.
  const ssize_t n = ::write(STDERR_FILENO, text, std::strlen(text));
  (void)n;
}

}  // namespace

namespace {

sigset_t stopSignals() {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGUSR1);  // save the map (map.save), not a stop
  return signals;
}

// SIGTERM/SIGINT are blocked before the shared libraries' initialisers run
// (OpenCV, Ceres, GDAL, ...) and before the config loads: until then their
// default action would end the process with 143 and no message. Every thread
// inherits the mask; one thread takes the signals with sigtimedwait, and one
// that came during start-up ends it cleanly. Started through the launcher
// (stillpointd_launcher.c) the signals are blocked from exec on; this covers
// a service started directly.
void blockStopSignals(int, char**, char**) {
  const sigset_t signals = stopSignals();
  sigprocmask(SIG_BLOCK, &signals, nullptr);
}
__attribute__((section(".preinit_array"), used)) void (*const kBlockStopSignals)(int, char**, char**) =
    blockStopSignals;

}  // namespace

static int daemonMain(int argc, char** argv) {
  sigset_t signals = stopSignals();
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);  // already blocked (preinit); kept for clarity
  std::string config_path = "/etc/stillpoint/stillpointd.yaml", log_level;
  bool print_config = false;
  long max_frames = -1;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](std::string* out) {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "stillpointd: option %s needs a value\n\n%s", a.c_str(), kUsage);
        std::exit(2);
      }
      *out = argv[++i];
    };
    if (a == "--help" || a == "-h") {
      std::fputs(kUsage, stdout);
      return 0;
    } else if (a == "--version") {
      std::puts("stillpointd " STILLPOINT_VERSION " (" STILLPOINT_ARCH ")");
      return 0;
    } else if (a == "--config") {
      value(&config_path);
    } else if (a == "--print-config") {
      print_config = true;
    } else if (a == "--log-level") {
      value(&log_level);
    } else if (a == "--max-frames") {
      std::string v;
      value(&v);
      char* end = nullptr;
      max_frames = std::strtol(v.c_str(), &end, 10);
      if (v.empty() || *end || max_frames <= 0) {
        std::fprintf(stderr, "stillpointd: --max-frames needs a positive integer\n\n%s", kUsage);
        return 2;
      }
    } else {
      std::fprintf(stderr, "stillpointd: unknown argument %s\n\n%s", a.c_str(), kUsage);
      return 2;
    }
  }

  if (const char* slow = std::getenv("STILLPOINTD_TEST_SLOW_CONFIG_MS"))  // tests: a signal while the config loads
    std::this_thread::sleep_for(std::chrono::milliseconds(std::atoi(slow)));
  auto loaded = daemon::loadDaemonConfig(config_path);
  if (!loaded) {
    std::fprintf(stderr, "stillpointd: %s\n", loaded.error().c_str());
    return 1;
  }
  daemon::DaemonConfig config = std::move(*loaded);
  if (max_frames > 0) config.source.replay.max_frames = static_cast<std::uint64_t>(max_frames);
  if (!log_level.empty()) config.log_level = log_level;
  log::Level level;
  if (!log::parseLevel(config.log_level, &level)) {
    std::fprintf(stderr, "stillpointd: bad log level '%s'\n", config.log_level.c_str());
    return 2;
  }
  if (print_config) {
    std::fputs(daemon::toYaml(config).c_str(), stdout);
    return 0;
  }
  log::setLevel(level);
  cv::setNumThreads(1);  // OpenCV's pool would compete with our pinned threads

  // A signal that came while the config loaded is pending now: it ends
  // start-up here, whatever the signal thread would see first.
  const timespec no_wait{0, 0};
  if (const int early = sigtimedwait(&signals, nullptr, &no_wait); early > 0 && early != SIGUSR1) {
    writeAll("stillpointd: signal during start-up, exiting\n");
    return 0;
  }
  daemon::Daemon service(config);
  // First signal: orderly stop. Second signal, or a stop overrunning
  // shutdown_timeout_s: immediate _exit (nothing flushed). A signal during
  // start-up (opening the camera, loading and warming up a network: seconds
  // on a loaded CPU) exits at once: nothing has been tracked or written yet.
  std::atomic<bool> started{false}, finished{false};
  const auto timeout = std::chrono::duration<double>(config.shutdown_timeout_s);
  std::thread signal_thread([&] {
    pthread_setname_np(pthread_self(), "sp-signals");
    bool stopping = false;
    auto stop_at = std::chrono::steady_clock::now();
    const timespec poll{0, 50'000'000};
    while (!finished) {
      const int sig = sigtimedwait(&signals, nullptr, &poll);
      if (sig == SIGUSR1) {
        if (started && !stopping) service.saveMap();
        continue;
      }
      if (sig > 0) {
        if (!started) {
          writeAll("stillpointd: signal during start-up, exiting\n");
          ::_exit(0);
        }
        if (stopping) {
          writeAll("stillpointd: second signal, forcing exit\n");
          ::_exit(130);
        }
        stopping = true;
        stop_at = std::chrono::steady_clock::now();
        service.requestStop();
      } else if (stopping && !finished && std::chrono::steady_clock::now() - stop_at > timeout) {
        writeAll("stillpointd: stop did not finish within shutdown_timeout_s, forcing exit\n");
        ::_exit(1);
      }
    }
  });
  // Joined on every way out, an exception's too (runProgram reports it).
  struct JoinOnExit {
    std::atomic<bool>& finished;
    std::thread& thread;
    ~JoinOnExit() {
      finished = true;
      thread.join();
    }
  } join_on_exit{finished, signal_thread};
  if (Status s = service.start(); !s) {
    std::fprintf(stderr, "stillpointd: %s\n", s.error().c_str());
    return 1;
  }
  started = true;
  return service.run();
}

int main(int argc, char** argv) { return stillpoint::runProgram("stillpointd", daemonMain, argc, argv); }
