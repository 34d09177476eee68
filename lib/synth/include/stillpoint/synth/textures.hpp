#pragma once
// Procedural textures that look enough like real surfaces for ORB: multi-scale
// value noise for the base, plus shapes and printed text for corners. All are
// deterministic functions of their seed.
#include <cstdint>
#include <string>

#include <opencv2/core/mat.hpp>

#include "stillpoint/core/result.hpp"

namespace stillpoint::synth {

enum class TextureStyle {
  kPaper,     // light base, coloured blocks, lines of text (posters, walls)
  kWood,      // planks with grain (floor, furniture)
  kFabric,    // coloured multi-scale noise with a fine weave (clothes, sofas)
  kStone,     // grey blotches and cracks (walls)
  kSkin,      // smooth warm tone (walker heads and hands)
};

// Parses "paper", "wood", "fabric", "stone", "skin".
Result<TextureStyle> parseTextureStyle(const std::string& name);

// A width x height CV_8UC3 texture.
cv::Mat makeTexture(TextureStyle style, int width, int height, std::uint64_t seed);

// Reads a photo (any format OpenCV reads) as CV_8UC3; the error names the file.
Result<cv::Mat> loadPhoto(const std::string& path);

// Reads a mask image as CV_8UC1 (colour images are converted to grey); the
// error names the file. Errors also when no pixel is >= 128 (nothing kept).
Result<cv::Mat> loadMask(const std::string& path);

}  // namespace stillpoint::synth
