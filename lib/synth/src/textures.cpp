#include "stillpoint/synth/textures.hpp"

#include <algorithm>
#include <cmath>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stillpoint/dataset/tum_dataset.hpp"

namespace stillpoint::synth {
namespace {

// Sum of octaves of smoothly interpolated random grids, in [0, 1].
cv::Mat valueNoise(int width, int height, cv::RNG& rng, int coarsest_cells, int octaves,
                   double persistence) {
  cv::Mat sum(height, width, CV_32FC1, cv::Scalar(0));
  double amplitude = 1.0, total = 0.0;
  int cells = coarsest_cells;
  for (int o = 0; o < octaves; ++o) {
    const int gw = std::max(2, cells), gh = std::max(2, cells * height / std::max(1, width));
    cv::Mat grid(gh, gw, CV_32FC1);
    rng.fill(grid, cv::RNG::UNIFORM, 0.0, 1.0);
    cv::Mat up;
    cv::resize(grid, up, cv::Size(width, height), 0, 0, cv::INTER_CUBIC);
    sum += up * amplitude;
    total += amplitude;
    amplitude *= persistence;
    cells *= 2;
    if (cells > width / 2) break;
  }
  sum /= total;
  return sum;
}

cv::Scalar randomColour(cv::RNG& rng, int lo, int hi) {
  return cv::Scalar(rng.uniform(lo, hi), rng.uniform(lo, hi), rng.uniform(lo, hi));
}

// Tints a [0,1] noise field between two colours.
cv::Mat tint(const cv::Mat& noise, const cv::Scalar& dark, const cv::Scalar& light) {
  cv::Mat out(noise.size(), CV_8UC3);
  for (int y = 0; y < noise.rows; ++y) {
    const float* n = noise.ptr<float>(y);
    cv::Vec3b* o = out.ptr<cv::Vec3b>(y);
    for (int x = 0; x < noise.cols; ++x) {
      const double t = std::clamp(static_cast<double>(n[x]), 0.0, 1.0);
      for (int c = 0; c < 3; ++c) o[x][c] = cv::saturate_cast<std::uint8_t>(dark[c] + t * (light[c] - dark[c]));
    }
  }
  return out;
}

std::string randomWord(cv::RNG& rng) {
  static const char* kLetters = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789abcdefghkmnprstuwxyz";
  std::string w;
  const int n = rng.uniform(3, 10);
  for (int i = 0; i < n; ++i) w += kLetters[rng.uniform(0, 56)];
  return w;
}

void drawText(cv::Mat* img, cv::RNG& rng, int lines, double scale_lo, double scale_hi) {
  for (int i = 0; i < lines; ++i) {
    const double scale = rng.uniform(scale_lo, scale_hi);
    const cv::Point org(rng.uniform(0, img->cols), rng.uniform(0, img->rows));
    std::string line = randomWord(rng) + " " + randomWord(rng) + " " + randomWord(rng);
    cv::putText(*img, line, org, rng.uniform(0, 2) ? cv::FONT_HERSHEY_SIMPLEX : cv::FONT_HERSHEY_DUPLEX,
                scale, randomColour(rng, 0, 90), std::max(1, static_cast<int>(scale * 2)), cv::LINE_AA);
  }
}

void drawBlocks(cv::Mat* img, cv::RNG& rng, int count, int min_size, int max_size) {
  for (int i = 0; i < count; ++i) {
    const int w = rng.uniform(min_size, max_size), h = rng.uniform(min_size, max_size);
    const cv::Point p(rng.uniform(-w / 2, img->cols), rng.uniform(-h / 2, img->rows));
    if (rng.uniform(0, 3) == 0) {
      cv::circle(*img, p, w / 2, randomColour(rng, 30, 230), cv::FILLED, cv::LINE_AA);
    } else {
      cv::rectangle(*img, cv::Rect(p.x, p.y, w, h), randomColour(rng, 30, 230), cv::FILLED);
      cv::rectangle(*img, cv::Rect(p.x, p.y, w, h), randomColour(rng, 0, 80), 2);
    }
  }
}

}  // namespace

Result<TextureStyle> parseTextureStyle(const std::string& name) {
  if (name == "paper") return TextureStyle::kPaper;
  if (name == "wood") return TextureStyle::kWood;
  if (name == "fabric") return TextureStyle::kFabric;
  if (name == "stone") return TextureStyle::kStone;
  if (name == "skin") return TextureStyle::kSkin;
  return Error{"unknown texture style '" + name + "' (paper, wood, fabric, stone, skin)"};
}

cv::Mat makeTexture(TextureStyle style, int width, int height, std::uint64_t seed) {
  width = std::max(8, width);
  height = std::max(8, height);
  cv::RNG rng(seed * 0x9E3779B97F4A7C15ULL + 0x1234567ULL);
  const double size = std::max(width, height);
  switch (style) {
    case TextureStyle::kPaper: {
      cv::Mat img = tint(valueNoise(width, height, rng, 4, 7, 0.55), randomColour(rng, 150, 200),
                         randomColour(rng, 215, 255));
      drawBlocks(&img, rng, static_cast<int>(size / 40), static_cast<int>(size / 40), static_cast<int>(size / 6));
      drawText(&img, rng, static_cast<int>(size / 20), size / 2500.0, size / 1000.0);
      return img;
    }
    case TextureStyle::kWood: {
      cv::Mat img(height, width, CV_8UC3);
      const int planks = std::max(2, height / 96);
      const cv::Mat grain = valueNoise(width, height, rng, 3, 6, 0.6);
      for (int p = 0; p < planks; ++p) {
        const int y0 = p * height / planks, y1 = (p + 1) * height / planks;
        const cv::Scalar dark = randomColour(rng, 40, 70) + cv::Scalar(0, 25, 60);
        const cv::Scalar light = dark + cv::Scalar(40, 60, 80);
        const double freq = rng.uniform(0.02, 0.06);
        const double phase = rng.uniform(0.0, 6.28);
        for (int y = y0; y < y1; ++y) {
          cv::Vec3b* o = img.ptr<cv::Vec3b>(y);
          const float* g = grain.ptr<float>(y);
          for (int x = 0; x < width; ++x) {
            const double t = 0.5 + 0.35 * std::sin(freq * x + 12.0 * g[x] + phase + 0.3 * y) + 0.3 * (g[x] - 0.5);
            for (int c = 0; c < 3; ++c) o[x][c] = cv::saturate_cast<std::uint8_t>(dark[c] + t * (light[c] - dark[c]));
          }
        }
        cv::line(img, {0, y0}, {width, y0}, cv::Scalar(20, 30, 45), 2);
        for (int k = 0; k < 2; ++k) {
          const int x = rng.uniform(0, width);
          cv::line(img, {x, y0}, {x, y1}, cv::Scalar(25, 35, 50), 2);
          const cv::Point knot(rng.uniform(0, width), rng.uniform(y0, std::max(y0 + 1, y1)));
          cv::ellipse(img, knot, cv::Size(rng.uniform(4, 14), rng.uniform(3, 8)), 0, 0, 360,
                      cv::Scalar(30, 45, 70), cv::FILLED, cv::LINE_AA);
        }
      }
      return img;
    }
    case TextureStyle::kFabric: {
      // Printed cloth: contrasting stripes or checks, patches and a few printed words,
      // so that clothes carry corners the way patterned real clothes do.
      cv::Mat img = tint(valueNoise(width, height, rng, 6, 7, 0.6), randomColour(rng, 10, 70),
                         randomColour(rng, 140, 250));
      const int step = std::max(6, static_cast<int>(size / rng.uniform(8, 16)));
      const cv::Scalar stripe = randomColour(rng, 0, 255);
      for (int x = 0; x < width; x += step) cv::line(img, {x, 0}, {x, height}, stripe, std::max(2, step / 4));
      if (rng.uniform(0, 2)) {
        for (int y = 0; y < height; y += step) cv::line(img, {0, y}, {width, y}, stripe, std::max(2, step / 4));
      }
      drawBlocks(&img, rng, static_cast<int>(size / 25), static_cast<int>(size / 20), static_cast<int>(size / 6));
      drawText(&img, rng, static_cast<int>(size / 60) + 2, size / 700.0, size / 350.0);
      return img;
    }
    case TextureStyle::kStone: {
      cv::Mat img = tint(valueNoise(width, height, rng, 8, 8, 0.65), cv::Scalar(70, 75, 80),
                         cv::Scalar(200, 205, 210));
      for (int i = 0; i < static_cast<int>(size / 30); ++i) {
        cv::Point p(rng.uniform(0, width), rng.uniform(0, height));
        for (int k = 0; k < 6; ++k) {
          const cv::Point q = p + cv::Point(rng.uniform(-30, 31), rng.uniform(-30, 31));
          cv::line(img, p, q, cv::Scalar(40, 45, 50), 1, cv::LINE_AA);
          p = q;
        }
      }
      drawBlocks(&img, rng, static_cast<int>(size / 80), static_cast<int>(size / 30), static_cast<int>(size / 8));
      return img;
    }
    case TextureStyle::kSkin:
      return tint(valueNoise(width, height, rng, 3, 4, 0.5), cv::Scalar(90, 120, 170),
                  cv::Scalar(150, 180, 225));
  }
  return cv::Mat(height, width, CV_8UC3, cv::Scalar(128, 128, 128));
}

Result<cv::Mat> loadPhoto(const std::string& path) {
  return dataset::readImageFile("texture", path, cv::IMREAD_COLOR);
}

Result<cv::Mat> loadMask(const std::string& path) {
  Result<cv::Mat> img = dataset::readImageFile("mask", path, cv::IMREAD_GRAYSCALE);
  if (img.ok() && cv::countNonZero(*img >= 128) == 0)
    return Error{"mask file '" + path + "' keeps no pixel (none >= 128)"};
  return img;
}

}  // namespace stillpoint::synth
