#pragma once
// The dense static cloud: keyframes keep a reduced view of their depth and
// colour (every 4th pixel) with the pixels the modules found moving or
// movable marked, and the export fuses the views into a voxel grid. A voxel
// that other views saw through (they measured a surface well behind it
// where it projects) was there only for a moment, a mover the modules
// missed: it is carved away, so walkers leave no ghost trails.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/geometry.hpp"
#include "stillpoint/core/result.hpp"

namespace stillpoint::slam {

struct DenseView {
  static constexpr int kStep = 4;  // pixels of the full image per view pixel
  cv::Mat depth;   // CV_32F metres, 0 = none
  cv::Mat bgr;     // CV_8UC3, empty without colour
  cv::Mat moving;  // CV_8U, non-zero: left out (moving or movable)
};

// The view of a frame: `moving_full` (CV_8U, full size, may be empty) marks
// the pixels to leave out.
DenseView makeDenseView(const cv::Mat& depth_m, const cv::Mat& bgr, const cv::Mat& moving_full);

struct PosedView {
  std::shared_ptr<const DenseView> view;
  SE3 T_c_w;
};

struct ColouredPoint {
  float x = 0, y = 0, z = 0;
  std::uint8_t r = 128, g = 128, b = 128;
};

struct DenseCloudOptions {
  double voxel_m = 0.01;
  bool carve = true;
  // A view saw through a voxel when its depth there exceeds the voxel's by
  // more than margin_m + margin_rel * depth (depth noise grows with depth).
  double margin_m = 0.03, margin_rel = 0.02;
};

struct DenseCloud {
  std::vector<ColouredPoint> points;  // one per kept voxel: mean position and colour
  std::size_t voxels = 0, carved = 0;
};

DenseCloud fuseDenseCloud(const std::vector<PosedView>& views, const CameraModel& camera,
                          const DenseCloudOptions& options = {});

// Binary little-endian PLY: x y z float, red green blue uchar.
Status writePly(const std::string& path, const std::vector<ColouredPoint>& points, const std::string& comment);

}  // namespace stillpoint::slam
