#pragma once
// The SLAM core's public face: feed RGB-D frames, read poses and the
// trajectory. Tracking runs in the caller's thread; local mapping runs in its
// own thread, or inline when options.sequential is set (deterministic).
#include <cstdint>
#include <functional>
#include <memory>
#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/result.hpp"
#include "stillpoint/core/time.hpp"
#include "stillpoint/slam/options.hpp"
#include "stillpoint/slam/outputs.hpp"

namespace stillpoint::semantic {
class Segmenter;
}

namespace stillpoint::slam {

struct RgbdInput {
  Timestamp stamp;
  cv::Mat gray;     // CV_8UC1, camera size
  cv::Mat depth_m;  // CV_32FC1 metres, 0 = no measurement, camera size
  // CV_8UC3 colour image (camera size) for the semantic module; may be empty:
  // a keyframe made from a frame without colour is not segmented.
  cv::Mat bgr{};  // (default initialiser: 3-field aggregate initialisation stays warning-free)
  // Known movers (may be empty): CV_8UC1 or CV_16UC1, camera size, non-zero
  // where something moves, e.g. from a detector in another process. The
  // features there stay out of the pose and the map, as the semantic
  // module's do. With a sequence's true masks (stillpoint-replay
  // --known-movers) it measures the best the dynamic-object modules can do.
  cv::Mat movers{};
};

// Lets the caller place threads the SLAM core starts (name, CPU affinity,
// scheduling). Each hook runs first on its thread. A thread without a hook
// inherits the placement of the thread that called create().
struct SlamThreadHooks {
  std::function<void()> semantic_start;  // the semantic module's segmentation thread
};

// The model the semantic options select, checked without loading the network:
// the card parses and its model file exists. create() does the full check
// (network loads, a warm-up inference matches the card).
struct SemanticModelChoice {
  std::string card_path;
  std::string model_path;
  std::string name;
  std::string reason;  // why this model was chosen
};
// Errors name the card or model file (and "semantic.model_card" for a bad card).
Result<SemanticModelChoice> checkSemanticModel(const SemanticOptions& options);

class SlamSystem {
 public:
  // Loads and checks everything the options need now, the segmentation model
  // included: a bad model is an error here, not at the first keyframe.
  static Result<std::unique_ptr<SlamSystem>> create(const CameraModel& camera, const SlamOptions& options,
                                                    const SlamThreadHooks& hooks = {});
  // With a segmenter of the caller's (another network backend, or a test
  // double); options.semantic.enabled must be set, its model fields are ignored.
  static Result<std::unique_ptr<SlamSystem>> create(const CameraModel& camera, const SlamOptions& options,
                                                    std::unique_ptr<semantic::Segmenter> segmenter,
                                                    const SlamThreadHooks& hooks = {});
  ~SlamSystem();
  SlamSystem(const SlamSystem&) = delete;
  SlamSystem& operator=(const SlamSystem&) = delete;

  // Bad input (wrong size/type, empty images, a stamp not after the last
  // frame's) returns an Error and leaves the system unchanged.
  Result<TrackOutput> track(const RgbdInput& input);
  // Drains local mapping and stops its thread; tracking may not be called after.
  // Keyframes still waiting for segmentation are segmented first, unless
  // `discard_pending_segmentation` (a stop on request: one segmentation can
  // take seconds on a loaded CPU); they then count as dropped. A segmentation
  // already running completes either way.
  void finish(bool discard_pending_segmentation = false);
  // Every tracked frame (the most recent tracking.trajectory_records of them),
  // expressed through its reference keyframe so that it benefits from bundle
  // adjustment. Call after finish() for final values.
  std::vector<TrajectoryPose> trajectory() const;
  MapStats mapStats() const;
  // Every keyframe in memory, in creation order: culled ones are freed unless
  // mapping.keep_culled_keyframes (call after finish() for final values).
  std::vector<KeyFrameView> keyframes() const;

  // The maps in memory as a file (every keyframe and map point; a versioned,
  // checksummed binary format), written next to `path` and renamed over it.
  // Safe from any thread; after finish() it holds the final map.
  Status saveMap(const std::string& path) const;
  // Reads a map file before the first frame: frames then relocalise against
  // it (with `localisation`, only against it). A truncated, corrupt or
  // wrong-version file, or one made with another camera, is an error naming
  // the file; the system is unchanged then.
  Status loadMap(const std::string& path);
  // The map points as a coloured point cloud (PLY, binary little-endian:
  // x y z as float, red green blue as uchar; grey where a point's keyframe
  // had no colour image). Only the static map: points the modules found
  // moving were culled from it.
  Status exportCloud(const std::string& path) const;
  // The static map points of map `map_id` (TrackOutput::map_id), in its
  // frame. Safe from any thread.
  std::vector<Vec3> mapPoints(std::uint32_t map_id) const;
  // The dense static cloud (PLY as above): the keyframes' depth views of the
  // map being tracked fused in voxels of `voxel_m`, without the pixels the
  // modules found moving or movable, and without voxels other keyframes saw
  // through (a mover that was missed). Needs mapping.dense_views.
  Status exportDenseCloud(const std::string& path, double voxel_m = 0.01) const;

 private:
  Result<TrackOutput> trackChecked(const RgbdInput& input);
  struct Impl;
  explicit SlamSystem(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace stillpoint::slam
