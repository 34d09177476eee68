#include "stillpoint/features/vocabulary.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <deque>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <type_traits>

#include "stillpoint/core/checksum.hpp"
#include "stillpoint/features/descriptor.hpp"

namespace stillpoint::features {
namespace {

constexpr char kMagic[8] = {'S', 'P', 'V', 'O', 'C', 'A', 'B', '\n'};
constexpr std::uint32_t kVersion = 1;
constexpr std::size_t kHeaderBytes = 8 + 6 * 4 + 2 * 8;
constexpr std::size_t kNodeBytes = kDescriptorBytes + 2 * 4;

using Descriptor = std::array<std::uint8_t, kDescriptorBytes>;

// The bitwise majority of a set of descriptors: the descriptor with the least
// summed Hamming distance to them (ties to 0).
Descriptor majority(const std::vector<const std::uint8_t*>& members) {
  std::array<int, kDescriptorBytes * 8> ones{};
  for (const std::uint8_t* d : members)
    for (int b = 0; b < kDescriptorBytes; ++b)
      for (int bit = 0; bit < 8; ++bit) ones[b * 8 + bit] += (d[b] >> bit) & 1;
  Descriptor out{};
  const int half = static_cast<int>(members.size());
  for (int b = 0; b < kDescriptorBytes; ++b)
    for (int bit = 0; bit < 8; ++bit)
      if (2 * ones[b * 8 + bit] > half) out[b] |= static_cast<std::uint8_t>(1u << bit);
  return out;
}

// k-medians of `set` (k-means++ seeding, Hamming distance, majority
// centres): the non-empty clusters, each as the indices of its members.
std::vector<std::vector<std::size_t>> kMedians(const std::vector<const std::uint8_t*>& all,
                                               const std::vector<std::size_t>& set, int k, int iterations,
                                               std::mt19937& rng) {
  std::vector<Descriptor> centres;
  {
    std::uniform_int_distribution<std::size_t> pick(0, set.size() - 1);
    Descriptor first;
    std::memcpy(first.data(), all[set[pick(rng)]], kDescriptorBytes);
    centres.push_back(first);
    std::vector<double> d2(set.size(), std::numeric_limits<double>::infinity());
    while (static_cast<int>(centres.size()) < k) {
      double total = 0;
      for (std::size_t i = 0; i < set.size(); ++i) {
        const double d = hammingDistance(all[set[i]], centres.back().data());
        d2[i] = std::min(d2[i], d * d);
        total += d2[i];
      }
      if (total <= 0) break;  // every member equals a centre already
      std::uniform_real_distribution<double> u(0.0, total);
      double r = u(rng);
      std::size_t chosen = set.size() - 1;
      for (std::size_t i = 0; i < set.size(); ++i) {
        r -= d2[i];
        if (r <= 0 && d2[i] > 0) {
          chosen = i;
          break;
        }
      }
      Descriptor next;
      std::memcpy(next.data(), all[set[chosen]], kDescriptorBytes);
      centres.push_back(next);
    }
  }
  std::vector<int> assignment(set.size(), -1);
  std::vector<std::vector<std::size_t>> clusters;
  for (int round = 0; round < iterations; ++round) {
    bool changed = false;
    clusters.assign(centres.size(), {});
    for (std::size_t i = 0; i < set.size(); ++i) {
      int best = 0, best_d = std::numeric_limits<int>::max();
      for (std::size_t c = 0; c < centres.size(); ++c) {
        const int d = hammingDistance(all[set[i]], centres[c].data());
        if (d < best_d) best_d = d, best = static_cast<int>(c);
      }
      changed |= assignment[i] != best;
      assignment[i] = best;
      clusters[best].push_back(set[i]);
    }
    if (!changed) break;
    for (std::size_t c = 0; c < centres.size(); ++c) {
      if (clusters[c].empty()) continue;
      std::vector<const std::uint8_t*> members;
      members.reserve(clusters[c].size());
      for (std::size_t i : clusters[c]) members.push_back(all[i]);
      centres[c] = majority(members);
    }
  }
  std::erase_if(clusters, [](const auto& c) { return c.empty(); });
  return clusters;
}

template <typename T>
void put(std::string* out, T v) {
  static_assert(std::is_trivially_copyable_v<T>);
  out->append(reinterpret_cast<const char*>(&v), sizeof(T));
}

template <typename T>
T get(const char* data, std::size_t* pos) {
  T v;
  std::memcpy(&v, data + *pos, sizeof(T));
  *pos += sizeof(T);
  return v;
}

}  // namespace

double bowScore(const BowVector& a, const BowVector& b) {
  // |a - b|_1 = |a|_1 + |b|_1 - sum over shared words (|a_i| + |b_i| - |a_i - b_i|);
  // with unit norms the score is half that sum.
  double shared = 0;
  auto i = a.entries.begin(), j = b.entries.begin();
  while (i != a.entries.end() && j != b.entries.end()) {
    if (i->first < j->first) {
      ++i;
    } else if (j->first < i->first) {
      ++j;
    } else {
      shared += std::abs(i->second) + std::abs(j->second) - std::abs(i->second - j->second);
      ++i, ++j;
    }
  }
  return std::clamp(0.5 * shared, 0.0, 1.0);
}

Status VocabularyParams::validate() const {
  if (branching < 2 || branching > 64) return Error{"vocabulary branching must be 2..64"};
  if (depth < 1 || depth > 8) return Error{"vocabulary depth must be 1..8"};
  if (std::pow(static_cast<double>(branching), depth) > 5e6) return Error{"vocabulary branching^depth must be <= 5e6 words"};
  if (iterations < 1 || iterations > 100) return Error{"vocabulary iterations must be 1..100"};
  return Status::success();
}

struct VocabularyBuilder {
  static Result<Vocabulary> build(const std::vector<cv::Mat>& images, const VocabularyParams& params) {
    if (Status s = params.validate(); !s) return Error{s.error()};
    std::vector<const std::uint8_t*> all;
    std::vector<std::pair<std::size_t, std::size_t>> image_ranges;  // [begin, end) in `all`
    for (const cv::Mat& d : images) {
      if (d.empty()) {
        image_ranges.emplace_back(all.size(), all.size());
        continue;
      }
      if (d.type() != CV_8UC1 || d.cols != kDescriptorBytes || !d.isContinuous())
        return Error{"training descriptors must be continuous CV_8UC1 rows of 32 bytes"};
      const std::size_t begin = all.size();
      for (int r = 0; r < d.rows; ++r) all.push_back(d.ptr<std::uint8_t>(r));
      image_ranges.emplace_back(begin, all.size());
    }
    if (all.size() < static_cast<std::size_t>(params.branching))
      return Error{"too few training descriptors (" + std::to_string(all.size()) + ") for a vocabulary"};

    Vocabulary v;
    v.branching_ = params.branching;
    v.depth_ = params.depth;
    v.training_images_ = images.size();
    v.training_descriptors_ = all.size();
    std::mt19937 rng(params.seed);
    struct Pending {
      std::uint32_t node;
      int level;
      std::vector<std::size_t> members;
    };
    std::deque<Pending> queue;
    v.nodes_.emplace_back();
    {
      std::vector<std::size_t> everything(all.size());
      for (std::size_t i = 0; i < all.size(); ++i) everything[i] = i;
      queue.push_back({0, 0, std::move(everything)});
    }
    // Breadth first: a node's children are appended together, so they are
    // consecutive and the file order is the tree's level order.
    while (!queue.empty()) {
      Pending p = std::move(queue.front());
      queue.pop_front();
      if (p.level == params.depth || p.members.size() <= 1) continue;  // a leaf
      std::vector<std::vector<std::size_t>> clusters;
      if (p.members.size() <= static_cast<std::size_t>(params.branching)) {
        for (std::size_t m : p.members) clusters.push_back({m});
      } else {
        clusters = kMedians(all, p.members, params.branching, params.iterations, rng);
      }
      if (clusters.size() <= 1) continue;  // all alike: nothing to split
      const auto first = static_cast<std::uint32_t>(v.nodes_.size());
      v.nodes_[p.node].first_child = first;
      v.nodes_[p.node].children = static_cast<std::uint32_t>(clusters.size());
      for (auto& c : clusters) {
        std::vector<const std::uint8_t*> members;
        for (std::size_t i : c) members.push_back(all[i]);
        Vocabulary::Node node;
        const Descriptor centre = majority(members);
        std::memcpy(node.centre, centre.data(), kDescriptorBytes);
        const auto index = static_cast<std::uint32_t>(v.nodes_.size());
        v.nodes_.push_back(node);
        queue.push_back({index, p.level + 1, std::move(c)});
      }
    }
    numberWords(&v);
    // Inverse document frequency: ln(N / images containing the word). A word
    // no training image reaches (possible when the medians moved after the
    // last assignment) counts as the rarest.
    std::vector<std::uint32_t> images_with(v.words_, 0);
    std::vector<std::int64_t> last_image(v.words_, -1);
    for (std::size_t img = 0; img < image_ranges.size(); ++img)
      for (std::size_t i = image_ranges[img].first; i < image_ranges[img].second; ++i) {
        const WordId w = v.wordOf(all[i]);
        if (last_image[w] != static_cast<std::int64_t>(img)) ++images_with[w], last_image[w] = static_cast<std::int64_t>(img);
      }
    const double n = static_cast<double>(images.size());
    v.word_weight_.resize(v.words_);
    for (std::size_t w = 0; w < v.words_; ++w)
      v.word_weight_[w] = static_cast<float>(std::log(n / std::max<std::uint32_t>(1, images_with[w])));
    return v;
  }

  // Leaves in node order are words 0, 1, ...
  static void numberWords(Vocabulary* v) {
    v->words_ = 0;
    for (auto& node : v->nodes_)
      if (node.children == 0) node.word = static_cast<WordId>(v->words_++);
  }
};

Result<Vocabulary> Vocabulary::train(const std::vector<cv::Mat>& image_descriptors, const VocabularyParams& params) {
  try {
    return VocabularyBuilder::build(image_descriptors, params);
  } catch (const std::exception& e) {
    return Error{std::string("vocabulary training failed: ") + e.what()};
  }
}

VocabularyInfo Vocabulary::info() const {
  return {branching_, depth_, nodes_.size(), words_, training_images_, training_descriptors_};
}

WordId Vocabulary::wordOf(const std::uint8_t* descriptor) const {
  std::uint32_t at = 0;
  while (nodes_[at].children != 0) {
    const Node& n = nodes_[at];
    std::uint32_t best = n.first_child;
    int best_d = std::numeric_limits<int>::max();
    for (std::uint32_t c = n.first_child; c < n.first_child + n.children; ++c) {
      const int d = hammingDistance(descriptor, nodes_[c].centre);
      if (d < best_d) best_d = d, best = c;
    }
    at = best;
  }
  return nodes_[at].word;
}

BowVector Vocabulary::transform(const cv::Mat& descriptors, std::vector<WordId>* words) const {
  BowVector v;
  if (words) words->clear();
  if (empty() || descriptors.empty() || descriptors.type() != CV_8UC1 || descriptors.cols != kDescriptorBytes) return v;
  std::vector<std::pair<WordId, float>> raw;
  raw.reserve(descriptors.rows);
  for (int r = 0; r < descriptors.rows; ++r) {
    const WordId w = wordOf(descriptors.ptr<std::uint8_t>(r));
    if (words) words->push_back(w);
    if (word_weight_[w] > 0) raw.emplace_back(w, word_weight_[w]);
  }
  std::sort(raw.begin(), raw.end());
  double total = 0;
  for (const auto& [w, weight] : raw) {
    if (!v.entries.empty() && v.entries.back().first == w) v.entries.back().second += weight;
    else v.entries.emplace_back(w, weight);
    total += weight;
  }
  if (total > 0)
    for (auto& e : v.entries) e.second = static_cast<float>(e.second / total);
  return v;
}

Status Vocabulary::save(const std::string& path) const {
  if (empty()) return Error{"vocabulary " + path + ": nothing to save (empty vocabulary)"};
  std::string out;
  out.append(kMagic, sizeof(kMagic));
  put<std::uint32_t>(&out, kVersion);
  put<std::uint32_t>(&out, static_cast<std::uint32_t>(branching_));
  put<std::uint32_t>(&out, static_cast<std::uint32_t>(depth_));
  put<std::uint32_t>(&out, static_cast<std::uint32_t>(nodes_.size()));
  put<std::uint32_t>(&out, static_cast<std::uint32_t>(words_));
  put<std::uint32_t>(&out, 0);  // reserved
  put<std::uint64_t>(&out, training_images_);
  put<std::uint64_t>(&out, training_descriptors_);
  for (const Node& n : nodes_) {
    out.append(reinterpret_cast<const char*>(n.centre), kDescriptorBytes);
    put<std::uint32_t>(&out, n.first_child);
    put<std::uint32_t>(&out, n.children);
  }
  for (float w : word_weight_) put<float>(&out, w);
  put<std::uint64_t>(&out, fnv1a64(out.data(), out.size()));
  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) return Error{"vocabulary " + path + ": cannot open " + tmp + " for writing"};
    f.write(out.data(), static_cast<std::streamsize>(out.size()));
    f.close();
    if (!f) return Error{"vocabulary " + path + ": write failed (disk full?)"};
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) return Error{"vocabulary " + path + ": cannot rename " + tmp};
  return Status::success();
}

Result<Vocabulary> Vocabulary::load(const std::string& path) {
  auto error = [&path](const std::string& what) { return Error{"vocabulary " + path + ": " + what}; };
  std::string bytes;
  try {
    std::ifstream f(path, std::ios::binary);
    if (!f) return error("cannot open");
    bytes.assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
    if (f.bad()) return error("read failed");
  } catch (const std::exception& e) {
    return error(std::string("read failed: ") + e.what());
  }
  if (bytes.size() < kHeaderBytes + 8) return error("too short to be a vocabulary (truncated?)");
  if (std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) != 0) return error("not a stillpoint vocabulary (bad magic)");
  std::size_t pos = sizeof(kMagic);
  const char* d = bytes.data();
  const auto version = get<std::uint32_t>(d, &pos);
  if (version != kVersion)
    return error("version " + std::to_string(version) + ", this build reads version " + std::to_string(kVersion));
  Vocabulary v;
  v.branching_ = static_cast<int>(get<std::uint32_t>(d, &pos));
  v.depth_ = static_cast<int>(get<std::uint32_t>(d, &pos));
  const auto nodes = get<std::uint32_t>(d, &pos);
  const auto words = get<std::uint32_t>(d, &pos);
  get<std::uint32_t>(d, &pos);
  v.training_images_ = get<std::uint64_t>(d, &pos);
  v.training_descriptors_ = get<std::uint64_t>(d, &pos);
  const std::uint64_t expected = kHeaderBytes + std::uint64_t{nodes} * kNodeBytes + std::uint64_t{words} * 4 + 8;
  if (bytes.size() != expected)
    return error("size " + std::to_string(bytes.size()) + " bytes, its header says " + std::to_string(expected) +
                 " (truncated or corrupt)");
  std::uint64_t checksum;
  std::memcpy(&checksum, d + bytes.size() - 8, 8);
  if (fnv1a64(d, bytes.size() - 8) != checksum) return error("checksum mismatch (corrupt file)");
  if (nodes == 0 || words == 0) return error("no words");
  v.nodes_.resize(nodes);
  // Children must be consecutive and follow their parents in level order:
  // then the nodes form a tree and every descent ends at a leaf.
  std::uint64_t next_child = 1;
  std::size_t leaves = 0;
  for (std::uint32_t i = 0; i < nodes; ++i) {
    Node& n = v.nodes_[i];
    std::memcpy(n.centre, d + pos, kDescriptorBytes);
    pos += kDescriptorBytes;
    n.first_child = get<std::uint32_t>(d, &pos);
    n.children = get<std::uint32_t>(d, &pos);
    if (n.children == 0) {
      ++leaves;
      continue;
    }
    if (n.first_child != next_child || n.children > nodes - next_child) return error("node " + std::to_string(i) + " is not in tree order (corrupt)");
    next_child += n.children;
  }
  if (next_child != nodes || leaves != words) return error("the tree's leaves do not match its word count (corrupt)");
  VocabularyBuilder::numberWords(&v);
  v.word_weight_.resize(words);
  for (std::uint32_t w = 0; w < words; ++w) {
    v.word_weight_[w] = get<float>(d, &pos);
    if (!std::isfinite(v.word_weight_[w]) || v.word_weight_[w] < 0) return error("word " + std::to_string(w) + " has a bad weight");
  }
  return v;
}

}  // namespace stillpoint::features
