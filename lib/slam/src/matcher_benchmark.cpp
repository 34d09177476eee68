// Window-free descriptor matching at a frame's size: the anchor matching
// (whole frame, mutual) and the nearer anchors' (a quarter of the frame's
// keypoints), on 1000 random descriptors per frame spread over the pyramid
// levels as ORB spreads them, half of the current frame's copied from the
// other's with a few bits flipped. Also the distance kernel alone.
#include <benchmark/benchmark.h>

#include <cmath>
#include <random>
#include <vector>

#include "matcher.hpp"
#include "stillpoint/features/descriptor.hpp"

namespace stillpoint::slam {
namespace {

constexpr int kFeatures = 1000;
constexpr int kLevels = 8;

Frame randomFrame(std::mt19937* rng) {
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  Frame f;
  f.descriptors = cv::Mat(kFeatures, features::kDescriptorBytes, CV_8U);
  // Level l holds a share proportional to 1.2^-2l of the features (area).
  std::vector<double> share(kLevels);
  double total = 0;
  for (int l = 0; l < kLevels; ++l) total += share[l] = std::pow(1.2, -2.0 * l);
  for (int i = 0; i < kFeatures; ++i) {
    double u = unit(*rng) * total;
    int level = 0;
    while (level + 1 < kLevels && u > share[level]) u -= share[level++];
    f.keys.emplace_back(640 * unit(*rng), 480 * unit(*rng), 7.0f, 360 * unit(*rng), 0.0f, level);
    for (int b = 0; b < features::kDescriptorBytes; ++b) f.descriptors.at<std::uint8_t>(i, b) = byte(*rng);
  }
  f.depth.assign(kFeatures, 2.0f);
  f.dynamic.assign(kFeatures, kNotDynamic);
  f.clearMatches();
  return f;
}

struct FramePair {
  Frame current, other;
};

const FramePair& framePair() {
  static const FramePair pair = [] {
    std::mt19937 rng(3);
    FramePair p{randomFrame(&rng), randomFrame(&rng)};
    std::uniform_int_distribution<int> bit(0, 8 * features::kDescriptorBytes - 1);
    for (int j = 0; j < kFeatures; j += 2) {
      p.other.descriptors.row(j).copyTo(p.current.descriptors.row(j));
      p.current.keys[j].octave = p.other.keys[j].octave;
      p.current.keys[j].angle = p.other.keys[j].angle;
      for (int flips = j % 20; flips > 0; --flips) {
        const int b = bit(rng);
        p.current.descriptors.at<std::uint8_t>(j, b / 8) ^= static_cast<std::uint8_t>(1 << (b % 8));
      }
    }
    return p;
  }();
  return pair;
}

void BM_MatchByDescriptorWholeFrame(benchmark::State& state) {
  const FramePair& p = framePair();
  std::size_t matches = 0;
  for (auto _ : state) {
    const auto m = matchByDescriptor(p.current, p.other, 0.7f, false, true);
    matches = m.size();
    benchmark::DoNotOptimize(m.data());
  }
  state.counters["matches"] = static_cast<double>(matches);
}
BENCHMARK(BM_MatchByDescriptorWholeFrame)->Unit(benchmark::kMillisecond);

void BM_MatchSomeByDescriptor(benchmark::State& state) {
  const FramePair& p = framePair();
  std::vector<int> some;
  for (int j = 0; j < kFeatures; j += kFeatures / static_cast<int>(state.range(0))) some.push_back(j);
  std::size_t matches = 0;
  for (auto _ : state) {
    const auto m = matchSomeByDescriptor(p.current, p.other, 0.7f, some);
    matches = m.size();
    benchmark::DoNotOptimize(m.data());
  }
  state.counters["matches"] = static_cast<double>(matches);
}
BENCHMARK(BM_MatchSomeByDescriptor)->Arg(125)->Arg(250)->Unit(benchmark::kMillisecond);

// One query against 1000 descriptors; arg 1 takes the dispatched path
// (AVX-512 where the CPU has it), 0 the scalar one.
void BM_HammingDistances(benchmark::State& state) {
  const Frame& f = framePair().other;
  std::vector<int> out(kFeatures);
  const std::uint8_t* query = framePair().current.descriptor(0);
  for (auto _ : state) {
    if (state.range(0))
      features::hammingDistances(query, f.descriptor(0), kFeatures, out.data());
    else
      features::hammingDistancesScalar(query, f.descriptor(0), kFeatures, out.data());
    benchmark::DoNotOptimize(out.data());
  }
  state.SetLabel(state.range(0) ? features::hammingDistancesPath() : "scalar");
  state.SetItemsProcessed(state.iterations() * kFeatures);
}
BENCHMARK(BM_HammingDistances)->Arg(0)->Arg(1);

}  // namespace
}  // namespace stillpoint::slam
