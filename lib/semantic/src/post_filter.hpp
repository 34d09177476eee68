#pragma once
// The post-filter between decoding and the movable mask: which movable
// instances (YOLO detections, or connected regions of dense decoders) are
// kept. Every drop is recorded on the instance (kept, drop_reason).
#include "stillpoint/semantic/segmentation.hpp"
#include "stillpoint/semantic/segmenter.hpp"

namespace stillpoint::semantic {

// Needs seg->instances with movable set and masks; fills seg->movable_mask
// (allocated by the caller, image size) and seg->filtered_pixels. A movable
// instance is dropped when its area < min_area_px, its score is below
// options.min_region_confidence, or its mask overlaps a higher-scoring static
// instance with IoU >= options.static_overlap_iou (when that is > 0).
void filterInstances(const SegmenterOptions& options, double min_area_px, Segmentation* seg);

// Mask IoU of two instances (box-cropped masks).
double maskIou(const Instance& a, const Instance& b);

}  // namespace stillpoint::semantic
