#pragma once
// The result of segmenting one frame.
#include <opencv2/core.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace stillpoint::semantic {

// Label value of pixels that belong to no class (background or unknown).
inline constexpr std::uint8_t kNoLabel = 255;

struct Instance {
  int class_id = -1;
  std::string class_name;
  float score = 0.0f;   // YOLO: objectness x class probability; dense decoders: mean probability of the region
  cv::Rect box;         // in input-image pixels, clipped to the image
  cv::Mat mask;         // CV_8U 0/255, box.size(): the instance's pixels inside box
  int area = 0;         // pixels in mask
  bool movable = false;
  // False when the post-filter (min area / min confidence) dropped it from
  // the movable mask; kept in the list so the drop is visible.
  bool kept = true;
  std::string drop_reason;  // why kept is false ("area", "confidence", "same object as static 'teddy bear'")
  // Kept only as the continuation of an instance of the previous keyframe
  // (the SLAM's detector hysteresis, SemanticOptions::track_*).
  bool continued = false;
  // Found by a person model beside the main one, where the main model saw
  // nothing (person_second_opinion.hpp).
  bool second_opinion = false;
};

struct SegmentationTiming {
  double preprocess_ms = 0.0;
  double inference_ms = 0.0;
  double decode_ms = 0.0;
  double total_ms = 0.0;
};

struct Segmentation {
  // CV_8U, input resolution: class id per pixel, kNoLabel for none. Raw
  // decoder output: pixels of regions the post-filter dropped keep their label.
  cv::Mat labels;
  // CV_8U 0/255, input resolution: pixels of movable classes after the
  // post-filter. This is what the SLAM pipeline should use.
  cv::Mat movable_mask;
  // YOLO: one entry per detection after NMS. Dense decoders: one entry per
  // connected region of a movable class (score = mean probability).
  std::vector<Instance> instances;
  SegmentationTiming timing;
  int movable_pixels = 0;
  // Movable pixels the decoder produced but the post-filter removed.
  int filtered_pixels = 0;

  double movableFraction() const {
    return movable_mask.empty() ? 0.0 : double(movable_pixels) / double(movable_mask.total());
  }
};

}  // namespace stillpoint::semantic
