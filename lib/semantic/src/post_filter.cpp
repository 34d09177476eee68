#include "post_filter.hpp"

#include <opencv2/core.hpp>

namespace stillpoint::semantic {

double maskIou(const Instance& a, const Instance& b) {
  const cv::Rect both = a.box & b.box;
  if (both.empty() || a.mask.empty() || b.mask.empty()) return 0.0;
  cv::Mat inter;
  cv::bitwise_and(a.mask(both - a.box.tl()), b.mask(both - b.box.tl()), inter);
  const double n = cv::countNonZero(inter);
  const double uni = double(a.area) + double(b.area) - n;
  return uni > 0 ? n / uni : 0.0;
}

void filterInstances(const SegmenterOptions& options, double min_area_px, Segmentation* seg) {
  for (Instance& inst : seg->instances) {
    if (!inst.movable || inst.area == 0) continue;
    inst.kept = true;
    inst.drop_reason.clear();
    if (inst.area < min_area_px) {
      inst.kept = false;
      inst.drop_reason = "area";
    } else if (inst.score < options.min_region_confidence) {
      inst.kept = false;
      inst.drop_reason = "confidence";
    } else if (options.static_overlap_iou > 0) {
      // Class-aware NMS keeps one object under two labels; the stronger
      // static label wins (TUM teddy: "teddy bear" 0.78 over "person" 0.66).
      for (const Instance& other : seg->instances) {
        if (other.movable || other.score <= inst.score || other.area == 0) continue;
        if (maskIou(inst, other) >= options.static_overlap_iou) {
          inst.kept = false;
          inst.drop_reason = "same object as static '" + other.class_name + "'";
          break;
        }
      }
    }
    if (inst.kept)
      seg->movable_mask(inst.box).setTo(255, inst.mask);
    else
      seg->filtered_pixels += inst.area;
  }
}

}  // namespace stillpoint::semantic
