// Cost of publishPose() to the tracking thread: copying the pose into the bounded
// drop-oldest queue and waking the publisher thread. The transports behind it (here
// the real shared-memory ring) run on the publisher thread and are not timed.
#include <benchmark/benchmark.h>
#include <unistd.h>

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
