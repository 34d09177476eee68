#include <opencv2/dnn.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <set>
#include <sstream>

#include "decoders.hpp"
#include "onnx_info.hpp"
#include "post_filter.hpp"
#include "stillpoint/core/log.hpp"
#include "stillpoint/semantic/segmenter.hpp"

namespace stillpoint::semantic {
namespace {

log::Logger logger("semantic");

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

class DnnSegmenter final : public Segmenter {
 public:
  DnnSegmenter(ModelCard card, SegmenterOptions options, cv::dnn::Net net, std::vector<int> movable)
      : card_(std::move(card)), options_(std::move(options)), net_(std::move(net)), movable_ids_(std::move(movable)) {
    is_movable_.fill(false);
    for (int id : movable_ids_) is_movable_[id] = true;
    threshold_ = options_.threshold >= 0 ? options_.threshold : card_.decoder.threshold;
    score_threshold_ = options_.score_threshold >= 0 ? options_.score_threshold : card_.decoder.score_threshold;
  }

  const ModelCard& card() const override { return card_; }
  const std::vector<int>& movableClassIds() const override { return movable_ids_; }

  // Runs the network only; used by the start-up check too.
  Result<std::vector<cv::Mat>> infer(const cv::Mat& blob) {
    try {
      net_.setInput(blob, card_.input.name);
      std::vector<cv::Mat> outs;
      net_.forward(outs, card_.decoder.outputs);
      return outs;
    } catch (const cv::Exception& e) {
      return Error{"model '" + card_.model_path.string() + "': inference failed: " + e.what()};
    }
  }

  Result<Segmentation> segment(const cv::Mat& bgr) override {
    try {
      return segmentOrThrow(bgr);
    } catch (const cv::Exception& e) {
      return Error{"segment: OpenCV error: " + std::string(e.what())};
    } catch (const std::exception& e) {
      return Error{"segment: " + std::string(e.what())};
    }
  }

 private:
  Result<Segmentation> segmentOrThrow(const cv::Mat& bgr) {
    const auto t0 = std::chrono::steady_clock::now();
    if (bgr.empty()) return Error{"segment: empty image"};
    if (bgr.type() != CV_8UC3)
      return Error{"segment: expected an 8-bit 3-channel BGR image, got type " + std::to_string(bgr.type()) +
                   " with " + std::to_string(bgr.channels()) + " channel(s)"};
    Segmentation seg;
    const InputGeometry geometry =
        computeGeometry(bgr.size(), {card_.input.width, card_.input.height}, card_.input.resize);
    const cv::Mat blob = makeInputBlob(bgr, card_.input, geometry);
    seg.timing.preprocess_ms = msSince(t0);

    const auto t1 = std::chrono::steady_clock::now();
    auto outs = infer(blob);
    if (!outs) return Error{outs.error()};
    seg.timing.inference_ms = msSince(t1);

    const auto t2 = std::chrono::steady_clock::now();
    if (Status s = decode(*outs, geometry, &seg); !s) return Error{s.error()};
    seg.timing.decode_ms = msSince(t2);
    seg.timing.total_ms = msSince(t0);
    return seg;
  }

  Status decode(const std::vector<cv::Mat>& outs, const InputGeometry& geometry, Segmentation* seg) const {
    const std::string where = "model '" + card_.name + "': ";
    const DecoderSpec& spec = card_.decoder;
    const double min_area = options_.min_region_fraction * double(geometry.image.area());
    seg->movable_mask = cv::Mat(geometry.image, CV_8U, cv::Scalar(0));
    if (spec.type == DecoderType::kYoloInstance) {
      auto r = decodeYolo(outs[0], outs[1], spec, card_.classes, geometry, score_threshold_, threshold_);
      if (!r) return Error{where + r.error()};
      seg->labels = std::move(r->labels);
      seg->instances = std::move(r->instances);
      for (Instance& inst : seg->instances) inst.movable = is_movable_[inst.class_id];
      filterInstances(options_, min_area, seg);
    } else {
      Result<DenseDecoding> r =
          spec.type == DecoderType::kPersonProbability
              ? decodeProbabilityMap(outs[0], spec, geometry, threshold_)
              : decodeSemanticScores(outs[0], spec, int(card_.classes.size()), card_.classId(spec.background_class),
                                     geometry);
      if (!r) return Error{where + r.error()};
      seg->labels = std::move(r->labels);
      regionsFromDense(r->confidence, min_area, seg);
    }
    seg->movable_pixels = cv::countNonZero(seg->movable_mask);
    return Status::success();
  }

  // Dense decoders: every connected region of a movable class becomes an
  // instance; small or low-confidence regions stay out of the movable mask.
  void regionsFromDense(const cv::Mat& confidence, double min_area, Segmentation* seg) const {
    for (int class_id : movable_ids_) {
      const cv::Mat of_class = seg->labels == class_id;
      cv::Mat components, stats, centroids;
      const int n = cv::connectedComponentsWithStats(of_class, components, stats, centroids, 8, CV_32S);
      if (n <= 1) continue;
      // Mean confidence per region in one pass.
      std::vector<double> conf_sum(n, 0.0);
      for (int y = 0; y < components.rows; ++y) {
        const int* c = components.ptr<int>(y);
        const float* p = confidence.ptr<float>(y);
        for (int x = 0; x < components.cols; ++x)
          if (c[x]) conf_sum[c[x]] += p[x];
      }
      for (int i = 1; i < n; ++i) {
        Instance inst;
        inst.class_id = class_id;
        inst.class_name = card_.classes[class_id];
        inst.box = cv::Rect(stats.at<int>(i, cv::CC_STAT_LEFT), stats.at<int>(i, cv::CC_STAT_TOP),
                            stats.at<int>(i, cv::CC_STAT_WIDTH), stats.at<int>(i, cv::CC_STAT_HEIGHT));
        inst.area = stats.at<int>(i, cv::CC_STAT_AREA);
        inst.score = float(conf_sum[i] / std::max(1, inst.area));
        inst.mask = components(inst.box) == i;
        inst.movable = true;
        seg->instances.push_back(std::move(inst));
      }
    }
    filterInstances(options_, min_area, seg);
    std::sort(seg->instances.begin(), seg->instances.end(),
              [](const Instance& a, const Instance& b) { return a.area > b.area; });
  }

  ModelCard card_;
  SegmenterOptions options_;
  cv::dnn::Net net_;
  std::vector<int> movable_ids_;
  std::array<bool, 256> is_movable_{};
  double threshold_ = 0.5;
  double score_threshold_ = 0.25;
};

std::string dimsString(const std::vector<std::int64_t>& dims) {
  std::string s = "[";
  for (std::size_t i = 0; i < dims.size(); ++i) {
    if (i) s += ',';
    s += dims[i] < 0 ? std::string("?") : std::to_string(dims[i]);
  }
  s += ']';
  return s;
}

// The card's input against the shape the ONNX file declares.
Status checkDeclaredInput(const ModelCard& card, const std::vector<OnnxTensorInfo>& inputs) {
  const std::string where = "model card '" + card.card_path.string() + "': ";
  const OnnxTensorInfo* in = nullptr;
  if (card.input.name.empty()) {
    if (inputs.size() != 1)
      return Error{where + "field 'input.name' is needed: the model has " + std::to_string(inputs.size()) + " inputs"};
    in = &inputs[0];
  } else {
    for (const auto& i : inputs)
      if (i.name == card.input.name) in = &i;
    if (!in) {
      std::string names;
      for (const auto& i : inputs) { if (!names.empty()) names += ", "; names += i.name; }
      return Error{where + "field 'input.name': model has no input '" + card.input.name + "' (inputs: " + names + ")"};
    }
  }
  if (in->dims.empty()) return Status::success();  // shape not declared: the warm-up run decides
  if (in->dims.size() != 4)
    return Error{where + "model input '" + in->name + "' has shape " + dimsString(in->dims) + ", expected 4-D"};
  const bool nchw = card.input.layout == TensorLayout::kNCHW;
  const std::int64_t c = nchw ? in->dims[1] : in->dims[3];
  const std::int64_t h = nchw ? in->dims[2] : in->dims[1];
  const std::int64_t w = nchw ? in->dims[3] : in->dims[2];
  if (c > 0 && c != 3)
    return Error{where + "field 'input.layout': model input '" + in->name + "' has shape " + dimsString(in->dims) +
                 ", which is not 3-channel " + (nchw ? "NCHW" : "NHWC")};
  if ((h > 0 && h != card.input.height) || (w > 0 && w != card.input.width))
    return Error{where + "fields 'input.width'/'input.height' (" + std::to_string(card.input.width) + "x" +
                 std::to_string(card.input.height) + ") do not match the model input '" + in->name + "' " +
                 dimsString(in->dims) + (nchw ? " (NCHW)" : " (NHWC)")};
  return Status::success();
}

}  // namespace

namespace {

struct Device {
  const char* name;
  cv::dnn::Backend backend;
  cv::dnn::Target target;
};
constexpr Device kDevices[] = {{"cpu", cv::dnn::DNN_BACKEND_OPENCV, cv::dnn::DNN_TARGET_CPU},
                               {"cuda", cv::dnn::DNN_BACKEND_CUDA, cv::dnn::DNN_TARGET_CUDA},
                               {"cuda_fp16", cv::dnn::DNN_BACKEND_CUDA, cv::dnn::DNN_TARGET_CUDA_FP16},
                               {"opencl", cv::dnn::DNN_BACKEND_OPENCV, cv::dnn::DNN_TARGET_OPENCL},
                               {"opencl_fp16", cv::dnn::DNN_BACKEND_OPENCV, cv::dnn::DNN_TARGET_OPENCL_FP16}};

const Device* findDevice(const std::string& name) {
  for (const Device& d : kDevices)
    if (name == d.name) return &d;
  return nullptr;
}

// Whether this OpenCV build offers `d` (its backend compiled in, the target
// usable on this machine).
bool available(const Device& d) {
  try {
    const auto targets = cv::dnn::getAvailableTargets(d.backend);
    return std::find(targets.begin(), targets.end(), d.target) != targets.end();
  } catch (const cv::Exception&) {
    return false;
  }
}

}  // namespace

Status checkDevice(const std::string& device) {
  if (findDevice(device)) return Status::success();
  return Error{"'" + device + "' is not one of cpu, cuda, cuda_fp16, opencl, opencl_fp16"};
}

Status SegmenterOptions::validate() const {
  if (threads < 0 || threads > 256) return Error{"segmenter option 'threads' must be in 0..256"};
  if (Status s = checkDevice(device); !s) return Error{"segmenter option 'device': " + s.error()};
  if (threshold >= 1) return Error{"segmenter option 'threshold' must be below 1 (negative = card value)"};
  if (score_threshold >= 1) return Error{"segmenter option 'score_threshold' must be below 1 (negative = card value)"};
  if (!(min_region_fraction >= 0 && min_region_fraction < 1))
    return Error{"segmenter option 'min_region_fraction' must be in [0, 1)"};
  if (!(min_region_confidence >= 0 && min_region_confidence <= 1))
    return Error{"segmenter option 'min_region_confidence' must be in [0, 1]"};
  if (!(static_overlap_iou >= 0 && static_overlap_iou <= 1))
    return Error{"segmenter option 'static_overlap_iou' must be in [0, 1]"};
  return Status::success();
}

Result<std::unique_ptr<Segmenter>> createSegmenterOrThrow(const ModelCard& card, const SegmenterOptions& options);

Result<std::unique_ptr<Segmenter>> createSegmenter(const ModelCard& card, const SegmenterOptions& options) {
  try {
    return createSegmenterOrThrow(card, options);
  } catch (const std::exception& e) {
    return Error{"model card '" + card.card_path.string() + "': cannot create the segmenter: " + e.what()};
  }
}

Result<std::unique_ptr<Segmenter>> createSegmenterOrThrow(const ModelCard& card, const SegmenterOptions& options) {
  if (Status s = card.validate(); !s) return Error{s.error()};
  if (Status s = options.validate(); !s) return Error{s.error()};
  const std::string where = "model card '" + card.card_path.string() + "': ";

  std::vector<int> movable;
  std::vector<std::string> names = card.movable;
  if (options.movable_furniture) names.insert(names.end(), card.optional_movable.begin(), card.optional_movable.end());
  names.insert(names.end(), options.extra_movable.begin(), options.extra_movable.end());
  for (const auto& n : names) {
    const int id = card.classId(n);
    if (id < 0) return Error{where + "movable class '" + n + "' is not one of the card's classes"};
    if (std::find(movable.begin(), movable.end(), id) == movable.end()) movable.push_back(id);
  }
  std::sort(movable.begin(), movable.end());

  std::error_code ec;
  if (!std::filesystem::is_regular_file(card.model_path, ec))
    return Error{where + "field 'model': file '" + card.model_path.string() + "' does not exist"};
  std::ifstream in(card.model_path, std::ios::binary | std::ios::ate);
  const std::streamoff size = in ? std::streamoff(in.tellg()) : -1;
  std::string bytes(size > 0 ? std::size_t(size) : 0, '\0');
  in.seekg(0);
  if (size <= 0 || !in.read(bytes.data(), size))
    return Error{where + "cannot read model '" + card.model_path.string() + "' (empty or unreadable)"};
  auto inputs = parseOnnxInputs(bytes);
  if (!inputs) return Error{where + "model '" + card.model_path.string() + "': " + inputs.error()};
  if (Status s = checkDeclaredInput(card, *inputs); !s) return Error{s.error()};

  cv::dnn::Net net;
  try {
    net = cv::dnn::readNetFromONNX(bytes.data(), bytes.size());
  } catch (const cv::Exception& e) {
    return Error{where + "OpenCV cannot load model '" + card.model_path.string() + "': " + e.what()};
  }
  if (net.empty()) return Error{where + "OpenCV loaded an empty network from '" + card.model_path.string() + "'"};
  const Device* device = findDevice(options.device);
  if (!available(*device)) {
    SP_WARN(logger, "semantic device '" << device->name << "': this OpenCV build (" << CV_VERSION
                                        << ") cannot run it (no such dnn backend or target); running on the CPU");
    device = findDevice("cpu");
  }
  net.setPreferableBackend(device->backend);
  net.setPreferableTarget(device->target);
  for (const auto& out : card.decoder.outputs)
    if (net.getLayerId(out) < 0) {
      std::string names_list;
      for (const auto& n : net.getUnconnectedOutLayersNames()) { if (!names_list.empty()) names_list += ", "; names_list += n; }
      return Error{where + "field 'decoder.outputs': model has no output '" + out + "' (outputs: " + names_list + ")"};
    }
  if (options.threads > 0) cv::setNumThreads(options.threads);

  // One warm-up run on a grey frame of the input size: checks the output
  // shapes against the decoder now, not at the first keyframe. A device that
  // fails it (a GPU without the memory, a broken driver) gives way to the CPU.
  const cv::Mat probe(card.input.height, card.input.width, CV_8UC3, cv::Scalar(128, 128, 128));
  if (device->target != cv::dnn::DNN_TARGET_CPU) {
    auto trial = std::make_unique<DnnSegmenter>(card, options, net, movable);
    if (auto r = trial->segment(probe); r) {
      SP_INFO(logger, "'" << card.name << "' runs on " << device->name);
      return std::unique_ptr<Segmenter>(std::move(trial));
    } else {
      SP_WARN(logger, "semantic device '" << device->name << "' failed the warm-up (" << r.error()
                                          << "); running on the CPU");
      net.setPreferableBackend(cv::dnn::DNN_BACKEND_OPENCV);
      net.setPreferableTarget(cv::dnn::DNN_TARGET_CPU);
    }
  }
  auto seg = std::make_unique<DnnSegmenter>(card, options, std::move(net), std::move(movable));
  auto result = seg->segment(probe);
  if (!result) return Error{where + "the model's outputs do not match the card: " + result.error()};
  SP_INFO(logger, "loaded '" << card.name << "' (" << card.model_path.string() << "), warm-up "
                             << result->timing.total_ms << " ms, " << seg->movableClassIds().size()
                             << " movable classes");
  return std::unique_ptr<Segmenter>(std::move(seg));
}

Result<std::unique_ptr<Segmenter>> createSegmenter(const std::filesystem::path& card_path,
                                                   const SegmenterOptions& options) {
  auto card = loadModelCard(card_path);
  if (!card) return Error{card.error()};
  return createSegmenter(*card, options);
}

}  // namespace stillpoint::semantic
