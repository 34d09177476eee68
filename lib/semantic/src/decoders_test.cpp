// Decoders on hand-made output blobs: letterbox geometry and its exact undo,
// the probability map, per-pixel argmax, YOLO scores, NMS and masks.
#include "decoders.hpp"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

namespace stillpoint::semantic {
namespace {

cv::Mat blob(std::vector<int> shape, float fill = 0.0f) {
  return cv::Mat(int(shape.size()), shape.data(), CV_32F, cv::Scalar(fill));
}

TEST(Geometry, LetterboxCentresAndUndoesExactly) {
  const InputGeometry g = computeGeometry({640, 480}, {320, 320}, ResizeMode::kLetterbox);
  EXPECT_EQ(g.content, cv::Rect(0, 40, 320, 240));
  EXPECT_EQ(g.toImage({0, 40}), cv::Point2d(0, 0));
  EXPECT_EQ(g.toImage({320, 280}), cv::Point2d(640, 480));
  EXPECT_EQ(g.toImage({160, 160}), cv::Point2d(320, 240));
  // Portrait image: padding left and right.
  const InputGeometry p = computeGeometry({300, 600}, {320, 320}, ResizeMode::kLetterbox);
  EXPECT_EQ(p.content, cv::Rect(80, 0, 160, 320));
  EXPECT_EQ(p.toImage({240, 320}), cv::Point2d(300, 600));
  // Stretch: the whole input, no padding.
  const InputGeometry s = computeGeometry({640, 480}, {256, 256}, ResizeMode::kStretch);
  EXPECT_EQ(s.content, cv::Rect(0, 0, 256, 256));
  EXPECT_EQ(s.toImage({128, 64}), cv::Point2d(320, 120));
}

TEST(Geometry, InputBlobHasPaddingScaleAndColourOrder) {
  InputSpec spec;
  spec.width = 8, spec.height = 8, spec.resize = ResizeMode::kLetterbox, spec.pad_value = 114;
  spec.colour_order = ColourOrder::kRGB, spec.scale = 1.0 / 255.0;
  spec.mean = {0.5, 0.0, 0.0}, spec.std = {0.5, 1.0, 1.0};
  const cv::Mat bgr(4, 8, CV_8UC3, cv::Scalar(255, 0, 51));  // B=255, G=0, R=51
  const InputGeometry g = computeGeometry(bgr.size(), {8, 8}, spec.resize);
  ASSERT_EQ(g.content, cv::Rect(0, 2, 8, 4));
  const cv::Mat nchw = makeInputBlob(bgr, spec, g);
  ASSERT_EQ(shapeString(nchw), "[1x3x8x8]");
  auto at = [&](int c, int y, int x) { return nchw.ptr<float>()[(c * 8 + y) * 8 + x]; };
  EXPECT_NEAR(at(0, 4, 4), (51 / 255.0 - 0.5) / 0.5, 1e-5);  // R first, normalised
  EXPECT_NEAR(at(2, 4, 4), 1.0, 1e-5);                          // B last
  EXPECT_NEAR(at(1, 0, 0), 114 / 255.0, 1e-5);                  // padding row
  spec.layout = TensorLayout::kNHWC;
  const cv::Mat nhwc = makeInputBlob(bgr, spec, g);
  ASSERT_EQ(shapeString(nhwc), "[1x8x8x3]");
  EXPECT_NEAR(nhwc.ptr<float>()[(4 * 8 + 4) * 3 + 2], 1.0, 1e-5);
}

TEST(ProbabilityMap, ThresholdsAtImageResolution) {
  cv::Mat out = blob({1, 4, 4, 1}, 0.1f);
  float* p = out.ptr<float>();
  p[0] = p[1] = p[4] = p[5] = 0.9f;  // top-left quadrant
  DecoderSpec spec;
  spec.output_layout = TensorLayout::kNHWC;
  const InputGeometry g = computeGeometry({40, 40}, {4, 4}, ResizeMode::kStretch);
  auto d = decodeProbabilityMap(out, spec, g, 0.5);
  ASSERT_TRUE(d.ok()) << d.error();
  ASSERT_EQ(d->labels.size(), cv::Size(40, 40));
  EXPECT_EQ(d->labels.at<uchar>(5, 5), 0);
  EXPECT_EQ(d->labels.at<uchar>(30, 30), kNoLabel);
  EXPECT_EQ(d->labels.at<uchar>(5, 30), kNoLabel);
  EXPECT_NEAR(d->confidence.at<float>(2, 2), 0.9f, 1e-5);
  // The card says NCHW but the blob is NHWC: a shape error, not garbage.
  spec.output_layout = TensorLayout::kNCHW;
  auto bad = decodeProbabilityMap(out, spec, g, 0.5);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().find("[1x4x4x1]"), std::string::npos) << bad.error();
}

TEST(SemanticArgmax, PicksBestClassAndMapsBackground) {
  // 3 classes, 2x2 output, NCHW. Pixel (0,0): class 1, (0,1): class 2,
  // (1,0): class 0 (background), (1,1): class 2.
  cv::Mat out = blob({1, 3, 2, 2});
  float* p = out.ptr<float>();
  const float scores[3][4] = {{0.1f, 0.2f, 0.9f, 0.0f}, {0.8f, 0.1f, 0.05f, 0.3f}, {0.1f, 0.7f, 0.05f, 0.7f}};
  for (int c = 0; c < 3; ++c)
    for (int i = 0; i < 4; ++i) p[c * 4 + i] = scores[c][i];
  DecoderSpec spec;
  spec.output_layout = TensorLayout::kNCHW;
  const InputGeometry g = computeGeometry({2, 2}, {2, 2}, ResizeMode::kStretch);
  auto d = decodeSemanticScores(out, spec, 3, 0, g);
  ASSERT_TRUE(d.ok()) << d.error();
  EXPECT_EQ(d->labels.at<uchar>(0, 0), 1);
  EXPECT_EQ(d->labels.at<uchar>(0, 1), 2);
  EXPECT_EQ(d->labels.at<uchar>(1, 0), kNoLabel);
  EXPECT_EQ(d->labels.at<uchar>(1, 1), 2);
  EXPECT_NEAR(d->confidence.at<float>(0, 0), 0.8f, 1e-6);

  // Same scores as NHWC, with softmax confidences and no background class.
  cv::Mat nhwc = blob({1, 2, 2, 3});
  for (int c = 0; c < 3; ++c)
    for (int i = 0; i < 4; ++i) nhwc.ptr<float>()[i * 3 + c] = scores[c][i];
  spec.output_layout = TensorLayout::kNHWC;
  spec.softmax = true;
  auto e = decodeSemanticScores(nhwc, spec, 3, -1, g);
  ASSERT_TRUE(e.ok()) << e.error();
  EXPECT_EQ(e->labels.at<uchar>(1, 0), 0);
  EXPECT_EQ(e->labels.at<uchar>(0, 0), 1);
  const double softmax = std::exp(0.8) / (std::exp(0.1) + std::exp(0.8) + std::exp(0.1));
  EXPECT_NEAR(e->confidence.at<float>(0, 0), softmax, 1e-5);

  auto wrong = decodeSemanticScores(out, DecoderSpec{}, 21, 0, g);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.error().find("[1,21,H,W]"), std::string::npos) << wrong.error();
}

Detection det(float x, float y, float w, float h, int cls, float score) {
  return {cv::Rect2f(x, y, w, h), cls, score, -1};
}

TEST(Nms, SuppressesOverlapsOfTheSameClassOnly) {
  // Boxes 0, 1, 3 are class 0; IoU(1, 0) = 80/120 = 0.67, IoU(1, 3) = 60/140 = 0.43.
  const std::vector<Detection> dets = {det(0, 0, 10, 10, 0, 0.6f), det(2, 0, 10, 10, 0, 0.9f),
                                       det(2, 0, 10, 10, 1, 0.5f), det(6, 0, 10, 10, 0, 0.4f)};
  EXPECT_NEAR(iou(dets[0].box_net, dets[1].box_net), 80.0 / 120.0, 1e-6);
  const std::vector<int> keep = classAwareNms(dets, 0.45, 100);
  // 1 (best) suppresses 0; 3 survives at 0.45 but not at 0.4; 2 is another
  // class and survives although it overlaps 1 completely.
  EXPECT_EQ(keep, (std::vector<int>{1, 2, 3}));
  EXPECT_EQ(classAwareNms(dets, 0.4, 100), (std::vector<int>{1, 2}));
  EXPECT_EQ(classAwareNms(dets, 0.45, 1), (std::vector<int>{1}));
}

// A YOLO-style output for 3 classes and 2 mask coefficients on a 320x320
// input with 80x80 prototypes.
struct YoloBlobs {
  static constexpr int kClasses = 3, kCoeffs = 2, kRowLen = 5 + kClasses + kCoeffs;
  cv::Mat det = blob({1, 4, kRowLen});
  cv::Mat protos = blob({1, kCoeffs, 80, 80}, -10.0f);
  void set(int row, std::vector<float> values) {
    std::copy(values.begin(), values.end(), det.ptr<float>() + row * kRowLen);
  }
};

TEST(Yolo, DecodesScoresBoxesAndMasksThroughTheLetterbox) {
  YoloBlobs y;
  // Prototype 0: +10 everywhere; prototype 1: +10 on the left half only.
  std::fill(y.protos.ptr<float>(), y.protos.ptr<float>() + 80 * 80, 10.0f);
  for (int r = 0; r < 80; ++r)
    for (int c = 0; c < 40; ++c) y.protos.ptr<float>()[80 * 80 + r * 80 + c] = 10.0f;
  //           cx   cy   w    h    obj  p0   p1   p2   m0  m1
  y.set(0, {150, 140, 100, 80, 0.9f, 0.1f, 0.9f, 0.0f, 1, 0});   // class 1, score 0.81, full box mask
  y.set(1, {150, 140, 100, 80, 0.5f, 0.4f, 0.0f, 0.0f, 1, 0});   // score 0.2 < 0.25: dropped
  y.set(2, {160, 160, 200, 200, 0.8f, 0.0f, 0.0f, 0.9f, 0, 1});  // class 2, left-half mask
  y.set(3, {152, 140, 100, 80, 0.9f, 0.1f, 0.8f, 0.0f, 1, 0});   // same class as row 0, IoU 0.96: suppressed
  DecoderSpec spec;
  spec.type = DecoderType::kYoloInstance;
  spec.mask_coefficients = 2;
  const InputGeometry g = computeGeometry({640, 480}, {320, 320}, ResizeMode::kLetterbox);
  auto d = decodeYolo(y.det, y.protos, spec, {"a", "b", "c"}, g, 0.25, 0.5);
  ASSERT_TRUE(d.ok()) << d.error();
  ASSERT_EQ(d->instances.size(), 2u);
  const Instance& first = d->instances[0];
  EXPECT_EQ(first.class_id, 1);
  EXPECT_EQ(first.class_name, "b");
  EXPECT_NEAR(first.score, 0.81f, 1e-6);
  // Net box (100,100)-(200,180) -> image (200,120)-(400,280): x*2, (y-40)*2.
  EXPECT_EQ(first.box, cv::Rect(200, 120, 200, 160));
  EXPECT_EQ(first.area, 200 * 160);
  const Instance& second = d->instances[1];
  EXPECT_EQ(second.class_id, 2);
  // Net box (60,60)-(260,260) -> image (120,40)-(520,440); mask = net x < 160 = image x < 320.
  EXPECT_EQ(second.box, cv::Rect(120, 40, 400, 400));
  EXPECT_NEAR(second.area, 200 * 400, 2 * 400);  // one bilinear column either side
  EXPECT_EQ(second.mask.at<uchar>(200, 10), 255);
  EXPECT_EQ(second.mask.at<uchar>(200, 390), 0);
  // Labels: the higher-scoring instance is painted last, so it wins the overlap.
  EXPECT_EQ(d->labels.at<uchar>(200, 300), 1);
  EXPECT_EQ(d->labels.at<uchar>(100, 150), 2);
  EXPECT_EQ(d->labels.at<uchar>(100, 450), kNoLabel);
  EXPECT_EQ(d->labels.at<uchar>(10, 10), kNoLabel);
}

TEST(Yolo, RejectsOutputsThatDoNotMatchTheCard) {
  YoloBlobs y;
  DecoderSpec spec;
  spec.type = DecoderType::kYoloInstance;
  spec.mask_coefficients = 32;  // the blobs have 2
  const InputGeometry g = computeGeometry({640, 480}, {320, 320}, ResizeMode::kLetterbox);
  auto d = decodeYolo(y.det, y.protos, spec, {"a", "b", "c"}, g, 0.25, 0.5);
  ASSERT_FALSE(d.ok());
  EXPECT_NE(d.error().find("32 mask coefficients"), std::string::npos) << d.error();
  spec.mask_coefficients = 2;
  auto e = decodeYolo(y.det, y.protos, spec, {"a", "b", "c", "d"}, g, 0.25, 0.5);
  ASSERT_FALSE(e.ok());
  EXPECT_NE(e.error().find("4 classes"), std::string::npos) << e.error();
  auto f = decodeYolo(y.det, cv::Mat(), spec, {"a", "b", "c"}, g, 0.25, 0.5);
  ASSERT_FALSE(f.ok());
}

}  // namespace
}  // namespace stillpoint::semantic

// ---- Post-filter ----------------------------------------------------------
#include "post_filter.hpp"

namespace stillpoint::semantic {
namespace {

Instance square(const std::string& name, bool movable, float score, cv::Rect box) {
  Instance inst;
  inst.class_name = name;
  inst.movable = movable;
  inst.score = score;
  inst.box = box;
  inst.mask = cv::Mat(box.size(), CV_8U, cv::Scalar(255));
  inst.area = box.area();
  return inst;
}

TEST(PostFilter, DropsSmallWeakAndRelabelledInstancesVisibly) {
  Segmentation seg;
  seg.movable_mask = cv::Mat(100, 100, CV_8U, cv::Scalar(0));
  seg.instances = {
      square("teddy bear", false, 0.78f, {10, 10, 40, 40}),
      square("person", true, 0.66f, {12, 10, 40, 40}),   // mask IoU 0.9 with the bear: same object
      square("person", true, 0.90f, {60, 60, 30, 30}),   // real
      square("dog", true, 0.50f, {0, 90, 3, 3}),          // 9 px: too small
      square("cat", true, 0.30f, {60, 10, 20, 20}),       // below the confidence floor
      square("person", true, 0.95f, {10, 10, 40, 40}),    // stronger than the bear: kept
  };
  SegmenterOptions options;
  options.min_region_confidence = 0.4;
  options.static_overlap_iou = 0.6;
  filterInstances(options, 20.0, &seg);
  EXPECT_FALSE(seg.instances[1].kept);
  EXPECT_EQ(seg.instances[1].drop_reason, "same object as static 'teddy bear'");
  EXPECT_TRUE(seg.instances[2].kept);
  EXPECT_EQ(seg.instances[3].drop_reason, "area");
  EXPECT_EQ(seg.instances[4].drop_reason, "confidence");
  EXPECT_TRUE(seg.instances[5].kept);
  EXPECT_TRUE(seg.instances[0].kept);  // static instances are never in the mask
  EXPECT_EQ(seg.movable_mask.at<uchar>(75, 75), 255);
  EXPECT_EQ(seg.movable_mask.at<uchar>(91, 1), 0);
  EXPECT_EQ(seg.filtered_pixels, 1600 + 9 + 400);
  EXPECT_NEAR(maskIou(seg.instances[0], seg.instances[1]), 38.0 * 40 / (2 * 1600 - 38 * 40), 1e-9);

  // Switched off, the relabelled teddy stays in the mask.
  Segmentation off = seg;
  off.movable_mask = cv::Mat(100, 100, CV_8U, cv::Scalar(0));
  off.filtered_pixels = 0;
  off.instances.erase(off.instances.begin() + 5);
  options.static_overlap_iou = 0;
  filterInstances(options, 20.0, &off);
  EXPECT_TRUE(off.instances[1].kept);
  EXPECT_EQ(off.movable_mask.at<uchar>(30, 48), 255);
}

}  // namespace
}  // namespace stillpoint::semantic

// ---- ONNX input reader ----------------------------------------------------
#include <fstream>
#include <random>

#include "onnx_info.hpp"

namespace stillpoint::semantic {
namespace {

TEST(OnnxInputs, ReadsDeclaredShapesAndSurvivesCorruptFiles) {
  std::ifstream in(std::string(STILLPOINT_PROJECT_MODELS_DIR) + "/person_selfie_256.onnx", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 100000u);
  auto inputs = parseOnnxInputs(bytes);
  ASSERT_TRUE(inputs.ok()) << inputs.error();
  ASSERT_EQ(inputs->size(), 1u);
  EXPECT_EQ((*inputs)[0].name, "input_1");
  EXPECT_EQ((*inputs)[0].dims, (std::vector<std::int64_t>{1, 3, 256, 256}));
  // Truncated and bit-flipped copies: an error or a result, never a crash.
  std::mt19937 rng(7);
  for (int i = 0; i < 200; ++i) {
    std::string broken = bytes.substr(0, rng() % bytes.size());
    for (int k = 0; k < 4 && !broken.empty(); ++k) broken[rng() % broken.size()] ^= char(1 << (rng() % 8));
    auto r = parseOnnxInputs(broken);
    if (r.ok()) {
      EXPECT_FALSE(r->empty());
    }
  }
  EXPECT_FALSE(parseOnnxInputs("").ok());
  EXPECT_FALSE(parseOnnxInputs(std::string(64, '\xff')).ok());
}

}  // namespace
}  // namespace stillpoint::semantic

// ---- Depth agreement ------------------------------------------------------
#include "stillpoint/semantic/depth_agreement.hpp"

namespace stillpoint::semantic {
namespace {

TEST(DepthAgreement, CutsBackgroundOutOfTheMaskAndKeepsPixelsWithoutDepth) {
  // A person at 2 m whose mask bleeds 10 columns onto a wall at 4 m; some
  // mask pixels have no depth.
  Segmentation seg;
  seg.movable_mask = cv::Mat(60, 80, CV_8U, cv::Scalar(0));
  Instance person;
  person.class_name = "person";
  person.movable = true;
  person.box = cv::Rect(10, 10, 40, 40);
  person.mask = cv::Mat(40, 40, CV_8U, cv::Scalar(255));
  person.area = 1600;
  seg.instances = {person};
  seg.movable_mask(person.box).setTo(255);
  cv::Mat depth(60, 80, CV_16U, cv::Scalar(4.0 * 5000));     // wall
  depth(cv::Rect(10, 10, 30, 40)).setTo(2.0 * 5000);         // the person: columns 10..39
  depth(cv::Rect(12, 12, 4, 4)).setTo(0);                    // no measurement
  auto r = applyDepthAgreement(depth, {}, &seg);
  ASSERT_TRUE(r.ok()) << r.error();
  ASSERT_EQ(r->size(), 1u);
  EXPECT_FLOAT_EQ((*r)[0].median_m, 2.0f);
  EXPECT_EQ((*r)[0].removed_pixels, 10 * 40);
  EXPECT_EQ(seg.instances[0].area, 1200);
  EXPECT_EQ(seg.movable_pixels, 1200);
  EXPECT_EQ(seg.movable_mask.at<uchar>(30, 45), 0);    // wall
  EXPECT_EQ(seg.movable_mask.at<uchar>(30, 20), 255);  // person
  EXPECT_EQ(seg.movable_mask.at<uchar>(13, 13), 255);  // no depth: kept

  auto wrong = applyDepthAgreement(cv::Mat(10, 10, CV_16U), {}, &seg);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.error().find("10x10"), std::string::npos) << wrong.error();
  EXPECT_FALSE(applyDepthAgreement(cv::Mat(60, 80, CV_8U), {}, &seg).ok());
}

}  // namespace
}  // namespace stillpoint::semantic
