#pragma once
// A vocabulary of binary visual words for place recognition: a tree of
// 256-bit descriptors built by hierarchical k-medians, whose leaves are the
// words, each weighted by its inverse document frequency in the training
// images. A view becomes a sparse tf-idf vector of words (transform); two
// views of one place share words, so their vectors score high (score), and
// an inverted index over keyframes finds them among thousands without
// matching a single descriptor.
//
// Files are binary: a header, the nodes in breadth-first order, and a
// checksum; a 10x10x10x10 vocabulary is about 0.4 MB and loads in a few
// milliseconds. A truncated, corrupt or foreign file is an error that names
// it.
#include <opencv2/core.hpp>

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "stillpoint/core/result.hpp"

namespace stillpoint::features {

using WordId = std::uint32_t;

// Sparse tf-idf vector of a view: (word, weight) sorted by word, weights
// summing to 1 (L1).
struct BowVector {
  std::vector<std::pair<WordId, float>> entries;
  bool empty() const { return entries.empty(); }
};

// Similarity of two views in [0, 1]: 1 - |a - b|_1 / 2 (1: the same words in
// the same proportions; 0: no word in common).
double bowScore(const BowVector& a, const BowVector& b);

struct VocabularyParams {
  int branching = 10;  // children per node, the k of k-medians
  int depth = 4;       // levels below the root: up to branching^depth words
  int iterations = 12; // k-medians rounds per node at most
  std::uint32_t seed = 1;
  Status validate() const;
};

struct VocabularyInfo {
  int branching = 0, depth = 0;
  std::size_t nodes = 0, words = 0;
  std::uint64_t training_images = 0, training_descriptors = 0;
};

class Vocabulary {
 public:
  Vocabulary() = default;

  // Builds a vocabulary from the descriptors of a set of images (one CV_8UC1
  // matrix of 32-byte rows per image). Deterministic for a given seed.
  static Result<Vocabulary> train(const std::vector<cv::Mat>& image_descriptors, const VocabularyParams& params);
  static Result<Vocabulary> load(const std::string& path);
  Status save(const std::string& path) const;

  bool empty() const { return words_ == 0; }
  VocabularyInfo info() const;

  // The word of one descriptor (kDescriptorBytes bytes): the leaf reached by
  // following the nearest child (Hamming distance) from the root.
  WordId wordOf(const std::uint8_t* descriptor) const;
  float weight(WordId word) const { return word_weight_[word]; }
  // A view's vector from its descriptors (rows of 32 bytes). `words`
  // (optional): the word of every descriptor, in row order.
  BowVector transform(const cv::Mat& descriptors, std::vector<WordId>* words = nullptr) const;

 private:
  friend struct VocabularyBuilder;
  struct Node {
    std::uint8_t centre[32];
    std::uint32_t first_child = 0;  // index of the first child (children are consecutive)
    std::uint32_t children = 0;     // 0: a leaf
    std::uint32_t word = 0;         // a leaf's word
  };
  std::vector<Node> nodes_;  // breadth first; nodes_[0] is the root
  std::vector<float> word_weight_;
  std::size_t words_ = 0;
  int branching_ = 0, depth_ = 0;
  std::uint64_t training_images_ = 0, training_descriptors_ = 0;
};

}  // namespace stillpoint::features
