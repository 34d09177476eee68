// The dnn segmenter end to end: the hand-made semantic network, start-up
// errors, and the real models on real photos (astronaut.png, coffee.png).
// Tests that need ../shared/models (STILLPOINT_MODELS_DIR) skip without it.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stillpoint/semantic/segmenter.hpp"

namespace stillpoint::semantic {
namespace {

namespace fs = std::filesystem;
const fs::path kSharedModels = STILLPOINT_MODELS_DIR;
const fs::path kProjectModels = STILLPOINT_PROJECT_MODELS_DIR;
const fs::path kTestData = STILLPOINT_SEMANTIC_TESTDATA;

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

fs::path tempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("stillpoint_seg_test_" + std::to_string(::getpid())) / name;
  fs::create_directories(dir);
  return dir;
}

double coverage(const cv::Mat& mask, const cv::Rect& r) { return cv::countNonZero(mask(r)) / double(r.area()); }

// Red | grey | blue bands: the tiny network labels them person | none | car.
cv::Mat bands() {
  cv::Mat bgr(48, 64, CV_8UC3, cv::Scalar(128, 128, 128));
  bgr(cv::Rect(0, 0, 24, 48)).setTo(cv::Scalar(0, 0, 255));
  bgr(cv::Rect(40, 0, 24, 48)).setTo(cv::Scalar(255, 0, 0));
  return bgr;
}

TEST(TinySemantic, ArgmaxLabelsMovableMaskAndRegions) {
  auto seg = createSegmenter(kTestData / "tiny_semantic.yaml");
  ASSERT_TRUE(seg.ok()) << seg.error();
  auto r = (*seg)->segment(bands());
  ASSERT_TRUE(r.ok()) << r.error();
  ASSERT_EQ(r->labels.size(), cv::Size(64, 48));
  EXPECT_EQ(r->labels.at<uchar>(24, 10), 1);  // person
  EXPECT_EQ(r->labels.at<uchar>(24, 32), kNoLabel);
  EXPECT_EQ(r->labels.at<uchar>(24, 56), 2);  // car
  EXPECT_EQ(r->labels.at<uchar>(0, 10), 1);   // letterbox padding is not in the image
  EXPECT_EQ(r->movable_mask.at<uchar>(24, 10), 255);
  EXPECT_EQ(r->movable_mask.at<uchar>(24, 32), 0);
  // Two movable regions, one per band; their union is the movable mask.
  ASSERT_EQ(r->instances.size(), 2u);
  int area = 0;
  for (const Instance& inst : r->instances) {
    EXPECT_TRUE(inst.kept);
    EXPECT_GT(inst.score, 0.5f);  // softmax confidence of the winning class
    area += inst.area;
  }
  EXPECT_EQ(area, r->movable_pixels);
  EXPECT_NEAR(r->movableFraction(), 48.0 / 64.0, 0.1);
  EXPECT_EQ(r->filtered_pixels, 0);
  // Only "person" movable: the car band leaves the mask.
  auto card = loadModelCard(kTestData / "tiny_semantic.yaml");
  ASSERT_TRUE(card.ok());
  card->movable = {"person"};
  auto person_only = createSegmenter(*card);
  ASSERT_TRUE(person_only.ok()) << person_only.error();
  auto p = (*person_only)->segment(bands());
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(p->movable_mask.at<uchar>(24, 56), 0);
  EXPECT_EQ(p->labels.at<uchar>(24, 56), 2);
}

// Every device name is accepted; where this OpenCV build cannot run it (no
// CUDA here; OpenCL only with a platform), the segmenter falls back to the
// CPU and labels as it does there. An unknown device is an error.
TEST(TinySemantic, AnyDeviceRunsAndFallsBackToTheCpu) {
  auto cpu = createSegmenter(kTestData / "tiny_semantic.yaml");
  ASSERT_TRUE(cpu.ok()) << cpu.error();
  auto expected = (*cpu)->segment(bands());
  ASSERT_TRUE(expected.ok()) << expected.error();
  for (const char* device : {"cuda", "cuda_fp16", "opencl", "opencl_fp16"}) {
    SegmenterOptions options;
    options.device = device;
    auto seg = createSegmenter(kTestData / "tiny_semantic.yaml", options);
    ASSERT_TRUE(seg.ok()) << device << ": " << seg.error();
    auto r = (*seg)->segment(bands());
    ASSERT_TRUE(r.ok()) << device << ": " << r.error();
    EXPECT_EQ(r->movable_pixels, expected->movable_pixels) << device;
  }
  SegmenterOptions bad;
  bad.device = "gpu";
  auto seg = createSegmenter(kTestData / "tiny_semantic.yaml", bad);
  ASSERT_FALSE(seg.ok());
  EXPECT_NE(seg.error().find("'gpu' is not one of"), std::string::npos) << seg.error();
}

TEST(TinySemantic, PostFilterDropsSmallRegionsVisibly) {
  SegmenterOptions options;
  options.min_region_fraction = 0.5;  // both bands are ~37 % of the image
  auto seg = createSegmenter(kTestData / "tiny_semantic.yaml", options);
  ASSERT_TRUE(seg.ok()) << seg.error();
  auto r = (*seg)->segment(bands());
  ASSERT_TRUE(r.ok()) << r.error();
  EXPECT_EQ(r->movable_pixels, 0);
  EXPECT_GT(r->filtered_pixels, 48 * 48 / 2);
  ASSERT_EQ(r->instances.size(), 2u);
  EXPECT_FALSE(r->instances[0].kept);
  EXPECT_EQ(r->labels.at<uchar>(24, 10), 1);  // labels stay raw
}

// The intended use: created on one thread, used from one worker thread.
TEST(TinySemantic, RunsOnAWorkerThread) {
  auto seg = createSegmenter(kTestData / "tiny_semantic.yaml");
  ASSERT_TRUE(seg.ok()) << seg.error();
  std::unique_ptr<Segmenter> segmenter = std::move(seg).value();
  int movable = -1;
  {
    std::jthread worker([s = segmenter.get(), &movable] {
      for (int i = 0; i < 3; ++i) {
        auto r = s->segment(bands());
        movable = r.ok() ? r->movable_pixels : -1;
      }
    });
  }
  EXPECT_GT(movable, 0);
}

TEST(TinySemantic, BadImagesAreErrors) {
  auto seg = createSegmenter(kTestData / "tiny_semantic.yaml");
  ASSERT_TRUE(seg.ok()) << seg.error();
  auto empty = (*seg)->segment(cv::Mat());
  ASSERT_FALSE(empty.ok());
  EXPECT_TRUE(contains(empty.error(), "empty")) << empty.error();
  auto grey = (*seg)->segment(cv::Mat(10, 10, CV_8UC1, cv::Scalar(3)));
  ASSERT_FALSE(grey.ok());
  EXPECT_TRUE(contains(grey.error(), "3-channel")) << grey.error();
  auto tiny = (*seg)->segment(cv::Mat(1, 1, CV_8UC3, cv::Scalar(0, 0, 255)));
  EXPECT_TRUE(tiny.ok()) << tiny.error();
}

// A copy of a card with some lines replaced, next to a given model.
fs::path editedCard(const fs::path& card, const std::string& name,
                    const std::vector<std::pair<std::string, std::string>>& edits, const fs::path& model) {
  std::ifstream in(card);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  for (const auto& [from, to] : edits) {
    const auto at = text.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    if (at != std::string::npos) text.replace(at, from.size(), to);
  }
  const fs::path dir = tempDir(name);
  const auto model_at = text.find("model: ");
  text.replace(model_at, text.find('\n', model_at) - model_at, "model: " + model.string());
  std::ofstream(dir / "card.yaml") << text;
  return dir / "card.yaml";
}

TEST(StartUpErrors, MissingCorruptOrMismatchedModels) {
  const fs::path tiny_card = kTestData / "tiny_semantic.yaml";
  const fs::path tiny_model = kTestData / "tiny_semantic.onnx";
  const fs::path person_card = kProjectModels / "person_selfie_256.yaml";
  const fs::path person_model = kProjectModels / "person_selfie_256.onnx";
  struct Case {
    fs::path card;
    std::vector<std::pair<std::string, std::string>> edits;
    fs::path model;
    std::string expect;
  };
  const fs::path garbage = tempDir("garbage") / "garbage.onnx";
  std::ofstream(garbage) << "this is not a network";
  const fs::path empty = tempDir("garbage") / "empty.onnx";
  std::ofstream{empty};
  const std::vector<Case> cases = {
      {tiny_card, {}, "/nonexistent/model.onnx", "does not exist"},
      {tiny_card, {}, garbage, "not a valid ONNX"},
      {tiny_card, {}, empty, "empty or unreadable"},
      {person_card, {{"width: 256", "width: 320"}}, person_model, "'input.width'/'input.height' (320x256)"},
      {person_card, {{"layout: NCHW", "layout: NHWC"}}, person_model, "input.layout"},
      {person_card, {{"name: input_1", "name: input_2"}}, person_model, "no input 'input_2'"},
      {person_card, {{"outputs: [activation_10]", "outputs: [mask]"}}, person_model, "no output 'mask'"},
      {person_card, {{"output_layout: NHWC", "output_layout: NCHW"}}, person_model, "[1,1,H,W]"},
      {tiny_card, {{"classes: [background, person, car]", "classes: [background, person, car, dog]"}}, tiny_model,
       "do not match the card"},
      {tiny_card, {{"type: semantic_argmax", "type: person_probability"}, {"classes: [background, person, car]", "classes: [person]"},
                   {"movable: [person, car]", "movable: [person]"}, {"  background_class: background\n", ""}},
       tiny_model, "probability output"},
  };
  for (const Case& c : cases) {
    const fs::path card = editedCard(c.card, "case", c.edits, c.model);
    auto seg = createSegmenter(card);
    ASSERT_FALSE(seg.ok()) << "accepted a bad model: " << c.expect;
    EXPECT_TRUE(contains(seg.error(), c.expect)) << seg.error();
  }
  SegmenterOptions options;
  options.extra_movable = {"unicorn"};
  auto seg = createSegmenter(tiny_card, options);
  ASSERT_FALSE(seg.ok());
  EXPECT_TRUE(contains(seg.error(), "unicorn")) << seg.error();
  options = {};
  options.min_region_fraction = 2;
  seg = createSegmenter(tiny_card, options);
  ASSERT_FALSE(seg.ok());
  EXPECT_TRUE(contains(seg.error(), "min_region_fraction")) << seg.error();
}

// ---- Real models on real photos ------------------------------------------

// Regions of astronaut.png checked by looking at the image (512x512): the
// face, the orange suit, and grey studio background right of the head.
const cv::Rect kFace(185, 80, 80, 90);
const cv::Rect kSuit(80, 330, 120, 150);
const cv::Rect kBackground(300, 10, 50, 50);

cv::Mat testImage(const char* name) {
  return cv::imread((kSharedModels / "testdata" / name).string(), cv::IMREAD_COLOR);
}

#define REQUIRE_SHARED(file)                                                                    \
  if (!fs::exists(kSharedModels / (file)))                                                     \
  GTEST_SKIP() << (kSharedModels / (file)).string() << " not found (set STILLPOINT_MODELS_DIR)"

void expectAstronautPerson(const Segmentation& r, const std::string& model) {
  SCOPED_TRACE(model);
  std::printf("[ %s ] astronaut.png: person %.1f %% of the image, face %.0f %%, background %.0f %%\n",
              model.c_str(), 100 * r.movableFraction(), 100 * coverage(r.movable_mask, kFace),
              100 * coverage(r.movable_mask, kBackground));
  EXPECT_GE(r.movableFraction(), 0.35);
  EXPECT_GE(coverage(r.movable_mask, kFace), 0.9);
  EXPECT_GE(coverage(r.movable_mask, kSuit), 0.9);
  EXPECT_LE(coverage(r.movable_mask, kBackground), 0.1);
}

TEST(PersonModel, LabelsTheAstronautFromTheInTreeCopy) {
  REQUIRE_SHARED("testdata/astronaut.png");
  for (const char* card : {"person_selfie_256.yaml", "person_selfie_landscape_144x256.yaml"}) {
    auto seg = createSegmenter(kProjectModels / card);
    ASSERT_TRUE(seg.ok()) << seg.error();
    auto r = (*seg)->segment(testImage("astronaut.png"));
    ASSERT_TRUE(r.ok()) << r.error();
    ASSERT_EQ(r->labels.size(), cv::Size(512, 512));
    expectAstronautPerson(*r, card);
    EXPECT_EQ(r->labels.at<uchar>(120, 225), 0);  // face pixel labelled "person" (class 0)
  }
}

// The person model's known weakness, measured and reported: it labels a
// large part of coffee.png (a cup, no person) as person. If this starts
// failing the model changed; update the numbers in docs/dynamic-objects.md.
TEST(PersonModel, ReportsItsHallucinationOnCoffee) {
  REQUIRE_SHARED("testdata/coffee.png");
  auto seg = createSegmenter(kProjectModels / "person_selfie_256.yaml");
  ASSERT_TRUE(seg.ok()) << seg.error();
  auto r = (*seg)->segment(testImage("coffee.png"));
  ASSERT_TRUE(r.ok()) << r.error();
  std::printf("[ person_selfie_256 ] coffee.png (no person): %.1f %% labelled person (false positive)\n",
              100 * r->movableFraction());
  ::testing::Test::RecordProperty("coffee_false_positive_pct", std::to_string(100 * r->movableFraction()));
  EXPECT_GT(r->movableFraction(), 0.10);  // reported, not hidden by the post-filter
  EXPECT_LT(r->movableFraction(), 0.35);
  ASSERT_FALSE(r->instances.empty());
  EXPECT_GT(r->instances.front().score, 0.5f);
}

// The C++ decoding against make_yolo_reference.py's independent numpy
// decoding (testdata/<name>_coco_reference.{txt,png}) of the same model.
void expectMatchesReference(const Segmentation& r, const std::string& name) {
  SCOPED_TRACE(name);
  std::ifstream txt(kTestData / (name + "_coco_reference.txt"));
  const cv::Mat ref = cv::imread((kTestData / (name + "_coco_reference.png")).string(), cv::IMREAD_UNCHANGED);
  ASSERT_TRUE(txt && !ref.empty()) << "reference files missing";
  std::vector<std::vector<double>> rows;
  std::string line;
  while (std::getline(txt, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ss(line);
    std::vector<double> v(7);
    for (double& x : v) ss >> x;
    rows.push_back(v);
  }
  ASSERT_EQ(r.instances.size(), rows.size());
  cv::Mat ours(r.labels.size(), CV_8U, cv::Scalar(0));
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const Instance& inst = r.instances[i];
    EXPECT_EQ(inst.class_id, int(rows[i][0])) << i;
    EXPECT_NEAR(inst.score, rows[i][1], 1e-3) << i;
    // Reference boxes are continuous and unclipped; ours are whole pixels, clipped.
    const cv::Rect image(0, 0, r.labels.cols, r.labels.rows);
    const cv::Rect ref_box = cv::Rect(cv::Point(int(std::lround(rows[i][2])), int(std::lround(rows[i][3]))),
                                      cv::Point(int(std::lround(rows[i][4])), int(std::lround(rows[i][5])))) & image;
    EXPECT_LE(std::abs(inst.box.x - ref_box.x) + std::abs(inst.box.y - ref_box.y), 2) << i;
    EXPECT_LE(std::abs(inst.box.br().x - ref_box.br().x) + std::abs(inst.box.br().y - ref_box.br().y), 2) << i;
    // The reference crops at network resolution before resizing, we crop at
    // image resolution (like YOLOv5's "native" mask path): edges differ by a
    // pixel or so.
    EXPECT_NEAR(inst.area, rows[i][6], 0.02 * rows[i][6]) << i;
  }
  for (int i = int(r.instances.size()) - 1; i >= 0; --i)
    ours(r.instances[i].box).setTo(i + 1, r.instances[i].mask);
  const double agree = 1.0 - cv::countNonZero(ours != ref) / double(ref.total());
  std::printf("[ coco_yolov5s_seg_320 ] %s: %zu instances, %.3f %% of pixels agree with the numpy reference\n",
              name.c_str(), rows.size(), 100 * agree);
  EXPECT_GE(agree, 0.99);
}

class CocoModel : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (!fs::exists(kSharedModels / "coco_yolov5s_seg_320.onnx")) return;
    auto card = loadModelCard(kProjectModels / "coco_yolov5s_seg_320.yaml");
    ASSERT_TRUE(card.ok()) << card.error();
    card->model_path = kSharedModels / "coco_yolov5s_seg_320.onnx";
    SegmenterOptions options;
    options.movable_furniture = true;  // tested on coffee.png's table below
    auto seg = createSegmenter(*card, options);
    ASSERT_TRUE(seg.ok()) << seg.error();
    segmenter_ = std::move(seg).value().release();
  }
  static void TearDownTestSuite() {
    delete segmenter_;
    segmenter_ = nullptr;
  }
  void SetUp() override {
    if (!segmenter_) GTEST_SKIP() << "coco_yolov5s_seg_320.onnx not in " << kSharedModels.string();
  }
  static Segmenter* segmenter_;
};
Segmenter* CocoModel::segmenter_ = nullptr;

TEST_F(CocoModel, LabelsTheAstronaut) {
  auto r = segmenter_->segment(testImage("astronaut.png"));
  ASSERT_TRUE(r.ok()) << r.error();
  expectAstronautPerson(*r, "coco_yolov5s_seg_320");
  expectMatchesReference(*r, "astronaut");
  ASSERT_FALSE(r->instances.empty());
  const Instance& best = r->instances.front();
  EXPECT_EQ(best.class_name, "person");
  EXPECT_GT(best.score, 0.5f);
  EXPECT_TRUE(best.movable);
  EXPECT_TRUE((best.box & kFace) == kFace);
}

TEST_F(CocoModel, FindsNoPersonOnCoffeeButTheTableWhenFurnitureIsMovable) {
  auto r = segmenter_->segment(testImage("coffee.png"));
  ASSERT_TRUE(r.ok()) << r.error();
  expectMatchesReference(*r, "coffee");
  float max_person = 0;
  bool table = false;
  for (const Instance& inst : r->instances) {
    if (inst.class_name == "person") max_person = std::max(max_person, inst.score);
    if (inst.class_name == "dining table" && inst.movable) table = true;
    if (inst.class_name == "cup") {
      EXPECT_FALSE(inst.movable);
    }
  }
  EXPECT_EQ(max_person, 0.0f);  // no person detection at all (score >= 0.25)
  for (int y = 0; y < r->labels.rows; ++y)
    for (int x = 0; x < r->labels.cols; ++x) ASSERT_NE(r->labels.at<uchar>(y, x), 0) << x << "," << y;
  // movable_furniture is on for this fixture: the table becomes movable.
  EXPECT_TRUE(table);
  EXPECT_GT(r->movable_pixels, 0);
}

// TUM fr3/teddy frame 59: no person in view, but the model scores the
// teddy bear both as "teddy bear" (0.78) and as "person" (0.66) with nearly
// the same mask. The post-filter keeps the bear out of the movable mask.
TEST_F(CocoModel, TeddyBearCalledPersonTooIsDroppedAsTheSameObject) {
  const fs::path frame = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200/rgb/1341841875.249806.png";
  if (!fs::exists(frame)) GTEST_SKIP() << frame.string() << " not found";
  auto r = segmenter_->segment(cv::imread(frame.string(), cv::IMREAD_COLOR));
  ASSERT_TRUE(r.ok()) << r.error();
  const Instance* person = nullptr;
  for (const Instance& inst : r->instances)
    if (inst.class_name == "person") person = &inst;
  ASSERT_NE(person, nullptr) << "the model no longer confuses the bear: update this test and docs/dynamic-objects.md";
  std::printf("[ coco_yolov5s_seg_320 ] teddy frame 59: 'person' %.2f on %.1f %% of the image, %s\n", person->score,
              100.0 * person->area / r->labels.total(), person->kept ? "KEPT" : person->drop_reason.c_str());
  EXPECT_FALSE(person->kept);
  EXPECT_EQ(person->drop_reason, "same object as static 'teddy bear'");
  EXPECT_EQ(r->movable_pixels, 0);
  EXPECT_GT(r->filtered_pixels, int(r->labels.total() / 10));
}

TEST(ModelLookup, PrefersCocoWhenFoundElseThePersonModel) {
  ::unsetenv("STILLPOINT_MODEL_DIR");
  const fs::path dir = tempDir("lookup");
  for (const char* f : {kRecommendedCardFile, kPersonCardFile, "person_selfie_256.onnx"})
    fs::copy_file(kProjectModels / f, dir / f, fs::copy_options::overwrite_existing);
  auto fallback = resolveRecommendedModel({dir, {}});
  ASSERT_TRUE(fallback.ok()) << fallback.error();
  EXPECT_EQ(fallback->card.name, "person_selfie_256");
  EXPECT_TRUE(contains(fallback->reason, "not found")) << fallback->reason;

  if (fs::exists(kSharedModels / "coco_yolov5s_seg_320.onnx")) {
    auto coco = resolveRecommendedModel({dir, {"/nonexistent", kSharedModels}});
    ASSERT_TRUE(coco.ok()) << coco.error();
    EXPECT_EQ(coco->card.name, "coco_yolov5s_seg_320_people");
    EXPECT_EQ(coco->card.person_model, dir / kPersonCardFile);
    EXPECT_EQ(coco->card.model_path, kSharedModels / "coco_yolov5s_seg_320.onnx");
    ::setenv("STILLPOINT_MODEL_DIR", kSharedModels.c_str(), 1);
    auto env = resolveRecommendedModel({dir, {}});
    ::unsetenv("STILLPOINT_MODEL_DIR");
    ASSERT_TRUE(env.ok());
    EXPECT_EQ(env->card.name, "coco_yolov5s_seg_320_people");
  }
  fs::remove(dir / "person_selfie_256.onnx");
  auto none = resolveRecommendedModel({dir, {}});
  ASSERT_FALSE(none.ok());
  EXPECT_TRUE(contains(none.error(), "person_selfie_256.onnx")) << none.error();
}

}  // namespace
}  // namespace stillpoint::semantic
