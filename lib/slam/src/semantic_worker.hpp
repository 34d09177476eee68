#pragma once
// The semantic module's worker: segments keyframes (only keyframes) in its own
// thread and hands each result to a sink (local mapping's mailbox, which
// applies it under the map's exclusive lock). Tracking never waits for it.
//
// Queue: bounded (SemanticOptions::queue_capacity), drop-oldest. When a new
// keyframe arrives and the queue is full, the oldest waiting keyframe is left
// unsegmented (counted): the newest keyframes are the ones tracking matches
// against, and a live camera cannot wait. process() runs one job on the
// calling thread (sequential mode, tests).
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "stillpoint/semantic/segmenter.hpp"
#include "stillpoint/slam/options.hpp"

namespace stillpoint::slam {

using SteadyTime = std::chrono::steady_clock::time_point;

struct SemanticJob {
  std::int64_t keyframe_id = -1;
  cv::Mat bgr;      // CV_8UC3, owned by the job
  cv::Mat depth_m;  // CV_32FC1 or empty (depth agreement skipped)
  SteadyTime created;
  // A frame segmented where no keyframe is made (localisation, a place a
  // loaded map holds): its id, with keyframe_id -1. Its result goes to
  // tracking, not to the map.
  std::int64_t frame_id = -1;
  // The frame a map is about to start from (SlamSystem's map start): the
  // person model beside the main one is consulted too (setPersonModel).
  bool map_start = false;
};

// One kept movable instance, dilated, as a region of the label image.
struct SemanticRegion {
  std::string class_name;
  float score = 0;
  int pixels = 0;
  bool continued = false;  // kept only as the continuation of a track (hysteresis)
  // Found by the person model beside the main one where a map starts
  // (SemanticWorker::setPersonModel): its features make points on a mover's
  // probation there, and it never keeps anything out of a keyframe.
  bool second_opinion = false;
};

struct SemanticResult {
  std::int64_t keyframe_id = -1;
  std::int64_t frame_id = -1;  // SemanticJob::frame_id
  bool ok = false;
  std::string error;
  // CV_8U, image size: 0 = no movable object, k = regions[k - 1]. Where
  // dilated instances overlap, the higher-scoring one wins.
  cv::Mat labels;
  std::vector<SemanticRegion> regions;
  // CV_8U 0/255, image size: the pixels of confident instances of static
  // classes (a teddy bear, a chair), undilated: the map remembers which of its
  // points were seen on them (MapPoint::Semantic::static_hits).
  cv::Mat static_mask;
  double segment_ms = 0;  // segment() + depth agreement + dilation
  SteadyTime created;
};

// A movable instance followed from keyframe to keyframe (detector hysteresis).
struct SemanticTrack {
  cv::Rect box;
  int class_id = -1;
  std::string class_name;
  int weak_keyframes = 0;  // keyframes in a row continued by weak evidence only
  int hits = 1;            // keyframes with a strong detection of it
  bool second_opinion = false;  // started by the person model beside the main one: its continuations too
};

// Detector hysteresis (SemanticOptions::track_*): drops the kept movable
// instances below `strong_score` except those that continue one of `tracks`
// (box IoU >= track_iou; same class, or any class with track_any_class; at
// least track_score_ratio x strong_score; a track seen strong in at least
// track_min_hits keyframes), keeps the weaker continuations the
// post-filter dropped, rebuilds movable_mask, and replaces `tracks` by this
// keyframe's kept instances. Returns how many instances were continued.
int continueTracks(const SemanticOptions& options, double strong_score, semantic::Segmentation* seg,
                   std::vector<SemanticTrack>* tracks);

class SemanticWorker {
 public:
  using Sink = std::function<void(SemanticResult)>;
  SemanticWorker(std::unique_ptr<semantic::Segmenter> segmenter, const SemanticOptions& options, Sink sink);
  ~SemanticWorker();
  SemanticWorker(const SemanticWorker&) = delete;
  SemanticWorker& operator=(const SemanticWorker&) = delete;

  const semantic::ModelCard& card() const { return segmenter_->card(); }

  // A person model consulted beside the main one for map-start jobs
  // (SemanticJob::map_start, semantic::ModelCard::person_model): the people it
  // finds that the main model does not explain join the result as regions
  // marked second_opinion. Errors: semantic::secondOpinionPersonId's.
  Status setPersonModel(std::unique_ptr<semantic::Segmenter> person);

  // Segments one keyframe on the calling thread (no queue, no sink); calls
  // from several threads take turns.
  SemanticResult process(const SemanticJob& job);

  // Threaded use.
  void start(std::function<void()> on_thread_start = {});  // runs first on the worker thread
  void submit(SemanticJob job);  // never blocks; drop-oldest when full
  // Segments what is queued (or drops it, counted as dropped), then joins.
  void finish(bool discard_queued = false);
  int dropped() const;
  // Nothing queued and nothing being segmented.
  bool idle() const;

 private:
  void run(std::stop_token stop);

  std::unique_ptr<semantic::Segmenter> segmenter_;
  std::unique_ptr<semantic::Segmenter> person_;  // may be null
  int person_id_ = -1;                             // the main card's "person"
  SemanticOptions options_;
  std::mutex process_mutex_;  // one process() at a time: the network and tracks_
  std::vector<SemanticTrack> tracks_;
  Sink sink_;
  mutable std::mutex mutex_;
  std::condition_variable_any cv_;
  std::deque<SemanticJob> queue_;
  bool closed_ = false;
  bool segmenting_ = false;
  int dropped_ = 0;
  std::jthread worker_;
};

// The region (1-based index into r.regions) whose label covers pixel `px`
// (clamped to the image), 0 for none.
int regionAt(const SemanticResult& r, const cv::Point2f& px);
// Whether pixel `px` (clamped to the image) lies on r.static_mask.
bool onStaticObject(const SemanticResult& r, const cv::Point2f& px);

// Builds the region label image from a segmentation: kept movable instances,
// each dilated by `dilation_px`, painted in ascending score order; and the
// static mask from the instances of static classes scoring at least
// `static_min_score`.
void buildRegions(const semantic::Segmentation& seg, int dilation_px, double static_min_score, SemanticResult* out);

}  // namespace stillpoint::slam
