// Rendering speed of the dynamic-sequence generator at 640x480 (PNG I/O excluded).
#include <benchmark/benchmark.h>

#include <filesystem>

#include <opencv2/imgcodecs.hpp>

#include "stillpoint/synth/config.hpp"
#include "stillpoint/synth/generator.hpp"
#include "stillpoint/synth/room.hpp"
#include "stillpoint/synth/sensor.hpp"

namespace {

using namespace stillpoint;
using namespace stillpoint::synth;

const std::string kTeddy = std::string(STILLPOINT_DATA_DIR) + "/tum_fr3_teddy_200";

// A real 640x480 frame when the TUM excerpt is there, otherwise a flat grey one at 2 m.
void realFrame(cv::Mat* bgr, cv::Mat* depth) {
  const std::string rgb = kTeddy + "/rgb/1341841874.981953.png";
  const std::string dep = kTeddy + "/depth/1341841874.981969.png";
  if (std::filesystem::exists(rgb) && std::filesystem::exists(dep)) {
    *bgr = cv::imread(rgb, cv::IMREAD_COLOR);
    *depth = cv::imread(dep, cv::IMREAD_UNCHANGED);
  }
  if (bgr->empty() || depth->empty()) {
    *bgr = cv::Mat(480, 640, CV_8UC3, cv::Scalar(128, 128, 128));
    *depth = cv::Mat(480, 640, CV_16UC1, cv::Scalar(10000));
  }
}

// Movers of a preset composited onto a real frame (render, z-test, sensor model on mover pixels).
void BM_OverlayCompose(benchmark::State& state, const char* preset) {
  cv::Mat bgr, depth;
  realFrame(&bgr, &depth);
  Result<SynthConfig> config = synthPreset(preset, std::string(STILLPOINT_DATA_DIR) + "/../models/testdata");
  const CameraModel cam = roomCamera(640, 480);
  const SE3 T_w_c = Eigen::Translation3d(0, 0, 1.5) * Eigen::AngleAxisd(-1.9, Vec3::UnitX());
  Result<MoverRenderer> movers = MoverRenderer::create(*config, stageFromCamera(T_w_c));
  double t = 0;
  double coverage = 0;
  for (auto _ : state) {
    const CompositeFrame f = composeOverlay(*movers, bgr, depth, t, T_w_c, cam, config->sensor, 7);
    coverage = cv::countNonZero(f.mask) / double(f.mask.total());
    t += 1.0 / 30;
    if (t > 6) t = 0;
  }
  state.counters["coverage"] = coverage;
}
BENCHMARK_CAPTURE(BM_OverlayCompose, poster_big, "poster-big")->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_OverlayCompose, mix, "mix")->Unit(benchmark::kMillisecond);

// A full synthetic room frame with a walker, sensor model on every pixel.
void BM_RoomFrame(benchmark::State& state) {
  Result<SynthConfig> config = synthPreset("room-walker", "");
  Result<Room> room = buildRoom(config->room, "", 1);
  const CameraModel cam = roomCamera(640, 480);
  Result<MoverRenderer> movers = MoverRenderer::create(*config, stageFromCamera(roomCameraPose(CameraMotion::kXyz, 0)));
  double t = 0;
  for (auto _ : state) {
    const SE3 T_w_c = roomCameraPose(CameraMotion::kXyz, t);
    RenderTarget target = RenderTarget::blank(640, 480);
    render(room->mesh, T_w_c, cam, &target);
    movers->render(t, T_w_c, cam, &target);
    cv::Mat raw;
    applyDepthSensor(target.depth, cv::Mat(), config->sensor, 3, &raw);
    benchmark::DoNotOptimize(raw.data);
    t += 1.0 / 30;
  }
}
BENCHMARK(BM_RoomFrame)->Unit(benchmark::kMillisecond);

void BM_DepthSensorFullFrame(benchmark::State& state) {
  cv::Mat z(480, 640, CV_32FC1);
  cv::randu(z, 0.5, 4.0);
  cv::Mat raw;
  const DepthSensorOptions o;
  for (auto _ : state) {
    applyDepthSensor(z, cv::Mat(), o, 5, &raw);
    benchmark::DoNotOptimize(raw.data);
  }
}
BENCHMARK(BM_DepthSensorFullFrame)->Unit(benchmark::kMillisecond);

}  // namespace
