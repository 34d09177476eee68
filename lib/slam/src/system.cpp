#include "stillpoint/slam/system.hpp"

#include <chrono>
#include <mutex>

#include "frame.hpp"
#include "local_mapping.hpp"
#include "map.hpp"
#include "tracking.hpp"

namespace stillpoint::slam {

const char* toString(TrackingState state) {
  switch (state) {
    case TrackingState::kInitialising: return "initialising";
    case TrackingState::kOk: return "ok";
    case TrackingState::kLost: return "lost";
    case TrackingState::kRelocalised: return "relocalised";
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
  Tracker tracker;
  LocalMapper mapper;
  bool finished = false;
};

SlamSystem::SlamSystem(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

SlamSystem::~SlamSystem() {
  if (impl_) impl_->mapper.finish();
}

Result<std::unique_ptr<SlamSystem>> SlamSystem::create(const CameraModel& camera, const SlamOptions& options) {
  if (Status s = camera.validate(); !s) return Error{s.error()};
  if (Status s = options.validate(); !s) return Error{s.error()};
  auto system = std::unique_ptr<SlamSystem>(new SlamSystem(std::make_unique<Impl>(camera, options)));
  if (!options.sequential) system->impl_->mapper.start();
  return system;
}

Result<TrackOutput> SlamSystem::track(const RgbdInput& input) {
  Impl& s = *impl_;
  if (s.finished) return Error{"track() called after finish()"};
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

  const auto t0 = std::chrono::steady_clock::now();
  Frame frame;
  frame.id = s.map.nextFrameId();
  frame.stamp = input.stamp;
  frame.camera = &s.camera;
  frame.levels = &s.levels;
  // Clustering runs in its own thread while features are extracted; the
  // worker gets its own copy (the caller may reuse its buffer after track()).
  const bool clusters_pending = s.clustering && !input.depth_m.empty();
  if (clusters_pending) s.clustering->submit(frame.id, s.options.sequential ? input.depth_m : input.depth_m.clone());
  buildFrame(&frame, input.gray, input.depth_m, &s.orb);
  const auto t1 = std::chrono::steady_clock::now();

  TrackOutput out;
  const bool idle = s.options.sequential || s.mapper.idle();
  KeyFrame* kf = s.tracker.track(std::move(frame), idle, clusters_pending, &out);
  const auto t2 = std::chrono::steady_clock::now();
  out.extract_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
  out.stages.extract = out.extract_ms;
  out.track_ms = std::chrono::duration<double, std::milli>(t2 - t0).count();
  if (kf) {
    if (s.options.sequential)
      s.mapper.process(kf);
    else
      s.mapper.enqueue(kf);
  }
  {
    std::shared_lock lock(s.map.mutex());
    out.keyframes = s.map.goodKeyFrameCount();
  }
  return out;
}

void SlamSystem::finish() {
  impl_->mapper.finish();
  impl_->finished = true;
}

std::vector<TrajectoryPose> SlamSystem::trajectory() const {
  std::shared_lock lock(impl_->map.mutex());
  std::vector<TrajectoryPose> out;
  out.reserve(impl_->tracker.records().size());
  for (const TrajectoryRecord& r : impl_->tracker.records()) {
    const SE3 T_c_w = renormalized(r.T_c_ref * r.reference->resolvedT_c_w());
    out.push_back({r.stamp, T_c_w.inverse()});
  }
  return out;
}

MapStats SlamSystem::mapStats() const {
  std::shared_lock lock(impl_->map.mutex());
  MapStats stats;
  stats.keyframes = impl_->map.goodKeyFrameCount();
  stats.points = impl_->map.pointCount();
  stats.local_ba_runs = impl_->mapper.baRuns();
  stats.local_mapping_ms_total = impl_->mapper.totalMs();
  stats.dynamic_points_culled = impl_->mapper.dynamicPointsCulled();
  if (impl_->clustering) stats.geometry_deadline_misses = impl_->clustering->deadlineMisses();
  return stats;
}

}  // namespace stillpoint::slam
