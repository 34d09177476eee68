// ORB extraction on a real 640x480 TUM frame (falls back to a synthetic image).
#include <benchmark/benchmark.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stillpoint/features/orb_extractor.hpp"

namespace {

cv::Mat benchmarkImage() {
  cv::Mat image = cv::imread(std::string(STILLPOINT_DATA_DIR) +
                                 "/tum_fr3_teddy_200/rgb/1341841873.273798.png",
                             cv::IMREAD_GRAYSCALE);
  if (image.empty()) {
    image = cv::Mat(480, 640, CV_8UC1);
    cv::randu(image, 0, 255);
    cv::GaussianBlur(image, image, cv::Size(5, 5), 1.5);
  }
  return image;
}

void BM_OrbExtract(benchmark::State& state) {
  stillpoint::features::OrbOptions options;
  options.num_features = static_cast<int>(state.range(0));
  options.num_levels = static_cast<int>(state.range(1));
  stillpoint::features::OrbExtractor orb(options);
  const cv::Mat image = benchmarkImage();
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  for (auto _ : state) {
    orb.extract(image, &kps, &desc);
    benchmark::DoNotOptimize(desc.data);
  }
  state.counters["keypoints"] = static_cast<double>(kps.size());
}
// Arguments: feature budget, pyramid levels.
BENCHMARK(BM_OrbExtract)->Args({1000, 8})->Args({1000, 3})->Args({2000, 8})->Unit(benchmark::kMillisecond);

}  // namespace
