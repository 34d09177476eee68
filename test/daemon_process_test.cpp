// stillpointd as a real process: poses on the shared-memory ring, one daemon per
// ring, clean stop on SIGTERM, forced exit on a second signal, bad configs, pinning
// to an absent core, and the systemd notification protocol through a fake NOTIFY_SOCKET.
// Time bounds here are generous limits from the spec (stop within
// shutdown_timeout_s), not performance assertions.
#include <fcntl.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "stillpoint/dataset/testing.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/eval/metrics.hpp"
#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint_shm.h"

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using stillpoint::dataset::testing::SyntheticDatasetOptions;

fs::path g_root;
std::string g_fast_seq, g_slow_seq, g_camera;

std::string readFile(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::map<std::string, std::string> readStatus(const fs::path& p) {
  std::map<std::string, std::string> kv;
  std::ifstream in(p);
  for (std::string line; std::getline(in, line);) {
    const auto eq = line.find('=');
    if (eq != std::string::npos) kv[line.substr(0, eq)] = line.substr(eq + 1);
  }
  return kv;
}

class Daemon {
 public:
  // Starts stillpointd with `config_text` (written to the test dir) and extra environment.
  Daemon(const fs::path& dir, const std::string& config_text, std::vector<std::string> env = {},
         std::vector<std::string> args = {})
      : dir_(dir) {
    fs::create_directories(dir);
    std::ofstream(dir / "stillpointd.yaml") << config_text;
    const std::string out = (dir / "stdout.txt").string(), err = (dir / "stderr.txt").string(),
                      cfg = (dir / "stillpointd.yaml").string();
    pid_ = fork();
    if (pid_ == 0) {
      const int o = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      const int e = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      dup2(o, 1);
      dup2(e, 2);
      for (const auto& kv : env) putenv(const_cast<char*>(kv.c_str()));
      std::vector<std::string> all = {STILLPOINTD, "--config", cfg};
      all.insert(all.end(), args.begin(), args.end());
      std::vector<char*> argv;
      for (auto& a : all) argv.push_back(a.data());
      argv.push_back(nullptr);
      execv(STILLPOINTD, argv.data());
      _exit(127);
    }
  }
  ~Daemon() {
    if (pid_ > 0 && !exited_) {
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
    }
  }
  void signal(int sig) { kill(pid_, sig); }
  // Waits until the child runs stillpointd (past exec), at most `limit`.
  bool waitExec(std::chrono::milliseconds limit) const {
    const auto until = Clock::now() + limit;
    const fs::path exe = fs::path("/proc") / std::to_string(pid_) / "exe";
    while (Clock::now() < until) {
      std::error_code ec;
      // The launcher (stillpointd) or the service it execs (stillpointd-service).
      if (fs::read_symlink(exe, ec).filename().string().rfind("stillpointd", 0) == 0) return true;
      std::this_thread::sleep_for(std::chrono::microseconds(50));
    }
    return false;
  }
  pid_t pid() const { return pid_; }
  // Exit status, or -1 when the process is still running after `limit`.
  int waitExit(std::chrono::milliseconds limit) {
    const auto until = Clock::now() + limit;
    while (Clock::now() < until) {
      int status = 0;
      const pid_t r = waitpid(pid_, &status, WNOHANG);
      if (r == pid_) {
        exited_ = true;
        return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      }
      std::this_thread::sleep_for(5ms);
    }
    return -1;
  }
  std::string err() const { return readFile(dir_ / "stderr.txt"); }
  std::string out() const { return readFile(dir_ / "stdout.txt"); }

 private:
  fs::path dir_;
  pid_t pid_ = -1;
  bool exited_ = false;
};

std::string config(const std::string& seq, const fs::path& dir, const std::string& ring, bool paced, bool loop,
                   const std::string& extra = "") {
  return "camera: " + g_camera + "\nlog_level: info\nsource:\n  replay: {path: " + seq + ", paced: " +
         (paced ? "true" : "false") + ", loop: " + (loop ? "true" : "false") +
         "}\nslam: {options: {orb: {num_features: 500}}}\noutput: {trajectory: " + (dir / "traj.txt").string() +
         ", status: " + (dir / "status.txt").string() + "}\nipc: {" +
         // Unpaced, frames come as fast as they track: a publisher queue that
         // holds them all (see RealExcerptPosesMatchGroundTruth).
         (paced ? "" : "queue_capacity: 1024, ") + "shm: {name: " + ring + "}}\n" + extra;
}

std::string uniqueRing(const std::string& what) { return "sp_dtest_" + std::to_string(getpid()) + "_" + what; }

// Waits until the ring has at least `n` records; returns them (oldest first).
std::vector<sp_pose_record> readPoses(const std::string& ring, std::size_t n, std::chrono::milliseconds limit) {
  std::vector<sp_pose_record> poses;
  sp_shm_reader r;
  sp_shm_reader_init(&r);
  const auto until = Clock::now() + limit;
  bool open = false;
  while (Clock::now() < until && poses.size() < n) {
    if (!open) {
      open = sp_shm_reader_open(&r, ring.c_str(), SP_SHM_START_OLDEST) == SP_SHM_OK;
      if (!open) {
        std::this_thread::sleep_for(10ms);
        continue;
      }
    }
    sp_pose_record p;
    const int rc = sp_shm_reader_next(&r, &p);
    if (rc == SP_SHM_OK) poses.push_back(p);
    else std::this_thread::sleep_for(2ms);
  }
  if (open) sp_shm_reader_close(&r);
  return poses;
}

class NotifySocket {
 public:
  explicit NotifySocket(const fs::path& path) : path_(path.string()) {
    fd_ = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::snprintf(addr.sun_path, sizeof addr.sun_path, "%s", path_.c_str());
    unlink(path_.c_str());
    ok_ = fd_ >= 0 && bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
    timeval tv{0, 20000};
    setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  }
  ~NotifySocket() {
    if (fd_ >= 0) close(fd_);
    unlink(path_.c_str());
  }
  bool ok() const { return ok_; }
  const std::string& path() const { return path_; }
  // Collects datagrams for `span`; each line of each datagram is one entry.
  void collect(std::chrono::milliseconds span) {
    const auto until = Clock::now() + span;
    char buf[4096];
    while (Clock::now() < until) {
      const ssize_t n = recv(fd_, buf, sizeof buf, 0);
      if (n <= 0) continue;
      std::istringstream in(std::string(buf, n));
      for (std::string line; std::getline(in, line);) messages.push_back({Clock::now(), line});
    }
  }
  int count(const std::string& m) const {
    int c = 0;
    for (const auto& [t, s] : messages) c += s == m;
    return c;
  }
  bool any(const std::string& prefix) const {
    for (const auto& [t, s] : messages)
      if (s.rfind(prefix, 0) == 0) return true;
    return false;
  }
  std::vector<std::pair<Clock::time_point, std::string>> messages;

 private:
  std::string path_;
  int fd_ = -1;
  bool ok_ = false;
};

class DaemonProcess : public ::testing::Test {
 public:
  static void SetUpTestSuite() {
    g_root = fs::temp_directory_path() / ("sp_daemon_process_" + std::to_string(getpid()));
    fs::create_directories(g_root);
    SyntheticDatasetOptions fast;
    fast.n_frames = 40;
    fast.width = 640;
    fast.height = 480;
    auto f = stillpoint::dataset::testing::writeSyntheticTumDataset((g_root / "fast").string(), fast);
    ASSERT_TRUE(f) << f.error();
    SyntheticDatasetOptions slow = fast;
    slow.n_frames = 3;
    slow.rate_hz = 0.4;  // a frame every 2.5 s: tracking idles in between
    auto s = stillpoint::dataset::testing::writeSyntheticTumDataset((g_root / "slow").string(), slow);
    ASSERT_TRUE(s) << s.error();
    g_fast_seq = (g_root / "fast").string();
    g_slow_seq = (g_root / "slow").string();
    const auto& c = f->camera;
    g_camera = (g_root / "camera.yaml").string();
    std::ofstream(g_camera) << "width: " << c.width << "\nheight: " << c.height << "\nfx: " << c.fx
                            << "\nfy: " << c.fy << "\ncx: " << c.cx << "\ncy: " << c.cy
                            << "\ndepth_factor: " << c.depth_factor << "\n";
  }
  static void TearDownTestSuite() { fs::remove_all(g_root); }

 protected:
  fs::path dir(const std::string& name) { return g_root / name; }
  void TearDown() override {
    for (const auto& r : rings_) {
      unlink(("/dev/shm/" + r).c_str());
      unlink(("/dev/shm/" + r + SP_SHM_LOCK_SUFFIX).c_str());
    }
  }
  std::string ring(const std::string& what) {
    rings_.push_back(uniqueRing(what));
    return rings_.back();
  }
  std::vector<std::string> rings_;
};

TEST_F(DaemonProcess, PublishesPosesAndStopsCleanlyOnSigterm) {
  const auto d = dir("sigterm");
  const std::string r = ring("sigterm");
  Daemon daemon(d, config(g_fast_seq, d, r, /*paced=*/true, /*loop=*/true));
  const auto poses = readPoses(r, 20, 60s);
  ASSERT_GE(poses.size(), 20u) << daemon.err();
  for (std::size_t i = 1; i < poses.size(); ++i) {
    EXPECT_EQ(poses[i].sequence, poses[i - 1].sequence + 1);
    EXPECT_GT(poses[i].sensor_stamp_ns, poses[i - 1].sensor_stamp_ns);
  }
  EXPECT_NE(poses.back().publish_stamp_ns, 0);
  daemon.signal(SIGTERM);
  const auto t0 = Clock::now();
  // Spec bound: shutdown_timeout_s (5 s); measured stops are well under 1 s.
  const int rc = daemon.waitExit(5s);
  ASSERT_EQ(rc, 0) << daemon.err();
  const double stop_s = std::chrono::duration<double>(Clock::now() - t0).count();
  std::printf("stop after SIGTERM: %.3f s\n", stop_s);
  const auto status = readStatus(d / "status.txt");
  EXPECT_EQ(status.at("exit_reason"), "signal");
  EXPECT_GE(std::stoul(status.at("frames_processed")), 20u);
  EXPECT_EQ(status.at("frames_dropped"), "0");  // blocking queue in replay
  EXPECT_TRUE(fs::exists(d / "traj.txt"));
  EXPECT_NE(daemon.err().find("stopping: signal"), std::string::npos) << daemon.err();
}

TEST_F(DaemonProcess, EndOfRecordingDrainsAndExitsZero) {
  const auto d = dir("end");
  Daemon daemon(d, config(g_fast_seq, d, ring("end"), /*paced=*/false, /*loop=*/false), {}, {"--max-frames", "25"});
  ASSERT_EQ(daemon.waitExit(120s), 0) << daemon.err();
  const auto status = readStatus(d / "status.txt");
  EXPECT_EQ(status.at("exit_reason"), "end of recording");
  EXPECT_EQ(status.at("frames_received"), "25");
  EXPECT_EQ(status.at("frames_processed"), "25");
  EXPECT_GE(std::stoul(status.at("publisher_sent")), 25u);  // every pose, plus status messages
  EXPECT_EQ(status.at("publisher_dropped"), "0");
  // The trajectory holds what SLAM tracked, after local mapping finished.
  auto traj = stillpoint::eval::readTumTrajectory((d / "traj.txt").string());
  ASSERT_TRUE(traj) << traj.error();
  EXPECT_EQ(traj->size(), std::stoul(status.at("frames_tracked")));
  // Every pose has a health level, and every one below good a cause.
  const unsigned long good = std::stoul(status.at("frames_good")), degraded = std::stoul(status.at("frames_degraded")),
                      unreliable = std::stoul(status.at("frames_unreliable"));
  EXPECT_EQ(good + degraded + unreliable, std::stoul(status.at("frames_tracked")));
  unsigned long causes = 0;
  for (const char* name : {"few_inliers", "view_moving", "poor_conditioning", "high_reprojection",
                           "fallback_evidence", "masks_late", "recovering"}) {
    const unsigned long n = std::stoul(status.at(std::string("frames_") + name));
    EXPECT_LE(n, degraded + unreliable) << name << ": a good pose has no cause";
    causes += n;
  }
  EXPECT_GE(causes, degraded + unreliable);
}

TEST_F(DaemonProcess, SecondSignalForcesExit) {
  const auto d = dir("second");
  const std::string r = ring("second");
  Daemon daemon(d, config(g_fast_seq, d, r, true, true), {"STILLPOINTD_TEST_SLOW_STOP_MS=20000"});
  ASSERT_GE(readPoses(r, 3, 60s).size(), 3u) << daemon.err();
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.waitExit(300ms), -1);  // the (slowed) orderly stop is under way
  daemon.signal(SIGINT);
  EXPECT_EQ(daemon.waitExit(5s), 130) << daemon.err();
  EXPECT_NE(daemon.err().find("second signal"), std::string::npos) << daemon.err();
  EXPECT_FALSE(fs::exists(d / "status.txt"));  // forced: nothing flushed
}

// The ring's header, copied (zeroed when there is no ring).
sp_shm_header ringHeader(const std::string& ring) {
  sp_shm_header h{};
  const int fd = ::open(("/dev/shm/" + ring).c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  if (fd >= 0 && ::pread(fd, &h, sizeof(h), 0) != static_cast<ssize_t>(sizeof(h))) h = sp_shm_header{};
  if (fd >= 0) ::close(fd);
  return h;
}

TEST_F(DaemonProcess, FifoAtTheRingPathFailsStartUpNamingIt) {
  const auto d = dir("fifo");
  const std::string r = ring("fifo");
  ASSERT_EQ(mkfifo(("/dev/shm/" + r).c_str(), 0666), 0);
  Daemon daemon(d, config(g_fast_seq, d, r, true, true));
  EXPECT_EQ(daemon.waitExit(60s), 1) << "blocked opening the FIFO? " << daemon.err();
  EXPECT_NE(daemon.err().find("/dev/shm/" + r + " is a FIFO"), std::string::npos) << daemon.err();
}

TEST_F(DaemonProcess, SecondDaemonOnTheRingFailsWhileTheFirstPublishes) {
  const auto d1 = dir("owner1"), d2 = dir("owner2");
  const std::string r = ring("owner");
  Daemon first(d1, config(g_fast_seq, d1, r, true, true));
  ASSERT_GE(readPoses(r, 3, 60s).size(), 3u) << first.err();
  Daemon second(d2, config(g_fast_seq, d2, r, true, true));
  EXPECT_EQ(second.waitExit(60s), 1) << second.err();
  EXPECT_NE(second.err().find("ring " + r + " is owned by a running writer, pid " + std::to_string(first.pid())),
            std::string::npos)
      << second.err();
  // The first still publishes into the ring the name refers to.
  auto waitFor = [](const std::function<bool()>& condition) {
    const auto until = Clock::now() + 60s;
    while (!condition() && Clock::now() < until) std::this_thread::sleep_for(20ms);
    return condition();
  };
  EXPECT_EQ(ringHeader(r).writer_pid, static_cast<std::uint32_t>(first.pid()));
  const std::uint64_t before = ringHeader(r).write_count;
  EXPECT_TRUE(waitFor([&] { return ringHeader(r).write_count > before; })) << first.err();

  // Killed, it leaves a ring that says "running"; readers see it gone, a new daemon takes over.
  first.signal(SIGKILL);
  EXPECT_EQ(first.waitExit(5s), 128 + SIGKILL);
  sp_shm_reader reader;
  sp_shm_reader_init(&reader);
  ASSERT_EQ(sp_shm_reader_open(&reader, r.c_str(), SP_SHM_START_LATEST), SP_SHM_OK);
  EXPECT_EQ(sp_shm_writer_alive(&reader), 0);
  EXPECT_EQ(sp_shm_reader_writer_died(&reader), 1);
  sp_shm_reader_close(&reader);
  Daemon third(d2, config(g_fast_seq, d2, r, true, true));
  ASSERT_TRUE(waitFor([&] { return ringHeader(r).generation == 2 && ringHeader(r).write_count >= 3; }))
      << third.err();
  EXPECT_EQ(ringHeader(r).writer_pid, static_cast<std::uint32_t>(third.pid()));
}

TEST_F(DaemonProcess, SignalDuringStartUpExitsAtOnce) {
  const auto d = dir("startup");
  Daemon daemon(d, config(g_fast_seq, d, ring("startup"), true, true), {"STILLPOINTD_TEST_SLOW_START_MS=60000"});
  const auto until = Clock::now() + 60s;  // the source is open: start-up is under way
  while (daemon.err().find("source:") == std::string::npos && Clock::now() < until) std::this_thread::sleep_for(20ms);
  ASSERT_NE(daemon.err().find("source:"), std::string::npos) << daemon.err();
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.waitExit(5s), 0) << daemon.err();
  EXPECT_NE(daemon.err().find("signal during start-up"), std::string::npos) << daemon.err();
  EXPECT_FALSE(fs::exists(d / "status.txt"));  // nothing ran
}

// SIGTERM while the config is still being read (slowed down here): the
// daemon ends with its start-up message and status 0, not by the signal's
// default action (143, no message: the mask used to be set only after the
// config had loaded). Then a signal at once after exec, several times: never
// an exit by the signal once the program's own code runs.
TEST_F(DaemonProcess, SignalWhileTheConfigLoadsEndsCleanly) {
  const auto d = dir("config_signal");
  Daemon daemon(d, config(g_fast_seq, d, ring("config_signal"), true, true), {"STILLPOINTD_TEST_SLOW_CONFIG_MS=3000"});
  ASSERT_TRUE(daemon.waitExec(5s));
  std::this_thread::sleep_for(1s);  // well inside the slowed config load
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.waitExit(10s), 0) << daemon.err();
  EXPECT_NE(daemon.err().find("signal during start-up"), std::string::npos) << daemon.err();
}

// The launcher (stillpointd, libc only) blocks the stop signals before it
// execs the service, so the service already has them blocked while its
// ~170 shared libraries load (about 0.1-0.6 s after exec, when a SIGTERM
// used to end it by the signal's default action, exit 143, no message).
TEST_F(DaemonProcess, StopSignalsAreBlockedWhileTheServiceLoads) {
  const auto d = dir("blocked");
  Daemon daemon(d, config(g_fast_seq, d, ring("blocked"), true, true), {"STILLPOINTD_TEST_SLOW_CONFIG_MS=3000"});
  const fs::path proc = fs::path("/proc") / std::to_string(daemon.pid());
  std::string sig_blk;
  const auto until = Clock::now() + 5s;
  while (Clock::now() < until && sig_blk.empty()) {
    std::error_code ec;
    if (fs::read_symlink(proc / "exe", ec).filename() != "stillpointd-service") continue;
    std::istringstream status(readFile(proc / "status"));  // read at once: before the service's own code runs
    for (std::string line; std::getline(status, line);)
      if (line.rfind("SigBlk:", 0) == 0) sig_blk = line.substr(7);
  }
  ASSERT_FALSE(sig_blk.empty()) << "the service never started";
  const unsigned long long mask = std::stoull(sig_blk, nullptr, 16);
  EXPECT_TRUE(mask & (1ull << (SIGTERM - 1))) << "SigBlk " << sig_blk;
  EXPECT_TRUE(mask & (1ull << (SIGINT - 1))) << "SigBlk " << sig_blk;
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.waitExit(10s), 0) << daemon.err();
  EXPECT_NE(daemon.err().find("signal during start-up"), std::string::npos) << daemon.err();
}

TEST_F(DaemonProcess, StopOverrunningTheTimeoutForcesExit) {
  const auto d = dir("overrun");
  const std::string r = ring("overrun");
  Daemon daemon(d, config(g_fast_seq, d, r, true, true, "shutdown_timeout_s: 0.5\n"),
                {"STILLPOINTD_TEST_SLOW_STOP_MS=20000"});
  ASSERT_GE(readPoses(r, 3, 60s).size(), 3u) << daemon.err();
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.waitExit(5s), 1) << daemon.err();
  EXPECT_NE(daemon.err().find("shutdown_timeout_s"), std::string::npos) << daemon.err();
}

TEST_F(DaemonProcess, BadConfigsNameTheField) {
  const auto d = dir("bad");
  const std::string base = config(g_fast_seq, d, ring("bad"), false, false);
  struct Case {
    std::string extra, expect;
  };
  const Case cases[] = {
      {"threads: {tracking: {cores: fast}}\n", "threads.tracking.cores"},
      {"source_typo: 1\n", "unknown field 'source_typo'"},
      {"modules: {semantic: true, semantic_model_card: /nonexistent/card.yaml}\n", "modules.semantic_model_card"},
      {"status_period_s: -1\n", "status_period_s"},
  };
  for (const auto& c : cases) {
    Daemon daemon(d, base + c.extra);
    EXPECT_EQ(daemon.waitExit(10s), 1) << c.extra;
    EXPECT_NE(daemon.err().find(c.expect), std::string::npos) << daemon.err();
    EXPECT_NE(daemon.err().find("stillpointd.yaml"), std::string::npos) << daemon.err();
  }
  {  // ipc section errors carry their prefix (the ring must be a power of two)
    std::string bad = base;
    bad.replace(bad.find("shm: {name: "), 12, "shm: {capacity: 1000, name: ");
    Daemon daemon(d, bad);
    EXPECT_EQ(daemon.waitExit(10s), 1);
    EXPECT_NE(daemon.err().find("ipc"), std::string::npos) << daemon.err();
    EXPECT_NE(daemon.err().find("capacity"), std::string::npos) << daemon.err();
  }
  {  // A V4L2 camera that is not there: a start-up error naming the device.
    Daemon daemon(d, "camera: " + g_camera + "\nsource: {type: v4l2, v4l2: {colour_device: /dev/sp-no-colour, "
                     "depth_device: /dev/sp-no-depth, depth_registered: true}}\n");
    EXPECT_EQ(daemon.waitExit(10s), 1);
    EXPECT_NE(daemon.err().find("/dev/sp-no-colour"), std::string::npos) << daemon.err();
  }
  // A missing sequence is a start-up error naming it.
  Daemon missing(d, config((g_root / "no_such_seq").string(), d, ring("bad2"), false, false));
  EXPECT_EQ(missing.waitExit(10s), 1);
  EXPECT_NE(missing.err().find("no_such_seq"), std::string::npos) << missing.err();
}

TEST_F(DaemonProcess, PrintConfigAndVersion) {
  const auto d = dir("print");
  Daemon daemon(d, config(g_fast_seq, d, ring("print"), false, false), {}, {"--print-config"});
  ASSERT_EQ(daemon.waitExit(10s), 0) << daemon.err();
  const std::string out = daemon.out();
  EXPECT_NE(out.find("num_features: 500"), std::string::npos) << out;
  EXPECT_NE(out.find("threads:"), std::string::npos) << out;
  Daemon version(d, "", {}, {"--version"});
  ASSERT_EQ(version.waitExit(10s), 0);
  EXPECT_EQ(version.out().rfind("stillpointd " STILLPOINT_VERSION, 0), 0u) << version.out();
}

TEST_F(DaemonProcess, PinningToAnAbsentCoreDegradesWithAWarning) {
  const auto d = dir("pin");
  Daemon daemon(d, config(g_fast_seq, d, ring("pin"), false, false,
                          "threads:\n  tracking: {cores: [0, 999]}\n  mapping: {cores: [998]}\n"),
                {}, {"--max-frames", "5"});
  ASSERT_EQ(daemon.waitExit(60s), 0) << daemon.err();
  const std::string err = daemon.err();
  EXPECT_NE(err.find("threads.tracking.cores: core(s) 999 not available"), std::string::npos) << err;
  EXPECT_NE(err.find("pinned to 0"), std::string::npos) << err;
  EXPECT_NE(err.find("threads.mapping.cores: core(s) 998 not available"), std::string::npos) << err;
  EXPECT_EQ(readStatus(d / "status.txt").at("frames_processed"), "5");
}

TEST_F(DaemonProcess, NotifiesSystemdReadyWatchdogStatusStopping) {
  const auto d = dir("notify");
  fs::create_directories(d);
  NotifySocket sock(d / "notify.sock");
  ASSERT_TRUE(sock.ok());
  Daemon daemon(d, config(g_fast_seq, d, ring("notify"), true, true, "status_period_s: 0.2\n"),
                {"NOTIFY_SOCKET=" + sock.path(), "WATCHDOG_USEC=200000"});
  sock.collect(4000ms);
  daemon.signal(SIGTERM);
  sock.collect(1000ms);
  ASSERT_EQ(daemon.waitExit(5s), 0) << daemon.err();
  EXPECT_EQ(sock.count("READY=1"), 1);
  EXPECT_GE(sock.count("WATCHDOG=1"), 3);  // tracking progresses at 30 Hz
  EXPECT_TRUE(sock.any("STATUS=")) << "no STATUS=";
  EXPECT_EQ(sock.count("STOPPING=1"), 1);
  // Order: READY before any WATCHDOG; STOPPING last of the protocol messages.
  std::size_t ready = 0, first_watchdog = 0, stopping = 0;
  for (std::size_t i = 0; i < sock.messages.size(); ++i) {
    const auto& m = sock.messages[i].second;
    if (m == "READY=1") ready = i;
    if (m == "WATCHDOG=1" && !first_watchdog) first_watchdog = i;
    if (m == "STOPPING=1") stopping = i;
  }
  EXPECT_LT(ready, first_watchdog);
  EXPECT_GT(stopping, first_watchdog);
}

// The shipped default: an OpenNI2 camera, not plugged in. The service comes
// up and waits for it: READY=1, a status saying so, the watchdog fed, and a
// clean stop.
TEST_F(DaemonProcess, WaitsForACameraThatIsNotThereYet) {
  const auto d = dir("nocamera");
  fs::create_directories(d);
  NotifySocket sock(d / "notify.sock");
  ASSERT_TRUE(sock.ok());
  Daemon daemon(d,
                "camera: " + g_camera + "\nstatus_period_s: 0.2\nsource: {type: openni2, openni2: {uri: \"\"}}\n"
                "ipc: {shm: {name: " + ring("nocamera") + "}}\n",
                {"NOTIFY_SOCKET=" + sock.path(), "WATCHDOG_USEC=200000"});
  sock.collect(2500ms);
  daemon.signal(SIGTERM);
  sock.collect(500ms);
  ASSERT_EQ(daemon.waitExit(5s), 0) << daemon.err();
  EXPECT_NE(daemon.err().find("waiting for the camera"), std::string::npos) << daemon.err();
  EXPECT_EQ(sock.count("READY=1"), 1);
  EXPECT_TRUE(sock.any("STATUS=waiting for camera")) << "no waiting status";
  EXPECT_GE(sock.count("WATCHDOG=1"), 5);  // 2.5 s at 100 ms: fed while waiting
  EXPECT_EQ(sock.count("STOPPING=1"), 1);
}

TEST_F(DaemonProcess, NoWatchdogWhileTrackingIdles) {
  const auto d = dir("idle");
  fs::create_directories(d);
  NotifySocket sock(d / "notify.sock");
  ASSERT_TRUE(sock.ok());
  // Frames 2.5 s apart: after the first frame, tracking makes no progress.
  Daemon daemon(d, config(g_slow_seq, d, ring("idle"), true, false),
                {"NOTIFY_SOCKET=" + sock.path(), "WATCHDOG_USEC=200000"});
  sock.collect(2000ms);
  daemon.signal(SIGTERM);
  ASSERT_EQ(daemon.waitExit(5s), 0) << daemon.err();
  EXPECT_EQ(sock.count("READY=1"), 1);
  // 20 watchdog periods of 100 ms passed; at most the one(s) right after frame 1.
  EXPECT_LE(sock.count("WATCHDOG=1"), 2);
}

// The semantic module with the in-tree person model over the synthetic
// sequence: keyframes reach the segmentation thread in colour and are segmented.
TEST_F(DaemonProcess, SemanticModuleSegmentsKeyframes) {
  const auto d = dir("semantic");
  Daemon daemon(d,
                config(g_fast_seq, d, ring("semantic"), false, false,
                       "modules: {semantic: true, semantic_model_card: person_selfie_256.yaml}\n"
                       "threads: {semantic: {cores: [0, 997]}}\n"),
                {}, {"--max-frames", "30"});
  ASSERT_EQ(daemon.waitExit(120s), 0) << daemon.err();
  const auto status = readStatus(d / "status.txt");
  EXPECT_EQ(status.at("frames_processed"), "30");
  EXPECT_NE(status.at("semantic_model").find("person_selfie_256"), std::string::npos);
  EXPECT_GE(std::stoul(status.at("semantic_keyframes_segmented")), 1u) << daemon.err();
  EXPECT_EQ(status.at("semantic_keyframes_no_colour"), "0");  // the source delivered colour
  EXPECT_EQ(status.at("semantic_failures"), "0");
  const std::string err = daemon.err();
  EXPECT_NE(err.find("semantic module: person_selfie_256"), std::string::npos) << err;
  // The segmentation thread placed itself: its own field in the warning.
  EXPECT_NE(err.find("threads.semantic.cores: core(s) 997 not available"), std::string::npos) << err;
}

TEST_F(DaemonProcess, SemanticModelProblemsFailStartUp) {
  const auto d = dir("semantic_bad");
  fs::create_directories(d / "models");
  // A card whose model file is missing: caught when the configuration loads.
  fs::copy_file(fs::path(STILLPOINT_SOURCE_DIR) / "models" / "person_selfie_256.yaml", d / "models" / "card.yaml",
                fs::copy_options::overwrite_existing);
  const std::string card = (d / "models" / "card.yaml").string();
  {
    Daemon daemon(d, config(g_fast_seq, d, ring("semantic_bad"), false, false,
                            "modules: {semantic: true, semantic_model_card: " + card + "}\n"));
    EXPECT_EQ(daemon.waitExit(30s), 1);
    const std::string err = daemon.err();
    EXPECT_NE(err.find("field 'modules.semantic_model_card'"), std::string::npos) << err;
    EXPECT_NE(err.find("person_selfie_256.onnx"), std::string::npos) << err;
    EXPECT_NE(err.find("not found"), std::string::npos) << err;
  }
  // A model file that is no network: caught when the network loads at start-up.
  std::ofstream(d / "models" / "person_selfie_256.onnx") << "not an onnx file";
  {
    Daemon daemon(d, config(g_fast_seq, d, ring("semantic_bad2"), false, false,
                            "modules: {semantic: true, semantic_model_card: " + card + "}\n"));
    EXPECT_EQ(daemon.waitExit(30s), 1);
    const std::string err = daemon.err();
    EXPECT_NE(err.find("field 'modules.semantic_model_card'"), std::string::npos) << err;
    EXPECT_NE(err.find("card.yaml"), std::string::npos) << err;
  }
  EXPECT_FALSE(fs::exists(d / "status.txt"));  // never started
}

// The semantic module on the real excerpt (COCO model when present beside the
// data, else the person model): keyframes segmented, poses still accurate.
TEST_F(DaemonProcess, SemanticModuleRealExcerptMatchesGroundTruth) {
  const fs::path seq = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200";
  if (!fs::exists(seq / "rgb.txt")) GTEST_SKIP() << "no " << seq;
  const fs::path model_dir = fs::path(STILLPOINT_DATA_DIR) / ".." / "models";
  const bool coco = fs::exists(model_dir / "coco_yolov5s_seg_320.onnx");
  const auto d = dir("semantic_teddy");
  const std::string r = ring("semantic_teddy");
  Daemon daemon(d, "camera: fr3\nsource: {replay: {path: " + seq.string() +
                       ", paced: false}}\nmodules: {semantic: true, semantic_model_card: " +
                       (coco ? "coco_yolov5s_seg_320.yaml" : "person_selfie_256.yaml") + ", semantic_model_dirs: [" +
                       model_dir.string() + "]}\noutput: {status: " + (d / "status.txt").string() +
                       "}\nipc: {queue_capacity: 1024, shm: {name: " + r + ", capacity: 1024}}\n"
                       // Replayed as fast as it goes, tracking and mapping keep both cores busy:
                       // the default nice values (mapping 5, semantic 10; they serve paced, live
                       // runs) would leave segmentation little CPU. This test is about the
                       // module's results: all threads at the process's nice.
                       "threads: {mapping: {nice: 0}, semantic: {nice: 0}}\n");
  ASSERT_EQ(daemon.waitExit(300s), 0) << daemon.err();
  const auto status = readStatus(d / "status.txt");
  std::printf("semantic (%s): %s keyframes, %s segmented, %s dropped; segmentation median %s ms p95 %s ms; "
              "keyframe -> mask median %s ms p95 %s ms; pose latency median %s ms\n",
              status.at("semantic_model").c_str(), status.at("keyframes").c_str(),
              status.at("semantic_keyframes_segmented").c_str(), status.at("semantic_keyframes_dropped").c_str(),
              status.at("segmentation_ms_median").c_str(), status.at("segmentation_ms_p95").c_str(),
              status.at("semantic_latency_ms_median").c_str(), status.at("semantic_latency_ms_p95").c_str(),
              status.at("latency_ms_median").c_str());
  EXPECT_NE(status.at("semantic_model").find(coco ? "coco" : "person"), std::string::npos);
  EXPECT_GE(std::stoul(status.at("semantic_keyframes_segmented")), 10u);
  EXPECT_EQ(status.at("semantic_keyframes_no_colour"), "0");
  EXPECT_EQ(status.at("semantic_failures"), "0");
  // COCO sees the teddy bear, a static class, in most keyframes: the map remembers where.
  if (coco) {
    EXPECT_GT(std::stoul(status.at("semantic_sighting_cells")), 0u);
  }
  const auto poses = readPoses(r, 193, 5s);
  ASSERT_EQ(poses.size(), 193u);
  stillpoint::eval::Trajectory est;
  for (const auto& p : poses) {
    if (p.tracking_state != SP_TRACKING_OK && p.tracking_state != SP_TRACKING_RELOCALISED) continue;
    const Eigen::Quaterniond q(p.orientation[3], p.orientation[0], p.orientation[1], p.orientation[2]);
    est.push_back({stillpoint::Timestamp::fromNanoseconds(p.sensor_stamp_ns),
                   stillpoint::makeSE3(q, {p.position[0], p.position[1], p.position[2]})});
  }
  auto gt = stillpoint::eval::readTumTrajectory((seq / "groundtruth.txt").string());
  ASSERT_TRUE(gt) << gt.error();
  auto ev = stillpoint::eval::evaluate(*gt, est);
  ASSERT_TRUE(ev) << ev.error();
  std::printf("semantic module on, published poses vs ground truth: ate_rmse_m=%.4f matched=%zu\n", ev->ate_rmse_m,
              ev->matched);
  EXPECT_GE(est.size(), 185u);
  EXPECT_LT(ev->ate_rmse_m, 0.04);
}

// The tests that count every pose of an unpaced replay give the publisher a
// hand-off queue that holds the whole excerpt: its default (8, drop-oldest) is
// sized for a camera's rate, and frames replayed as fast as they track would
// overrun it whenever the machine holds the publisher thread back.
TEST_F(DaemonProcess, RealExcerptPosesMatchGroundTruth) {
  const fs::path seq = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200";
  if (!fs::exists(seq / "rgb.txt")) GTEST_SKIP() << "no " << seq;
  const auto d = dir("teddy");
  const std::string r = ring("teddy");
  Daemon daemon(d,
                "camera: fr3\nsource: {replay: {path: " + seq.string() +
                    ", paced: false}}\noutput: {status: " + (d / "status.txt").string() +
                    "}\nipc: {queue_capacity: 1024, shm: {name: " + r + ", capacity: 1024}}\n");
  ASSERT_EQ(daemon.waitExit(300s), 0) << daemon.err();
  const auto status = readStatus(d / "status.txt");
  const auto poses = readPoses(r, 193, 5s);  // the writer left the ring with every pose
  ASSERT_EQ(poses.size(), 193u) << "frames_processed=" << status.at("frames_processed")
                                << " frames_bad=" << status.at("frames_bad")
                                << " publisher_dropped=" << status.at("publisher_dropped");
  stillpoint::eval::Trajectory est;
  for (const auto& p : poses) {
    if (p.tracking_state != SP_TRACKING_OK && p.tracking_state != SP_TRACKING_RELOCALISED) continue;
    const Eigen::Quaterniond q(p.orientation[3], p.orientation[0], p.orientation[1], p.orientation[2]);
    est.push_back({stillpoint::Timestamp::fromNanoseconds(p.sensor_stamp_ns),
                   stillpoint::makeSE3(q, {p.position[0], p.position[1], p.position[2]})});
  }
  EXPECT_GE(est.size(), 185u);
  auto gt = stillpoint::eval::readTumTrajectory((seq / "groundtruth.txt").string());
  ASSERT_TRUE(gt) << gt.error();
  auto ev = stillpoint::eval::evaluate(*gt, est);
  ASSERT_TRUE(ev) << ev.error();
  // Live (per-frame, not bundle-adjusted) poses; the replay's refined trajectory is ~0.012 m.
  std::printf("published poses vs ground truth: ate_rmse_m=%.4f matched=%zu\n", ev->ate_rmse_m, ev->matched);
  EXPECT_LT(ev->ate_rmse_m, 0.04);
}

TEST_F(DaemonProcess, RealExcerptMapSavedOnStopThenLocalisedAgainst) {
  const fs::path seq = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200";
  if (!fs::exists(seq / "rgb.txt")) GTEST_SKIP() << "no " << seq;
  const auto d = dir("map_files");
  const fs::path map = d / "teddy.map";
  {
    Daemon mapping(d, "camera: fr3\nsource: {replay: {path: " + seq.string() + ", paced: false}}\nmap: {save: " +
                          map.string() + "}\noutput: {status: " + (d / "mapping.txt").string() + "}\n");
    ASSERT_EQ(mapping.waitExit(300s), 0) << mapping.err();
  }
  ASSERT_TRUE(fs::is_regular_file(map));
  const auto mapped = readStatus(d / "mapping.txt");
  const std::string r = ring("map_files");
  Daemon localising(d, "camera: fr3\nsource: {replay: {path: " + seq.string() + ", paced: false}}\nmap: {load: " +
                           map.string() + ", mode: localisation}\noutput: {status: " + (d / "localising.txt").string() +
                           "}\nipc: {queue_capacity: 1024, shm: {name: " + r + ", capacity: 1024}}\n");
  ASSERT_EQ(localising.waitExit(300s), 0) << localising.err();
  const auto status = readStatus(d / "localising.txt");
  // The map did not grow, and nearly every frame found its place in it.
  EXPECT_EQ(status.at("map_keyframes"), mapped.at("map_keyframes"));
  EXPECT_EQ(status.at("map_points"), mapped.at("map_points"));
  EXPECT_EQ(status.at("maps"), "1");
  EXPECT_EQ(status.at("relocalisations_refused"), "0");  // the first frame's place agrees with its depth
  const auto poses = readPoses(r, 193, 5s);
  ASSERT_EQ(poses.size(), 193u);
  std::size_t with_pose = 0;
  for (const auto& p : poses) with_pose += p.tracking_state == SP_TRACKING_OK || p.tracking_state == SP_TRACKING_RELOCALISED;
  EXPECT_GE(with_pose, 184u);  // 95 %
  std::printf("localisation against the saved map: %zu of 193 frames with a pose, map %s keyframes %s points\n",
              with_pose, status.at("map_keyframes").c_str(), status.at("map_points").c_str());
  // A map file that cannot be read is a start-up error naming it.
  fs::resize_file(map, fs::file_size(map) / 2);
  Daemon broken(d, "camera: fr3\nsource: {replay: {path: " + seq.string() + ", paced: false}}\nmap: {load: " +
                       map.string() + "}\n");
  EXPECT_EQ(broken.waitExit(60s), 1);
  EXPECT_NE(broken.err().find(map.string()), std::string::npos) << broken.err();
}

TEST_F(DaemonProcess, RealExcerptStatusCarriesTheTrackingRate) {
  // Status messages over DDS (loopback only), read by stillpoint-echo while
  // the excerpt plays at its recorded 30 Hz: the tracking thread's loop rate,
  // the tracking state and the pose health.
  const fs::path seq = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200";
  if (!fs::exists(seq / "rgb.txt")) GTEST_SKIP() << "no " << seq;
  const auto d = dir("loop_rate");
  fs::create_directories(d);
  const std::string tag = std::to_string(::getpid());
  const std::string ipc = "ipc: {shm: {enabled: false}, dds: {enabled: true, config: \"file://" STILLPOINT_SOURCE_DIR
                          "/ipc/test/cyclonedds-loopback.xml\", pose_topic: sp_rate_pose_" + tag +
                          ", status_topic: sp_rate_status_" + tag + "}}\n";
  std::ofstream(d / "echo.yaml") << ipc;
  const std::string echo_out = (d / "echo.txt").string();
  std::thread echo([&] {
    const std::string cmd = std::string(STILLPOINT_ECHO) + " --dds --config " + (d / "echo.yaml").string() +
                            " --seconds 9 > " + echo_out + " 2>&1";
    (void)std::system(cmd.c_str());
  });
  std::this_thread::sleep_for(1s);  // the reader is up and discovered
  Daemon daemon(d, "camera: fr3\nsource: {replay: {path: " + seq.string() + ", paced: true}}\nstatus_period_s: 0.5\n" + ipc);
  const int rc = daemon.waitExit(120s);
  echo.join();
  ASSERT_EQ(rc, 0) << daemon.err();
  // "status ... tracking=29.9Hz/..." lines: while the excerpt plays, about 30.
  std::ifstream in(echo_out);
  // And the newest frame's state and health: tracked, and good on this static scene.
  int near_30 = 0, statuses = 0, ok_good = 0;
  for (std::string line; std::getline(in, line);) {
    const auto at = line.find("tracking=");
    if (at == std::string::npos) continue;
    ++statuses;
    const double hz = std::strtod(line.c_str() + at + 9, nullptr);
    near_30 += hz > 20 && hz < 40;
    ok_good += line.find("state=ok health=good") != std::string::npos;
  }
  EXPECT_GE(statuses, 5) << readFile(echo_out);
  EXPECT_GE(near_30, 3) << readFile(echo_out);
  EXPECT_GE(ok_good, 3) << readFile(echo_out);
}

// OpenNI2: a private copy of libOpenNI2.so.0 with our replay driver as its only
// driver (Debian's loader looks in OpenNI2/Drivers beside the library).
// The system's .oni player driver (Debian: beside libOpenNI2.so.0).
fs::path oniFileDriver() {
  return fs::canonical(STILLPOINT_OPENNI2_LIBRARY).parent_path() / "OpenNI2" / "Drivers" / "libOniFile.so.0";
}

std::vector<std::string> openni2Env(const fs::path& dir, const std::string& sequence,
                                    const std::string& gone_after = "", bool file_player = false,
                                    const std::string& pairs = "") {
  const fs::path lib = dir / "oni-lib";
  fs::create_directories(lib / "OpenNI2" / "Drivers");
  fs::copy_file(fs::canonical(STILLPOINT_OPENNI2_LIBRARY), lib / "libOpenNI2.so.0",
                fs::copy_options::overwrite_existing);
  fs::copy_file(STILLPOINT_ONI_DRIVER, lib / "OpenNI2" / "Drivers" / "libStillpointReplay.so.0",
                fs::copy_options::overwrite_existing);
  if (file_player)  // plays .oni files
    fs::copy_file(oniFileDriver(), lib / "OpenNI2" / "Drivers" / "libOniFile.so.0",
                  fs::copy_options::overwrite_existing);
  std::vector<std::string> env = {"LD_LIBRARY_PATH=" + lib.string(), "STILLPOINT_ONI_REPLAY_DIR=" + sequence};
  if (!gone_after.empty()) env.push_back("STILLPOINT_ONI_GONE_AFTER=" + gone_after);
  if (!pairs.empty()) env.push_back("STILLPOINT_ONI_PAIRS=" + pairs);
  return env;
}

TEST_F(DaemonProcess, OpenNI2ReplayCameraPosesMatchGroundTruth) {
  const fs::path seq = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200";
  if (!fs::exists(seq / "rgb.txt")) GTEST_SKIP() << "no " << seq;
  const auto d = dir("oni_teddy");
  const std::string r = ring("oni_teddy");
  Daemon daemon(d,
                "camera: fr3\nsource: {type: openni2, queue_capacity: 2}\noutput: {status: " +
                    (d / "status.txt").string() + "}\nipc: {shm: {name: " + r + "}}\n",
                openni2Env(d, seq.string()));
  // The camera serves 193 pairs at 30 Hz (6.4 s) and a live camera never ends. The
  // newest frame is never dropped (drop-oldest), so the pose of the last frame
  // (frame_counter 192) arrives: stop then.
  std::vector<sp_pose_record> poses;
  const auto until = Clock::now() + 180s;
  while (Clock::now() < until && (poses.empty() || poses.back().frame_counter < 192)) {
    poses = readPoses(r, 1000, 500ms);
  }
  daemon.signal(SIGTERM);
  ASSERT_EQ(daemon.waitExit(5s), 0) << daemon.err();
  poses = readPoses(r, 1000, 1s);
  const auto status = readStatus(d / "status.txt");
  std::printf("openni2 replay camera: %zu poses, received=%s dropped=%s latency_ms median=%s p99=%s\n",
              poses.size(), status.at("frames_received").c_str(), status.at("frames_dropped").c_str(),
              status.at("latency_ms_median").c_str(), status.at("latency_ms_p99").c_str());
  // A live camera drops the oldest frame when tracking falls behind (on a loaded
  // 2-core machine, most of them): check the bookkeeping, and the accuracy of what
  // was published.
  EXPECT_EQ(std::stoul(status.at("frames_received")), 193u);
  // The tracking step is part of each frame's pose latency (arrival -> published).
  const double track_ms = std::stod(status.at("track_ms_median"));
  EXPECT_GT(track_ms, 0.0);
  EXPECT_LE(track_ms, std::stod(status.at("latency_ms_median")));
  EXPECT_LE(std::stod(status.at("track_ms_p99")), std::stod(status.at("latency_ms_p99")));
  EXPECT_EQ(std::stoul(status.at("frames_processed")) + std::stoul(status.at("frames_dropped")) +
                std::stoul(status.at("frames_discarded_at_stop")),
            193u);
  ASSERT_GE(poses.size(), 30u) << daemon.err();
  stillpoint::eval::Trajectory est;
  for (const auto& p : poses) {
    if (p.tracking_state != SP_TRACKING_OK && p.tracking_state != SP_TRACKING_RELOCALISED) continue;
    const Eigen::Quaterniond q(p.orientation[3], p.orientation[0], p.orientation[1], p.orientation[2]);
    est.push_back({stillpoint::Timestamp::fromNanoseconds(p.sensor_stamp_ns),
                   stillpoint::makeSE3(q, {p.position[0], p.position[1], p.position[2]})});
  }
  auto gt = stillpoint::eval::readTumTrajectory((seq / "groundtruth.txt").string());
  ASSERT_TRUE(gt) << gt.error();
  auto ev = stillpoint::eval::evaluate(*gt, est);
  ASSERT_TRUE(ev) << ev.error();
  std::printf("openni2 replay camera vs ground truth: ate_rmse_m=%.4f matched=%zu\n", ev->ate_rmse_m, ev->matched);
  EXPECT_GE(ev->matched, 30u);
  EXPECT_LT(ev->ate_rmse_m, 0.05);
}

TEST_F(DaemonProcess, OpenNI2CameraUnplugReconnects) {
  const auto d = dir("oni_unplug");
  const std::string r = ring("oni_unplug");
  Daemon daemon(d,
                "camera: " + g_camera + "\nsource: {type: openni2}\noutput: {status: " +
                    (d / "status.txt").string() + "}\nipc: {shm: {name: " + r + "}}\n",
                openni2Env(d, g_fast_seq, "10"));
  // 10 frames, unplug, replug ~1 s later (reopened within the 100-200 ms back-off steps).
  const auto poses = readPoses(r, 15, 30s);
  daemon.signal(SIGTERM);
  ASSERT_EQ(daemon.waitExit(5s), 0) << daemon.err();
  const std::string err = daemon.err();
  EXPECT_NE(err.find("camera gone"), std::string::npos) << err;
  EXPECT_NE(err.find("reconnected"), std::string::npos) << err;
  const auto status = readStatus(d / "status.txt");
  EXPECT_GE(std::stoul(status.at("reconnects")), 1u);
  EXPECT_GT(std::stoul(status.at("frames_received")), 10u);  // frames came after the replug
  EXPECT_GE(poses.size(), 15u);
  // The camera plugged back in serves its frames from the first one again,
  // stamps and all, as a device clock that starts again: they go on from the
  // last stamp, and tracking takes them.
  EXPECT_NE(err.find("clock started again"), std::string::npos) << err;
  for (std::size_t i = 1; i < poses.size(); ++i)
    EXPECT_GT(poses[i].sensor_stamp_ns, poses[i - 1].sensor_stamp_ns) << "pose " << i;
}

// Runs a program to its end with extra environment; stdout and stderr go to
// files beside `out`. Returns the exit status (-1 when it overran `limit` and was killed).
int runProgram(const std::vector<std::string>& args, const std::vector<std::string>& env, const fs::path& out,
               std::chrono::seconds limit) {
  const std::string out_path = out.string(), err_path = out.string() + ".err";
  const pid_t pid = fork();
  if (pid == 0) {
    const int o = ::open(out_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int e = ::open(err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    dup2(o, 1);
    dup2(e, 2);
    for (const auto& kv : env) putenv(const_cast<char*>(kv.c_str()));
    std::vector<std::string> all = args;
    std::vector<char*> argv;
    for (auto& a : all) argv.push_back(a.data());
    argv.push_back(nullptr);
    execv(argv[0], argv.data());
    _exit(127);
  }
  const auto until = Clock::now() + limit;
  while (Clock::now() < until) {
    int status = 0;
    if (waitpid(pid, &status, WNOHANG) == pid) return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    std::this_thread::sleep_for(10ms);
  }
  kill(pid, SIGKILL);
  waitpid(pid, nullptr, 0);
  return -1;
}

// Record to .oni through openni::Recorder from the replay camera, play it back
// through OpenNI2Source (file URI) and compare with the sequence, then run
// stillpointd on the recording. The player needs the streams' cropping
// property (the replay driver has it) or playback yields no frames.
void checkOniRoundTrip(const fs::path& d, const std::string& sequence, const std::string& camera, int kFrames,
                       const std::string& ring) {
  // The camera serves exactly kFrames pairs: the recorder takes frames on its
  // own thread and would record any the camera sends before the streams stop.
  const auto env = openni2Env(d, sequence, "", /*file_player=*/true, std::to_string(kFrames));
  const std::string oni = (d / "rec.oni").string();
  ASSERT_EQ(runProgram({STILLPOINT_ONI_TOOL, "record", oni, std::to_string(kFrames)}, env, d / "record.txt", 60s), 0)
      << readFile(d / "record.txt.err");
  ASSERT_GT(fs::file_size(oni), 0u);
  ASSERT_EQ(runProgram({STILLPOINT_ONI_TOOL, "dump", oni, (d / "dump").string(), camera}, env, d / "dump.txt", 60s),
            0)
      << readFile(d / "dump.txt.err");
  // Played at the recorded rate: never faster than the stamps advance (a slow
  // reader may take longer; the player then waits for it and loses nothing).
  const std::string dump_out = readFile(d / "dump.txt");
  EXPECT_EQ(dump_out.substr(0, dump_out.find('\n') + 1), "frames=" + std::to_string(kFrames) + "\n");
  double played_s = 0, recorded_s = 0;
  ASSERT_EQ(std::sscanf(dump_out.c_str() + dump_out.find('\n') + 1, "played_s=%lf recorded_s=%lf", &played_s,
                        &recorded_s),
            2)
      << dump_out;
  EXPECT_GT(recorded_s, 0.0);
  EXPECT_GE(played_s, recorded_s - 0.005) << dump_out;

  // Every frame that came back: colour identical to a frame of the sequence,
  // the frames consecutive, depth equal within the 1 mm quantisation of
  // DEPTH_1_MM. The recorder keeps stamps relative to its first frame: the
  // played stamps are the sequence's minus the first recorded one.
  stillpoint::dataset::DatasetOptions original_options;
  original_options.depth_factor = 5000.0;
  auto original = stillpoint::dataset::TumDataset::open(sequence, original_options);
  ASSERT_TRUE(original) << original.error();
  stillpoint::dataset::DatasetOptions dump_options;
  dump_options.depth_factor = 1000.0;  // the dump writes 1 mm units
  auto played = stillpoint::dataset::TumDataset::open((d / "dump").string(), dump_options);
  ASSERT_TRUE(played) << played.error();
  ASSERT_EQ(played->size(), static_cast<std::size_t>(kFrames));
  auto first = played->load(0);
  ASSERT_TRUE(first) << first.error();
  std::size_t j0 = 0;
  while (j0 < original->size() && cv::norm(first->bgr, original->load(j0)->bgr, cv::NORM_INF) != 0) ++j0;
  ASSERT_LT(j0 + kFrames, original->size() + 1) << "the first played frame is no frame of the sequence";
  const std::int64_t first_ns = original->load(j0)->stamp.nanoseconds();
  double max_depth_error = 0;
  for (std::size_t i = 0; i < played->size(); ++i) {
    auto p = played->load(i);
    ASSERT_TRUE(p) << p.error();
    auto o = original->load(j0 + i);
    ASSERT_TRUE(o) << o.error();
    EXPECT_NEAR(p->stamp.nanoseconds(), o->stamp.nanoseconds() - first_ns, 1000) << "stamp of frame " << i;
    EXPECT_EQ(cv::norm(p->bgr, o->bgr, cv::NORM_INF), 0.0) << "colour of frame " << i;
    cv::Mat diff;
    cv::absdiff(p->depth_m, o->depth_m, diff);
    double worst = 0;
    cv::minMaxLoc(diff, nullptr, &worst);
    max_depth_error = std::max(max_depth_error, worst);
    EXPECT_EQ(cv::countNonZero(p->depth_m > 0), cv::countNonZero(o->depth_m > 0)) << "depth holes of frame " << i;
  }
  std::printf(".oni round trip of %s: %d frames, largest depth difference %.6f m\n", sequence.c_str(), kFrames,
              max_depth_error);
  EXPECT_LE(max_depth_error, 0.0005 + 1e-6);

  // stillpointd on the recording: it plays once and the daemon stops at its end.
  const std::string& r = ring;
  Daemon daemon(d,
                "camera: " + camera + "\nsource: {type: openni2, openni2: {uri: " + oni +
                    "}}\noutput: {status: " + (d / "status.txt").string() + "}\nipc: {shm: {name: " + r + "}}\n",
                env);
  ASSERT_EQ(daemon.waitExit(60s), 0) << daemon.err();
  const auto status = readStatus(d / "status.txt");
  EXPECT_EQ(status.at("exit_reason"), "end of recording");
  EXPECT_EQ(std::stoul(status.at("frames_received")), static_cast<unsigned long>(kFrames));
  EXPECT_EQ(std::stoul(status.at("frames_processed")) + std::stoul(status.at("frames_dropped")),
            static_cast<unsigned long>(kFrames));
  EXPECT_GE(readPoses(r, 1, 2s).size(), 1u);
}

TEST_F(DaemonProcess, OniRecordingPlaysBackThroughOpenNI2) {
  if (!fs::exists(oniFileDriver())) GTEST_SKIP() << "no .oni player driver at " << oniFileDriver();
  checkOniRoundTrip(dir("oni_record"), g_fast_seq, g_camera, 20, ring("oni_record"));
}

// The same with the real excerpt's depth (not whole millimetres: the 1 mm quantisation shows).
TEST_F(DaemonProcess, OniRecordingOfTheRealExcerpt) {
  if (!fs::exists(oniFileDriver())) GTEST_SKIP() << "no .oni player driver at " << oniFileDriver();
  const fs::path seq = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200";
  if (!fs::exists(seq / "rgb.txt")) GTEST_SKIP() << "no " << seq;
  checkOniRoundTrip(dir("oni_record_teddy"), seq.string(), "fr3", 60, ring("oni_record_teddy"));
}

}  // namespace
