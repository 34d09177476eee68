#pragma once
// Segmenter: one network that turns a BGR frame into a per-pixel label image
// and a mask of potentially movable objects (people, animals, vehicles).
//
// Threading: a Segmenter is NOT safe for concurrent calls. Create it on any
// thread, then call segment() from one worker thread (the keyframe
// segmentation thread); calls from several threads need one Segmenter each.
// The cv::dnn network and its buffers are reused between calls.
#include <opencv2/core.hpp>

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "stillpoint/core/result.hpp"
#include "stillpoint/semantic/model_card.hpp"
#include "stillpoint/semantic/segmentation.hpp"

namespace stillpoint::semantic {

// "cpu", "cuda", "cuda_fp16", "opencl" or "opencl_fp16"; anything else is an error.
Status checkDevice(const std::string& device);

struct SegmenterOptions {
  // OpenCV's thread count for inference. OpenCV keeps ONE process-wide
  // setting, so this also affects other OpenCV calls in the process;
  // 0 = leave it as it is.
  int threads = 1;
  // Where inference runs: "cpu" (OpenCV's own backend), "cuda" or
  // "cuda_fp16" (OpenCV's CUDA backend: a Jetson's GPU, with an OpenCV built
  // with CUDA and cuDNN, as JetPack's can be), "opencl" or "opencl_fp16". When
  // this OpenCV build has no such backend or target, or the warm-up inference
  // fails on it, the segmenter warns and runs on the CPU.
  std::string device = "cpu";
  // Also treat the card's optional_movable classes (chairs, furniture) as movable.
  bool movable_furniture = false;
  // Extra class names to treat as movable (must exist in the card).
  std::vector<std::string> extra_movable;
  // Overrides of the card's decoder thresholds; negative = keep the card's.
  double threshold = -1.0;        // probability map / YOLO mask threshold
  double score_threshold = -1.0;  // YOLO detection score threshold
  // Post-filter on the movable mask. A connected region (dense decoders) or an
  // instance mask (YOLO) is dropped when it covers less than this fraction of
  // the image...
  double min_region_fraction = 0.001;
  // ...or when its mean probability (dense: mean P over the region; YOLO:
  // detection score) is below this value. 0 = off.
  double min_region_confidence = 0.0;
  // Instance decoders: a movable instance whose mask overlaps a higher-scoring
  // instance of a static class with at least this mask IoU is the same object
  // under a second, weaker label (class-aware NMS keeps both), and is dropped.
  // Seen on the TUM teddy: "teddy bear" 0.78 and "person" 0.66 on one mask.
  // 0 = off.
  double static_overlap_iou = 0.6;

  // Names the bad field.
  Status validate() const;
};

class Segmenter {
 public:
  virtual ~Segmenter() = default;
  // bgr: CV_8UC3, any size. Errors (empty or wrong-type image, inference
  // failure) come back as a Result, never as an exception or a crash.
  virtual Result<Segmentation> segment(const cv::Mat& bgr) = 0;
  virtual const ModelCard& card() const = 0;
  // Class ids that end up in movable_mask.
  virtual const std::vector<int>& movableClassIds() const = 0;
};

// Loads the ONNX model of a card with OpenCV dnn (CPU backend) and checks,
// at once, that the model matches the card: the declared input shape against
// input.width/height/layout, output names, and, by one warm-up inference, the
// output shapes against the decoder (class count, mask coefficients).
Result<std::unique_ptr<Segmenter>> createSegmenter(const ModelCard& card,
                                                   const SegmenterOptions& options = {});
// loadModelCard + createSegmenter.
Result<std::unique_ptr<Segmenter>> createSegmenter(const std::filesystem::path& card_path,
                                                   const SegmenterOptions& options = {});

// ---- Model lookup -------------------------------------------------------
// COCO with the person model consulted beside it where a map starts.
inline constexpr const char* kRecommendedCardFile = "coco_yolov5s_seg_320_people.yaml";
inline constexpr const char* kPersonCardFile = "person_selfie_256.yaml";

struct ModelLookup {
  // Folder with the model cards (and the in-tree person model). Empty = the
  // project's models/ folder (build tree), else <prefix>/share/stillpoint/models.
  std::filesystem::path card_dir;
  // Folders searched, in order, for the COCO model file (e.g. a configured
  // path); then $STILLPOINT_MODEL_DIR; then the card's own model path.
  std::vector<std::filesystem::path> model_dirs;
};

struct ResolvedModel {
  ModelCard card;
  std::string reason;  // human-readable: why this model was chosen
};

// The recommended model: the COCO instance model when its ONNX file is found
// (card kRecommendedCardFile, whose person_model the SLAM consults where a map
// starts), else the in-tree person model. Error when neither is usable.
Result<ResolvedModel> resolveRecommendedModel(const ModelLookup& lookup = {});
// The models/ folder this build knows about (see ModelLookup::card_dir).
std::filesystem::path defaultModelCardDir();

}  // namespace stillpoint::semantic
