#pragma once
// Test doubles of the semantic module: a Segmenter that paints a known
// rectangle, so a test knows which features a mask must take.
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "stillpoint/semantic/segmenter.hpp"

namespace stillpoint::slam {

// A segmentation that found no one in an image of `size`.
inline semantic::Segmentation noOneFound(const cv::Size& size) {
  semantic::Segmentation seg;
  seg.labels = cv::Mat(size, CV_8U, cv::Scalar(semantic::kNoLabel));
  seg.movable_mask = cv::Mat(size, CV_8U, cv::Scalar(0));
  return seg;
}

// Labels one fixed rectangle as a "person" in every image.
class RectangleSegmenter : public semantic::Segmenter {
 public:
  RectangleSegmenter(cv::Rect rect, bool confirm_with_geometry) : rect_(rect) {
    card_.name = "rectangle";
    card_.classes = {"person"};
    card_.movable = {"person"};
    card_.confirm_with_geometry = confirm_with_geometry;
  }
  Result<semantic::Segmentation> segment(const cv::Mat& bgr) override {
    if (bgr.empty() || bgr.type() != CV_8UC3) return Error{"not a BGR image"};
    while (gate && !*gate && *calls >= ungated_calls) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    std::this_thread::sleep_for(delay);
    ++*calls;
    semantic::Segmentation seg = noOneFound(bgr.size());
    const cv::Rect r = rect_ & cv::Rect(cv::Point(0, 0), bgr.size());
    seg.labels(r).setTo(0);
    seg.movable_mask(r).setTo(255);
    semantic::Instance inst;
    inst.class_id = 0;
    inst.class_name = "person";
    inst.score = 0.9f;
    inst.box = r;
    inst.mask = cv::Mat(r.size(), CV_8U, cv::Scalar(255));
    inst.area = r.area();
    inst.movable = true;
    inst.second_opinion = second_opinion;
    seg.instances.push_back(inst);
    seg.movable_pixels = r.area();
    return seg;
  }
  bool second_opinion = false;  // the rectangle comes from a person model beside the main one
  std::chrono::milliseconds delay{0};  // each segment() takes at least this long
  int ungated_calls = 0;  // the first calls pass a closed gate
  const semantic::ModelCard& card() const override { return card_; }
  const std::vector<int>& movableClassIds() const override { return ids_; }
  std::shared_ptr<int> calls = std::make_shared<int>(0);  // outlives the segmenter (owned by the system)
  std::shared_ptr<std::atomic<bool>> gate;                 // when set, segment() waits until it is true

 private:
  cv::Rect rect_;
  semantic::ModelCard card_;
  std::vector<int> ids_{0};
};

inline const cv::Rect kRect(40, 100, 200, 280);  // x 40..239, y 100..379

// A detector that changes its mind: its first `static_calls` calls label the
// whole image a "teddy bear" (a static class), the later ones `rect` a
// "person", as COCO calls the teddy bear a person beside a person.
class RelabellingSegmenter : public semantic::Segmenter {
 public:
  RelabellingSegmenter(cv::Rect rect, int static_calls) : rect_(rect), static_calls_(static_calls) {
    card_.name = "relabelling";
    card_.classes = {"person", "teddy bear"};
    card_.movable = {"person"};
  }
  Result<semantic::Segmentation> segment(const cv::Mat& bgr) override {
    if (bgr.empty() || bgr.type() != CV_8UC3) return Error{"not a BGR image"};
    const bool as_static = calls_++ < static_calls_;
    semantic::Segmentation seg = noOneFound(bgr.size());
    const cv::Rect image(cv::Point(0, 0), bgr.size());
    const cv::Rect r = (as_static ? image : rect_) & image;
    semantic::Instance inst;
    inst.class_id = as_static ? 1 : 0;
    inst.class_name = as_static ? "teddy bear" : "person";
    inst.score = 0.9f;
    inst.box = r;
    inst.mask = cv::Mat(r.size(), CV_8U, cv::Scalar(255));
    inst.area = r.area();
    inst.movable = !as_static;
    seg.labels(r).setTo(inst.class_id);
    if (inst.movable) {
      seg.movable_mask(r).setTo(255);
      seg.movable_pixels = r.area();
    }
    seg.instances.push_back(inst);
    return seg;
  }
  const semantic::ModelCard& card() const override { return card_; }
  const std::vector<int>& movableClassIds() const override { return ids_; }

 private:
  cv::Rect rect_;
  int static_calls_;
  int calls_ = 0;
  semantic::ModelCard card_;
  std::vector<int> ids_{0};
};

}  // namespace stillpoint::slam
