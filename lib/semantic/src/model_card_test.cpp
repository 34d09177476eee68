// Model cards: the shipped cards load; bad cards name the field and the line.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <unistd.h>

#include "stillpoint/semantic/model_card.hpp"

namespace stillpoint::semantic {
namespace {

namespace fs = std::filesystem;
const fs::path kProjectModels = STILLPOINT_PROJECT_MODELS_DIR;

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

class CardFile : public ::testing::Test {
 protected:
  fs::path write(const std::string& text) {
    const fs::path dir = fs::temp_directory_path() / ("stillpoint_card_test_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    const fs::path path = dir / "card.yaml";
    std::ofstream(path) << text;
    return path;
  }
};

const char* kGood = R"(name: tiny
model: net.onnx
input:
  width: 32
  height: 16
  layout: NHWC
  colour_order: BGR
  scale: 1.0
  mean: [1, 2, 3]
  std: [4, 5, 6]
  resize: letterbox
  pad_value: 0
decoder:
  type: semantic_argmax
  outputs: [out]
  background_class: bg
classes: [bg, person, chair]
movable: [person]
optional_movable: [chair]
confirm_with_geometry: true
)";

TEST_F(CardFile, ReadsEveryField) {
  auto card = loadModelCard(write(kGood));
  ASSERT_TRUE(card.ok()) << card.error();
  EXPECT_EQ(card->name, "tiny");
  EXPECT_EQ(card->model_path, (card->card_path.parent_path() / "net.onnx").lexically_normal());
  EXPECT_EQ(card->input.width, 32);
  EXPECT_EQ(card->input.height, 16);
  EXPECT_EQ(card->input.layout, TensorLayout::kNHWC);
  EXPECT_EQ(card->input.colour_order, ColourOrder::kBGR);
  EXPECT_EQ(card->input.resize, ResizeMode::kLetterbox);
  EXPECT_EQ(card->input.pad_value, 0);
  EXPECT_EQ(card->input.mean, (std::vector<double>{1, 2, 3}));
  EXPECT_EQ(card->input.std, (std::vector<double>{4, 5, 6}));
  EXPECT_EQ(card->decoder.type, DecoderType::kSemanticArgmax);
  EXPECT_EQ(card->decoder.background_class, "bg");
  EXPECT_EQ(card->classId("chair"), 2);
  EXPECT_EQ(card->optional_movable, (std::vector<std::string>{"chair"}));
  EXPECT_TRUE(card->confirm_with_geometry);
}

struct BadCase {
  std::string from, to;  // text replacement applied to kGood
  std::string field;     // the error must name this field...
  std::string line;      // ...and this line ("" = no line check)
};

TEST_F(CardFile, ErrorsNameTheFieldAndLine) {
  const std::vector<BadCase> cases = {
      {"  height: 16\n", "", "input.height", "line 4"},                     // missing: first line of its mapping
      {"  width: 32", "  width: thirty", "input.width", "line 4"},          // wrong type
      {"  layout: NHWC", "  layout: CHW", "input.layout", "line 6"},        // bad enum, lists choices
      {"  pad_value: 0", "  pad_valu: 0", "input.pad_valu", "line 12"},     // unknown key (typo)
      {"  type: semantic_argmax", "  type: yolo", "decoder.type", "line 14"},
      {"movable: [person]", "movable: [dog]", "movable", "line 18"},
      {"  std: [4, 5, 6]", "  std: [4, 0, 6]", "input.std", "line 10"},
      {"  outputs: [out]", "  outputs: out", "decoder.outputs", "line 15"},
      {"  width: 32", "  width: 0", "input.width", "line 4"},
      {"  background_class: bg", "  background_class: sky", "decoder.background_class", "line 16"},
      {"classes: [bg, person, chair]", "classes: [bg, person, person]", "classes", ""},
      {"model: net.onnx\n", "", "model", ""},
      {"  background_class: bg", "  background_class: bg\n  threshold: 3", "decoder.threshold", "line 17"},
      {"  width: 32", "  width: 32\n  width: 64", "input.width", "line 5"},  // given twice: not the first silently
  };
  for (const BadCase& c : cases) {
    std::string text = kGood;
    const auto at = text.find(c.from);
    ASSERT_NE(at, std::string::npos) << c.from;
    text.replace(at, c.from.size(), c.to);
    auto card = loadModelCard(write(text));
    ASSERT_FALSE(card.ok()) << "accepted: " << c.to;
    EXPECT_TRUE(contains(card.error(), "field '" + c.field + "'")) << card.error();
    if (!c.line.empty()) {
      EXPECT_TRUE(contains(card.error(), c.line)) << card.error();
    }
    EXPECT_TRUE(contains(card.error(), "card.yaml")) << card.error();
  }
}

TEST_F(CardFile, SyntaxErrorsAndMissingFiles) {
  auto syntax = loadModelCard(write("name: x\ninput: [unclosed\n"));
  ASSERT_FALSE(syntax.ok());
  EXPECT_TRUE(contains(syntax.error(), "line ")) << syntax.error();
  auto missing = loadModelCard("/nonexistent/card.yaml");
  ASSERT_FALSE(missing.ok());
  EXPECT_TRUE(contains(missing.error(), "cannot be opened")) << missing.error();
  auto not_map = loadModelCard(write("- a\n- b\n"));
  ASSERT_FALSE(not_map.ok());
}

TEST(ShippedCards, LoadAndListTheDefaultMovableClasses) {
  for (const char* name : {"person_selfie_256.yaml", "person_selfie_landscape_144x256.yaml",
                           "coco_yolov5s_seg_320.yaml"}) {
    auto card = loadModelCard(kProjectModels / name);
    ASSERT_TRUE(card.ok()) << card.error();
    EXPECT_EQ(card->movable.front(), "person") << name;
    EXPECT_EQ(card->confirm_with_geometry, card->name != "coco_yolov5s_seg_320") << name;
  }
  auto coco = loadModelCard(kProjectModels / "coco_yolov5s_seg_320.yaml");
  ASSERT_TRUE(coco.ok());
  ASSERT_EQ(coco->classes.size(), 80u);
  EXPECT_EQ(coco->classes[0], "person");
  EXPECT_EQ(coco->classes[56], "chair");
  EXPECT_EQ(coco->classes[77], "teddy bear");
  EXPECT_EQ(coco->classes[79], "toothbrush");
  // People, animals and vehicles move by default; furniture only on request;
  // the teddy bear never.
  for (const char* c : {"person", "dog", "horse", "car", "bicycle", "truck"})
    EXPECT_NE(std::find(coco->movable.begin(), coco->movable.end(), c), coco->movable.end()) << c;
  for (const char* c : {"chair", "couch", "teddy bear", "tv"})
    EXPECT_EQ(std::find(coco->movable.begin(), coco->movable.end(), c), coco->movable.end()) << c;
  EXPECT_NE(std::find(coco->optional_movable.begin(), coco->optional_movable.end(), "chair"),
            coco->optional_movable.end());
  EXPECT_TRUE(coco->person_model.empty());
  // The same model with the person model beside it where a map starts: its
  // card is resolved from the card's folder, and loads.
  auto people = loadModelCard(kProjectModels / "coco_yolov5s_seg_320_people.yaml");
  ASSERT_TRUE(people.ok()) << people.error();
  EXPECT_EQ(people->classes, coco->classes);
  EXPECT_EQ(people->movable, coco->movable);
  EXPECT_EQ(people->model_path, coco->model_path);
  EXPECT_EQ(people->person_model, (kProjectModels / "person_selfie_256.yaml").lexically_normal());
  auto person = loadModelCard(people->person_model);
  ASSERT_TRUE(person.ok()) << person.error();
  EXPECT_EQ(person->decoder.type, DecoderType::kPersonProbability);
}

}  // namespace
}  // namespace stillpoint::semantic
