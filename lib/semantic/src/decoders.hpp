#pragma once
// Pre-processing geometry and the three output decoders, as plain functions
// on cv::Mat blobs so tests can feed them hand-made outputs.
#include <opencv2/core.hpp>

#include <vector>

#include "stillpoint/core/result.hpp"
#include "stillpoint/semantic/model_card.hpp"
#include "stillpoint/semantic/segmentation.hpp"

namespace stillpoint::semantic {

// Where the image sits inside the network input. Stretch: content = the whole
// input. Letterbox: aspect kept, centred, borders of pad_value.
struct InputGeometry {
  cv::Size image;    // original image size
  cv::Size network;  // network input size
  cv::Rect content;  // the resized image inside the network input

  // Network-input pixel coordinates -> image pixel coordinates (continuous,
  // pixel corners: x_img = (x_net - content.x) * image.width / content.width).
  cv::Point2d toImage(cv::Point2d net) const;
};

InputGeometry computeGeometry(cv::Size image, cv::Size network, ResizeMode mode);

// The network input tensor (CV_32F, 4-D, layout of the card).
cv::Mat makeInputBlob(const cv::Mat& bgr, const InputSpec& spec, const InputGeometry& geometry);

// A CV_32F map in network-input coordinates (any resolution covering the
// whole network input) -> image resolution, letterbox borders cut off.
cv::Mat mapToImage(const cv::Mat& net_map, const InputGeometry& geometry);

struct DenseDecoding {
  cv::Mat labels;      // CV_8U, image size, class id or kNoLabel
  cv::Mat confidence;  // CV_32F, image size, probability of the labelled class
};

// Output [1,H,W,1], [1,1,H,W] or [1,H,W] of P(class 0).
Result<DenseDecoding> decodeProbabilityMap(const cv::Mat& output, const DecoderSpec& spec,
                                           const InputGeometry& geometry, double threshold);
// Output [1,C,H,W] (NCHW) or [1,H,W,C] (NHWC) of per-class scores; label = argmax.
Result<DenseDecoding> decodeSemanticScores(const cv::Mat& output, const DecoderSpec& spec, int num_classes,
                                           int background_class, const InputGeometry& geometry);

struct Detection {
  cv::Rect2f box_net;  // network-input pixels (x1, y1, w, h)
  int class_id = -1;
  float score = 0.0f;
  int row = -1;        // row of the detection tensor (for its mask coefficients)
};

// Greedy NMS per class: a box is suppressed by a higher-scoring box of the
// same class with IoU > iou_threshold. Returns indices into dets, best first.
std::vector<int> classAwareNms(const std::vector<Detection>& dets, double iou_threshold, int max_keep);
float iou(const cv::Rect2f& a, const cv::Rect2f& b);

// detections [1,N,5+C+K] (cx, cy, w, h, objectness, C class probabilities, K
// mask coefficients), prototypes [1,K,h,w]. Instances come back best first
// with masks at image resolution cropped to their boxes; labels has the
// instances painted lowest score first.
struct YoloDecoding {
  std::vector<Instance> instances;
  cv::Mat labels;
};
Result<YoloDecoding> decodeYolo(const cv::Mat& detections, const cv::Mat& prototypes, const DecoderSpec& spec,
                                const std::vector<std::string>& class_names, const InputGeometry& geometry,
                                double score_threshold, double mask_threshold);

// Text like "[1x6300x117]".
std::string shapeString(const cv::Mat& m);

}  // namespace stillpoint::semantic
