#pragma once
// Evaluation only: a live run's segmentation delay, modelled deterministically
// for sequential replays (semantic.sequential_latency_frames). A keyframe's
// segmentation starts when the modelled segmenter is free and its result is
// applied `latency_frames` frames later; keyframes made meanwhile wait in a
// drop-oldest queue of semantic.queue_capacity, as in threaded mode.
#include <cstdint>
#include <deque>
#include <functional>
#include <optional>

#include "semantic_worker.hpp"

namespace stillpoint::slam {

class ModelledSegmentationLatency {
 public:
  // Segments a job and applies its result to the map.
  using Apply = std::function<void(const SemanticJob&)>;

  ModelledSegmentationLatency(int latency_frames, int queue_capacity)
      : latency_frames_(latency_frames), queue_capacity_(queue_capacity) {}

  // A keyframe made at frame `frame_id`.
  void submit(SemanticJob job, std::int64_t frame_id) {
    if (!running_) {
      running_ = std::move(job);
      due_ = frame_id + latency_frames_;
      return;
    }
    while (static_cast<int>(waiting_.size()) >= queue_capacity_) {
      waiting_.pop_front();
      ++dropped_;
    }
    waiting_.push_back(std::move(job));
  }
  // Applies every segmentation due by frame `frame_id`, and starts the next
  // waiting keyframe's as each finishes.
  void advance(std::int64_t frame_id, const Apply& apply) {
    while (running_ && frame_id >= due_) {
      apply(*running_);
      running_.reset();
      if (!waiting_.empty()) {
        running_ = std::move(waiting_.front());
        waiting_.pop_front();
        due_ += latency_frames_;
      }
    }
  }
  // The end of the run: what is under way or waiting is applied now, or
  // dropped with `discard`.
  void finish(bool discard, const Apply& apply) {
    if (discard && running_) {
      dropped_ += 1 + static_cast<int>(waiting_.size());
      running_.reset();
      waiting_.clear();
    }
    while (running_) advance(due_, apply);
  }
  bool busy() const { return running_.has_value(); }
  int dropped() const { return dropped_; }

 private:
  int latency_frames_;
  int queue_capacity_;
  std::optional<SemanticJob> running_;
  std::int64_t due_ = 0;
  std::deque<SemanticJob> waiting_;
  int dropped_ = 0;
};

}  // namespace stillpoint::slam
