#pragma once
// K-Means clustering of a depth image in 3D: the image is split into N
// surfaces, each assumed to share one rigid motion, so that a moving object
// (or each limb of a walking person) becomes one or more clusters whose
// features disagree with the camera pose.
#include <opencv2/core.hpp>

#include <cstdint>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/result.hpp"

namespace stillpoint::geometry {

struct ClusteringOptions {
  // Clusters at 640x480; other resolutions scale it by their pixel count
  // (clustersFor()), keeping the area per cluster constant.
  int clusters_at_vga = 24;
  // Pixels are sampled on a grid of this step at 640x480 (scaled likewise):
  // 8 gives 80x60 samples, enough for surfaces of a few % of the image.
  int sample_step_at_vga = 8;
  int max_iterations = 10;
  // Lloyd iterations stop when fewer than this fraction of samples change cluster.
  double converged_fraction = 0.005;
  // Reuse the previous frame's centres (camera frame) as the initialisation.
  bool warm_start = true;
  Status validate() const;
};

// Result of clustering one depth image.
struct DepthClusters {
  int clusters = 0;
  int step = 1;              // sample grid step in pixels
  cv::Mat labels;            // CV_16S, (rows/step) x (cols/step); kNoLabel where depth is missing
  std::vector<Vec3> centres; // camera frame, metres
  std::vector<int> sizes;    // samples per cluster
  // The depth image that was clustered (shared, not copied: the caller hands
  // over an image it no longer writes).
  cv::Mat depth;
  int iterations = 0;
  bool warm_started = false;

  static constexpr std::int16_t kNoLabel = -1;
  // Cluster of a pixel (distorted image coordinates, as the depth image is
  // registered to the colour image) with depth z (<= 0: unknown). With depth
  // the nearest centre decides (the K-Means partition itself); without, the
  // label of the enclosing sample cell. kNoLabel when neither is known.
  int labelAt(const CameraModel& camera, float x, float y, float z) const;
  // Full-resolution label image (for visualisation), nearest-neighbour upsampled.
  cv::Mat fullResolutionLabels(cv::Size size) const;
};

// Keeps the centres between frames for warm starts. Not thread-safe: one
// owner (the geometry worker) calls cluster() frame after frame.
class DepthClusterer {
 public:
  explicit DepthClusterer(ClusteringOptions options = {});

  // Clusters a CV_32F depth image in metres (0 or non-finite = no measurement)
  // taken by `camera`. Errors on size/type mismatch; an image with fewer valid
  // samples than clusters yields zero clusters (not an error).
  Result<DepthClusters> cluster(const cv::Mat& depth_m, const CameraModel& camera);
  // The next cluster() starts from these centres (camera frame; empty: from
  // the grid), not from the last call's.
  void warmStartFrom(std::vector<Vec3> centres) { previous_ = std::move(centres); }

  static int clustersFor(const ClusteringOptions& options, int width, int height);
  static int stepFor(const ClusteringOptions& options, int width, int height);

 private:
  ClusteringOptions options_;
  std::vector<Vec3> previous_;
};

}  // namespace stillpoint::geometry
