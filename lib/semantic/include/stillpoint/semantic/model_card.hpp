#pragma once
// A model card describes one segmentation network for the dnn backend: where
// the ONNX file is, how to turn a BGR frame into its input tensor, how to
// decode its outputs, its class names and which classes count as movable.
// Cards are small YAML files (see models/*.yaml); loading errors name the
// file, the field and the line.
#include <filesystem>
#include <string>
#include <vector>

#include "stillpoint/core/result.hpp"

namespace stillpoint::semantic {

enum class TensorLayout { kNCHW, kNHWC };
enum class ColourOrder { kRGB, kBGR };
enum class ResizeMode { kStretch, kLetterbox };
enum class DecoderType {
  kPersonProbability,  // one [1,H,W,1] / [1,1,H,W] map of P(person) (or of one class)
  kSemanticArgmax,     // [1,C,H,W] / [1,H,W,C] per-class scores, label = argmax
  kYoloInstance,       // [1,N,5+C+K] detections + [1,K,h,w] mask prototypes
};

struct InputSpec {
  std::string name;  // optional: empty = the network's only input
  int width = 0;
  int height = 0;
  TensorLayout layout = TensorLayout::kNCHW;
  ColourOrder colour_order = ColourOrder::kRGB;
  // value = (pixel * scale - mean[c]) / std[c], c in the network's colour order.
  double scale = 1.0 / 255.0;
  std::vector<double> mean{0.0, 0.0, 0.0};
  std::vector<double> std{1.0, 1.0, 1.0};
  ResizeMode resize = ResizeMode::kStretch;
  int pad_value = 114;  // letterbox border, 0..255 in pixel units (before scale)
};

struct DecoderSpec {
  DecoderType type = DecoderType::kPersonProbability;
  // Output tensor names in the order the decoder expects them
  // (probability: [map]; semantic: [scores]; yolo: [detections, prototypes]).
  std::vector<std::string> outputs;
  TensorLayout output_layout = TensorLayout::kNCHW;  // probability / semantic maps
  // Probability map: pixel is the class when P >= threshold. YOLO: instance
  // mask threshold on sigmoid(coefficients . prototypes).
  double threshold = 0.5;
  // Semantic argmax: class whose pixels are background (label 255); empty = none.
  std::string background_class;
  // Semantic argmax: "softmax" when the scores are logits and a per-pixel
  // confidence is wanted, "none" when they are already probabilities.
  bool softmax = false;
  // YOLO instance segmentation.
  double score_threshold = 0.25;  // objectness x class probability
  double nms_threshold = 0.45;    // IoU, class-aware
  int mask_coefficients = 32;
  int max_detections = 100;
};

struct ModelCard {
  std::filesystem::path card_path;   // where the card was read from
  std::string name;
  std::filesystem::path model_path;  // resolved: relative paths are taken from the card's folder
  InputSpec input;
  DecoderSpec decoder;
  std::vector<std::string> classes;   // class id = index; at most 255 classes
  std::vector<std::string> movable;   // default movable set: people, animals, vehicles
  // Classes that move only sometimes (chairs, other furniture); movable only
  // when SegmenterOptions::movable_furniture is set.
  std::vector<std::string> optional_movable;
  std::string licence;  // free text, shown by tools
  // The model is known to label static things as movable with high
  // confidence (the person models take the TUM teddy bear for a person at
  // P > 0.95, so no threshold helps): the pipeline should remove map content
  // under its masks only where another cue (geometry) agrees.
  bool confirm_with_geometry = false;
  // A person model's card (relative: to this card's folder) that the SLAM
  // consults beside this model where a map starts: an instance detector
  // misses a person near the camera, cut by the border or half hidden, whom
  // a person model paints (person_second_opinion.hpp). Empty: none.
  std::filesystem::path person_model;

  // Checks every field; the message names the field.
  Status validate() const;
  // Index of a class name, or -1.
  int classId(const std::string& name) const;
};

// Reads and validates a card. The model file itself is not opened here
// (createSegmenter does that), but a relative model path is resolved.
Result<ModelCard> loadModelCard(const std::filesystem::path& path);

}  // namespace stillpoint::semantic
