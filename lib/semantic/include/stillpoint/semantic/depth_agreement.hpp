#pragma once
// Agreement of segmentation masks with depth: a movable instance is one
// object, so its pixels lie near one depth. Mask pixels far behind (or in
// front of) the instance's median depth are background seen through the
// mask's soft edges and holes (the YOLO masks are upsampled from 80x80
// prototypes): they leave the mask, so their static features stay in the map.
// Pixels without depth stay in the mask.
#include <opencv2/core.hpp>

#include <vector>

#include "stillpoint/core/result.hpp"
#include "stillpoint/semantic/segmentation.hpp"

namespace stillpoint::semantic {

struct DepthAgreementOptions {
  double depth_scale = 1.0 / 5000.0;  // CV_16U depth value -> metres (TUM); CV_32F depth is taken as metres
  double abs_tolerance_m = 0.25;      // kept: |z - median| <= abs + rel * median
  double rel_tolerance = 0.15;
  int min_depth_pixels = 50;          // instances with fewer depth pixels are left as they are
};

struct InstanceDepth {
  float median_m = 0.0f;  // 0 when not enough depth
  int depth_pixels = 0;
  int removed_pixels = 0;
};

// depth: CV_16U or CV_32F, the size of seg->movable_mask. Refines every kept
// movable instance, rebuilds movable_mask and movable_pixels; one entry per
// instance in seg->instances.
Result<std::vector<InstanceDepth>> applyDepthAgreement(const cv::Mat& depth, const DepthAgreementOptions& options,
                                                       Segmentation* seg);

}  // namespace stillpoint::semantic
