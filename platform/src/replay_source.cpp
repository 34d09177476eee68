#include "stillpoint/platform/replay_source.hpp"

#include <thread>

#include "stillpoint/core/log.hpp"

namespace stillpoint::platform {
namespace {
log::Logger logger("replay");
}  // namespace

const char* toString(SourceEvent event) {
  switch (event) {
    case SourceEvent::kFrame: return "frame";
    case SourceEvent::kTimeout: return "timeout";
    case SourceEvent::kEnd: return "end";
    case SourceEvent::kBadFrame: return "bad frame";
    case SourceEvent::kDeviceGone: return "device gone";
  }
  return "?";
}

Status ReplaySourceOptions::validate() const {
  if (path.empty()) return Error{"source.replay.path: must name a TUM-layout folder"};
  return {};
}

ReplaySource::ReplaySource(ReplaySourceOptions options, CameraModel camera)
    : options_(std::move(options)), camera_(std::move(camera)) {}

std::string ReplaySource::describe() const {
  return "replay " + options_.path + (options_.paced ? " (paced)" : " (as fast as possible)");
}

Status ReplaySource::open() {
  if (Status s = options_.validate(); !s) return s;
  dataset::DatasetOptions dataset_options;
  dataset_options.expected_width = camera_.width;
  dataset_options.expected_height = camera_.height;
  dataset_options.depth_factor = camera_.depth_factor;
  auto data = dataset::TumDataset::open(options_.path, dataset_options);
  if (!data) return Error{data.error()};
  if (data->size() == 0) return Error{"replay '" + options_.path + "': no colour/depth pairs"};
  data_.emplace(std::move(*data));
  index_ = 0;
  delivered_ = 0;
  loop_offset_ns_ = 0;
  started_ = false;
  return {};
}

void ReplaySource::close() { data_.reset(); }

SourceResult ReplaySource::next(CameraFrame& frame, std::chrono::milliseconds timeout) {
  if (!data_) return {SourceEvent::kEnd, "not open"};
  if (options_.max_frames > 0 && delivered_ >= options_.max_frames) return {SourceEvent::kEnd, ""};
  if (index_ >= data_->size()) {
    if (!options_.loop) return {SourceEvent::kEnd, ""};
    // Keep stamps increasing across the wrap: one nominal frame period after
    // the last one. The span comes from the list, so an unreadable first or
    // last frame does not shrink it (each lap's stamps would jump back).
    const std::int64_t span = data_->stamp(data_->size() - 1).nanoseconds() - data_->stamp(0).nanoseconds();
    loop_offset_ns_ += span + 33'333'333;
    index_ = 0;
  }
  dataset::SkipReason reason;
  auto loaded = data_->load(index_, &reason);
  // The stamp is known from the list even when the images are bad; pace by it.
  const std::size_t i = index_++;
  if (!loaded) return {SourceEvent::kBadFrame, "frame " + std::to_string(i) + ": " + loaded.error()};
  const std::int64_t stamp_ns = loaded->stamp.nanoseconds() + loop_offset_ns_;
  if (!started_ || (options_.paced && stamp_ns - last_stamp_ns_ > kMaxPacedGapNs)) {
    if (started_)
      SP_WARN(logger, "replay " << options_.path << ": a gap of " << (stamp_ns - last_stamp_ns_) / 1e9
                                << " s in the stamps before frame " << i << " is not waited for");
    started_ = true;
    first_stamp_ns_ = stamp_ns;
    start_ = std::chrono::steady_clock::now();
  }
  if (options_.paced) {
    const auto due = start_ + std::chrono::nanoseconds(stamp_ns - first_stamp_ns_);
    const auto limit = std::chrono::steady_clock::now() + timeout;
    if (due > limit) {
      // Not due within this call: hand the frame back next time.
      --index_;
      std::this_thread::sleep_until(limit);
      return {SourceEvent::kTimeout, ""};
    }
    std::this_thread::sleep_until(due);
  }
  last_stamp_ns_ = stamp_ns;
  frame.stamp = Timestamp::fromNanoseconds(stamp_ns);
  frame.gray = std::move(loaded->gray);
  frame.depth_m = std::move(loaded->depth_m);
  if (options_.colour) frame.bgr = std::move(loaded->bgr);
  else frame.bgr.release();
  frame.sequence = delivered_++;
  frame.arrival = std::chrono::steady_clock::now();
  return {SourceEvent::kFrame, ""};
}

}  // namespace stillpoint::platform
