#pragma once
// Reads the declared graph inputs of an ONNX file (names and static shapes)
// with a minimal protobuf walker, so a card whose input size does not match
// the model is an error at start-up. OpenCV 4.6 dnn offers no getter for it.
#include <cstdint>
#include <string>
#include <vector>

#include "stillpoint/core/result.hpp"

namespace stillpoint::semantic {

struct OnnxTensorInfo {
  std::string name;
  std::vector<std::int64_t> dims;  // -1 for a symbolic or missing dimension
};

// Graph inputs that are not initializers, from the bytes of an .onnx file.
Result<std::vector<OnnxTensorInfo>> parseOnnxInputs(const std::string& bytes);

}  // namespace stillpoint::semantic
