// Cost of publishPose() to the tracking thread: copying the pose into the bounded
// drop-oldest queue and waking the publisher thread. The transports behind it (here
// the real shared-memory ring) run on the publisher thread and are not timed.
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <chrono>
#include <thread>

#include "stillpoint/ipc/publisher.hpp"
#include "stillpoint/ipc/shm_writer.hpp"

namespace stillpoint::ipc {
namespace {

void BM_PublishPoseHandoff(benchmark::State& state) {
  IpcOptions o;
  o.shm.name = "sp_bench_" + std::to_string(::getpid());
  auto pub = Publisher::create(o);
  if (!pub) {
    state.SkipWithError(pub.error().c_str());
    return;
  }
  PoseMessage p;
  p.state = TrackingState::kOk;
  std::uint64_t k = 0;
  for (auto _ : state) {
    p.frame_counter = ++k;
    (*pub)->publishPose(p);
  }
  const auto st = (*pub)->stats();
  state.counters["dropped"] = static_cast<double>(st.dropped);
  pub.value().reset();
  (void)ShmPoseWriter::remove(o.shm.name);
}
BENCHMARK(BM_PublishPoseHandoff);

// The camera-rate case: the publisher thread is asleep on an empty queue when the pose
// arrives, so the call includes the futex wake-up. Waiting for the drain is not timed.
void BM_PublishPoseHandoffIdleThread(benchmark::State& state) {
  IpcOptions o;
  o.shm.name = "sp_bench_idle_" + std::to_string(::getpid());
  auto pub = Publisher::create(o);
  if (!pub) {
    state.SkipWithError(pub.error().c_str());
    return;
  }
  PoseMessage p;
  std::uint64_t k = 0;
  for (auto _ : state) {
    state.PauseTiming();
    while ((*pub)->stats().sent < k) std::this_thread::yield();
    std::this_thread::sleep_for(std::chrono::microseconds(200));  // let the thread block again
    state.ResumeTiming();
    p.frame_counter = ++k;
    (*pub)->publishPose(p);
  }
  pub.value().reset();
  (void)ShmPoseWriter::remove(o.shm.name);
}
BENCHMARK(BM_PublishPoseHandoffIdleThread)->Iterations(5000);

void BM_PublishStatusHandoff(benchmark::State& state) {
  std::vector<std::unique_ptr<Transport>> none;
  Publisher pub(std::move(none), 8);
  StatusMessage s;
  s.threads = {{"tracking", 30, 12, 15}, {"local_mapping", 2.5, 40, 160}, {"publisher", 30, 0.01, 0.1}};
  s.queues = {{"camera", 1, 4, 0}, {"publish", 0, 8, 0}};
  for (auto _ : state) pub.publishStatus(s);
}
BENCHMARK(BM_PublishStatusHandoff);

void BM_ShmRingWrite(benchmark::State& state) {
  const std::string name = "sp_bench_ring_" + std::to_string(::getpid());
  auto w = ShmPoseWriter::create(name, 1024);
  if (!w) {
    state.SkipWithError(w.error().c_str());
    return;
  }
  sp_pose_record r{};
  for (auto _ : state) (*w)->write(r);
  w.value().reset();
  (void)ShmPoseWriter::remove(name);
}
BENCHMARK(BM_ShmRingWrite);

}  // namespace
}  // namespace stillpoint::ipc
