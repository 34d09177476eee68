// Per-keyframe segmentation time of each model card on a 640x480 TUM frame,
// OpenCV with 1 thread (SegmenterOptions::threads default). Counters split
// the time into pre-processing, inference and decoding.
#include <benchmark/benchmark.h>

#include <filesystem>
#include <opencv2/imgcodecs.hpp>

#include "stillpoint/semantic/segmenter.hpp"

namespace {

namespace fs = std::filesystem;
using namespace stillpoint::semantic;

cv::Mat frame() {
  const fs::path tum = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200/rgb/1341841873.273798.png";
  cv::Mat img = cv::imread(tum.string(), cv::IMREAD_COLOR);
  if (img.empty()) {  // no data folder: a noise frame of the same size
    img = cv::Mat(480, 640, CV_8UC3);
    cv::randu(img, 0, 255);
  }
  return img;
}

void segmentFrame(benchmark::State& state, const fs::path& card_path, const fs::path& model_dir) {
  auto card = loadModelCard(card_path);
  if (!card) return state.SkipWithError(card.error().c_str());
  if (!model_dir.empty()) card->model_path = model_dir / card->model_path.filename();
  if (!fs::exists(card->model_path)) return state.SkipWithError(("no " + card->model_path.string()).c_str());
  auto seg = createSegmenter(*card);
  if (!seg) return state.SkipWithError(seg.error().c_str());
  const cv::Mat img = frame();
  double pre = 0, inf = 0, dec = 0;
  for (auto _ : state) {
    auto r = (*seg)->segment(img);
    if (!r) return state.SkipWithError(r.error().c_str());
    pre += r->timing.preprocess_ms, inf += r->timing.inference_ms, dec += r->timing.decode_ms;
    benchmark::DoNotOptimize(r->movable_pixels);
  }
  const double n = double(state.iterations());
  state.counters["preprocess_ms"] = pre / n;
  state.counters["inference_ms"] = inf / n;
  state.counters["decode_ms"] = dec / n;
}

const fs::path kProject = STILLPOINT_PROJECT_MODELS_DIR;
const fs::path kShared = STILLPOINT_MODELS_DIR;

BENCHMARK_CAPTURE(segmentFrame, person_selfie_256, kProject / "person_selfie_256.yaml", fs::path())
    ->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK_CAPTURE(segmentFrame, person_selfie_landscape_144x256, kProject / "person_selfie_landscape_144x256.yaml",
                  fs::path())
    ->Unit(benchmark::kMillisecond)->MinTime(2.0);
BENCHMARK_CAPTURE(segmentFrame, coco_yolov5s_seg_320, kProject / "coco_yolov5s_seg_320.yaml", kShared)
    ->Unit(benchmark::kMillisecond)->MinTime(3.0);

}  // namespace
