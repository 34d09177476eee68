// Depth clustering and cluster scoring costs at 640x480.
#include <benchmark/benchmark.h>
#include <opencv2/imgcodecs.hpp>

#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "stillpoint/geometry/depth_clustering.hpp"
#include "stillpoint/geometry/dynamic_clusters.hpp"

namespace stillpoint::geometry {
namespace {

// Real depth images of the bundled excerpt when present, else a synthetic room.
std::vector<cv::Mat> depthImages() {
  std::vector<cv::Mat> out;
  const std::string dir = std::string(STILLPOINT_DATA_DIR) + "/tum_fr3_teddy_200/";
  std::ifstream list(dir + "depth.txt");
  std::string line;
  while (std::getline(list, line) && out.size() < 30) {
    if (line.empty() || line[0] == '#') continue;
    const std::string file = line.substr(line.find(' ') + 1);
    cv::Mat raw = cv::imread(dir + file, cv::IMREAD_UNCHANGED);
    if (raw.empty()) continue;
    cv::Mat m;
    raw.convertTo(m, CV_32F, 1.0 / 5000.0);
    out.push_back(m);
  }
  if (out.empty()) {
    cv::Mat d(480, 640, CV_32F, cv::Scalar(3.0f));
    d(cv::Rect(0, 240, 320, 240)).setTo(1.5f);
    d(cv::Rect(300, 100, 150, 200)).setTo(0.9f);
    out.push_back(d);
  }
  return out;
}

void BM_ClusterWarm(benchmark::State& state) {
  const auto images = depthImages();
  const CameraModel cam = *cameraPreset("fr3");
  ClusteringOptions o;
  o.sample_step_at_vga = static_cast<int>(state.range(0));
  DepthClusterer clusterer(o);
  std::size_t i = 0;
  int iterations = 0;
  for (auto _ : state) {
    auto c = clusterer.cluster(images[i++ % images.size()], cam);
    iterations += c->iterations;
    benchmark::DoNotOptimize(c);
  }
  state.counters["kmeans_iters"] = benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
}
BENCHMARK(BM_ClusterWarm)->Arg(4)->Arg(6)->Arg(8)->Unit(benchmark::kMillisecond);

void BM_ClusterCold(benchmark::State& state) {
  const auto images = depthImages();
  const CameraModel cam = *cameraPreset("fr3");
  ClusteringOptions o;
  o.warm_start = false;
  DepthClusterer clusterer(o);
  std::size_t i = 0;
  for (auto _ : state) benchmark::DoNotOptimize(clusterer.cluster(images[i++ % images.size()], cam));
}
BENCHMARK(BM_ClusterCold)->Unit(benchmark::kMillisecond);

void BM_ClassifyClusters(benchmark::State& state) {
  std::mt19937 rng(1);
  std::chi_squared_distribution<double> chi2(3.0);
  std::uniform_int_distribution<int> cluster(0, 23);
  std::vector<FeatureResidual> r(static_cast<std::size_t>(state.range(0)));
  for (auto& f : r) f = {cluster(rng), chi2(rng)};
  for (auto _ : state) benchmark::DoNotOptimize(classifyClusters(r, 24, {}));
}
BENCHMARK(BM_ClassifyClusters)->Arg(300)->Arg(1000)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace stillpoint::geometry
