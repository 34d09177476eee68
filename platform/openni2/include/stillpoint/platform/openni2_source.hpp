#pragma once
// An OpenNI2 camera (PrimeSense/Asus/Orbbec, RealSense through its OpenNI2
// driver plugin, or a .oni recording) as an RgbdSource. OpenNI2's headers stay
// inside platform/openni2/src.
#include <memory>
#include <string>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/platform/source.hpp"

namespace stillpoint::platform {

struct OpenNI2SourceOptions {
  std::string uri;  // device URI or .oni file; "" = the first device
  bool colour = false;  // also deliver the BGR image (CameraFrame::bgr); set by the daemon, not a config key
};

class OpenNI2Source final : public RgbdSource {
 public:
  OpenNI2Source(OpenNI2SourceOptions options, CameraModel camera);
  ~OpenNI2Source() override;
  // 640x480@30 colour and depth, depth registered to colour, frame sync on,
  // mirroring off. Errors carry OpenNI's extended error text. A .oni file is
  // played once with the modes it was recorded with; next() reports kEnd at
  // its end (see platform/README.md).
  Status open() override;
  SourceResult next(CameraFrame& frame, std::chrono::milliseconds timeout) override;
  void close() override;
  bool live() const override { return true; }
  std::string describe() const override;

 private:
  struct Impl;
  OpenNI2SourceOptions options_;
  CameraModel camera_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stillpoint::platform
