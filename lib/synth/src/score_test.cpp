// Scorer: hand-made masks and features with known answers, file parsing errors.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include <opencv2/imgcodecs.hpp>
#include <unistd.h>

#include "stillpoint/synth/score.hpp"

namespace stillpoint::synth {
namespace {

namespace fs = std::filesystem;

// 20 x 10 mask: mover 1 on columns 0-4, mover 2 on columns 15-19.
cv::Mat twoMovers() {
  cv::Mat m(10, 20, CV_16UC1, cv::Scalar(0));
  m(cv::Rect(0, 0, 5, 10)).setTo(1);
  m(cv::Rect(15, 0, 5, 10)).setTo(2);
  return m;
}

TEST(Score, CountsPrecisionRecallAndEligibleMovers) {
  std::vector<FlaggedFeature> f;
  for (int i = 0; i < 4; ++i) f.push_back({1.0, double(i), i < 3});     // mover 1: 4 features, 3 flagged
  for (int i = 0; i < 2; ++i) f.push_back({17.0, double(i), false});    // mover 2: 2 features, none flagged
  f.push_back({10.0, 5.0, true});                                       // static, flagged: false positive
  f.push_back({10.0, 6.0, false});                                      // static, not flagged
  f.push_back({4.6, 2.0, true});   // rounds to column 5: static
  f.push_back({-3.0, 2.0, true});  // outside the image: ignored
  const FrameScore s = scoreFrame(twoMovers(), f, 3);
  EXPECT_EQ(s.outside, 1);
  EXPECT_EQ(s.features, 9);
  EXPECT_EQ(s.flagged, 5);
  EXPECT_EQ(s.on_movers, 6);
  EXPECT_EQ(s.true_positives, 3);
  EXPECT_DOUBLE_EQ(s.precision(), 3.0 / 5.0);
  EXPECT_DOUBLE_EQ(s.recall(), 3.0 / 6.0);
  ASSERT_EQ(s.movers.size(), 2u);
  EXPECT_EQ(s.movers[0].id, 1);
  EXPECT_EQ(s.movers[0].features, 4);
  EXPECT_EQ(s.movers[0].flagged, 3);
  EXPECT_EQ(s.movers[1].features, 2);
  // Only mover 1 carries >= 3 features.
  EXPECT_EQ(s.eligible_movers, 1);
  EXPECT_DOUBLE_EQ(s.eligibleRecall(), 3.0 / 4.0);
  const FrameScore none = scoreFrame(twoMovers(), f, 10);
  EXPECT_EQ(none.eligible_movers, 0);
  EXPECT_TRUE(std::isnan(none.eligibleRecall()));
}

TEST(Score, UndefinedRatiosAreNanAndAveragesSkipThem) {
  const cv::Mat m = twoMovers();
  const std::vector<FlaggedFeature> static_only = {{10, 1, false}, {11, 1, true}};
  const FrameScore a = scoreFrame(m, static_only, 1);
  EXPECT_TRUE(std::isnan(a.recall()));
  EXPECT_DOUBLE_EQ(a.precision(), 0.0);
  const std::vector<FlaggedFeature> perfect = {{1, 1, true}, {2, 2, true}, {10, 3, false}};
  const FrameScore b = scoreFrame(m, perfect, 2);
  EXPECT_DOUBLE_EQ(b.precision(), 1.0);
  EXPECT_DOUBLE_EQ(b.recall(), 1.0);
  const std::vector<FlaggedFeature> missed = {{1, 1, false}, {2, 2, true}};
  const FrameScore c = scoreFrame(m, missed, 2);
  const std::vector<FrameScore> frames = {a, b, c};
  const SequenceScore q = averageScores(frames, 2);
  EXPECT_EQ(q.frames, 3);
  EXPECT_EQ(q.precision_frames, 3);
  EXPECT_DOUBLE_EQ(q.precision_mean, (0.0 + 1.0 + 1.0) / 3);
  EXPECT_EQ(q.recall_frames, 2);
  EXPECT_DOUBLE_EQ(q.recall_mean, (1.0 + 0.5) / 2);
  EXPECT_EQ(q.eligible_frames, 2);
  EXPECT_DOUBLE_EQ(q.eligible_recall_mean, 0.75);
  EXPECT_EQ(q.static_frames_with_flags, 1);
  EXPECT_EQ(q.true_positives, 3);
  EXPECT_EQ(q.movers.at(1).features, 4);
  EXPECT_EQ(q.mover_eligible_frames.at(1), 2);
}

fs::path writeSequence(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("stillpoint_score_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "mask");
  cv::imwrite((dir / "mask/1.000000.png").string(), twoMovers());
  cv::imwrite((dir / "mask/1.033333.png").string(), twoMovers());
  std::ofstream(dir / "mask.txt") << "# masks\n1.000000 mask/1.000000.png\n1.033333 mask/1.033333.png\n";
  return dir;
}

TEST(Score, ScoresAFeatureFileAgainstASequence) {
  const fs::path dir = writeSequence("ok");
  std::ofstream(dir / "features.txt") << "# timestamp u v flagged\n"
                                         "1.000000 1 1 1\n1.000000 2 2 0\n1.000000 10 2 0\n\n"
                                         "1.033333 16 3 1\n1.033333 12 3 1\n";
  Result<SequenceScoreReport> r = scoreSequence(dir.string(), (dir / "features.txt").string(), 1);
  ASSERT_TRUE(r.ok()) << r.error();
  EXPECT_EQ(r->frames.size(), 2u);
  EXPECT_EQ(r->frames_without_features, 0);
  EXPECT_DOUBLE_EQ(r->score.recall_mean, (0.5 + 1.0) / 2);
  EXPECT_DOUBLE_EQ(r->score.precision_mean, (1.0 + 0.5) / 2);
  fs::remove_all(dir);
}

TEST(Score, StillMoversCountForNeitherRecallNorFalsePositives) {
  std::vector<FlaggedFeature> f;
  for (int i = 0; i < 4; ++i) f.push_back({1.0, double(i), i < 3});   // mover 1: 3 of 4 flagged
  for (int i = 0; i < 3; ++i) f.push_back({17.0, double(i), i < 1});  // mover 2: 1 of 3 flagged
  f.push_back({10.0, 5.0, true});                                     // static, flagged
  const std::vector<std::uint16_t> still = {2};
  const FrameScore s = scoreFrame(twoMovers(), f, 3, still);
  EXPECT_EQ(s.on_movers, 4);
  EXPECT_EQ(s.true_positives, 3);
  EXPECT_EQ(s.on_still, 3);
  EXPECT_EQ(s.still_flagged, 1);
  EXPECT_DOUBLE_EQ(s.recall(), 3.0 / 4.0);
  EXPECT_DOUBLE_EQ(s.precision(), 4.0 / 5.0);  // the flag on the still mover is no false positive
  EXPECT_EQ(s.eligible_movers, 1);
  ASSERT_EQ(s.movers.size(), 1u);
  EXPECT_EQ(s.movers[0].id, 1);
  // Both still: nothing to find; flags on them alone are no false alarm.
  const std::vector<std::uint16_t> both = {1, 2};
  const std::vector<FlaggedFeature> on_still = {{1, 1, true}, {17, 1, true}};
  const FrameScore b = scoreFrame(twoMovers(), on_still, 1, both);
  EXPECT_TRUE(std::isnan(b.recall()));
  EXPECT_DOUBLE_EQ(b.precision(), 1.0);
  const std::vector<FrameScore> frames = {b};
  EXPECT_EQ(averageScores(frames, 1).static_frames_with_flags, 0);
}

TEST(Score, MinSpeedReadsTheMoverSpeedsOfTheSequence) {
  const fs::path dir = writeSequence("speed");
  std::ofstream(dir / "features.txt") << "1.000000 1 1 0\n1.000000 17 1 1\n1.033333 1 1 0\n1.033333 17 1 1\n";
  const std::string f = (dir / "features.txt").string();
  Result<SequenceScoreReport> r = scoreSequence(dir.string(), f, 1, 0.05);
  ASSERT_FALSE(r.ok());  // no movers.txt
  EXPECT_NE(r.error().find("movers.txt"), std::string::npos) << r.error();
  // Mover 1 still in the first frame, both moving in the second.
  std::ofstream(dir / "movers.txt") << "# timestamp id speed_m_s\n1.000000 1 0.01\n1.000000 2 0.5\n"
                                       "1.033333 1 0.2\n1.033333 2 0.5\n";
  r = scoreSequence(dir.string(), f, 1, 0.05);
  ASSERT_TRUE(r.ok()) << r.error();
  EXPECT_DOUBLE_EQ(r->score.recall_mean, (1.0 + 0.5) / 2);
  r = scoreSequence(dir.string(), f, 1);  // every mover counts
  ASSERT_TRUE(r.ok()) << r.error();
  EXPECT_DOUBLE_EQ(r->score.recall_mean, 0.5);
  std::ofstream(dir / "movers.txt") << "1.000000 1 fast\n";
  r = scoreSequence(dir.string(), f, 1, 0.05);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("movers.txt:1:"), std::string::npos) << r.error();
  std::ofstream(dir / "movers.txt") << "1.000000 1 0.2\n";  // no speeds for the second frame
  r = scoreSequence(dir.string(), f, 1, 0.05);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("1.033333"), std::string::npos) << r.error();
  fs::remove_all(dir);
}

TEST(Score, BadFilesNameFileAndLine) {
  const fs::path dir = writeSequence("bad");
  const std::string f = (dir / "f.txt").string();
  std::ofstream(f) << "# ok\n1.000000 1 1 1\n1.000000 1 1\n";
  Result<SequenceScoreReport> r = scoreSequence(dir.string(), f, 10);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find(f + ":3:"), std::string::npos) << r.error();
  std::ofstream(f) << "1.000000 1 1 2\n";
  r = scoreSequence(dir.string(), f, 10);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("0 or 1"), std::string::npos) << r.error();
  std::ofstream(f) << "1.000000 1 1 1 3 x\n";  // trailing columns must be numbers
  r = scoreSequence(dir.string(), f, 10);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("extra field 'x'"), std::string::npos) << r.error();
  std::ofstream(f) << "1.000000 1 1 1 3 2.5\n";  // cluster and chi2, as stillpoint-replay writes
  EXPECT_TRUE(scoreSequence(dir.string(), f, 10).ok());
  std::ofstream(f) << "2.000000 1 1 1\n";
  r = scoreSequence(dir.string(), f, 10);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("2.000000"), std::string::npos) << r.error();
  r = scoreSequence((dir / "missing").string(), f, 10);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("mask.txt"), std::string::npos) << r.error();
  r = scoreSequence(dir.string(), (dir / "nofile.txt").string(), 10);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("nofile.txt"), std::string::npos) << r.error();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace stillpoint::synth
