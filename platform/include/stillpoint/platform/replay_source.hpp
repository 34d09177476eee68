#pragma once
// A recorded TUM RGB-D sequence as a camera: frames at their recorded rate
// (paced) or as fast as the consumer takes them.
#include <chrono>
#include <memory>
#include <optional>
#include <string>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/platform/source.hpp"

namespace stillpoint::platform {

struct ReplaySourceOptions {
  std::string path;        // TUM layout folder
  bool paced = true;       // at the recorded rate; false: as fast as possible
  bool loop = false;       // start again at the end (stamps keep increasing)
  std::uint64_t max_frames = 0;  // stop after this many frames (0: all)
  // Behave like a live camera (drop-oldest queue behind it): shows what a
  // real camera at this rate would lose. Only meaningful when paced.
  bool as_live = false;
  bool colour = false;     // also deliver the BGR image (CameraFrame::bgr); set by the daemon, not a config key
  Status validate() const;
};

class ReplaySource final : public RgbdSource {
 public:
  ReplaySource(ReplaySourceOptions options, CameraModel camera);
  Status open() override;
  SourceResult next(CameraFrame& frame, std::chrono::milliseconds timeout) override;
  void close() override;
  bool live() const override { return options_.as_live; }
  std::string describe() const override;

  // A gap in the stamps longer than this is not slept through when paced
  // (a paused recording, a corrupt stamp): pacing starts again at the frame
  // after it, with a warning.
  static constexpr std::int64_t kMaxPacedGapNs = 1'000'000'000;

 private:
  ReplaySourceOptions options_;
  CameraModel camera_;
  std::optional<dataset::TumDataset> data_;
  std::size_t index_ = 0;        // next pair to load
  std::uint64_t delivered_ = 0;
  std::int64_t loop_offset_ns_ = 0;  // added to stamps after each wrap-around
  std::int64_t first_stamp_ns_ = 0;
  bool started_ = false;
  std::chrono::steady_clock::time_point start_;
  std::int64_t last_stamp_ns_ = 0;  // the last frame delivered
};

}  // namespace stillpoint::platform
