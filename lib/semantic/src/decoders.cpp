#include "decoders.hpp"

#include <opencv2/dnn.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <numeric>

namespace stillpoint::semantic {

std::string shapeString(const cv::Mat& m) {
  if (m.empty()) return "[empty]";
  std::string s = "[";
  for (int i = 0; i < m.dims; ++i) {
    if (i) s += 'x';
    s += std::to_string(m.size[i]);
  }
  s += ']';
  return s;
}

cv::Point2d InputGeometry::toImage(cv::Point2d net) const {
  return {(net.x - content.x) * image.width / double(content.width),
          (net.y - content.y) * image.height / double(content.height)};
}

InputGeometry computeGeometry(cv::Size image, cv::Size network, ResizeMode mode) {
  InputGeometry g{image, network, cv::Rect(0, 0, network.width, network.height)};
  if (mode == ResizeMode::kLetterbox) {
    const double r = std::min(network.width / double(image.width), network.height / double(image.height));
    const int w = std::clamp(int(std::lround(image.width * r)), 1, network.width);
    const int h = std::clamp(int(std::lround(image.height * r)), 1, network.height);
    g.content = cv::Rect((network.width - w) / 2, (network.height - h) / 2, w, h);
  }
  return g;
}

cv::Mat makeInputBlob(const cv::Mat& bgr, const InputSpec& spec, const InputGeometry& g) {
  cv::Mat resized;
  if (bgr.size() == g.content.size())
    resized = bgr;
  else
    cv::resize(bgr, resized, g.content.size(), 0, 0, cv::INTER_LINEAR);
  cv::Mat canvas;
  if (g.content.size() == g.network) {
    canvas = resized;
  } else {
    canvas = cv::Mat(g.network, CV_8UC3, cv::Scalar::all(spec.pad_value));
    resized.copyTo(canvas(g.content));
  }
  cv::Mat ordered;
  if (spec.colour_order == ColourOrder::kRGB)
    cv::cvtColor(canvas, ordered, cv::COLOR_BGR2RGB);
  else
    ordered = canvas;
  // (p * scale - mean) / std == p * (scale / std) - mean / std, per channel.
  cv::Mat f;
  ordered.convertTo(f, CV_32FC3);
  const cv::Scalar gain(spec.scale / spec.std[0], spec.scale / spec.std[1], spec.scale / spec.std[2]);
  const cv::Scalar offset(spec.mean[0] / spec.std[0], spec.mean[1] / spec.std[1], spec.mean[2] / spec.std[2]);
  cv::multiply(f, gain, f);
  cv::subtract(f, offset, f);
  if (spec.layout == TensorLayout::kNCHW) return cv::dnn::blobFromImage(f, 1.0, cv::Size(), cv::Scalar(), false, false, CV_32F);
  const int shape[4] = {1, g.network.height, g.network.width, 3};
  return cv::Mat(4, shape, CV_32F, f.ptr<float>()).clone();
}

namespace {

// A map in network coordinates (any resolution) -> the image: to the network
// size, then its content rectangle to the image size.
cv::Mat networkToImage(const cv::Mat& net, const InputGeometry& g, int interpolation) {
  cv::Mat at_net;
  if (net.size() == g.network)
    at_net = net;
  else
    cv::resize(net, at_net, g.network, 0, 0, interpolation);
  cv::Mat out;
  cv::resize(at_net(g.content), out, g.image, 0, 0, interpolation);
  return out;
}

// Labels: nearest neighbour.
cv::Mat labelsToImage(const cv::Mat& net_labels, const InputGeometry& g) {
  return networkToImage(net_labels, g, cv::INTER_NEAREST);
}

}  // namespace

cv::Mat mapToImage(const cv::Mat& net_map, const InputGeometry& g) { return networkToImage(net_map, g, cv::INTER_LINEAR); }

namespace {

Error shapeError(const char* what, const cv::Mat& m, const std::string& expected) {
  return Error{std::string(what) + " has shape " + shapeString(m) + ", expected " + expected};
}

}  // namespace

Result<DenseDecoding> decodeProbabilityMap(const cv::Mat& output, const DecoderSpec& spec,
                                           const InputGeometry& geometry, double threshold) {
  if (output.empty() || output.type() != CV_32F)
    return Error{"probability output " + shapeString(output) + " is empty or not float"};
  int h = 0, w = 0;
  const int* s = output.size.p;
  if (output.dims == 4 && s[0] == 1 && spec.output_layout == TensorLayout::kNHWC && s[3] == 1) {
    h = s[1], w = s[2];
  } else if (output.dims == 4 && s[0] == 1 && spec.output_layout == TensorLayout::kNCHW && s[1] == 1) {
    h = s[2], w = s[3];
  } else if (output.dims == 3 && s[0] == 1) {
    h = s[1], w = s[2];
  } else {
    return shapeError("probability output", output,
                      spec.output_layout == TensorLayout::kNHWC ? "[1,H,W,1] (decoder.output_layout NHWC)"
                                                                : "[1,1,H,W] (decoder.output_layout NCHW)");
  }
  const cv::Mat map(h, w, CV_32F, const_cast<float*>(output.ptr<float>()));
  DenseDecoding d;
  d.confidence = mapToImage(map, geometry);
  d.labels = cv::Mat(geometry.image, CV_8U, cv::Scalar(kNoLabel));
  d.labels.setTo(0, d.confidence >= threshold);
  return d;
}

Result<DenseDecoding> decodeSemanticScores(const cv::Mat& output, const DecoderSpec& spec, int num_classes,
                                           int background_class, const InputGeometry& geometry) {
  if (output.empty() || output.type() != CV_32F)
    return Error{"score output " + shapeString(output) + " is empty or not float"};
  const bool nchw = spec.output_layout == TensorLayout::kNCHW;
  const int* s = output.size.p;
  if (output.dims != 4 || s[0] != 1 || (nchw ? s[1] : s[3]) != num_classes)
    return shapeError("score output", output,
                      nchw ? "[1," + std::to_string(num_classes) + ",H,W] (one plane per class in 'classes')"
                           : "[1,H,W," + std::to_string(num_classes) + "] (one score per class in 'classes')");
  const int h = nchw ? s[2] : s[1], w = nchw ? s[3] : s[2];
  const std::size_t plane = std::size_t(h) * w;
  const float* data = output.ptr<float>();
  // Channel c of pixel i: NCHW data[c * plane + i], NHWC data[i * C + c].
  const std::size_t pixel_stride = nchw ? 1 : num_classes;
  const std::size_t class_stride = nchw ? plane : 1;
  cv::Mat best_label(h, w, CV_8U), best_conf(h, w, CV_32F);
  auto* lab = best_label.ptr<std::uint8_t>();
  auto* conf = best_conf.ptr<float>();
  for (std::size_t i = 0; i < plane; ++i) {
    const float* p = data + i * pixel_stride;
    int best = 0;
    float best_score = p[0];
    for (int c = 1; c < num_classes; ++c) {
      const float v = p[c * class_stride];
      if (v > best_score) best_score = v, best = c;
    }
    float confidence = best_score;
    if (spec.softmax) {
      double sum = 0.0;
      for (int c = 0; c < num_classes; ++c) sum += std::exp(double(p[c * class_stride]) - best_score);
      confidence = float(1.0 / sum);
    }
    lab[i] = best == background_class ? kNoLabel : std::uint8_t(best);
    conf[i] = confidence;
  }
  DenseDecoding d;
  d.labels = labelsToImage(best_label, geometry);
  d.confidence = mapToImage(best_conf, geometry);
  return d;
}

float iou(const cv::Rect2f& a, const cv::Rect2f& b) {
  const float inter = (a & b).area();
  const float uni = a.area() + b.area() - inter;
  return uni > 0 ? inter / uni : 0.0f;
}

std::vector<int> classAwareNms(const std::vector<Detection>& dets, double iou_threshold, int max_keep) {
  std::vector<int> order(dets.size());
  std::iota(order.begin(), order.end(), 0);
  // Ties broken by index so the result does not depend on the sort's whims.
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return dets[a].score != dets[b].score ? dets[a].score > dets[b].score : a < b;
  });
  std::vector<int> keep;
  for (int i : order) {
    if (int(keep.size()) >= max_keep) break;
    bool suppressed = false;
    for (int k : keep) {
      if (dets[k].class_id == dets[i].class_id && iou(dets[k].box_net, dets[i].box_net) > iou_threshold) {
        suppressed = true;
        break;
      }
    }
    if (!suppressed) keep.push_back(i);
  }
  return keep;
}

Result<YoloDecoding> decodeYolo(const cv::Mat& detections, const cv::Mat& prototypes, const DecoderSpec& spec,
                                const std::vector<std::string>& class_names, const InputGeometry& geometry,
                                double score_threshold, double mask_threshold) {
  const int num_classes = int(class_names.size());
  const int k = spec.mask_coefficients;
  const int row_len = 5 + num_classes + k;
  if (detections.empty() || detections.type() != CV_32F || detections.dims != 3 ||
      detections.size[0] != 1 || detections.size[2] != row_len)
    return shapeError("detection output", detections,
                      "[1,N," + std::to_string(row_len) + "] (5 + " + std::to_string(num_classes) +
                          " classes + " + std::to_string(k) + " mask coefficients)");
  if (prototypes.empty() || prototypes.type() != CV_32F || prototypes.dims != 4 || prototypes.size[0] != 1 ||
      prototypes.size[1] != k)
    return shapeError("prototype output", prototypes, "[1," + std::to_string(k) + ",h,w]");
  const int n = detections.size[1];
  const int ph = prototypes.size[2], pw = prototypes.size[3];
  const float* rows = detections.ptr<float>();

  std::vector<Detection> candidates;
  for (int i = 0; i < n; ++i) {
    const float* r = rows + std::size_t(i) * row_len;
    const float objectness = r[4];
    if (!(objectness >= score_threshold)) continue;  // score = objectness x p <= objectness
    const float* cls = r + 5;
    const int best = int(std::max_element(cls, cls + num_classes) - cls);
    const float score = objectness * cls[best];
    if (!(score >= score_threshold) || !(r[2] > 0) || !(r[3] > 0)) continue;
    candidates.push_back({cv::Rect2f(r[0] - r[2] / 2, r[1] - r[3] / 2, r[2], r[3]), best, score, i});
  }
  const std::vector<int> keep = classAwareNms(candidates, spec.nms_threshold, spec.max_detections);

  YoloDecoding out;
  out.labels = cv::Mat(geometry.image, CV_8U, cv::Scalar(kNoLabel));
  const cv::Mat protos(k, ph * pw, CV_32F, const_cast<float*>(prototypes.ptr<float>()));
  const cv::Rect image_rect(0, 0, geometry.image.width, geometry.image.height);
  for (int idx : keep) {
    const Detection& det = candidates[idx];
    const cv::Point2d tl = geometry.toImage({det.box_net.x, det.box_net.y});
    const cv::Point2d br = geometry.toImage({det.box_net.x + det.box_net.width, det.box_net.y + det.box_net.height});
    // Pixels whose centre lies inside the box.
    const cv::Rect box = cv::Rect(cv::Point(int(std::ceil(tl.x - 0.5)), int(std::ceil(tl.y - 0.5))),
                                  cv::Point(int(std::ceil(br.x - 0.5)), int(std::ceil(br.y - 0.5)))) & image_rect;
    Instance inst;
    inst.class_id = det.class_id;
    inst.class_name = class_names[det.class_id];
    inst.score = det.score;
    inst.box = box;
    if (box.area() > 0) {
      const cv::Mat coeffs(1, k, CV_32F, const_cast<float*>(rows + std::size_t(det.row) * row_len + 5 + num_classes));
      cv::Mat logits = coeffs * protos;  // 1 x (ph*pw)
      cv::Mat prob;
      cv::exp(-logits, prob);
      prob = 1.0 / (1.0 + prob);
      const cv::Mat full = mapToImage(prob.reshape(1, ph), geometry);
      inst.mask = full(box) > mask_threshold;
      inst.area = cv::countNonZero(inst.mask);
    } else {
      inst.mask = cv::Mat(box.size(), CV_8U, cv::Scalar(0));
    }
    out.instances.push_back(std::move(inst));
  }
  for (auto it = out.instances.rbegin(); it != out.instances.rend(); ++it)
    if (it->area > 0) out.labels(it->box).setTo(it->class_id, it->mask);
  return out;
}

}  // namespace stillpoint::semantic
