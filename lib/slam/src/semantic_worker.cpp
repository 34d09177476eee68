#include "semantic_worker.hpp"

#include "stillpoint/semantic/person_second_opinion.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <numeric>

#include "stillpoint/core/log.hpp"
#include "stillpoint/semantic/depth_agreement.hpp"

namespace stillpoint::slam {
namespace {
log::Logger logger("semantic");

// Box IoU a detection of another class needs to continue a track.
constexpr double kOtherClassIou = 0.6;

double boxIou(const cv::Rect& a, const cv::Rect& b) {
  const double inter = (a & b).area();
  const double uni = double(a.area()) + double(b.area()) - inter;
  return uni > 0 ? inter / uni : 0.0;
}
}  // namespace

int continueTracks(const SemanticOptions& options, double strong_score, semantic::Segmentation* seg,
                   std::vector<SemanticTrack>* tracks) {
  std::vector<semantic::Instance>& insts = seg->instances;
  const std::size_t n = insts.size();
  const double weak_score = options.track_score_ratio * strong_score;
  // Strong: what the segmenter keeps at the card's own threshold. Kept
  // instances below it (the decoder ran at the lower continuation score) wait
  // for a track.
  std::vector<char> strong(n, 0), used(n, 0);
  for (std::size_t i = 0; i < n; ++i) {
    semantic::Instance& inst = insts[i];
    if (!inst.movable || !inst.kept || inst.area == 0) continue;
    if (inst.score >= strong_score) {
      strong[i] = 1;
    } else {
      inst.kept = false;
      inst.drop_reason = "score";
    }
  }
  std::vector<SemanticTrack> next;
  int continued = 0;
  std::vector<int> hits(n, 1);  // of the strong instances' tracks
  for (const SemanticTrack& track : *tracks) {
    bool seen = false;  // a strong instance continues it
    for (std::size_t i = 0; i < n; ++i)
      if (strong[i] && insts[i].class_id == track.class_id && boxIou(insts[i].box, track.box) >= options.track_iou) {
        hits[i] = std::max(hits[i], track.hits + 1);
        seen = true;
      }
    // A one-off detection (a false positive, often) is not carried on.
    if (seen || track.weak_keyframes >= options.track_max_keyframes || track.hits < options.track_min_hits) continue;
    int best = -1;
    double best_iou = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const semantic::Instance& inst = insts[i];
      if (strong[i] || used[i] || inst.area == 0 || inst.mask.empty() || inst.score < weak_score) continue;
      if (inst.drop_reason == "area") continue;
      const bool same_class = inst.movable && inst.class_id == track.class_id;
      if (!same_class && !options.track_any_class) continue;
      // Another label must sit on the track's box itself: a larger object
      // behind the track (the teddy bear behind the person) overlaps it by
      // less.
      const double min_iou = same_class ? options.track_iou : std::max(options.track_iou, kOtherClassIou);
      const double iou = boxIou(inst.box, track.box);
      if (iou >= min_iou && iou > best_iou) {
        best = static_cast<int>(i);
        best_iou = iou;
      }
    }
    if (best < 0) continue;
    semantic::Instance& inst = insts[best];
    used[best] = 1;
    SP_DEBUG(logger, "track '" << track.class_name << "' continued by '" << inst.class_name << "' " << inst.score
                               << " (box IoU " << best_iou << ", " << track.weak_keyframes + 1 << " weak in a row)");
    if (inst.class_id != track.class_id) {
      inst.class_name = track.class_name + " (seen as " + inst.class_name + ")";
      inst.class_id = track.class_id;
    }
    inst.movable = true;
    inst.kept = true;
    inst.continued = true;
    inst.second_opinion = inst.second_opinion || track.second_opinion;
    inst.drop_reason.clear();
    next.push_back(
        {inst.box, track.class_id, track.class_name, track.weak_keyframes + 1, track.hits, inst.second_opinion});
    ++continued;
  }
  for (std::size_t i = 0; i < n; ++i)
    if (strong[i])
      next.push_back({insts[i].box, insts[i].class_id, insts[i].class_name, 0, hits[i], insts[i].second_opinion});
  seg->movable_mask.setTo(0);
  for (const semantic::Instance& inst : insts)
    if (inst.movable && inst.kept && inst.area > 0 && !inst.mask.empty()) seg->movable_mask(inst.box).setTo(255, inst.mask);
  seg->movable_pixels = cv::countNonZero(seg->movable_mask);
  *tracks = std::move(next);
  return continued;
}

void buildRegions(const semantic::Segmentation& seg, int dilation_px, double static_min_score, SemanticResult* out) {
  const cv::Size size = seg.movable_mask.size();
  out->labels = cv::Mat(size, CV_8U, cv::Scalar(0));
  out->static_mask = cv::Mat(size, CV_8U, cv::Scalar(0));
  out->regions.clear();
  const cv::Rect whole(cv::Point(0, 0), size);
  for (const semantic::Instance& inst : seg.instances) {
    if (inst.movable || inst.score < static_min_score || inst.area == 0 || inst.mask.empty()) continue;
    const cv::Rect box = inst.box & whole;
    if (box.empty() || box.size() != inst.mask.size()) continue;
    out->static_mask(box).setTo(255, inst.mask);
  }
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
    out->regions.push_back(
        {inst->class_name, inst->score, cv::countNonZero(local), inst->continued, inst->second_opinion});
  }
}

SemanticWorker::SemanticWorker(std::unique_ptr<semantic::Segmenter> segmenter, const SemanticOptions& options,
                               Sink sink)
    : segmenter_(std::move(segmenter)), options_(options), sink_(std::move(sink)) {}

SemanticWorker::~SemanticWorker() { finish(); }

Status SemanticWorker::setPersonModel(std::unique_ptr<semantic::Segmenter> person) {
  int id = -1;
  if (person) {
    auto checked = semantic::secondOpinionPersonId(segmenter_->card(), person->card());
    if (!checked) return Error{checked.error()};
    id = *checked;
  }
  std::lock_guard lock(process_mutex_);
  person_ = std::move(person);
  person_id_ = id;
  return Status::success();
}

SemanticResult SemanticWorker::process(const SemanticJob& job) {
  std::lock_guard lock(process_mutex_);
  const auto t0 = std::chrono::steady_clock::now();
  SemanticResult out;
  out.keyframe_id = job.keyframe_id;
  out.frame_id = job.frame_id;
  out.created = job.created;
  auto seg = segmenter_->segment(job.bgr);
  if (!seg) {
    out.error = seg.error();
  } else if (seg->movable_mask.size() != job.bgr.size()) {
    out.error = "segmenter returned a mask of another size than the keyframe";
  } else {
    if (job.map_start && person_) {
      // Where a map starts the geometry module has seen nothing move yet,
      // and a person the main model misses would go into the map.
      if (auto people = person_->segment(job.bgr); people) {
        const int added = semantic::joinPersonSecondOpinion(*people, person_id_, {}, &*seg);
        if (added > 0) SP_DEBUG(logger, "map start: the person model adds " << added << " regions");
      } else {
        SP_WARN(logger, "map start: person model '" << person_->card().name << "': " << people.error());
      }
    }
    if (options_.track_score_ratio > 0) {
      const semantic::ModelCard& card = segmenter_->card();
      const double strong = card.decoder.type == semantic::DecoderType::kYoloInstance ? card.decoder.score_threshold : 0.0;
      continueTracks(options_, strong, &*seg, &tracks_);
    }
    if (options_.depth_agreement && !job.depth_m.empty()) {
      if (auto agreed = semantic::applyDepthAgreement(job.depth_m, {}, &*seg); !agreed)
        SP_DEBUG(logger, "keyframe " << job.keyframe_id << ": depth agreement: " << agreed.error());
    }
    buildRegions(*seg, options_.mask_dilation_px, options_.static_memory_score, &out);
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

namespace {
// The value of a CV_8U image at pixel `px`, clamped to the image; 0 when empty.
int valueAt(const cv::Mat& image, const cv::Point2f& px) {
  if (image.empty()) return 0;
  const int x = std::clamp(cvRound(px.x), 0, image.cols - 1), y = std::clamp(cvRound(px.y), 0, image.rows - 1);
  return image.at<std::uint8_t>(y, x);
}
}  // namespace

int regionAt(const SemanticResult& r, const cv::Point2f& px) {
  const int label = valueAt(r.labels, px);
  return label <= static_cast<int>(r.regions.size()) ? label : 0;
}

bool onStaticObject(const SemanticResult& r, const cv::Point2f& px) { return valueAt(r.static_mask, px) != 0; }

bool SemanticWorker::idle() const {
  std::lock_guard lock(mutex_);
  return queue_.empty() && !segmenting_;
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
      segmenting_ = true;
    }
    SemanticResult result = process(job);
    sink_(std::move(result));
    std::lock_guard lock(mutex_);
    segmenting_ = false;
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
