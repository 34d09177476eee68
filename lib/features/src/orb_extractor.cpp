#include "stillpoint/features/orb_extractor.hpp"

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <random>

namespace stillpoint::features {
namespace {

// Sampling pairs of the binary test, drawn once from an isotropic Gaussian
// (sigma = patch/5, the BRIEF paper's best-performing "G II" layout) with a
// fixed seed, clipped to a disc so any rotation stays inside the patch.
struct TestPair {
  std::int8_t x1, y1, x2, y2;
};

std::array<TestPair, 256> makePattern() {
  std::mt19937 rng(0x5711u);
  // Box-Muller on the raw engine output: std::normal_distribution is
  // implementation defined, this is identical on every platform.
  auto uniform = [&]() { return (static_cast<double>(rng()) + 0.5) / 4294967296.0; };
  auto gaussian = [&]() {
    return std::sqrt(-2.0 * std::log(uniform())) * std::cos(2.0 * M_PI * uniform());
  };
  constexpr double kSigma = OrbExtractor::kPatchSize / 5.0;
  constexpr double kMaxRadius = 13.0;
  auto sample = [&](std::int8_t* x, std::int8_t* y) {
    while (true) {
      const double sx = std::round(gaussian() * kSigma), sy = std::round(gaussian() * kSigma);
      if (sx * sx + sy * sy <= kMaxRadius * kMaxRadius) {
        *x = static_cast<std::int8_t>(sx);
        *y = static_cast<std::int8_t>(sy);
        return;
      }
    }
  };
  std::array<TestPair, 256> pattern{};
  for (auto& p : pattern) {
    do {
      sample(&p.x1, &p.y1);
      sample(&p.x2, &p.y2);
    } while (p.x1 == p.x2 && p.y1 == p.y2);
  }
  return pattern;
}

const std::array<TestPair, 256>& pattern() {
  static const std::array<TestPair, 256> kPattern = makePattern();
  return kPattern;
}

// Orientation by the intensity centroid of the circular patch.
float patchAngle(const cv::Mat& image, cv::Point2f pt, const std::vector<int>& umax) {
  const int cx = cvRound(pt.x), cy = cvRound(pt.y);
  const std::uint8_t* centre = image.ptr<std::uint8_t>(cy) + cx;
  const int step = static_cast<int>(image.step1());
  int m01 = 0, m10 = 0;
  for (int u = -OrbExtractor::kHalfPatch; u <= OrbExtractor::kHalfPatch; ++u) m10 += u * centre[u];
  for (int v = 1; v <= OrbExtractor::kHalfPatch; ++v) {
    int v_sum = 0;
    const int d = umax[v];
    for (int u = -d; u <= d; ++u) {
      const int below = centre[u + v * step], above = centre[u - v * step];
      v_sum += below - above;
      m10 += u * (below + above);
    }
    m01 += v * v_sum;
  }
  return cv::fastAtan2(static_cast<float>(m01), static_cast<float>(m10));
}

void computeDescriptor(const cv::Mat& blurred, const cv::KeyPoint& kp, float level_scale,
                       std::uint8_t* out) {
  const float angle = kp.angle * static_cast<float>(M_PI / 180.0);
  const float c = std::cos(angle), s = std::sin(angle);
  const cv::Point2f pt = kp.pt * (1.0f / level_scale);
  const std::uint8_t* centre = blurred.ptr<std::uint8_t>(cvRound(pt.y)) + cvRound(pt.x);
  const int step = static_cast<int>(blurred.step1());
  auto at = [&](int x, int y) {
    const int rx = cvRound(x * c - y * s), ry = cvRound(x * s + y * c);
    return centre[ry * step + rx];
  };
  const auto& pairs = pattern();
  for (int byte = 0; byte < 32; ++byte) {
    std::uint8_t value = 0;
    for (int bit = 0; bit < 8; ++bit) {
      const TestPair& p = pairs[byte * 8 + bit];
      value |= static_cast<std::uint8_t>((at(p.x1, p.y1) < at(p.x2, p.y2)) << bit);
    }
    out[byte] = value;
  }
}

}  // namespace

Status OrbOptions::validate() const {
  if (num_features < 50 || num_features > 20000) return Error{"orb.num_features must be in 50..20000"};
  if (num_levels < 1 || num_levels > 16) return Error{"orb.num_levels must be in 1..16"};
  if (!(scale_factor > 1.0) || scale_factor > 2.0) return Error{"orb.scale_factor must be in (1, 2]"};
  if (fast_threshold < 1 || fast_threshold > 100) return Error{"orb.fast_threshold must be in 1..100"};
  if (min_fast_threshold < 1 || min_fast_threshold > fast_threshold)
    return Error{"orb.min_fast_threshold must be in 1..fast_threshold"};
  if (cell_size < 8 || cell_size > 256) return Error{"orb.cell_size must be in 8..256"};
  return Status::success();
}

Status OrbOptions::validateFor(int width, int height) const {
  // The extractor's border (OrbExtractor::kEdgeThreshold) on both sides, and
  // a little room for corners between them.
  constexpr int kMinLevelSize = 2 * OrbExtractor::kEdgeThreshold + 2;
  const double top = std::pow(scale_factor, num_levels - 1);
  const int w = cvRound(width / top), h = cvRound(height / top);
  if (w >= kMinLevelSize && h >= kMinLevelSize) return Status::success();
  return Error{"orb.num_levels " + std::to_string(num_levels) + " with orb.scale_factor " + std::to_string(scale_factor) +
               " shrinks a " + std::to_string(width) + "x" + std::to_string(height) + " image to " + std::to_string(w) +
               "x" + std::to_string(h) + " at the top pyramid level; it needs at least " + std::to_string(kMinLevelSize) +
               "x" + std::to_string(kMinLevelSize) + ": use fewer levels or a smaller scale factor"};
}

OrbExtractor::OrbExtractor(const OrbOptions& options) : options_(options) {
  const int levels = options_.num_levels;
  scales_.resize(levels);
  sigma2_.resize(levels);
  inv_sigma2_.resize(levels);
  for (int l = 0; l < levels; ++l) {
    scales_[l] = std::pow(options_.scale_factor, l);
    sigma2_[l] = scales_[l] * scales_[l];
    inv_sigma2_[l] = 1.0 / sigma2_[l];
  }
  // Feature budget per level falls geometrically with the level's linear size.
  const double f = 1.0 / options_.scale_factor;
  double per_level = options_.num_features * (1 - f) / (1 - std::pow(f, levels));
  int assigned = 0;
  features_per_level_.resize(levels);
  for (int l = 0; l < levels - 1; ++l) {
    features_per_level_[l] = static_cast<int>(std::round(per_level));
    assigned += features_per_level_[l];
    per_level *= f;
  }
  features_per_level_[levels - 1] = std::max(0, options_.num_features - assigned);

  umax_.resize(kHalfPatch + 1);
  for (int v = 0; v <= kHalfPatch; ++v)
    umax_[v] = static_cast<int>(std::floor(std::sqrt(kHalfPatch * kHalfPatch - v * v + 0.25)));
  (void)pattern();
}

void OrbExtractor::buildPyramid(const cv::Mat& gray) {
  pyramid_.resize(options_.num_levels);
  blurred_.resize(options_.num_levels);
  for (int l = 0; l < options_.num_levels; ++l) {
    if (l == 0) {
      pyramid_[0] = gray;
    } else {
      const cv::Size size(cvRound(gray.cols / scales_[l]), cvRound(gray.rows / scales_[l]));
      cv::resize(pyramid_[l - 1], pyramid_[l], size, 0, 0, cv::INTER_LINEAR);
    }
    cv::GaussianBlur(pyramid_[l], blurred_[l], cv::Size(7, 7), 2, 2, cv::BORDER_REFLECT_101);
  }
}

void OrbExtractor::detectLevel(int level, const cv::Mat& sparse, int sparse_every,
                               std::vector<cv::KeyPoint>* out) const {
  const cv::Mat& image = pyramid_[level];
  const int budget = features_per_level_[level];
  const int min_x = kEdgeThreshold - 3, min_y = kEdgeThreshold - 3;
  const int max_x = image.cols - kEdgeThreshold + 3, max_y = image.rows - kEdgeThreshold + 3;
  if (budget <= 0 || max_x - min_x < 16 || max_y - min_y < 16) return;

  // FAST with the preferred threshold over the whole level; cells left empty
  // are searched again with the low threshold (the adaptive threshold), so
  // weakly textured regions still get features without paying the low
  // threshold's cost everywhere.
  const cv::Rect region(min_x, min_y, max_x - min_x, max_y - min_y);
  std::vector<cv::KeyPoint> corners;
  cv::FAST(image(region), corners, options_.fast_threshold, true);
  const int cell = options_.cell_size;
  const int cols = std::max(1, (region.width + cell - 1) / cell);
  const int rows = std::max(1, (region.height + cell - 1) / cell);
  auto cellIndex = [&](const cv::Point2f& p) {
    const int c = std::min(cols - 1, static_cast<int>(p.x) / cell);
    const int r = std::min(rows - 1, static_cast<int>(p.y) / cell);
    return r * cols + c;
  };
  std::vector<std::vector<int>> per_cell(cols * rows);
  for (std::size_t i = 0; i < corners.size(); ++i) per_cell[cellIndex(corners[i].pt)].push_back(static_cast<int>(i));
  std::vector<cv::KeyPoint> weak;
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      if (!per_cell[r * cols + c].empty()) continue;
      // The cell plus the 3-pixel ring FAST needs, clipped to the region.
      const cv::Rect inner(c * cell, r * cell, cell, cell);
      const cv::Rect outer = cv::Rect(inner.x - 3, inner.y - 3, cell + 6, cell + 6) &
                             cv::Rect(0, 0, region.width, region.height);
      if (outer.width < 7 || outer.height < 7) continue;
      weak.clear();
      cv::FAST(image(region)(outer), weak, options_.min_fast_threshold, true);
      for (cv::KeyPoint kp : weak) {
        kp.pt.x += static_cast<float>(outer.x);
        kp.pt.y += static_cast<float>(outer.y);
        if (!inner.contains(cv::Point(static_cast<int>(kp.pt.x), static_cast<int>(kp.pt.y)))) continue;
        per_cell[r * cols + c].push_back(static_cast<int>(corners.size()));
        corners.push_back(kp);
      }
    }
  }
  struct Candidate {
    int rank;
    float response;
    int index;
    bool sparse;  // its cell lies in the sparse region
  };
  const bool thin = !sparse.empty() && sparse_every > 1;
  const double to_sparse_x = thin ? scales_[level] * sparse.cols / pyramid_[0].cols : 0;
  const double to_sparse_y = thin ? scales_[level] * sparse.rows / pyramid_[0].rows : 0;
  const auto sparseCell = [&](int cell_index) {
    if (!thin) return false;
    const int x = static_cast<int>((min_x + (cell_index % cols) * cell + cell / 2) * to_sparse_x);
    const int y = static_cast<int>((min_y + (cell_index / cols) * cell + cell / 2) * to_sparse_y);
    return sparse.at<std::uint8_t>(std::clamp(y, 0, sparse.rows - 1), std::clamp(x, 0, sparse.cols - 1)) != 0;
  };
  // Round robin over cells: every cell gives its best corner before any cell
  // gives its second, which spreads features evenly over the image.
  std::vector<Candidate> candidates;
  candidates.reserve(corners.size());
  for (std::size_t c = 0; c < per_cell.size(); ++c) {
    auto& members = per_cell[c];
    std::sort(members.begin(), members.end(),
              [&](int a, int b) { return corners[a].response > corners[b].response; });
    const bool in_sparse = !members.empty() && sparseCell(static_cast<int>(c));
    for (std::size_t rank = 0; rank < members.size(); ++rank)
      candidates.push_back({static_cast<int>(rank), corners[members[rank]].response, members[rank], in_sparse});
  }
  const auto order = [](const Candidate& a, const Candidate& b) {
    if (a.rank != b.rank) return a.rank < b.rank;
    if (a.response != b.response) return a.response > b.response;
    return a.index < b.index;
  };
  std::size_t keep = std::min<std::size_t>(budget, candidates.size());
  if (thin) {
    // The same order, but in the sparse region only every sparse_every-th
    // corner it reaches is kept. The order is needed only as far as the
    // budget reaches: at most sparse_every x budget candidates.
    const std::size_t reach = std::min(candidates.size(), keep * static_cast<std::size_t>(sparse_every));
    std::partial_sort(candidates.begin(), candidates.begin() + reach, candidates.end(), order);
    std::size_t kept = 0;
    int sparse_seen = 0;
    for (std::size_t k = 0; k < reach && kept < keep; ++k)
      if (!candidates[k].sparse || sparse_seen++ % sparse_every == 0) candidates[kept++] = candidates[k];
    keep = kept;
  } else {
    std::partial_sort(candidates.begin(), candidates.begin() + keep, candidates.end(), order);
  }
  const float scale = static_cast<float>(scales_[level]);
  for (std::size_t k = 0; k < keep; ++k) {
    cv::KeyPoint kp = corners[candidates[k].index];
    kp.pt.x += min_x;
    kp.pt.y += min_y;
    kp.angle = patchAngle(image, kp.pt, umax_);
    kp.octave = level;
    kp.size = kPatchSize * scale;
    kp.pt *= scale;
    out->push_back(kp);
  }
}

void OrbExtractor::extract(const cv::Mat& gray, std::vector<cv::KeyPoint>* keypoints, cv::Mat* descriptors,
                           const cv::Mat& sparse, int sparse_every) {
  keypoints->clear();
  CV_Assert(gray.type() == CV_8UC1);
  buildPyramid(gray);
  CV_Assert(sparse.empty() || sparse.type() == CV_8UC1);
  for (int l = 0; l < options_.num_levels; ++l) detectLevel(l, sparse, sparse_every, keypoints);
  descriptors->create(static_cast<int>(keypoints->size()), 32, CV_8U);
  for (std::size_t i = 0; i < keypoints->size(); ++i) {
    const cv::KeyPoint& kp = (*keypoints)[i];
    computeDescriptor(blurred_[kp.octave], kp, static_cast<float>(scales_[kp.octave]),
                      descriptors->ptr<std::uint8_t>(static_cast<int>(i)));
  }
}

}  // namespace stillpoint::features
