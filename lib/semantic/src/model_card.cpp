#include "stillpoint/semantic/model_card.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <set>

#include "stillpoint/core/yaml_file.hpp"

namespace stillpoint::semantic {
namespace {

// Reads fields of one YAML mapping; every error names the card, the dotted
// field path and the line.
class CardReader {
 public:
  CardReader(std::string file) : file_(std::move(file)) {}

  Error error(const YAML::Node& node, const std::string& field, const std::string& why) const {
    std::string where = "model card '" + file_ + "'";
    if (node && node.Mark().line >= 0) where += ": line " + std::to_string(node.Mark().line + 1);
    return Error{where + ": field '" + field + "' " + why};
  }
  Error error(const std::string& field, const std::string& why) const {
    return Error{"model card '" + file_ + "': field '" + field + "' " + why};
  }

  // Unknown keys are errors: a typo must not silently fall back to a default.
  Status checkKeys(const YAML::Node& map, const std::string& prefix,
                   const std::set<std::string>& known) const {
    std::set<std::string> seen;
    for (const auto& kv : map) {
      if (!kv.first.IsScalar()) return error(kv.first, prefix, "has a key that is not a plain name");
      const std::string key = kv.first.Scalar();
      if (!seen.insert(key).second) return error(kv.first, prefix + key, "is given twice");
      if (!known.count(key))
        return error(kv.first, prefix + key, "is not a known field");
    }
    return Status::success();
  }

  template <typename T>
  Status read(const YAML::Node& map, const std::string& prefix, const char* key, T* out,
              bool required) const {
    const YAML::Node n = map[key];
    if (!n) {
      if (required) return error(map, prefix + key, "is missing");
      return Status::success();
    }
    try {
      if (!n.IsScalar()) throw YAML::Exception(n.Mark(), "not a scalar");
      *out = n.as<T>();
    } catch (const YAML::Exception&) {
      return error(n, prefix + key, "has the wrong type");
    }
    return Status::success();
  }

  Status readList(const YAML::Node& map, const std::string& prefix, const char* key,
                  std::vector<std::string>* out, bool required) const {
    return readListT(map, prefix, key, out, required);
  }
  Status readNumbers(const YAML::Node& map, const std::string& prefix, const char* key,
                     std::vector<double>* out) const {
    return readListT(map, prefix, key, out, false);
  }

  // Reads a string and maps it through a table of allowed values.
  template <typename E>
  Status readEnum(const YAML::Node& map, const std::string& prefix, const char* key, E* out,
                  const std::vector<std::pair<std::string, E>>& table, bool required) const {
    std::string text;
    if (Status s = read(map, prefix, key, &text, required); !s) return s;
    if (text.empty()) return Status::success();
    std::string allowed;
    for (const auto& [name, value] : table) {
      if (name == text) {
        *out = value;
        return Status::success();
      }
      { if (!allowed.empty()) allowed += ", "; allowed += name; }
    }
    return error(map[key], prefix + key, "is '" + text + "', expected one of: " + allowed);
  }

 private:
  template <typename T>
  Status readListT(const YAML::Node& map, const std::string& prefix, const char* key,
                   std::vector<T>* out, bool required) const {
    const YAML::Node n = map[key];
    if (!n) {
      if (required) return error(map, prefix + key, "is missing");
      return Status::success();
    }
    if (!n.IsSequence()) return error(n, prefix + key, "must be a list");
    out->clear();
    for (std::size_t i = 0; i < n.size(); ++i) {
      try {
        out->push_back(n[i].as<T>());
      } catch (const YAML::Exception&) {
        return error(n[i], prefix + key + "[" + std::to_string(i) + "]", "has the wrong type");
      }
    }
    return Status::success();
  }

  std::string file_;
};

}  // namespace

int ModelCard::classId(const std::string& class_name) const {
  const auto it = std::find(classes.begin(), classes.end(), class_name);
  return it == classes.end() ? -1 : int(it - classes.begin());
}

Status ModelCard::validate() const {
  const std::string where = "model card '" + (card_path.empty() ? name : card_path.string()) + "': ";
  auto bad = [&](const std::string& field, const std::string& why) {
    return Error{where + "field '" + field + "' " + why};
  };
  if (model_path.empty()) return bad("model", "is empty");
  if (input.width <= 0 || input.width > 8192) return bad("input.width", "must be in 1..8192");
  if (input.height <= 0 || input.height > 8192) return bad("input.height", "must be in 1..8192");
  if (!(input.scale > 0) || !std::isfinite(input.scale)) return bad("input.scale", "must be a positive number");
  if (input.mean.size() != 3) return bad("input.mean", "must have 3 values");
  if (input.std.size() != 3) return bad("input.std", "must have 3 values");
  for (double m : input.mean)
    if (!std::isfinite(m)) return bad("input.mean", "must be finite");
  for (double s : input.std)
    if (!(s > 0) || !std::isfinite(s)) return bad("input.std", "values must be positive");
  if (input.pad_value < 0 || input.pad_value > 255) return bad("input.pad_value", "must be in 0..255");
  if (classes.empty()) return bad("classes", "must list at least one class");
  if (classes.size() > 255) return bad("classes", "has more than 255 classes");
  std::set<std::string> seen;
  for (const auto& c : classes) {
    if (c.empty()) return bad("classes", "contains an empty name");
    if (!seen.insert(c).second) return bad("classes", "lists '" + c + "' twice");
  }
  for (const auto& c : movable)
    if (classId(c) < 0) return bad("movable", "names '" + c + "', which is not in classes");
  for (const auto& c : optional_movable)
    if (classId(c) < 0) return bad("optional_movable", "names '" + c + "', which is not in classes");
  const DecoderSpec& d = decoder;
  const std::size_t want_outputs = d.type == DecoderType::kYoloInstance ? 2 : 1;
  if (d.outputs.size() != want_outputs)
    return bad("decoder.outputs", "must list " + std::to_string(want_outputs) + " output name(s) for this decoder");
  if (!(d.threshold > 0 && d.threshold < 1)) return bad("decoder.threshold", "must be in (0, 1)");
  if (d.type == DecoderType::kPersonProbability && classes.size() != 1)
    return bad("classes", "must hold exactly one class for the probability decoder");
  if (d.type == DecoderType::kSemanticArgmax && !d.background_class.empty() && classId(d.background_class) < 0)
    return bad("decoder.background_class", "names '" + d.background_class + "', which is not in classes");
  if (d.type == DecoderType::kYoloInstance) {
    if (!(d.score_threshold > 0 && d.score_threshold < 1)) return bad("decoder.score_threshold", "must be in (0, 1)");
    if (!(d.nms_threshold > 0 && d.nms_threshold <= 1)) return bad("decoder.nms_threshold", "must be in (0, 1]");
    if (d.mask_coefficients <= 0 || d.mask_coefficients > 1024) return bad("decoder.mask_coefficients", "must be in 1..1024");
    if (d.max_detections <= 0 || d.max_detections > 10000) return bad("decoder.max_detections", "must be in 1..10000");
  }
  return Status::success();
}

Result<ModelCard> loadModelCard(const std::filesystem::path& path) {
  const std::string file = path.string();
  auto loaded = loadYamlFile(file, "model card '" + file + "'");
  if (!loaded) return Error{loaded.error()};
  const YAML::Node root = *loaded;
  if (!root.IsMap()) return Error{"model card '" + file + "': expected a mapping at the top level"};
  CardReader r(file);
  ModelCard card;
  card.card_path = path;
  card.name = path.stem().string();
  std::string model, person_model;

  if (Status s = r.checkKeys(root, "", {"name", "model", "licence", "input", "decoder", "classes",
                                        "movable", "optional_movable", "confirm_with_geometry", "person_model"});
      !s)
    return Error{s.error()};
  for (Status s : {r.read(root, "", "name", &card.name, false), r.read(root, "", "model", &model, true),
                   r.read(root, "", "licence", &card.licence, false),
                   r.read(root, "", "confirm_with_geometry", &card.confirm_with_geometry, false),
                   r.read(root, "", "person_model", &person_model, false),
                   r.readList(root, "", "classes", &card.classes, true),
                   r.readList(root, "", "movable", &card.movable, false),
                   r.readList(root, "", "optional_movable", &card.optional_movable, false)})
    if (!s) return Error{s.error()};

  const YAML::Node in = root["input"];
  if (!in) return r.error(root, "input", "is missing");
  if (!in.IsMap()) return r.error(in, "input", "must be a mapping");
  InputSpec& is = card.input;
  const std::string ip = "input.";
  if (Status s = r.checkKeys(in, ip, {"name", "width", "height", "layout", "colour_order", "scale", "mean",
                                       "std", "resize", "pad_value"});
      !s)
    return Error{s.error()};
  const std::vector<std::pair<std::string, TensorLayout>> layouts{{"NCHW", TensorLayout::kNCHW},
                                                                  {"NHWC", TensorLayout::kNHWC}};
  for (Status s :
       {r.read(in, ip, "name", &is.name, false), r.read(in, ip, "width", &is.width, true),
        r.read(in, ip, "height", &is.height, true), r.readEnum(in, ip, "layout", &is.layout, layouts, true),
        r.readEnum(in, ip, "colour_order", &is.colour_order,
                   {{"RGB", ColourOrder::kRGB}, {"BGR", ColourOrder::kBGR}}, true),
        r.read(in, ip, "scale", &is.scale, false), r.readNumbers(in, ip, "mean", &is.mean),
        r.readNumbers(in, ip, "std", &is.std),
        r.readEnum(in, ip, "resize", &is.resize,
                   {{"stretch", ResizeMode::kStretch}, {"letterbox", ResizeMode::kLetterbox}}, true),
        r.read(in, ip, "pad_value", &is.pad_value, false)})
    if (!s) return Error{s.error()};

  const YAML::Node dec = root["decoder"];
  if (!dec) return r.error(root, "decoder", "is missing");
  if (!dec.IsMap()) return r.error(dec, "decoder", "must be a mapping");
  DecoderSpec& ds = card.decoder;
  const std::string dp = "decoder.";
  if (Status s = r.checkKeys(dec, dp, {"type", "outputs", "output_layout", "threshold", "background_class",
                                        "softmax", "score_threshold", "nms_threshold", "mask_coefficients",
                                        "max_detections"});
      !s)
    return Error{s.error()};
  for (Status s :
       {r.readEnum(dec, dp, "type", &ds.type,
                   {{"person_probability", DecoderType::kPersonProbability},
                    {"semantic_argmax", DecoderType::kSemanticArgmax},
                    {"yolo_instance", DecoderType::kYoloInstance}},
                   true),
        r.readList(dec, dp, "outputs", &ds.outputs, true),
        r.readEnum(dec, dp, "output_layout", &ds.output_layout, layouts, false),
        r.read(dec, dp, "threshold", &ds.threshold, false),
        r.read(dec, dp, "background_class", &ds.background_class, false),
        r.read(dec, dp, "softmax", &ds.softmax, false),
        r.read(dec, dp, "score_threshold", &ds.score_threshold, false),
        r.read(dec, dp, "nms_threshold", &ds.nms_threshold, false),
        r.read(dec, dp, "mask_coefficients", &ds.mask_coefficients, false),
        r.read(dec, dp, "max_detections", &ds.max_detections, false)})
    if (!s) return Error{s.error()};

  // Relative model paths are relative to the card, so a card and its model
  // can be moved together.
  std::filesystem::path model_path(model);
  if (!model.empty() && model_path.is_relative()) model_path = path.parent_path() / model_path;
  card.model_path = model_path.lexically_normal();
  if (!person_model.empty()) {
    std::filesystem::path person_path(person_model);
    if (person_path.is_relative()) person_path = path.parent_path() / person_path;
    card.person_model = person_path.lexically_normal();
  }

  if (Status s = card.validate(); !s) {
    // validate() knows the field, the YAML knows its line: add it.
    const std::string& msg = s.error();
    const auto at = msg.find("field '");
    if (at == std::string::npos) return Error{msg};
    const auto start = at + 7, end = msg.find('\'', start);
    // reset(), not operator=: assigning a yaml-cpp node overwrites the node it refers to.
    YAML::Node node;
    node.reset(root);
    std::string field = msg.substr(start, end - start);
    for (std::size_t dot; (dot = field.find('.')) != std::string::npos; field.erase(0, dot + 1))
      if (node.IsMap()) node.reset(node[field.substr(0, dot)]);
    if (node.IsMap()) node.reset(node[field]);
    if (!node.IsDefined() || node.IsNull() || node.Mark().line < 0) return Error{msg};
    const std::string prefix = "model card '" + file + "': ";
    return Error{prefix + "line " + std::to_string(node.Mark().line + 1) + ": " + msg.substr(prefix.size())};
  }
  return card;
}

}  // namespace stillpoint::semantic
