// A person model's second opinion beside a main model: two segmenters of
// fixed answers (test doubles of our own interface) so that the test knows
// which pixels each names.
#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "stillpoint/semantic/person_second_opinion.hpp"

namespace stillpoint::semantic {
namespace {

const cv::Size kImage(640, 480);
const cv::Rect kBear(300, 100, 200, 300);    // what the main model names "teddy bear"
const cv::Rect kPerson(40, 60, 220, 400);    // a person only the person model sees

Instance instanceOf(const cv::Mat& mask, int class_id, const std::string& name, bool movable, float score) {
  Instance inst;
  inst.class_id = class_id;
  inst.class_name = name;
  inst.score = score;
  inst.box = cv::boundingRect(mask);
  inst.mask = mask(inst.box).clone();
  inst.area = cv::countNonZero(inst.mask);
  inst.movable = movable;
  return inst;
}

cv::Mat maskOf(const std::vector<cv::Rect>& rects) {
  cv::Mat mask(kImage, CV_8U, cv::Scalar(0));
  for (const cv::Rect& r : rects) mask(r).setTo(255);
  return mask;
}

// Answers every image with fixed instances (one per mask), movable or not.
class FixedSegmenter : public Segmenter {
 public:
  FixedSegmenter(std::vector<std::string> classes, DecoderType decoder) {
    card_.name = "fixed";
    card_.classes = std::move(classes);
    card_.movable = {card_.classes.front()};
    card_.decoder.type = decoder;
  }
  void add(const cv::Mat& mask, int class_id, bool movable, float score = 0.9f, bool kept = true) {
    answer_.push_back(instanceOf(mask, class_id, card_.classes.at(class_id), movable, score));
    answer_.back().kept = kept;
  }
  Result<Segmentation> segment(const cv::Mat& bgr) override {
    if (bgr.empty()) return Error{"empty image"};
    Segmentation seg;
    seg.labels = cv::Mat(bgr.size(), CV_8U, cv::Scalar(kNoLabel));
    seg.movable_mask = cv::Mat(bgr.size(), CV_8U, cv::Scalar(0));
    seg.instances = answer_;
    for (const Instance& inst : answer_) {
      seg.labels(inst.box).setTo(inst.class_id, inst.mask);
      if (inst.movable && inst.kept) seg.movable_mask(inst.box).setTo(255, inst.mask);
    }
    seg.movable_pixels = cv::countNonZero(seg.movable_mask);
    return seg;
  }
  const ModelCard& card() const override { return card_; }
  const std::vector<int>& movableClassIds() const override { return ids_; }

 private:
  ModelCard card_;
  std::vector<int> ids_{0};
  std::vector<Instance> answer_;
};

std::unique_ptr<FixedSegmenter> mainModel() {
  auto main = std::make_unique<FixedSegmenter>(std::vector<std::string>{"person", "teddy bear"},
                                               DecoderType::kYoloInstance);
  main->add(maskOf({kBear}), 1, false);
  return main;
}

std::unique_ptr<FixedSegmenter> personModel(const cv::Mat& mask, float probability = 0.97f) {
  auto person = std::make_unique<FixedSegmenter>(std::vector<std::string>{"person"}, DecoderType::kPersonProbability);
  person->add(mask, 0, true, probability);
  return person;
}

Segmentation segmentWith(std::unique_ptr<Segmenter> main, std::unique_ptr<Segmenter> person) {
  auto paired = withPersonSecondOpinion(std::move(main), std::move(person));
  EXPECT_TRUE(paired.ok()) << paired.error();
  if (!paired.ok()) return {};
  auto seg = (*paired)->segment(cv::Mat(kImage, CV_8UC3, cv::Scalar(90, 90, 90)));
  EXPECT_TRUE(seg.ok()) << seg.error();
  return seg.ok() ? std::move(*seg) : Segmentation{};
}

TEST(PersonSecondOpinion, JoinsThePersonTheMainModelDoesNotExplain) {
  // The person model paints the person and the bear in one region, as the
  // selfie model paints a person standing behind the TUM teddy bear.
  const Segmentation seg = segmentWith(mainModel(), personModel(maskOf({kPerson, kBear})));
  ASSERT_EQ(seg.instances.size(), 2u);
  EXPECT_EQ(seg.instances[0].class_name, "teddy bear");
  EXPECT_FALSE(seg.instances[0].movable);
  const Instance& added = seg.instances[1];
  EXPECT_TRUE(added.second_opinion);
  EXPECT_TRUE(added.movable);
  EXPECT_TRUE(added.kept);
  EXPECT_EQ(added.class_name, "person");
  EXPECT_EQ(added.class_id, 0);  // the main card's person
  EXPECT_FLOAT_EQ(added.score, 0.97f);
  // The person's pixels, none of the bear's (the opening rounds its corners).
  EXPECT_EQ((added.box & kBear).area(), 0);
  EXPECT_GT(added.area, 0.99 * kPerson.area());
  EXPECT_LE(added.area, kPerson.area());
  EXPECT_EQ(seg.movable_pixels, added.area);
  EXPECT_EQ(cv::countNonZero(seg.movable_mask(kBear)), 0);
  EXPECT_EQ(seg.labels.at<std::uint8_t>(kPerson.y + 200, kPerson.x + 100), 0);
  EXPECT_EQ(seg.labels.at<std::uint8_t>(kBear.y + 100, kBear.x + 100), 1);
}

TEST(PersonSecondOpinion, ARimAroundANamedObjectIsNoPerson) {
  // The person model's outline of the bear is a few pixels wider than the main model's.
  cv::Mat rim = maskOf({kBear});
  cv::dilate(rim, rim, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(9, 9)));
  const Segmentation seg = segmentWith(mainModel(), personModel(rim));
  EXPECT_EQ(seg.instances.size(), 1u);
  EXPECT_EQ(seg.movable_pixels, 0);
}

TEST(PersonSecondOpinion, APersonTheMainModelKeepsIsNotAddedTwice) {
  auto main = mainModel();
  main->add(maskOf({kPerson}), 0, true);
  const Segmentation seg = segmentWith(std::move(main), personModel(maskOf({kPerson, kBear})));
  ASSERT_EQ(seg.instances.size(), 2u);
  EXPECT_FALSE(seg.instances[1].second_opinion);
  EXPECT_EQ(seg.movable_pixels, kPerson.area());
}

TEST(PersonSecondOpinion, WhatContinuesAPersonTheMainModelKeepsIsLeftToIt) {
  // The main model keeps the person's head; the person model paints the
  // head, the body below it and the box the body stands behind, in one region.
  const cv::Rect head(kPerson.x, kPerson.y, kPerson.width, 120);
  const cv::Rect body_and_box(kPerson.x, kPerson.y + 120, kPerson.width, kPerson.height - 120);
  const cv::Rect other(540, 100, 90, 300);  // a second person, apart from the first
  auto main = mainModel();
  main->add(maskOf({head}), 0, true);
  Segmentation seg = segmentWith(std::move(main), personModel(maskOf({kPerson, other})));
  ASSERT_EQ(seg.instances.size(), 3u);
  EXPECT_FALSE(seg.instances[1].second_opinion);
  EXPECT_TRUE(seg.instances[2].second_opinion);
  EXPECT_EQ((seg.instances[2].box & kPerson).area(), 0);
  EXPECT_EQ(cv::countNonZero(seg.movable_mask(body_and_box)), 0);

  // A person the main model's post-filter dropped explains nothing.
  main = mainModel();
  main->add(maskOf({head}), 0, true, 0.9f, /*kept=*/false);
  seg = segmentWith(std::move(main), personModel(maskOf({kPerson})));
  ASSERT_EQ(seg.instances.size(), 3u);
  EXPECT_TRUE(seg.instances[2].second_opinion);
  EXPECT_GT(seg.instances[2].area, 0.99 * kPerson.area());
}

TEST(PersonSecondOpinion, SmallOrUnsureRegionsAreLeftOut) {
  const cv::Rect small(40, 60, 60, 60);  // 1.2 % of the image, a far person: the main model's
  Segmentation seg = segmentWith(mainModel(), personModel(maskOf({small})));
  EXPECT_EQ(seg.instances.size(), 1u);
  seg = segmentWith(mainModel(), personModel(maskOf({kPerson}), 0.6f));
  EXPECT_EQ(seg.instances.size(), 1u);
}

TEST(PersonSecondOpinion, MismatchedModelsAndBadOptionsAreErrors) {
  auto no_person = std::make_unique<FixedSegmenter>(std::vector<std::string>{"car"}, DecoderType::kYoloInstance);
  auto r = withPersonSecondOpinion(std::move(no_person), personModel(maskOf({kPerson})));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("no class 'person'"), std::string::npos) << r.error();

  auto not_a_person_model =
      std::make_unique<FixedSegmenter>(std::vector<std::string>{"person"}, DecoderType::kYoloInstance);
  r = withPersonSecondOpinion(mainModel(), std::move(not_a_person_model));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("not a person model"), std::string::npos) << r.error();

  r = withPersonSecondOpinion(mainModel(), nullptr);
  EXPECT_FALSE(r.ok());

  SecondOpinionOptions bad;
  bad.min_region_fraction = 0;
  r = withPersonSecondOpinion(mainModel(), personModel(maskOf({kPerson})), bad);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("min_region_fraction"), std::string::npos) << r.error();
}

TEST(PersonSecondOpinion, ErrorsOfEitherModelComeBack) {
  auto paired = withPersonSecondOpinion(mainModel(), personModel(maskOf({kPerson})));
  ASSERT_TRUE(paired.ok()) << paired.error();
  EXPECT_FALSE((*paired)->segment(cv::Mat()).ok());
  EXPECT_EQ((*paired)->card().name, "fixed");
  EXPECT_EQ((*paired)->movableClassIds(), std::vector<int>{0});
}

}  // namespace
}  // namespace stillpoint::semantic
