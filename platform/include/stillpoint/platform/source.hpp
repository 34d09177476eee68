#pragma once
// The camera interface of the daemon: every RGB-D source (recorded sequence,
// OpenNI2 device, V4L2 device) delivers frames through RgbdSource. A source is
// used from one thread: open(), then next() until it says end or the daemon
// stops, then close(). next() never blocks longer than its timeout, so the
// owning thread can notice a stop request.
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"

namespace stillpoint::platform {

struct CameraFrame {
  Timestamp stamp;        // capture time (sensor clock, or the recording's stamp)
  cv::Mat gray;           // CV_8UC1
  // CV_8UC3 BGR colour image, camera size, for the semantic module; empty
  // unless the source was asked for colour (each source's `colour` option).
  cv::Mat bgr;
  cv::Mat depth_m;        // CV_32FC1 metres, 0 = no measurement, registered to colour
  std::uint64_t sequence = 0;  // 0-based count of frames delivered by this source
  // When the frame entered the process (steady clock): start of the pose latency.
  std::chrono::steady_clock::time_point arrival;
};

// What a call to next() produced.
enum class SourceEvent {
  kFrame,       // `frame` holds a new frame
  kTimeout,     // nothing within the timeout; try again
  kEnd,         // a recording ended; no more frames will come
  kBadFrame,    // one frame was unusable (message says why); the source goes on
  kDeviceGone,  // the camera disappeared; close() and open() again (with back-off)
};
const char* toString(SourceEvent event);

struct SourceResult {
  SourceEvent event = SourceEvent::kTimeout;
  std::string message;  // for kBadFrame / kDeviceGone: what happened
};

class RgbdSource {
 public:
  virtual ~RgbdSource() = default;
  // Opens the device or recording. An error names what is missing or wrong.
  virtual Status open() = 0;
  // Waits at most `timeout` for the next frame.
  virtual SourceResult next(CameraFrame& frame, std::chrono::milliseconds timeout) = 0;
  virtual void close() = 0;
  // A live camera does not wait for the consumer: the daemon puts a
  // drop-oldest queue behind it. A recording is replayed losslessly (blocking queue).
  virtual bool live() const = 0;
  virtual std::string describe() const = 0;
};

}  // namespace stillpoint::platform
