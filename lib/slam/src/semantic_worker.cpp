#include "semantic_worker.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <numeric>

#include "stillpoint/core/log.hpp"
#include "stillpoint/semantic/depth_agreement.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("semantic");
}

void buildRegions(const semantic::Segmentation& seg, int dilation_px, SemanticResult* out) {
  const cv::Size size = seg.movable_mask.size();
  out->labels = cv::Mat(size, CV_8U, cv::Scalar(0));
  out->regions.clear();
  std::vector<const semantic::Instance*> kept;
  for (const semantic::Instance& inst : seg.instances)
    if (inst.movable && inst.kept && inst.area > 0 && !inst.mask.empty()) kept.push_back(&inst);
  // Ascending score: where dilated masks overlap, the stronger instance paints last.
  std::stable_sort(kept.begin(), kept.end(), [](const auto* a, const auto* b) { return a->score < b->score; });
  if (kept.size() > 254) kept.erase(kept.begin(), kept.end() - 254);
  const cv::Mat kernel = dilation_px > 0 ? cv::getStructuringElement(cv::MORPH_ELLIPSE,
                                                                     cv::Size(2 * dilation_px + 1, 2 * dilation_px + 1))
                                         : cv::Mat();
  const cv::Rect image(cv::Point(0, 0), size);
  for (const semantic::Instance* inst : kept) {
    const cv::Rect box = inst->box & image;
    if (box.empty() || box.size() != inst->mask.size()) continue;
    // Dilate inside a box grown by the dilation radius.
    const cv::Rect grown =
        cv::Rect(box.x - dilation_px, box.y - dilation_px, box.width + 2 * dilation_px, box.height + 2 * dilation_px) &
        image;
    cv::Mat local(grown.size(), CV_8U, cv::Scalar(0));
    inst->mask.copyTo(local(box - grown.tl()));
    if (dilation_px > 0) cv::dilate(local, local, kernel);
    const int label = static_cast<int>(out->regions.size()) + 1;
    out->labels(grown).setTo(label, local);
    out->regions.push_back({inst->class_name, inst->score, cv::countNonZero(local)});
  }
}

SemanticWorker::SemanticWorker(std::unique_ptr<semantic::Segmenter> segmenter, const SemanticOptions& options,
                               Sink sink)
    : segmenter_(std::move(segmenter)), options_(options), sink_(std::move(sink)) {}

SemanticWorker::~SemanticWorker() { finish(); }

SemanticResult SemanticWorker::process(const SemanticJob& job) {
  const auto t0 = std::chrono::steady_clock::now();
  SemanticResult out;
  out.keyframe_id = job.keyframe_id;
  out.created = job.created;
  auto seg = segmenter_->segment(job.bgr);
  if (!seg) {
    out.error = seg.error();
  } else if (seg->movable_mask.size() != job.bgr.size()) {
    out.error = "segmenter returned a mask of another size than the keyframe";
  } else {
    if (options_.depth_agreement && !job.depth_m.empty()) {
      if (auto agreed = semantic::applyDepthAgreement(job.depth_m, {}, &*seg); !agreed)
        SP_DEBUG(logger, "keyframe " << job.keyframe_id << ": depth agreement: " << agreed.error());
    }
    buildRegions(*seg, options_.mask_dilation_px, &out);
    out.ok = true;
  }
  out.segment_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

void SemanticWorker::start(std::function<void()> on_thread_start) {
  worker_ = std::jthread([this, hook = std::move(on_thread_start)](std::stop_token stop) {
    if (hook) hook();
    run(stop);
  });
}

void SemanticWorker::submit(SemanticJob job) {
  {
    std::lock_guard lock(mutex_);
    if (closed_) return;
    while (static_cast<int>(queue_.size()) >= options_.queue_capacity) {
      SP_DEBUG(logger, "queue full: keyframe " << queue_.front().keyframe_id << " stays unsegmented");
      queue_.pop_front();
      ++dropped_;
    }
    queue_.push_back(std::move(job));
  }
  cv_.notify_all();
}

int SemanticWorker::dropped() const {
  std::lock_guard lock(mutex_);
  return dropped_;
}

void SemanticWorker::run(std::stop_token stop) {
  while (true) {
    SemanticJob job;
    {
      std::unique_lock lock(mutex_);
      cv_.wait(lock, [&] { return !queue_.empty() || closed_ || stop.stop_requested(); });
      if (queue_.empty()) return;  // closed and drained
      job = std::move(queue_.front());
      queue_.pop_front();
    }
    sink_(process(job));
  }
}

void SemanticWorker::finish(bool discard_queued) {
  {
    std::lock_guard lock(mutex_);
    closed_ = true;
    if (discard_queued) {
      dropped_ += static_cast<int>(queue_.size());
      queue_.clear();
    }
  }
  cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

}  // namespace stillpoint::slam
