#pragma once
// The SLAM core's public face: feed RGB-D frames, read poses and the
// trajectory. Tracking runs in the caller's thread; local mapping runs in its
// own thread, or inline when options.sequential is set (deterministic).
#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"
#include "stillpoint/slam/options.hpp"

namespace stillpoint::slam {

enum class TrackingState { kInitialising, kOk, kLost, kRelocalised };
const char* toString(TrackingState state);

struct RgbdInput {
  Timestamp stamp;
  cv::Mat gray;     // CV_8UC1, camera size
  cv::Mat depth_m;  // CV_32FC1 metres, 0 = no measurement, camera size
};

// Where one frame's tracking time went (milliseconds).
struct StageTimes {
  double extract = 0;         // ORB extraction and depth lookup
  double initial_pose = 0;    // motion model / reference keyframe / relocalisation matching
  double local_map = 0;       // local map update and projection search
  double pose_optimisation = 0;  // every pose-only optimisation of the frame
  double keyframe = 0;        // keyframe decision and creation
};

struct TrackOutput {
  TrackingState state = TrackingState::kInitialising;
  SE3 T_w_c = SE3::Identity();  // valid when state is kOk or kRelocalised
  int features = 0;
  int tracked = 0;  // inlier matches to map points
  bool new_keyframe = false;
  std::size_t keyframes = 0;
  double extract_ms = 0;  // ORB extraction
  double track_ms = 0;    // whole tracking step, extraction included
  StageTimes stages;
};

struct TrajectoryPose {
  Timestamp stamp;
  SE3 T_w_c;
};

struct MapStats {
  std::size_t keyframes = 0;
  std::size_t points = 0;
  int local_ba_runs = 0;
  double local_mapping_ms_total = 0;
};

class SlamSystem {
 public:
  static Result<std::unique_ptr<SlamSystem>> create(const CameraModel& camera, const SlamOptions& options);
  ~SlamSystem();
  SlamSystem(const SlamSystem&) = delete;
  SlamSystem& operator=(const SlamSystem&) = delete;

  // Bad input (wrong size/type, empty images) returns an Error and leaves the
  // system unchanged.
  Result<TrackOutput> track(const RgbdInput& input);
  // Drains local mapping and stops its thread; tracking may not be called after.
  void finish();
  // Every tracked frame, expressed through its reference keyframe so that it
  // benefits from bundle adjustment. Call after finish() for final values.
  std::vector<TrajectoryPose> trajectory() const;
  MapStats mapStats() const;

 private:
  struct Impl;
  explicit SlamSystem(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace stillpoint::slam
