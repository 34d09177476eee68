#include "stillpoint/platform/v4l2_source.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace stillpoint::platform {
namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

// Depth frames kept for pairing: a few frame periods are enough when both
// streams run at the same rate; more would only hide a stalled colour stream.
constexpr std::size_t kDepthFramesKept = 4;

V4l2Options captureOptions(const V4l2SourceOptions& o, bool depth) {
  V4l2Options c;
  c.device = depth ? o.depth_device : o.colour_device;
  c.width = o.width;
  c.height = o.height;
  c.fps = o.fps;
  c.format = depth ? V4l2Format::kZ16 : V4l2Format::kYuyv;
  c.colour = !depth && o.colour;
  return c;
}

std::string ms(std::int64_t ns) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f ms", ns / 1e6);
  return buf;
}

}  // namespace

Status V4l2SourceOptions::validate() const {
  if (colour_device.empty()) return Error{"source.v4l2.colour_device: required (the YUYV colour node, e.g. /dev/video4)"};
  if (depth_device.empty()) return Error{"source.v4l2.depth_device: required (the Z16 depth node, e.g. /dev/video0)"};
  if (colour_device == depth_device)
    return Error{"source.v4l2.depth_device: must differ from source.v4l2.colour_device (" + depth_device + ")"};
  if (width < 2 || width > 8192 || width % 2 != 0) return Error{"source.v4l2.width: must be an even number 2..8192"};
  if (height < 1 || height > 8192) return Error{"source.v4l2.height: must be 1..8192"};
  if (fps < 0 || fps > 1000) return Error{"source.v4l2.fps: must be 0 (the driver's rate) or 1..1000"};
  if (!(depth_scale > 0 && depth_scale <= 0.1))
    return Error{"source.v4l2.depth_scale: must be in (0, 0.1] metres per depth unit (0.001 = 1 mm)"};
  if (!(pair_tolerance_ms > 0 && pair_tolerance_ms <= 100))
    return Error{"source.v4l2.pair_tolerance_ms: must be in (0, 100] ms"};
  if (!depth_registered)
    return Error{"source.v4l2.depth_registered: the v4l2 source needs depth already registered to colour (depth "
                 "pixel (u,v) seeing what colour pixel (u,v) sees) and does not register it itself; set true only "
                 "when the device does (a RealSense's raw UVC depth node does not: use source.type openni2 there)"};
  return {};
}

V4l2Source::V4l2Source(V4l2SourceOptions options, CameraModel camera)
    : V4l2Source(options, std::move(camera), systemV4l2Device(), systemV4l2Device()) {}

V4l2Source::V4l2Source(V4l2SourceOptions options, CameraModel camera, std::unique_ptr<V4l2Device> colour_device,
                       std::unique_ptr<V4l2Device> depth_device)
    : options_(std::move(options)),
      camera_(std::move(camera)),
      colour_(std::move(colour_device), captureOptions(options_, false)),
      depth_(std::move(depth_device), captureOptions(options_, true)) {}

V4l2Source::~V4l2Source() { close(); }

std::string V4l2Source::describe() const {
  char buf[64];
  std::snprintf(buf, sizeof buf, " %dx%d@%d, pairs within %.0f ms", options_.width, options_.height, options_.fps,
                options_.pair_tolerance_ms);
  return "v4l2 colour " + options_.colour_device + " + depth " + options_.depth_device + buf;
}

Status V4l2Source::open() {
  close();
  if (Status s = options_.validate(); !s) return s;
  if (options_.width != camera_.width || options_.height != camera_.height)
    return Error{"v4l2: size " + std::to_string(options_.width) + "x" + std::to_string(options_.height) +
                 " differs from the camera's " + std::to_string(camera_.width) + "x" + std::to_string(camera_.height)};
  if (Status s = colour_.open(); !s) return s;
  if (Status s = depth_.open(); !s) {
    colour_.close();
    return s;
  }
  return {};
}

void V4l2Source::close() {
  colour_.close();
  depth_.close();
  pending_.reset();
  depth_frames_.clear();
}

// Takes every depth frame the driver holds, without waiting.
SourceResult V4l2Source::drainDepth() {
  for (;;) {
    V4l2Frame d;
    std::string message;
    switch (depth_.next(d, 0ms, &message)) {
      case V4l2Event::kFrame:
        depth_frames_.push_back(std::move(d));
        if (depth_frames_.size() > kDepthFramesKept) {
          depth_frames_.pop_front();
          ++counters_.depth_unpaired;
        }
        break;
      case V4l2Event::kTimeout: return {SourceEvent::kTimeout, ""};
      case V4l2Event::kGone: return {SourceEvent::kDeviceGone, "depth " + message};
      case V4l2Event::kError:
        ++counters_.corrupt;
        return {SourceEvent::kBadFrame, "depth " + options_.depth_device + ": " + message};
    }
  }
}

SourceResult V4l2Source::unpaired(const std::string& why) {
  ++counters_.colour_unpaired;
  const std::string stamp = pending_->stamp.toSecondsString();
  pending_.reset();
  return {SourceEvent::kBadFrame, "colour frame at " + stamp + " s has no depth frame: " + why};
}

void V4l2Source::deliver(const V4l2Frame& colour, const V4l2Frame& depth, CameraFrame& frame) {
  frame.stamp = colour.stamp;
  frame.gray = colour.gray;
  frame.bgr = options_.colour ? colour.bgr : cv::Mat();
  depth.depth.convertTo(frame.depth_m, CV_32FC1, options_.depth_scale);  // 0 (no measurement) stays 0
  frame.sequence = delivered_++;
  frame.arrival = Clock::now();
  ++counters_.paired;
}

SourceResult V4l2Source::next(CameraFrame& frame, std::chrono::milliseconds timeout) {
  const auto until = Clock::now() + timeout;
  const auto tolerance_ns = static_cast<std::int64_t>(std::llround(options_.pair_tolerance_ms * 1e6));
  const auto stale_after = std::max<Clock::duration>(100ms, std::chrono::nanoseconds(5 * tolerance_ns));
  for (;;) {
    if (SourceResult r = drainDepth(); r.event != SourceEvent::kTimeout) return r;
    const auto left = std::max<Clock::duration>(until - Clock::now(), Clock::duration::zero());
    if (!pending_) {
      // Wait for colour; depth frames queue in their driver meanwhile.
      V4l2Frame c;
      std::string message;
      switch (colour_.next(c, std::chrono::ceil<std::chrono::milliseconds>(left), &message)) {
        case V4l2Event::kFrame:
          pending_ = std::move(c);
          pending_since_ = Clock::now();
          continue;  // collect the depth frames that came meanwhile
        case V4l2Event::kTimeout:
          if (Clock::now() >= until) return {SourceEvent::kTimeout, ""};
          continue;
        case V4l2Event::kGone: return {SourceEvent::kDeviceGone, "colour " + message};
        case V4l2Event::kError:
          ++counters_.corrupt;
          return {SourceEvent::kBadFrame, "colour " + options_.colour_device + ": " + message};
      }
    }
    const std::int64_t colour_ns = pending_->stamp.nanoseconds();
    // Depth older than this colour frame's window can pair with no later one either.
    while (!depth_frames_.empty() && depth_frames_.front().stamp.nanoseconds() < colour_ns - tolerance_ns) {
      depth_frames_.pop_front();
      ++counters_.depth_unpaired;
    }
    std::size_t best = depth_frames_.size();
    std::int64_t best_dt = 0;
    for (std::size_t i = 0; i < depth_frames_.size(); ++i) {
      const std::int64_t dt = std::llabs(depth_frames_[i].stamp.nanoseconds() - colour_ns);
      if (dt <= tolerance_ns && (best == depth_frames_.size() || dt < best_dt)) {
        best = i;
        best_dt = dt;
      }
    }
    if (best < depth_frames_.size()) {
      deliver(*pending_, depth_frames_[best], frame);
      counters_.depth_unpaired += best;  // older ones in the window lose to the nearest
      depth_frames_.erase(depth_frames_.begin(), depth_frames_.begin() + best + 1);
      pending_.reset();
      return {SourceEvent::kFrame, ""};
    }
    if (!depth_frames_.empty())  // every remaining depth frame is past the window
      return unpaired("the nearest one is " + ms(depth_frames_.front().stamp.nanoseconds() - colour_ns) +
                      " later (tolerance " + ms(tolerance_ns) + ")");
    if (Clock::now() - pending_since_ >= stale_after)
      return unpaired("none arrived within " +
                      ms(std::chrono::duration_cast<std::chrono::nanoseconds>(stale_after).count()) +
                      " (depth stream stalled?)");
    if (Clock::now() >= until) return {SourceEvent::kTimeout, ""};
    // Wait for depth (at most until the frame goes stale or the call times out).
    const auto wait = std::min<Clock::duration>(until - Clock::now(), pending_since_ + stale_after - Clock::now());
    V4l2Frame d;
    std::string message;
    switch (depth_.next(d, std::chrono::ceil<std::chrono::milliseconds>(
                               std::max<Clock::duration>(wait, Clock::duration::zero())),
                        &message)) {
      case V4l2Event::kFrame: depth_frames_.push_back(std::move(d)); break;
      case V4l2Event::kTimeout: break;
      case V4l2Event::kGone: return {SourceEvent::kDeviceGone, "depth " + message};
      case V4l2Event::kError:
        ++counters_.corrupt;
        return {SourceEvent::kBadFrame, "depth " + options_.depth_device + ": " + message};
    }
  }
}

}  // namespace stillpoint::platform
