#pragma once
// Free space: depth samples of the current frame that lie in space an
// earlier frame saw empty along the same ray. Something moved there, whatever
// its features say; the surface grown from those samples is the moved object.
#include <opencv2/core.hpp>

#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/geometry.hpp"
#include "stillpoint/geometry/depth_clustering.hpp"

namespace stillpoint::geometry {

// Depths agree within base_m + z2 z^2 (m): a structured-light sensor's noise
// grows as z^2.
struct DepthTolerance {
  double base_m = 0.03;
  double z2 = 0.02;
  double at(double z) const { return base_m + z2 * z * z; }
};

struct FreeSpace {
  std::vector<float> share;     // per cluster; -1: fewer than 8 samples tested
  std::vector<int> violations;  // per cluster: samples in free space
  cv::Mat violated;             // CV_8U on the sample grid
  cv::Mat points;               // CV_32FC3 on the sample grid, camera frame (z = 0: no depth)
};

// The clustered samples of `clusters` (their depth image) against `seen_depth`
// (CV_32F metres, empty: nothing seen), taken at T_seen_current from the
// current camera: a sample is in free space when it lies in front of the
// nearest surface the seen frame had around that pixel by more than the
// tolerance.
FreeSpace freeSpaceViolations(const DepthClusters& clusters, const cv::Mat& seen_depth, const SE3& T_seen_current,
                              const CameraModel& camera, const DepthTolerance& tolerance);

// How the moved surface grows from the violating samples: between grid
// neighbours on one plane (offset below plane_m (1 + z^2)) whose normals
// differ by less than angle_deg. A depth edge stops it: that is where a
// walker's foot meets the floor.
struct SurfaceGrowth {
  double plane_m = 0.02;
  double angle_deg = 30.0;
};

// The samples connected to a violating one over a continuous surface: the
// whole moving object, not only the part that entered empty space. CV_8U on
// the sample grid; empty when `free` has no grid.
cv::Mat growMovedSurface(const DepthClusters& clusters, const FreeSpace& free, const SurfaceGrowth& growth);

}  // namespace stillpoint::geometry
