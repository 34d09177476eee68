#pragma once
// An RGB-D camera made of two V4L2 devices: a colour node (YUYV) and a depth
// node (Z16, 16-bit depth in a fixed unit), e.g. the two UVC nodes of an Intel
// RealSense D4xx. Both are opened at the camera's size and paired by driver
// timestamp.
//
// Pairing. Each colour frame takes the depth frame nearest to it in time among
// those already received, if it lies within pair_tolerance_ms. A colour frame
// waits for its depth frame until a depth frame newer than its stamp plus the
// tolerance arrives (then it has none: reported as a bad frame and counted) or
// for at most max(100 ms, 5 x tolerance) of wall time (a stalled depth
// stream). Depth frames older than the colour frame being paired are dropped
// (counted). Both drivers must stamp from the same clock (CLOCK_MONOTONIC for
// UVC); the frame carries the colour stamp.
//
// Registration. The depth image must already be registered to colour: depth
// pixel (u, v) must see what colour pixel (u, v) sees. This source does not
// register depth itself (that needs both cameras' intrinsics and the
// extrinsics between them), so it refuses to open unless
// `depth_registered` says the device does it. A RealSense's raw UVC depth
// node is NOT registered; use the OpenNI2 source with its driver plugin there.
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/platform/source.hpp"
#include "stillpoint/platform/v4l2_capture.hpp"

namespace stillpoint::platform {

struct V4l2SourceOptions {
  std::string colour_device;       // YUYV node, e.g. /dev/video4 (required)
  std::string depth_device;        // Z16 node, e.g. /dev/video0 (required)
  int width = 640, height = 480;   // both streams; must be the camera's size
  int fps = 30;                    // asked of both devices (best effort)
  double depth_scale = 0.001;      // metres per depth unit (1 mm)
  double pair_tolerance_ms = 20;   // largest colour/depth stamp difference of a pair
  bool depth_registered = false;   // the device registers depth to colour (required: see above)
  bool colour = false;             // also deliver BGR (CameraFrame::bgr); set by the daemon, not a config key
  // Errors read "source.v4l2.<field>: ...".
  Status validate() const;
};

class V4l2Source final : public RgbdSource {
 public:
  // On the real devices.
  V4l2Source(V4l2SourceOptions options, CameraModel camera);
  // On devices of the caller's (tests: a fake driver).
  V4l2Source(V4l2SourceOptions options, CameraModel camera, std::unique_ptr<V4l2Device> colour_device,
             std::unique_ptr<V4l2Device> depth_device);
  ~V4l2Source() override;
  Status open() override;
  SourceResult next(CameraFrame& frame, std::chrono::milliseconds timeout) override;
  void close() override;
  bool live() const override { return true; }
  std::string describe() const override;

  struct Counters {
    std::uint64_t paired = 0;
    std::uint64_t colour_unpaired = 0;  // colour frames without a depth frame within the tolerance
    std::uint64_t depth_unpaired = 0;   // depth frames no colour frame took
    std::uint64_t corrupt = 0;          // frames a driver flagged or truncated
  };
  Counters counters() const { return counters_; }

 private:
  SourceResult drainDepth();
  SourceResult unpaired(const std::string& why);
  void deliver(const V4l2Frame& colour, const V4l2Frame& depth, CameraFrame& frame);

  V4l2SourceOptions options_;
  CameraModel camera_;
  V4l2Capture colour_, depth_;
  std::optional<V4l2Frame> pending_;  // colour frame waiting for its depth frame
  std::chrono::steady_clock::time_point pending_since_;
  std::deque<V4l2Frame> depth_frames_;  // received, not yet paired, oldest first
  std::uint64_t delivered_ = 0;
  Counters counters_;
};

}  // namespace stillpoint::platform
