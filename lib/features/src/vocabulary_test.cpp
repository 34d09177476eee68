#include "stillpoint/features/vocabulary.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>

#include <unistd.h>

#include "stillpoint/features/descriptor.hpp"

namespace stillpoint::features {
namespace {

// A "place" is a set of random descriptors; a view of it keeps most of them,
// each with a few bits flipped (noise), and adds some clutter.
struct Places {
  explicit Places(int count, int per_place, std::uint32_t seed) : rng(seed), places(count) {
    std::uniform_int_distribution<int> byte(0, 255);
    for (auto& p : places) {
      p = cv::Mat(per_place, kDescriptorBytes, CV_8UC1);
      for (int r = 0; r < p.rows; ++r)
        for (int c = 0; c < p.cols; ++c) p.at<std::uint8_t>(r, c) = static_cast<std::uint8_t>(byte(rng));
    }
  }
  cv::Mat view(int place, double keep = 0.8, int flips = 8, int clutter = 40) {
    std::uniform_real_distribution<double> u(0, 1);
    std::uniform_int_distribution<int> bit(0, kDescriptorBytes * 8 - 1), byte(0, 255);
    cv::Mat out(0, kDescriptorBytes, CV_8UC1);
    const cv::Mat& p = places[place];
    for (int r = 0; r < p.rows; ++r) {
      if (u(rng) > keep) continue;
      cv::Mat row = p.row(r).clone();
      for (int f = 0; f < flips; ++f) {
        const int b = bit(rng);
        row.at<std::uint8_t>(0, b / 8) ^= static_cast<std::uint8_t>(1u << (b % 8));
      }
      out.push_back(row);
    }
    for (int k = 0; k < clutter; ++k) {
      cv::Mat row(1, kDescriptorBytes, CV_8UC1);
      for (int c = 0; c < kDescriptorBytes; ++c) row.at<std::uint8_t>(0, c) = static_cast<std::uint8_t>(byte(rng));
      out.push_back(row);
    }
    return out;
  }
  std::mt19937 rng;
  std::vector<cv::Mat> places;
};

std::filesystem::path tempPath(const std::string& name) {
  return std::filesystem::temp_directory_path() / ("stillpoint_vocab_" + std::to_string(::getpid()) + "_" + name);
}

TEST(BowScore, IsOneForTheSameViewAndZeroWithoutSharedWords) {
  BowVector a{{{1, 0.5f}, {4, 0.5f}}}, b{{{2, 0.25f}, {3, 0.75f}}}, c{{{1, 0.25f}, {4, 0.75f}}};
  EXPECT_DOUBLE_EQ(bowScore(a, a), 1.0);
  EXPECT_DOUBLE_EQ(bowScore(a, b), 0.0);
  EXPECT_NEAR(bowScore(a, c), 0.75, 1e-6);  // 1 - (0.25 + 0.25) / 2
  EXPECT_DOUBLE_EQ(bowScore(a, BowVector{}), 0.0);
}

TEST(VocabularyParams, RejectBadShapes) {
  EXPECT_FALSE((VocabularyParams{.branching = 1}.validate()));
  EXPECT_FALSE((VocabularyParams{.depth = 0}.validate()));
  EXPECT_FALSE((VocabularyParams{.branching = 64, .depth = 8}.validate()));
  EXPECT_TRUE(VocabularyParams{}.validate());
}

TEST(Vocabulary, TrainingNeedsEnoughWellFormedDescriptors) {
  EXPECT_FALSE(Vocabulary::train({}, {}));
  EXPECT_FALSE((Vocabulary::train({cv::Mat(100, 16, CV_8UC1, cv::Scalar(0))}, {})));
  EXPECT_FALSE((Vocabulary::train({cv::Mat(3, kDescriptorBytes, CV_8UC1, cv::Scalar(0))}, {})));
}

// Views of places the vocabulary was trained on, and of places it never saw:
// a view's best-scoring view among one per place is its own place's. (Real
// images: `stillpoint-vocab check`, docs/place-recognition.md.)
TEST(Vocabulary, RecognisesPlacesTrainedOnAndUnseenOnes) {
  Places places(40, 300, 11);
  std::vector<cv::Mat> training;
  for (int p = 0; p < 20; ++p)
    for (int v = 0; v < 3; ++v) training.push_back(places.view(p));
  auto vocab = Vocabulary::train(training, {.branching = 8, .depth = 3});
  ASSERT_TRUE(vocab) << vocab.error();
  const VocabularyInfo info = vocab->info();
  EXPECT_GT(info.words, 256u);
  EXPECT_LE(info.words, 512u);
  EXPECT_EQ(info.training_images, 60u);

  std::vector<BowVector> database;
  for (int p = 0; p < 40; ++p) database.push_back(vocab->transform(places.view(p)));
  int right_trained = 0, right_unseen = 0;
  for (int p = 0; p < 40; ++p) {
    const BowVector query = vocab->transform(places.view(p));
    int best = -1;
    double best_score = -1;
    for (int q = 0; q < 40; ++q)
      if (const double s = bowScore(query, database[q]); s > best_score) best_score = s, best = q;
    (p < 20 ? right_trained : right_unseen) += best == p;
  }
  EXPECT_EQ(right_trained, 20);
  // Random descriptors have none of the structure that lets real ones
  // generalise, yet unseen places are still found far above chance (1 in 40).
  EXPECT_GE(right_unseen, 15);
}

TEST(Vocabulary, TrainingIsDeterministicAndAFileRoundTrips) {
  Places places(10, 200, 3);
  std::vector<cv::Mat> training;
  for (int p = 0; p < 10; ++p) training.push_back(places.view(p));
  auto a = Vocabulary::train(training, {.branching = 6, .depth = 3, .seed = 5});
  auto b = Vocabulary::train(training, {.branching = 6, .depth = 3, .seed = 5});
  ASSERT_TRUE(a && b);
  const auto path = tempPath("roundtrip.vocab");
  ASSERT_TRUE(a->save(path.string()));
  auto loaded = Vocabulary::load(path.string());
  ASSERT_TRUE(loaded) << loaded.error();
  EXPECT_EQ(loaded->info().words, a->info().words);
  EXPECT_EQ(loaded->info().nodes, a->info().nodes);
  const cv::Mat probe = places.view(4);
  std::vector<WordId> wa, wb, wl;
  const BowVector va = a->transform(probe, &wa), vl = loaded->transform(probe, &wl);
  b->transform(probe, &wb);
  EXPECT_EQ(wa, wb);
  EXPECT_EQ(wa, wl);
  ASSERT_EQ(va.entries.size(), vl.entries.size());
  for (std::size_t i = 0; i < va.entries.size(); ++i) {
    EXPECT_EQ(va.entries[i].first, vl.entries[i].first);
    EXPECT_FLOAT_EQ(va.entries[i].second, vl.entries[i].second);
  }
  std::filesystem::remove(path);
}

// Every damaged file is an error naming it, never a crash or a vocabulary.
TEST(Vocabulary, DamagedFilesAreErrorsNamingTheFile) {
  Places places(6, 150, 9);
  std::vector<cv::Mat> training;
  for (int p = 0; p < 6; ++p) training.push_back(places.view(p));
  auto vocab = Vocabulary::train(training, {.branching = 4, .depth = 3});
  ASSERT_TRUE(vocab);
  const auto path = tempPath("damaged.vocab");
  ASSERT_TRUE(vocab->save(path.string()));
  std::string bytes;
  {
    std::ifstream f(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
  }
  auto write = [&path](const std::string& b) {
    std::ofstream f(path, std::ios::binary | std::ios::trunc);
    f.write(b.data(), static_cast<std::streamsize>(b.size()));
  };
  auto expectError = [&path](const std::string& what) {
    auto r = Vocabulary::load(path.string());
    ASSERT_FALSE(r) << what;
    EXPECT_NE(r.error().find(path.string()), std::string::npos) << r.error();
    EXPECT_NE(r.error().find(what), std::string::npos) << r.error();
  };
  write(bytes.substr(0, bytes.size() / 2));
  expectError("truncated");
  std::string flipped = bytes;
  flipped[bytes.size() / 2] ^= 0x10;
  write(flipped);
  expectError("checksum");
  std::string version = bytes;
  version[8] = 7;
  write(version);
  expectError("version 7");
  write("not a vocabulary at all, but long enough to have a header of forty-eight bytes");
  expectError("bad magic");
  std::filesystem::remove(path);
  auto missing = Vocabulary::load(path.string());
  ASSERT_FALSE(missing);
  EXPECT_NE(missing.error().find("cannot open"), std::string::npos);
}

}  // namespace
}  // namespace stillpoint::features
