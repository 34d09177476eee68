#include "stillpoint/slam/system.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <filesystem>
#include <mutex>
#include <optional>
#include <tuple>
#include <unordered_set>

#include "frame.hpp"
#include "local_mapping.hpp"
#include "loop_closing.hpp"
#include "map.hpp"
#include "map_io.hpp"
#include "segmentation_latency.hpp"
#include "semantic_worker.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/semantic/segmenter.hpp"
#include "tracking.hpp"

namespace stillpoint::slam {
namespace {

// Flags the features of `frame` inside the movable regions of `r` as the
// semantic module does, with their class. Not when that would leave out more
// than `max_fraction` of the features (the module's own cap for masks
// nothing confirms). Features of a person model's regions beside the main
// one are suspects too (Frame::suspect): they make points on probation.
// Returns whether it flagged any.
bool markMovable(Frame* frame, const SemanticResult& r, Map& map, double max_fraction) {
  std::vector<std::pair<int, int>> inside;  // feature, region
  for (int i = 0; i < frame->size(); ++i)
    if (const int label = regionAt(r, frame->keys[i].pt)) inside.emplace_back(i, label);
  if (inside.empty() || inside.size() > max_fraction * frame->size()) return false;
  frame->movable_class.resize(frame->size(), 0);
  for (const auto& [i, label] : inside) {
    const SemanticRegion& region = r.regions[label - 1];
    if (region.second_opinion) {
      frame->suspect.resize(frame->size(), 0);
      frame->suspect[i] = 1;
    }
    frame->dynamic[i] = kSemanticDynamic;
    frame->movable_class[i] = map.classId(region.class_name);
  }
  return true;
}
log::Logger logger("slam");

// Share of the depth image's pixels with a usable depth (as buildFrame takes
// them), from every 4th pixel of every 4th row; 0 for no image.
double depthShare(const cv::Mat& depth_m, const CameraModel& cam) {
  if (depth_m.empty()) return 0.0;
  std::size_t valid = 0, samples = 0;
  for (int y = 0; y < depth_m.rows; y += 4) {
    const float* row = depth_m.ptr<float>(y);
    for (int x = 0; x < depth_m.cols; x += 4, ++samples) valid += row[x] > cam.min_depth && row[x] < cam.max_depth;
  }
  return samples ? static_cast<double>(valid) / samples : 0.0;
}

constexpr const char* kDefaultVocabulary = "orb_words_10x4_tum.vocab";

std::pair<double, double> medianP95(std::vector<double> v) {
  if (v.empty()) return {0.0, 0.0};
  std::sort(v.begin(), v.end());
  const double median = v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  const std::size_t i95 = std::min(v.size() - 1, static_cast<std::size_t>(std::ceil(0.95 * v.size())) - 1);
  return {median, v[i95]};
}

// A model card named in the options (`field`): a relative path that does not
// exist is looked up in the project's models/ folder; the model file is looked
// up in model_dirs and $STILLPOINT_MODEL_DIR before the card's own folder.
Result<semantic::ResolvedModel> resolveCard(const std::string& path, const std::vector<std::string>& model_dirs,
                                            const char* field) {
  namespace fs = std::filesystem;
  std::vector<fs::path> dirs(model_dirs.begin(), model_dirs.end());
  std::error_code ec;
  fs::path card_path = path;
  if (card_path.is_relative() && !fs::exists(card_path, ec) && fs::exists(semantic::defaultModelCardDir() / card_path, ec))
    card_path = semantic::defaultModelCardDir() / card_path;
  auto card = semantic::loadModelCard(card_path);
  if (!card) return Error{std::string(field) + ": " + card.error()};
  if (const char* env = std::getenv("STILLPOINT_MODEL_DIR"); env && *env) dirs.emplace_back(env);
  for (const fs::path& d : dirs) {
    const fs::path candidate = d / card->model_path.filename();
    if (fs::is_regular_file(candidate, ec)) {
      card->model_path = candidate;
      break;
    }
  }
  return semantic::ResolvedModel{*card, "card " + card_path.string()};
}

// The main model card the options ask for: a named one, or the recommended one.
Result<semantic::ResolvedModel> resolveModel(const SemanticOptions& o) {
  if (o.model_card.empty()) {
    const std::vector<std::filesystem::path> dirs(o.model_dirs.begin(), o.model_dirs.end());
    return semantic::resolveRecommendedModel({.card_dir = {}, .model_dirs = dirs});
  }
  return resolveCard(o.model_card, o.model_dirs, "semantic.model_card");
}
}  // namespace

// Beside the model cards: models/ in the source tree, else the installed copy.
std::string defaultVocabularyPath() { return (semantic::defaultModelCardDir() / kDefaultVocabulary).string(); }

const char* toString(TrackingState state) {
  switch (state) {
    case TrackingState::kInitialising: return "initialising";
    case TrackingState::kOk: return "ok";
    case TrackingState::kLost: return "lost";
    case TrackingState::kRelocalised: return "relocalised";
    case TrackingState::kNoDepth: return "no_depth";
    case TrackingState::kNewMap: return "new_map";
  }
  return "?";
}

const char* toString(FeatureFate fate) {
  switch (fate) {
    case FeatureFate::kInPose: return "in the pose";
    case FeatureFate::kGeometryDynamic: return "dynamic (geometry)";
    case FeatureFate::kSemanticDynamic: return "dynamic (semantic)";
    case FeatureFate::kNoDepth: return "no depth";
    case FeatureFate::kUnused: return "unmatched";
  }
  return "?";
}

struct SlamSystem::Impl {
  Impl(const CameraModel& cam, const SlamOptions& opts)
      : camera(cam),
        options(opts),
        orb(opts.orb),
        levels(LevelInfo::from(orb)),
        clustering(opts.geometry.enabled ? std::make_unique<geometry::ClusteringWorker>(
                                               cam, opts.geometry.clustering, !opts.sequential)
                                         : nullptr),
        tracker(camera, options, levels, &map, clustering.get()),
        mapper(options, options.tracking.close_depth_baselines * camera.baseline, &map) {}

  CameraModel camera;
  SlamOptions options;
  features::OrbExtractor orb;
  LevelInfo levels;
  Map map;
  std::unique_ptr<geometry::ClusteringWorker> clustering;
  std::unique_ptr<features::Vocabulary> vocabulary;
  std::string vocabulary_path;
  // Before the mapper, which hands it keyframes: destroyed after it.
  std::unique_ptr<LoopCloser> loops;
  Tracker tracker;
  LocalMapper mapper;
  // After the mapper: its results go into the mapper's mailbox, so it is
  // stopped (and destroyed) first.
  std::unique_ptr<SemanticWorker> semantic;
  std::string semantic_model;
  std::atomic<int> semantic_no_colour{0};
  std::atomic<std::size_t> no_depth_frames{0};
  std::optional<Timestamp> last_stamp;  // of the last frame track() took (the tracking thread's)
  // The last frame made a keyframe in a young map (MappingOptions::young_map_keyframes):
  // local mapping finishes it before the next frame is tracked.
  bool young_map_wait = false;
  // A map seen to hold more keyframes than that is not counted again: culling
  // may take it back under the count, but it is no longer young.
  std::optional<std::uint32_t> grown_map;
  std::atomic<int> young_map_waits{0};
  std::atomic<double> young_map_wait_ms{0};
  log::RateLimiter no_colour_warning{std::chrono::seconds(10)};
  log::RateLimiter old_masks_warning{std::chrono::seconds(60)};
  bool finished = false;
  bool tracked_any = false;  // a frame reached tracking (no map can be loaded then)

  // Sequential mode with semantic.sequential_latency_frames (evaluation).
  ModelledSegmentationLatency latency{options.semantic.sequential_latency_frames, options.semantic.queue_capacity};
  void applySegmentation(const SemanticJob& job) {
    SemanticResult r = semantic->process(job);
    if (r.frame_id >= 0) {
      applyFrameResult(r);
      return;
    }
    mapper.postSemantic(std::move(r));
    mapper.applySemanticResults();
  }
  // Segmentations of frames where no keyframe was made (SemanticJob::
  // frame_id), from the segmentation thread to tracking.
  std::mutex frame_masks_mutex;
  std::optional<SemanticResult> frame_masks;
  std::atomic<int> frames_segmented{0};
  void applyFrameResult(const SemanticResult& r) {
    frames_segmented += tracker.applyFrameMasks(r, mapper.semanticConfirmation());
  }
  void postFrameMasks(SemanticResult r) {
    std::lock_guard lock(frame_masks_mutex);
    frame_masks = std::move(r);
  }
  // Movers present where a map starts (the first, or a new one after a
  // loss): a live run, or one modelling the delay, segments the frame the
  // map is built from before it is built, so its points on movable objects
  // never exist and the next frames cannot track on them while the
  // segmentation would be under way. (A sequential run segments every
  // keyframe before the next frame anyway.) The result is then that
  // keyframe's: it is not segmented twice.
  const RgbdInput* input_now = nullptr;  // during tracker.track()
  std::optional<SemanticResult> map_start_masks;
  bool segmentMapStart(Frame* frame) {
    if (!semantic || segmentsInline() || !input_now || input_now->bgr.empty()) return false;
    SemanticJob job{-1, input_now->bgr.clone(), input_now->depth_m.empty() ? cv::Mat() : input_now->depth_m.clone(),
                    std::chrono::steady_clock::now()};
    job.map_start = true;
    SemanticResult r = semantic->process(job);
    if (!r.ok) return false;
    const bool flagged = markMovable(frame, r, map, 1.0);
    map_start_masks = std::move(r);
    return flagged;
  }
  // A frame that made no keyframe but came back to an older place of the
  // map than the newest keyframe, unconnected to it, is a loop no keyframe's
  // check would see (LoopCloser::crossingDue).
  void checkCrossing() {
    Frame frame;
    std::int64_t reference = -1, newest = -1;
    std::uint64_t epoch = 0;
    {
      std::shared_lock lock(map.mutex());
      const KeyFrame* r = tracker.referenceKeyFrame();
      if (!r || r->bad) return;
      newest = loops->crossingDue(*r, tracker.lastFrame().stamp);
      if (newest < 0) return;
      reference = r->id;
      epoch = map.epoch();
      frame = tracker.lastFrame();
    }
    frame.clearMatches();  // the check finds its own; the copy holds no map point
    features::BowVector words = tracker.staticWords(frame);
    if (options.sequential)
      loops->processCrossing(frame, words, reference, newest, epoch);
    else
      loops->enqueueCrossing(std::move(frame), std::move(words), reference, newest, epoch);
  }
  // A sequential run that does not model the segmentation's delay segments
  // each keyframe as it is made, before the next frame.
  bool segmentsInline() const { return options.sequential && options.semantic.sequential_latency_frames <= 0; }
  void applyFrameMasks() {
    std::optional<SemanticResult> r;
    {
      std::lock_guard lock(frame_masks_mutex);
      r.swap(frame_masks);
    }
    if (r) applyFrameResult(*r);
  }
};

SlamSystem::SlamSystem(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

SlamSystem::~SlamSystem() {
  if (!impl_) return;
  if (impl_->semantic) impl_->semantic->finish();
  impl_->mapper.finish();
  if (impl_->loops) impl_->loops->finish();
}

Result<SemanticModelChoice> checkSemanticModel(const SemanticOptions& options) {
  auto model = resolveModel(options);
  if (!model) return Error{model.error()};
  std::error_code ec;
  const semantic::ModelCard& card = model->card;
  if (!std::filesystem::is_regular_file(card.model_path, ec))
    return Error{"model file " + card.model_path.string() + " of card " + card.card_path.string() + " not found"};
  return SemanticModelChoice{card.card_path.string(), card.model_path.string(), card.name, model->reason};
}

Result<std::unique_ptr<SlamSystem>> SlamSystem::create(const CameraModel& camera, const SlamOptions& options,
                                                       const SlamThreadHooks& hooks) {
  if (!options.semantic.enabled) return create(camera, options, nullptr, hooks);
  if (Status s = options.validate(); !s) return Error{s.error()};
  // The model is loaded and checked (with a warm-up inference) now.
  auto model = resolveModel(options.semantic);
  if (!model) return Error{model.error()};
  semantic::SegmenterOptions so;
  so.threads = options.semantic.threads;
  so.device = options.semantic.device;
  so.movable_furniture = options.semantic.movable_furniture;
  so.min_region_fraction = options.semantic.min_region_fraction;
  so.min_region_confidence = options.semantic.min_region_confidence;
  so.static_overlap_iou = options.semantic.static_overlap_iou;
  // Hysteresis: the decoder keeps detections down to the continuation score;
  // the worker keeps those below the card's threshold only when they continue
  // a track.
  if (options.semantic.track_score_ratio > 0 && model->card.decoder.type == semantic::DecoderType::kYoloInstance)
    so.score_threshold = model->card.decoder.score_threshold * options.semantic.track_score_ratio;
  auto segmenter = semantic::createSegmenter(model->card, so);
  if (!segmenter) return Error{"semantic model '" + model->card.card_path.string() + "': " + segmenter.error()};
  // The person model the card names, consulted beside it where a map starts.
  std::unique_ptr<semantic::Segmenter> person;
  if (!model->card.person_model.empty()) {
    const std::string where = "semantic model '" + model->card.card_path.string() + "': person_model";
    auto person_model = resolveCard(model->card.person_model.string(), options.semantic.model_dirs, where.c_str());
    if (!person_model) return Error{person_model.error()};
    semantic::SegmenterOptions po;
    po.threads = options.semantic.threads;
    po.device = options.semantic.device;
    auto created = semantic::createSegmenter(person_model->card, po);
    if (!created) return Error{where + " '" + person_model->card.card_path.string() + "': " + created.error()};
    person = std::move(*created);
  }
  auto system = create(camera, options, std::move(*segmenter), hooks);
  if (!system) return system;
  Impl& s = *(*system)->impl_;
  s.semantic_model = model->card.name + " (" + model->reason + ")";
  if (person) {
    s.semantic_model += ", with " + person->card().name + " where a map starts";
    if (Status st = s.semantic->setPersonModel(std::move(person)); !st) return Error{st.error()};
  }
  return system;
}

Result<std::unique_ptr<SlamSystem>> SlamSystem::create(const CameraModel& camera, const SlamOptions& options,
                                                       std::unique_ptr<semantic::Segmenter> segmenter,
                                                       const SlamThreadHooks& hooks) {
  if (Status s = camera.validate(); !s) return Error{s.error()};
  if (Status s = options.validate(); !s) return Error{s.error()};
  if (Status s = options.orb.validateFor(camera.width, camera.height); !s) return Error{s.error()};
  if (segmenter && !options.semantic.enabled) return Error{"a segmenter was given but semantic.enabled is false"};
  if (!segmenter && options.semantic.enabled) return Error{"semantic.enabled is set but no segmenter was given"};
  auto system = std::unique_ptr<SlamSystem>(new SlamSystem(std::make_unique<Impl>(camera, options)));
  Impl& s = *system->impl_;
  {
    // Place recognition: a named vocabulary must load; without one named,
    // the shipped one is used when it is there.
    const bool named = !options.place.vocabulary.empty();
    const std::string path = named ? options.place.vocabulary : defaultVocabularyPath();
    auto vocabulary = features::Vocabulary::load(path);
    if (vocabulary) {
      s.vocabulary = std::make_unique<features::Vocabulary>(std::move(*vocabulary));
      s.vocabulary_path = path;
      s.tracker.setVocabulary(s.vocabulary.get());
    } else if (named) {
      return Error{"place.vocabulary: " + vocabulary.error()};
    } else {
      SP_WARN(logger, "no place-recognition vocabulary (" << vocabulary.error()
                                                          << "): relocalisation ranks keyframes by small views, loops "
                                                             "are not closed");
    }
  }
  if (s.vocabulary && options.place.loop_closing && !options.localisation) {
    s.loops = std::make_unique<LoopCloser>(options, s.camera, &s.map);
    if (!options.sequential) {
      s.loops->start();
      s.mapper.setKeyFrameDone([loops = s.loops.get()](std::int64_t id) { loops->enqueue(id); });
    }
  }
  if (segmenter) {
    const std::string& confirm = options.semantic.confirm_with_geometry;
    const bool required = confirm == "always" || (confirm == "card" && segmenter->card().confirm_with_geometry);
    s.mapper.setSemanticConfirmation(required);
    if (required && !options.geometry.enabled)
      SP_WARN(logger, "model '" << segmenter->card().name
                                << "' needs the geometry module's agreement (confirm_with_geometry) but the geometry "
                                   "module is off: its masks will remove nothing");
    s.semantic_model = segmenter->card().name;
    s.semantic = std::make_unique<SemanticWorker>(std::move(segmenter), options.semantic, [impl = &s](SemanticResult r) {
      if (r.frame_id >= 0)
        impl->postFrameMasks(std::move(r));
      else
        impl->mapper.postSemantic(std::move(r));
    });
    if (!options.sequential) s.semantic->start(hooks.semantic_start);
    s.tracker.setMapStartMasks([impl = &s](Frame* frame) { return impl->segmentMapStart(frame); });
  }
  if (!options.sequential) s.mapper.start();
  return system;
}

Result<TrackOutput> SlamSystem::track(const RgbdInput& input) {
  // Bad input is checked up front; what a library call still throws on
  // input it did not foresee becomes an error, never a crash.
  try {
    return trackChecked(input);
  } catch (const std::exception& e) {
    return Error{std::string("tracking failed: ") + e.what()};
  }
}

Result<TrackOutput> SlamSystem::trackChecked(const RgbdInput& input) {
  Impl& s = *impl_;
  if (s.finished) return Error{"track() called after finish()"};
  if (s.options.localisation && s.map.mapsStarted() == 0)
    return Error{"localisation needs a loaded map (SlamSystem::loadMap) to track against"};
  const cv::Size expected(s.camera.width, s.camera.height);
  if (input.gray.empty()) return Error{"grey image is empty"};
  if (input.gray.type() != CV_8UC1) return Error{"grey image must be 8-bit single channel"};
  if (input.gray.size() != expected)
    return Error{"grey image is " + std::to_string(input.gray.cols) + "x" + std::to_string(input.gray.rows) +
                 ", camera expects " + std::to_string(expected.width) + "x" + std::to_string(expected.height)};
  if (!input.depth_m.empty()) {
    if (input.depth_m.type() != CV_32FC1) return Error{"depth image must be CV_32FC1 metres"};
    if (input.depth_m.size() != expected) return Error{"depth image size differs from the camera's"};
  }
  if (!input.bgr.empty()) {
    if (input.bgr.type() != CV_8UC3) return Error{"colour image must be CV_8UC3 (BGR)"};
    if (input.bgr.size() != expected) return Error{"colour image size differs from the camera's"};
  }
  if (!input.movers.empty()) {
    if (input.movers.type() != CV_8UC1 && input.movers.type() != CV_16UC1)
      return Error{"movers mask must be CV_8UC1 or CV_16UC1"};
    if (input.movers.size() != expected) return Error{"movers mask size differs from the camera's"};
  }

  // Time runs forward: the motion model, the lost-for timer and the
  // trajectory's order all rest on it.
  if (s.last_stamp && input.stamp <= *s.last_stamp)
    return Error{"frame stamped " + input.stamp.toSecondsString() + " s, not after the last frame's (" +
                 s.last_stamp->toSecondsString() + " s)"};
  s.last_stamp = input.stamp;

  const auto t0 = std::chrono::steady_clock::now();
  if (depthShare(input.depth_m, s.camera) < s.options.tracking.min_depth_share) {
    // A covered or blinded camera: no pose, said so, never the last state.
    ++s.no_depth_frames;
    s.tracker.noDepth(input.stamp);
    TrackOutput out;
    out.state = TrackingState::kNoDepth;
    out.map_id = s.tracker.mapId();
    out.track_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    std::shared_lock lock(s.map.mutex());
    out.keyframes = s.map.goodKeyFrameCount();
    return out;
  }
  Frame frame;
  frame.id = s.map.nextFrameId();
  frame.stamp = input.stamp;
  frame.camera = &s.camera;
  frame.levels = &s.levels;
  // Clustering runs in its own thread while features are extracted; the
  // worker gets its own copy (the caller may reuse its buffer after track(),
  // and the tracker keeps it for geometry.anchor_frames frames).
  const bool clusters_pending = s.clustering && !input.depth_m.empty();
  if (clusters_pending) s.clustering->submit(frame.id, input.depth_m.clone());
  buildFrame(&frame, input.gray, input.depth_m, &s.orb, s.tracker.moverCells(), s.options.tracking.mover_cells_every);
  if (!input.movers.empty()) markKnownMovers(&frame, input.movers);
  frame.thumbnail = viewThumbnail(input.gray);
  if (!input.bgr.empty()) {
    frame.colour.resize(frame.keys.size());
    for (int i = 0; i < frame.size(); ++i)
      frame.colour[i] = input.bgr.at<cv::Vec3b>(std::clamp(cvRound(frame.keys[i].pt.y), 0, input.bgr.rows - 1),
                                                std::clamp(cvRound(frame.keys[i].pt.x), 0, input.bgr.cols - 1));
  }
  // The tracker keeps it for geometry.freespace_frames frames.
  if (clusters_pending && s.options.geometry.photo_release_ncc > 0) frame.gray = input.gray.clone();
  const bool modelled_delay = s.options.sequential && s.options.semantic.sequential_latency_frames > 0;
  const auto t1 = std::chrono::steady_clock::now();

  if (s.latency.busy()) s.latency.advance(frame.id, [&s](const SemanticJob& job) { s.applySegmentation(job); });
  if (s.semantic) s.applyFrameMasks();
  TrackOutput out;
  if (s.young_map_wait) {
    // Features are extracted meanwhile.
    s.young_map_wait = false;
    const auto wait_from = std::chrono::steady_clock::now();
    s.mapper.waitIdle(std::chrono::duration<double, std::milli>(s.options.mapping.young_map_wait_ms));
    out.stages.mapping_wait =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - wait_from).count();
    ++s.young_map_waits;
    s.young_map_wait_ms += out.stages.mapping_wait;
  }
  const bool idle = s.options.sequential || s.mapper.idle();
  s.tracked_any = true;
  s.input_now = &input;
  s.map_start_masks.reset();
  KeyFrame* kf = s.tracker.track(std::move(frame), idle, clusters_pending, &out);
  s.input_now = nullptr;
  if (out.quality.causes & health_cause::kMasksLate) {
    // Segmentation cannot keep up: said to whoever runs it, now and then.
    char what[64];
    if (std::isinf(out.quality.mask_age_s))
      std::snprintf(what, sizeof what, "no keyframe near the camera has semantic masks");
    else
      std::snprintf(what, sizeof what, "the newest semantic masks are %.2f s old", out.quality.mask_age_s);
    SP_WARN_EVERY(logger, s.old_masks_warning,
                  what << ": with the semantic module alone the pose health is lowered (docs/pose-health.md); "
                         "the geometry module, or inference on a GPU (semantic.device), keeps up");
  }
  const auto t2 = std::chrono::steady_clock::now();
  out.extract_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
  out.stages.extract = out.extract_ms;
  out.track_ms = std::chrono::duration<double, std::milli>(t2 - t0).count();
  if (kf && s.options.mapping.dense_views && !input.depth_m.empty()) {
    // Pixels left out of the dense cloud: the depth clusters the geometry
    // module found moving, and known movers; semantic masks join later.
    cv::Mat moving;
    const GeometryOutput& g = out.geometry;
    if (g.labels && !g.labels->labels.empty()) {
      moving = cv::Mat::zeros(input.depth_m.size(), CV_8U);
      const int step = std::max(1, g.labels->step);
      for (int r = 0; r < g.labels->labels.rows; ++r)
        for (int c = 0; c < g.labels->labels.cols; ++c) {
          const int label = g.labels->labels.at<std::int16_t>(r, c);
          if (label >= 0 && label < static_cast<int>(g.scores.size()) && g.scores[label].dynamic)
            moving(cv::Rect(c * step, r * step, step, step) & cv::Rect(0, 0, moving.cols, moving.rows)).setTo(1);
        }
    }
    if (!input.movers.empty()) {
      cv::Mat known = input.movers != 0;
      if (moving.empty()) moving = known;
      else moving |= known;
    }
    auto view = std::make_shared<const DenseView>(makeDenseView(input.depth_m, input.bgr, moving));
    std::unique_lock lock(s.map.mutex());
    kf->dense = std::move(view);
  }
  if (!kf && s.semantic && !input.bgr.empty() && hasPose(out.state) && s.tracker.mapsNothingHere()) {
    // No keyframe is made where the place is mapped (localisation, a place a
    // loaded map holds), so none brings masks: the frame itself is segmented
    // whenever the segmenter is free, and its masks follow its movers into
    // the frames after it as a keyframe's do.
    const bool inline_now = s.segmentsInline();
    const bool free = inline_now || (modelled_delay ? !s.latency.busy() : s.semantic->idle());
    if (free) {
      const std::int64_t id = s.tracker.keepForMasks();
      SemanticJob job{-1, input.bgr.clone(), input.depth_m.empty() ? cv::Mat() : input.depth_m.clone(), t2, id};
      if (inline_now)
        s.applyFrameResult(s.semantic->process(job));
      else if (modelled_delay)
        s.latency.submit(std::move(job), id);
      else
        s.semantic->submit(std::move(job));
    }
  }
  if (kf && s.map_start_masks) {
    s.map_start_masks->keyframe_id = kf->id;  // its result, applied as any keyframe's
    // Its points were made outside the masks: they wait for nothing.
    s.map.maskRequested(kf->id);
    s.map.maskResolved(kf->id);
    s.mapper.postSemantic(std::move(*s.map_start_masks));
    s.map_start_masks.reset();
  } else if (kf && s.semantic) {
    if (input.bgr.empty()) {
      ++s.semantic_no_colour;
      SP_WARN_EVERY(logger, s.no_colour_warning,
                    "keyframe " << kf->id << " has no colour image: not segmented (" << s.semantic_no_colour.load()
                                << " so far)");
    } else {
      // The job keeps its own images unless it is segmented right now.
      const bool inline_now = s.segmentsInline();
      SemanticJob job{kf->id, inline_now ? input.bgr : input.bgr.clone(),
                      inline_now ? input.depth_m : input.depth_m.clone(), t2};
      s.map.maskRequested(kf->id);
      if (modelled_delay) {
        s.latency.submit(std::move(job), kf->frame.id);
      } else if (inline_now) {
        s.mapper.postSemantic(s.semantic->process(job));  // applied at the start of process(kf)
      } else {
        s.semantic->submit(std::move(job));
      }
    }
  }
  if (kf) {
    if (s.options.sequential) {
      const std::int64_t id = kf->id;
      s.mapper.process(kf);
      if (s.loops) s.loops->process(id);
    } else {
      const std::uint32_t map_id = kf->map_id;
      s.mapper.enqueue(kf);  // kf may be culled from here on
      const int young = s.options.mapping.young_map_keyframes;
      if (young > 0 && s.options.mapping.local_ba && s.grown_map != map_id) {
        std::shared_lock lock(s.map.mutex());
        s.young_map_wait = s.map.goodKeyFrameCount(map_id) <= static_cast<std::size_t>(young);
        if (!s.young_map_wait) s.grown_map = map_id;
      }
    }
  } else if (s.loops && s.options.place.global_ba && hasPose(out.state)) {
    s.checkCrossing();
  }
  {
    std::shared_lock lock(s.map.mutex());
    out.keyframes = s.map.goodKeyFrameCount();
  }
  if (s.options.report_fates) std::tie(out.semantic_labels, out.semantic_stamp) = s.mapper.latestSemanticLabels();
  return out;
}

void SlamSystem::finish(bool discard_pending_segmentation) {
  Impl& s = *impl_;
  // Modelled latency: what is under way or waiting is segmented now (or dropped).
  s.latency.finish(discard_pending_segmentation, [&s](const SemanticJob& job) { s.applySegmentation(job); });
  if (impl_->semantic) impl_->semantic->finish(discard_pending_segmentation);  // segments what is queued
  impl_->mapper.finish();                          // then applies it
  if (impl_->loops) impl_->loops->finish();        // then the loops it found
  impl_->finished = true;
}

std::vector<TrajectoryPose> SlamSystem::trajectory() const {
  std::shared_lock lock(impl_->map.mutex());
  std::vector<TrajectoryPose> out;
  out.reserve(impl_->tracker.records().size());
  for (const TrajectoryRecord& r : impl_->tracker.records()) out.push_back({r.stamp, r.T_c_w().inverse(), r.map_id});
  return out;
}

Status SlamSystem::saveMap(const std::string& path) const {
  try {
    std::shared_lock lock(impl_->map.mutex());
    return slam::saveMap(impl_->map, impl_->camera, impl_->levels, path);
  } catch (const std::exception& e) {
    return Error{"cannot write the map " + path + ": " + e.what()};
  }
}

Status SlamSystem::loadMap(const std::string& path) {
  Impl& s = *impl_;
  try {
    std::unique_lock lock(s.map.mutex());
    if (s.tracked_any) return Error{"map " + path + ": a map can only be loaded before the first frame"};
    Map loaded;
    if (Status st = slam::loadMap(path, s.camera, s.levels, &loaded); !st) return st;
    s.map.adoptLoaded(std::move(loaded));
    // Its keyframes' words (the file keeps descriptors, not words: a map
    // outlives a vocabulary change).
    if (s.vocabulary)
      for (const auto& kf : s.map.keyframes())
        if (!kf->bad) {
          kf->bow = s.tracker.staticWords(kf->frame);
          s.map.indexKeyFrame(kf.get());
        }
    s.tracker.mapLoaded();
    SP_INFO(logger, "map " << path << " loaded: " << s.map.goodKeyFrameCount() << " keyframes, " << s.map.pointCount()
                           << " points in " << s.map.mapsStarted() << " map(s)");
    return Status::success();
  } catch (const std::exception& e) {
    return Error{"map " + path + ": " + e.what()};
  }
}

Status SlamSystem::exportDenseCloud(const std::string& path, double voxel_m) const {
  if (!impl_->options.mapping.dense_views)
    return Error{"the dense cloud needs keyframes' depth views (mapping.dense_views: true)"};
  if (!(voxel_m >= 0.001 && voxel_m <= 1.0)) return Error{"the dense cloud's voxel must be 0.001..1 m"};
  std::vector<PosedView> views;
  {
    std::shared_lock lock(impl_->map.mutex());
    for (const auto& kf : impl_->map.keyframes())
      if (!kf->bad && kf->dense && kf->map_id == impl_->map.activeMapId()) views.push_back({kf->dense, kf->T_c_w()});
  }
  try {
    DenseCloudOptions options;
    options.voxel_m = voxel_m;
    const DenseCloud cloud = fuseDenseCloud(views, impl_->camera, options);
    SP_INFO(logger, "dense cloud: " << views.size() << " keyframes, " << cloud.voxels << " voxels, " << cloud.carved
                                    << " seen through by other keyframes and carved, " << cloud.points.size()
                                    << " points -> " << path);
    return writePly(path, cloud.points, "stillpoint dense static cloud");
  } catch (const std::exception& e) {
    return Error{"dense cloud " + path + ": " + e.what()};
  }
}

Status SlamSystem::exportCloud(const std::string& path) const {
  std::vector<ColouredPoint> points;
  {
    std::shared_lock lock(impl_->map.mutex());
    std::unordered_set<const MapPoint*> seen;
    for (const auto& kf : impl_->map.keyframes()) {
      if (kf->bad) continue;
      const Frame& f = kf->frame;
      for (int i = 0; i < f.size(); ++i) {
        const auto& p = f.points[i];
        if (!p || p->bad || p->isTemporary() || !seen.insert(p.get()).second) continue;
        const cv::Vec3b c = f.colour.empty() ? cv::Vec3b(128, 128, 128) : f.colour[i];
        points.push_back({static_cast<float>(p->position.x()), static_cast<float>(p->position.y()),
                          static_cast<float>(p->position.z()), c[2], c[1], c[0]});
      }
    }
  }
  return writePly(path, points, "stillpoint static map points");
}

std::vector<Vec3> SlamSystem::mapPoints(std::uint32_t map_id) const {
  std::vector<Vec3> out;
  std::shared_lock lock(impl_->map.mutex());
  std::unordered_set<const MapPoint*> seen;
  for (const auto& kf : impl_->map.keyframes()) {
    if (kf->bad || kf->map_id != map_id) continue;
    for (const auto& p : kf->frame.points)
      if (p && !p->bad && !p->isTemporary() && seen.insert(p.get()).second) out.push_back(p->position);
  }
  return out;
}

std::vector<KeyFrameView> SlamSystem::keyframes() const {
  std::shared_lock lock(impl_->map.mutex());
  std::vector<KeyFrameView> out;
  for (const auto& kf : impl_->map.keyframes()) {
    KeyFrameView v;
    v.id = kf->id;
    v.map_id = kf->map_id;
    v.stamp = kf->frame.stamp;
    v.bad = kf->bad;
    v.segmented = kf->segmented;
    v.T_w_c = kf->anchor()->T_c_w().inverse();  // a culled keyframe kept in memory follows its parent
    const Frame& f = kf->frame;
    v.features.reserve(f.keys.size());
    for (int i = 0; i < f.size(); ++i)
      v.features.push_back({f.keys[i].pt.x, f.keys[i].pt.y, f.points[i] && !f.points[i]->bad, f.dynamic[i] != 0});
    out.push_back(std::move(v));
  }
  return out;
}

MapStats SlamSystem::mapStats() const {
  std::shared_lock lock(impl_->map.mutex());
  MapStats stats;
  stats.keyframes = impl_->map.goodKeyFrameCount();
  stats.maps = impl_->map.mapsStarted();
  stats.no_depth_frames = impl_->no_depth_frames;
  stats.points = impl_->map.pointCount();
  stats.keyframes_in_memory = impl_->map.keyframes().size();
  stats.points_in_memory = impl_->map.pointsInMemory();
  stats.trajectory_records = impl_->tracker.records().size();
  stats.semantic_sighting_cells = impl_->map.staticSightings().cells();
  stats.local_ba_runs = impl_->mapper.baRuns();
  stats.local_mapping_ms_total = impl_->mapper.totalMs();
  stats.young_map_waits = impl_->young_map_waits;
  stats.young_map_wait_ms_total = impl_->young_map_wait_ms;
  stats.dynamic_points_culled = impl_->mapper.dynamicPointsCulled();
  stats.vocabulary = impl_->vocabulary_path;
  if (impl_->loops) {
    const LoopStats l = impl_->loops->stats();
    stats.loops_detected = l.detected;
    stats.loops_rejected = l.rejected;
    stats.loops_closed = l.closed;
    stats.loops_crossings_checked = l.crossings_checked;
    stats.loops_crossings_closed = l.crossings_closed;
    stats.global_ba_runs = l.global_ba_runs;
    stats.global_ba_dropped = l.global_ba_dropped;
    stats.global_ba_out_of_time = l.global_ba_out_of_time;
  }
  stats.relocalisations_refused = impl_->tracker.relocalisationsRefused();
  if (impl_->clustering) stats.geometry_deadline_misses = impl_->clustering->deadlineMisses();
  if (impl_->semantic) {
    const SemanticStats& st = impl_->mapper.semanticStats();
    stats.semantic_keyframes_segmented = st.segmented;
    stats.semantic_frames_segmented = impl_->frames_segmented.load();
    stats.semantic_frame_regions_known_static = impl_->tracker.frameRegionsKnownStatic();
    stats.semantic_keyframes_no_colour = impl_->semantic_no_colour.load();
    stats.semantic_keyframes_dropped = impl_->semantic->dropped() + impl_->latency.dropped();
    stats.semantic_failures = st.failures;
    stats.semantic_features_removed = st.features_removed;
    stats.semantic_points_removed = st.points_removed;
    stats.semantic_points_culled = st.points_culled;
    stats.semantic_instances_applied = st.instances_applied;
    stats.semantic_instances_unconfirmed = st.instances_unconfirmed;
    stats.semantic_instances_capped = st.instances_capped;
    stats.semantic_instances_followed = st.instances_followed;
    stats.semantic_instances_continued = st.instances_continued;
    stats.semantic_instances_known_static = st.instances_known_static;
    stats.semantic_features_on_standing = st.features_on_standing;
    std::tie(stats.semantic_latency_ms_median, stats.semantic_latency_ms_p95) = medianP95(st.latency_ms.values());
    std::tie(stats.segmentation_ms_median, stats.segmentation_ms_p95) = medianP95(st.segment_ms.values());
    stats.semantic_model = impl_->semantic_model;
  }
  return stats;
}

}  // namespace stillpoint::slam
