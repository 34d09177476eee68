#include <cstdlib>

#include "stillpoint/semantic/segmenter.hpp"

namespace stillpoint::semantic {

std::filesystem::path defaultModelCardDir() {
  std::error_code ec;
  const std::filesystem::path build_tree(STILLPOINT_SOURCE_MODELS_DIR);
  if (std::filesystem::is_directory(build_tree, ec)) return build_tree;
  return std::filesystem::path(STILLPOINT_INSTALL_MODELS_DIR);
}

Result<ResolvedModel> resolveRecommendedModel(const ModelLookup& lookup) {
  const std::filesystem::path dir = lookup.card_dir.empty() ? defaultModelCardDir() : lookup.card_dir;
  std::error_code ec;
  std::string coco_note;
  auto coco = loadModelCard(dir / kRecommendedCardFile);
  if (coco) {
    std::vector<std::filesystem::path> candidates;
    const std::filesystem::path file = coco->model_path.filename();
    for (const auto& d : lookup.model_dirs) candidates.push_back(d / file);
    if (const char* env = std::getenv("STILLPOINT_MODEL_DIR"); env && *env)
      candidates.push_back(std::filesystem::path(env) / file);
    candidates.push_back(coco->model_path);
    for (const auto& c : candidates) {
      if (std::filesystem::is_regular_file(c, ec)) {
        coco->model_path = c;
        return ResolvedModel{*coco, "COCO instance model found at " + c.string()};
      }
    }
    coco_note = "COCO model " + file.string() + " not found (run models/fetch-coco-model.sh or set STILLPOINT_MODEL_DIR)";
  } else {
    coco_note = coco.error();
  }
  auto person = loadModelCard(dir / kPersonCardFile);
  if (!person) return Error{"no usable segmentation model: " + coco_note + "; " + person.error()};
  if (!std::filesystem::is_regular_file(person->model_path, ec))
    return Error{"no usable segmentation model: " + coco_note + "; person model '" + person->model_path.string() +
                 "' does not exist"};
  return ResolvedModel{*person, coco_note + "; using the in-tree person model"};
}

}  // namespace stillpoint::semantic
