// stillpoint-oni: test helper for .oni recordings (built with the tests, not installed).
//
//   stillpoint-oni record OUT.oni N [URI]
//     Records N colour/depth frames of an OpenNI2 device (the first device, or
//     URI) into OUT.oni with openni::Recorder, lossless: colour RGB888, depth
//     1 mm, 640x480@30, depth registered to colour.
//   stillpoint-oni dump IN.oni OUT_DIR CAMERA.yaml|fr1|fr2|fr3
//     Plays IN.oni back through OpenNI2Source (file URI, as the daemon would)
//     until the recording ends and writes every frame pair it delivers in the
//     TUM layout: rgb/<stamp>.png (colour as delivered, BGR), depth/<stamp>.png
//     (16-bit, 1 mm per unit), rgb.txt, depth.txt. Prints "frames=<n>".
//
// Exit status: 0 ok, 1 failure (message on stderr), 2 usage.
#include <OpenNI.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/program.hpp"
#include "stillpoint/platform/openni2_source.hpp"

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

int fail(const std::string& what) {
  std::fprintf(stderr, "stillpoint-oni: %s: %s\n", what.c_str(), openni::OpenNI::getExtendedError());
  return 1;
}

int record(const std::string& out, int n, const std::string& uri) {
  if (openni::OpenNI::initialize() != openni::STATUS_OK) return fail("initialize");
  openni::Device device;
  if (device.open(uri.empty() ? openni::ANY_DEVICE : uri.c_str()) != openni::STATUS_OK) return fail("open device");
  openni::VideoStream colour, depth;
  auto setUp = [&](openni::VideoStream& s, openni::SensorType type, openni::PixelFormat format) {
    if (s.create(device, type) != openni::STATUS_OK) return false;
    openni::VideoMode mode;
    mode.setResolution(640, 480);
    mode.setFps(30);
    mode.setPixelFormat(format);
    return s.setVideoMode(mode) == openni::STATUS_OK;
  };
  if (!setUp(colour, openni::SENSOR_COLOR, openni::PIXEL_FORMAT_RGB888)) return fail("colour stream");
  if (!setUp(depth, openni::SENSOR_DEPTH, openni::PIXEL_FORMAT_DEPTH_1_MM)) return fail("depth stream");
  if (device.isImageRegistrationModeSupported(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR))
    device.setImageRegistrationMode(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR);
  openni::Recorder recorder;
  if (recorder.create(out.c_str()) != openni::STATUS_OK) return fail("create recorder " + out);
  if (recorder.attach(colour, false) != openni::STATUS_OK) return fail("attach colour");
  if (recorder.attach(depth, false) != openni::STATUS_OK) return fail("attach depth");
  // Start the recorder first so that it sees every frame the streams produce.
  if (recorder.start() != openni::STATUS_OK) return fail("start recorder");
  if (colour.start() != openni::STATUS_OK || depth.start() != openni::STATUS_OK) return fail("start streams");
  int colour_frames = 0, depth_frames = 0;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10 + n / 10);
  while ((colour_frames < n || depth_frames < n) && std::chrono::steady_clock::now() < until) {
    openni::VideoStream* streams[] = {&colour, &depth};
    int ready = -1;
    if (openni::OpenNI::waitForAnyStream(streams, 2, &ready, 500) != openni::STATUS_OK) continue;
    openni::VideoFrameRef frame;
    if (streams[ready]->readFrame(&frame) != openni::STATUS_OK) continue;
    ++(ready == 0 ? colour_frames : depth_frames);
  }
  // The recorder takes the frames through its own listener, on the camera's
  // thread: a camera that sends on may have put a frame beyond the last one
  // counted here into the recording before the streams stop. Stop them first.
  colour.stop();
  depth.stop();
  recorder.stop();
  recorder.destroy();
  colour.destroy();
  depth.destroy();
  device.close();
  openni::OpenNI::shutdown();
  if (colour_frames < n || depth_frames < n) {
    std::fprintf(stderr, "stillpoint-oni: only %d colour and %d depth frames in time\n", colour_frames, depth_frames);
    return 1;
  }
  std::printf("recorded colour=%d depth=%d -> %s\n", colour_frames, depth_frames, out.c_str());
  return 0;
}

int dump(const std::string& in, const fs::path& dir, const std::string& camera_spec) {
  auto camera = stillpoint::loadCamera(camera_spec);
  if (!camera) {
    std::fprintf(stderr, "stillpoint-oni: %s\n", camera.error().c_str());
    return 1;
  }
  stillpoint::platform::OpenNI2SourceOptions options;
  options.uri = in;
  options.colour = true;
  stillpoint::platform::OpenNI2Source source(options, *camera);
  if (auto s = source.open(); !s) {
    std::fprintf(stderr, "stillpoint-oni: %s\n", s.error().c_str());
    return 1;
  }
  // Frames are kept in memory and written at the end, so that the time between
  // the first and the last frame's arrival is the source's pacing alone.
  std::vector<stillpoint::platform::CameraFrame> frames;
  const auto until = std::chrono::steady_clock::now() + 120s;
  while (std::chrono::steady_clock::now() < until) {
    stillpoint::platform::CameraFrame frame;
    const auto r = source.next(frame, 200ms);
    if (r.event == stillpoint::platform::SourceEvent::kEnd) break;
    if (r.event == stillpoint::platform::SourceEvent::kTimeout) continue;
    if (r.event != stillpoint::platform::SourceEvent::kFrame) {
      std::fprintf(stderr, "stillpoint-oni: %s: %s\n", toString(r.event), r.message.c_str());
      return 1;
    }
    if (frame.bgr.empty()) {
      std::fprintf(stderr, "stillpoint-oni: frame %zu without colour\n", frames.size());
      return 1;
    }
    frames.push_back(std::move(frame));
  }
  source.close();
  fs::create_directories(dir / "rgb");
  fs::create_directories(dir / "depth");
  std::ofstream rgb_list(dir / "rgb.txt"), depth_list(dir / "depth.txt");
  for (const auto& frame : frames) {
    const std::string stamp = frame.stamp.toSecondsString();
    cv::Mat mm;
    frame.depth_m.convertTo(mm, CV_16UC1, 1000.0);
    if (!cv::imwrite((dir / "rgb" / (stamp + ".png")).string(), frame.bgr) ||
        !cv::imwrite((dir / "depth" / (stamp + ".png")).string(), mm)) {
      std::fprintf(stderr, "stillpoint-oni: cannot write into %s\n", dir.c_str());
      return 1;
    }
    rgb_list << stamp << " rgb/" << stamp << ".png\n";
    depth_list << stamp << " depth/" << stamp << ".png\n";
  }
  std::printf("frames=%zu\n", frames.size());
  if (frames.size() > 1) {
    const double played_s = std::chrono::duration<double>(frames.back().arrival - frames.front().arrival).count();
    const double recorded_s = (frames.back().stamp.nanoseconds() - frames.front().stamp.nanoseconds()) / 1e9;
    std::printf("played_s=%.3f recorded_s=%.3f\n", played_s, recorded_s);
  }
  return 0;
}

}  // namespace

static int oniMain(int argc, char** argv) {
  const std::string command = argc > 1 ? argv[1] : "";
  if (command == "record" && (argc == 4 || argc == 5)) return record(argv[2], std::atoi(argv[3]), argc == 5 ? argv[4] : "");
  if (command == "dump" && argc == 5) return dump(argv[2], argv[3], argv[4]);
  std::fprintf(stderr,
               "usage: stillpoint-oni record OUT.oni N [URI]\n"
               "       stillpoint-oni dump IN.oni OUT_DIR CAMERA\n");
  return 2;
}

int main(int argc, char** argv) { return stillpoint::runProgram("stillpoint-oni", oniMain, argc, argv); }
