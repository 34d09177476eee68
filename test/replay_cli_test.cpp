// stillpoint-replay's command-line contract on small synthetic sequences:
// exit status, which file/field/line the errors name, and the skipped-frame
// accounting of the summary. Tracking accuracy is not asserted here (the
// synthetic scene is a textured plane); see replay_teddy_sequential for that.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "cli_runner.hpp"
#include "stillpoint/dataset/testing.hpp"

namespace stillpoint {
namespace {

namespace fs = std::filesystem;
using test::readFile;
using test::RunResult;
using test::writeFile;

constexpr int kFrames = 10;

std::string describe(const RunResult& r) {
  return "exit " + std::to_string(r.exit_code) + "\n--- stdout ---\n" + r.out + "--- stderr ---\n" + r.err;
}

::testing::AssertionResult contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "\"" << part << "\" not found in:\n" << text;
}

class ReplayCli : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    scratch_ = fs::temp_directory_path() /
               ("stillpoint_replay_cli_" + std::to_string(::getpid()) + "_" + info->name());
    fs::remove_all(scratch_);
    fs::create_directories(scratch_);
    dataset::testing::SyntheticDatasetOptions options;
    options.n_frames = kFrames;
    options.width = 320;
    options.height = 240;
    auto written = dataset::testing::writeSyntheticTumDataset((scratch_ / "seq").string(), options);
    ASSERT_TRUE(written.ok()) << written.error();
    seq_ = *written;
    const CameraModel& c = seq_.camera;
    camera_ = (scratch_ / "camera.yaml").string();
    writeFile(camera_, "width: " + std::to_string(c.width) + "\nheight: " + std::to_string(c.height) +
                           "\nfx: " + std::to_string(c.fx) + "\nfy: " + std::to_string(c.fy) +
                           "\ncx: " + std::to_string(c.cx) + "\ncy: " + std::to_string(c.cy) +
                           "\ndepth_factor: " + std::to_string(c.depth_factor) + "\n");
    output_ = (scratch_ / "traj.txt").string();
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(scratch_);
  }

  RunResult replay(std::vector<std::string> args) {
    args.insert(args.begin(), STILLPOINT_REPLAY);
    return test::run(args, scratch_);
  }
  // The synthetic sequence with our camera file and any extra options.
  RunResult replaySequence(std::vector<std::string> extra = {}) {
    std::vector<std::string> args{seq_.directory, "--camera", camera_, "--output", output_, "--sequential"};
    args.insert(args.end(), extra.begin(), extra.end());
    return replay(args);
  }
  std::string writeScratch(const std::string& name, const std::string& text) {
    const auto path = scratch_ / name;
    writeFile(path, text);
    return path.string();
  }
  std::string rgbFile(int k) const { return "rgb/" + seq_.colour_stamps[k].toSecondsString() + ".png"; }
  std::string depthFile(int k) const { return "depth/" + seq_.depth_stamps[k].toSecondsString() + ".png"; }

  fs::path scratch_;
  dataset::testing::SyntheticDataset seq_;
  std::string camera_, output_;
};

// --- success path -----------------------------------------------------------

TEST_F(ReplayCli, GoodSequenceWritesTrajectoryAndMachineReadableLastLine) {
  const RunResult r = replaySequence();
  ASSERT_EQ(r.exit_code, 0) << describe(r);
  EXPECT_TRUE(fs::is_regular_file(output_)) << describe(r);
  EXPECT_TRUE(contains(r.out, "0 skipped (bad input)"));
  const std::regex last(
      "frames=10 tracked=[0-9]+ lost=[0-9]+ keyframes=[0-9]+ track_ms_median=[0-9.]+ track_ms_p95=[0-9.]+ "
      "geometry_ms_median=[0-9.]+ segment_ms_median=[0-9.]+ segmentations_dropped=[0-9]+");
  EXPECT_TRUE(std::regex_match(test::lastLine(r.out), last)) << describe(r);
}

TEST_F(ReplayCli, GroundTruthGivesTheDriftOfEachHealthLevel) {
  // 20 frames: the last 10 have a pose 1/3 s back, and a textured plane
  // slid along is tracked to the millimetre.
  dataset::testing::SyntheticDatasetOptions options;
  options.n_frames = 20;
  options.width = 320;
  options.height = 240;
  auto longer = dataset::testing::writeSyntheticTumDataset((scratch_ / "seq20").string(), options);
  ASSERT_TRUE(longer.ok()) << longer.error();
  const RunResult r = replay({longer->directory, "--camera", camera_, "--output", output_, "--sequential"});
  ASSERT_EQ(r.exit_code, 0) << describe(r);
  ASSERT_TRUE(contains(r.out, "tracked=20 ")) << describe(r);
  const std::regex level("(good|degraded|unreliable) ([0-9]+) poses: drift over 1/3 s median ([0-9.]+) m, p90 [0-9.]+ m, "
                         "max ([0-9.]+) m, ([0-9.]+) % over 2 cm");
  int poses = 0, lines = 0;
  std::istringstream out(r.out);
  bool in_health = false;
  for (std::string line; std::getline(out, line);) {
    if (line.rfind("health:", 0) == 0) in_health = true;
    else if (!in_health || line.rfind("              ", 0) != 0) {
      in_health = false;
      continue;
    }
    std::smatch m;
    const std::string rest = line.substr(14);
    ASSERT_TRUE(std::regex_match(rest, m, level)) << line;
    poses += std::stoi(m[2]);
    ++lines;
    EXPECT_LT(std::stod(m[4]), 0.01) << line;
  }
  EXPECT_GE(lines, 1) << describe(r);
  EXPECT_EQ(poses, 10) << describe(r);  // The same poses by what lowered their health: at least each pose once.
  const std::regex cause("(none|few_inliers|view_moving|poor_conditioning|high_reprojection|fallback_evidence|"
                         "masks_late|recovering) ([0-9]+) poses: drift over 1/3 s median [0-9.]+ m, p90 [0-9.]+ m, "
                         "max [0-9.]+ m, [0-9.]+ % over 2 cm");
  const std::size_t at = r.out.find("\ncauses:       ");
  ASSERT_NE(at, std::string::npos) << describe(r);
  std::istringstream rest(r.out.substr(at + 1));
  int counted = 0;
  for (std::string line; std::getline(rest, line) && (counted == 0 || line.rfind("              ", 0) == 0);) {
    std::smatch m;
    const std::string after_lead = line.substr(14);
    ASSERT_TRUE(std::regex_match(after_lead, m, cause)) << line;
    counted += std::stoi(m[2]);
  }
  EXPECT_GE(counted, 10) << describe(r);
  // And how well the covariance covered the drift, over the same 10 poses.
  std::smatch m;
  ASSERT_TRUE(std::regex_search(r.out, m,
                                std::regex("\ncovariance:   10 poses: drift within its 95 % ellipsoid ([0-9.]+) % "
                                           "\\(median ([0-9.]+) of a Gaussian's\\), rotation ([0-9.]+) % "
                                           "\\(([0-9.]+)\\)\n")))
      << describe(r);
  EXPECT_LE(std::stod(m[1]), 100.0);
  EXPECT_LE(std::stod(m[3]), 100.0);
}

TEST_F(ReplayCli, HelpPrintsUsageAndExitsZero) {
  const RunResult r = replay({"--help"});
  EXPECT_EQ(r.exit_code, 0) << describe(r);
  EXPECT_TRUE(contains(r.out, "usage: stillpoint-replay DATASET_DIR"));
}

TEST_F(ReplayCli, VersionExitsZero) {
  const RunResult r = replay({"--version"});
  EXPECT_EQ(r.exit_code, 0) << describe(r);
  EXPECT_TRUE(contains(r.out, "stillpoint-replay " STILLPOINT_VERSION)) << describe(r);
}

TEST_F(ReplayCli, ShippedDefaultConfigIsAccepted) {
  const RunResult r = replaySequence({"--config", STILLPOINT_SOURCE_DIR "/config/slam.yaml"});
  EXPECT_EQ(r.exit_code, 0) << describe(r);
}

// --- usage errors: exit 2 with the usage text --------------------------------

TEST_F(ReplayCli, UnknownOptionExitsTwoWithUsage) {
  const RunResult r = replaySequence({"--frobnicate"});
  EXPECT_EQ(r.exit_code, 2) << describe(r);
  EXPECT_TRUE(contains(r.err, "unknown option --frobnicate"));
  EXPECT_TRUE(contains(r.err, "usage: stillpoint-replay"));
  EXPECT_TRUE(r.out.empty()) << describe(r);
}

TEST_F(ReplayCli, MissingRequiredOptionsExitTwo) {
  RunResult r = replay({seq_.directory, "--output", output_});
  EXPECT_EQ(r.exit_code, 2) << describe(r);
  EXPECT_TRUE(contains(r.err, "missing --camera"));
  r = replay({seq_.directory, "--camera", "fr3"});
  EXPECT_EQ(r.exit_code, 2) << describe(r);
  EXPECT_TRUE(contains(r.err, "missing --output"));
  r = replay({"--camera", "fr3", "--output", output_});
  EXPECT_EQ(r.exit_code, 2) << describe(r);
  EXPECT_TRUE(contains(r.err, "missing DATASET_DIR"));
  r = replaySequence({"--max-frames", "zero"});
  EXPECT_EQ(r.exit_code, 2) << describe(r);
  EXPECT_TRUE(contains(r.err, "--max-frames"));
}

// --- bad input: exit 1 naming what is wrong ----------------------------------

TEST_F(ReplayCli, KeyframeSpacingNeedsSequentialAndAPositiveCount) {
  RunResult r = replay({seq_.directory, "--camera", camera_, "--output", output_, "--keyframe-spacing", "2"});
  EXPECT_EQ(r.exit_code, 2) << describe(r);
  EXPECT_TRUE(contains(r.err, "--keyframe-spacing needs --sequential")) << describe(r);
  for (const char* bad : {"0", "-1", "two", "1001"}) {
    r = replaySequence({"--keyframe-spacing", bad});
    EXPECT_EQ(r.exit_code, 2) << bad << ": " << describe(r);
    EXPECT_TRUE(contains(r.err, "--keyframe-spacing needs an integer in 1..1000")) << describe(r);
  }
}

TEST_F(ReplayCli, MissingDatasetDirectoryIsNamed) {
  const std::string missing = (scratch_ / "no_such_sequence").string();
  const RunResult r = replay({missing, "--camera", "fr3", "--output", output_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, missing));
  EXPECT_TRUE(contains(r.err, "does not exist"));
}

TEST_F(ReplayCli, UnknownCameraPresetOrMissingFileIsNamed) {
  const std::string missing = (scratch_ / "no_camera.yaml").string();
  const RunResult r = replay({seq_.directory, "--camera", missing, "--output", output_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, missing));
  EXPECT_TRUE(contains(r.err, "cannot be opened"));
}

TEST_F(ReplayCli, CameraFileMissingFieldIsNamed) {
  const std::string camera = writeScratch("nofy.yaml", "width: 320\nheight: 240\nfx: 256\ncx: 160\ncy: 120\n");
  const RunResult r = replay({seq_.directory, "--camera", camera, "--output", output_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, camera));
  EXPECT_TRUE(contains(r.err, "missing field 'fy'"));
}

TEST_F(ReplayCli, CameraFileSyntaxErrorNamesLine) {
  const std::string camera =
      writeScratch("syntax.yaml", "width: 320\nheight: 240\nfx: [256, \nfy: 256\ncx: 160\ncy: 120\n");
  const RunResult r = replay({seq_.directory, "--camera", camera, "--output", output_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, camera));
  EXPECT_TRUE(std::regex_search(r.err, std::regex("line [0-9]+"))) << describe(r);
}

TEST_F(ReplayCli, CameraFileWrongTypeNamesFieldAndLine) {
  const std::string camera =
      writeScratch("type.yaml", "width: 320\nheight: 240\nfx: wide\nfy: 256\ncx: 160\ncy: 120\n");
  const RunResult r = replay({seq_.directory, "--camera", camera, "--output", output_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, "line 3: field 'fx' has the wrong type"));
}

TEST_F(ReplayCli, CameraFileInvalidValueNamesField) {
  const std::string camera =
      writeScratch("range.yaml", "width: 320\nheight: 240\nfx: -5\nfy: 256\ncx: 160\ncy: 120\n");
  const RunResult r = replay({seq_.directory, "--camera", camera, "--output", output_});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, "field 'fx'"));
}

TEST_F(ReplayCli, ConfigUnknownKeyIsNamedWithLine) {
  const std::string config = writeScratch("unknown.yaml", "tracking:\n  min_inliers_local_map: 30\n  min_inlier: 3\n");
  const RunResult r = replaySequence({"--config", config});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, config));
  EXPECT_TRUE(contains(r.err, "line 3: unknown field 'tracking.min_inlier'"));
}

TEST_F(ReplayCli, ConfigWrongTypeIsNamedWithLine) {
  const std::string config = writeScratch("type.yaml", "orb:\n  num_features: many\n");
  const RunResult r = replaySequence({"--config", config});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, "line 2: field 'orb.num_features' has the wrong type"));
}

TEST_F(ReplayCli, ConfigOutOfRangeValueIsNamed) {
  const std::string config = writeScratch("range.yaml", "mapping:\n  ba_max_keyframes: 0\n");
  const RunResult r = replaySequence({"--config", config});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, "mapping.ba_max_keyframes"));
}

// A full disk for the features file is an error (it used to exit 0), and an
// unwritable trajectory path is one before the run, not after it.
TEST_F(ReplayCli, OutputsThatCannotBeWrittenAreErrors) {
  const RunResult full = replaySequence({"--features-out", "/dev/full"});
  EXPECT_EQ(full.exit_code, 1) << describe(full);
  EXPECT_TRUE(contains(full.err, "/dev/full"));
  const std::string nowhere = (scratch_ / "no_such_dir" / "traj.txt").string();
  const RunResult r = replay({seq_.directory, "--camera", camera_, "--output", nowhere, "--sequential"});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, nowhere));
  EXPECT_FALSE(contains(r.out, "frames=")) << "the sequence ran first";
}

TEST_F(ReplayCli, ConfigSyntaxErrorNamesLine) {
  const std::string config = writeScratch("syntax.yaml", "orb:\n  num_features: 500\n  num_levels: [8\n");
  const RunResult r = replaySequence({"--config", config});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, config));
  EXPECT_TRUE(std::regex_search(r.err, std::regex("line [0-9]+"))) << describe(r);
}

TEST_F(ReplayCli, TimestampsOutOfOrderNameFileAndLine) {
  // rgb.txt: three comment lines, then frame k on line k + 4. Swap frames 4 and 5.
  const fs::path list = fs::path(seq_.directory) / "rgb.txt";
  std::string text = readFile(list);
  const std::string line4 = seq_.colour_stamps[4].toSecondsString() + " " + rgbFile(4) + "\n";
  const std::string line5 = seq_.colour_stamps[5].toSecondsString() + " " + rgbFile(5) + "\n";
  const auto at = text.find(line4 + line5);
  ASSERT_NE(at, std::string::npos) << text;
  text.replace(at, line4.size() + line5.size(), line5 + line4);
  writeFile(list, text);

  const RunResult r = replaySequence();
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, list.string() + ":9:")) << describe(r);
  EXPECT_TRUE(contains(r.err, "timestamps must increase strictly"));
}

// --- bad frames are skipped and counted, the run goes on ----------------------

TEST_F(ReplayCli, CorruptPngIsSkippedAndEmptyDepthIsNoDepth) {
  const fs::path dir(seq_.directory);
  writeFile(dir / rgbFile(3), "\x89PNG\r\n\x1a\n this is not really a PNG");
  const cv::Mat zeros(seq_.camera.height, seq_.camera.width, CV_16UC1, cv::Scalar(0));
  ASSERT_TRUE(cv::imwrite((dir / depthFile(6)).string(), zeros));
  const fs::path frame_log = fs::path(seq_.directory) / "frames.txt";

  const RunResult r = replaySequence({"--frame-log", frame_log.string()});
  ASSERT_EQ(r.exit_code, 0) << describe(r);
  EXPECT_TRUE(contains(r.out, "1 skipped (bad input)")) << describe(r);
  EXPECT_TRUE(contains(r.out, "1 without depth")) << describe(r);
  EXPECT_TRUE(contains(test::lastLine(r.out), "frames=9 ")) << describe(r);
  EXPECT_TRUE(contains(r.err, "skipping frame 3")) << describe(r);
  EXPECT_TRUE(contains(r.err, rgbFile(3))) << describe(r);
  // The all-zero depth frame is tracked as a frame without depth, not skipped.
  EXPECT_FALSE(contains(r.err, "skipping frame 6")) << describe(r);
  const std::string log = test::readFile(frame_log);
  EXPECT_TRUE(contains(log, "\n3 ") && contains(log, " skipped ")) << log;
  EXPECT_TRUE(contains(log, "\n6 ") && contains(log, " no_depth ")) << log;
  // Every line has the header's columns; a pose has a covariance, a frame
  // without one (skipped, no depth) all zeros.
  std::istringstream lines(log);
  std::string line;
  std::size_t columns = 0;
  int posed = 0;
  while (std::getline(lines, line)) {
    std::istringstream in(line);
    std::vector<std::string> fields{std::istream_iterator<std::string>(in), std::istream_iterator<std::string>()};
    if (line.starts_with("#")) {
      columns = fields.size() - 1;
      continue;
    }
    ASSERT_EQ(fields.size(), columns) << line;
    std::vector<double> covariance;
    std::istringstream numbers(fields.back());
    for (std::string n; std::getline(numbers, n, ',');) covariance.push_back(std::stod(n));
    ASSERT_EQ(covariance.size(), 21u) << line;
    const bool has_pose = fields[2] == "ok" || fields[2] == "relocalised" || fields[2] == "new_map";
    posed += has_pose;
    if (has_pose) {
      EXPECT_GT(std::stod(fields[fields.size() - 3]), 0) << line;  // position_sigma_m
      EXPECT_GT(covariance[0], 0) << line;                          // the x variance
    } else {
      EXPECT_TRUE(std::all_of(covariance.begin(), covariance.end(), [](double v) { return v == 0; })) << line;
    }
  }
  EXPECT_EQ(columns, 21u);
  EXPECT_GT(posed, 0);
}

TEST_F(ReplayCli, EveryFrameBadExitsOne) {
  const fs::path dir(seq_.directory);
  for (int k = 0; k < kFrames; ++k) writeFile(dir / rgbFile(k), "garbage");
  const RunResult r = replaySequence();
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.out, "10 skipped (bad input)")) << describe(r);
  EXPECT_TRUE(contains(test::lastLine(r.out), "frames=0 ")) << describe(r);
}

// --- known movers (--known-movers: the sequence's own mask.txt) ----------------

// mask.txt and one mask per colour frame, as stillpoint-synth writes them
// (16-bit, 0 = static), of the given size.
void writeMasks(const dataset::testing::SyntheticDataset& seq, cv::Size size) {
  const fs::path dir(seq.directory);
  fs::create_directories(dir / "mask");
  std::string list = "# mover masks\n";
  for (const Timestamp& stamp : seq.colour_stamps) {
    const std::string file = "mask/" + stamp.toSecondsString() + ".png";
    cv::Mat mask(size, CV_16UC1, cv::Scalar(0));
    mask(cv::Rect(0, 0, size.width / 4, size.height / 4)).setTo(1);
    ASSERT_TRUE(cv::imwrite((dir / file).string(), mask));
    list += stamp.toSecondsString() + " " + file + "\n";
  }
  writeFile(dir / "mask.txt", list);
}

TEST_F(ReplayCli, KnownMoversAreReadForEveryFrame) {
  ASSERT_NO_FATAL_FAILURE(writeMasks(seq_, cv::Size(seq_.camera.width, seq_.camera.height)));
  const RunResult r = replaySequence({"--known-movers"});
  ASSERT_EQ(r.exit_code, 0) << describe(r);
  EXPECT_TRUE(contains(r.out, "0 skipped (bad input)")) << describe(r);
}

TEST_F(ReplayCli, KnownMoversWithoutMaskListIsNamed) {
  const RunResult r = replaySequence({"--known-movers"});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, "mask.txt")) << describe(r);
}

TEST_F(ReplayCli, KnownMoversMissingMaskStopsTheRun) {
  ASSERT_NO_FATAL_FAILURE(writeMasks(seq_, cv::Size(seq_.camera.width, seq_.camera.height)));
  fs::remove(fs::path(seq_.directory) / "mask" / (seq_.colour_stamps[4].toSecondsString() + ".png"));
  const RunResult r = replaySequence({"--known-movers"});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, "no readable mask for frame 4")) << describe(r);
}

// A mask whose PNG header promises more pixels than OpenCV decodes (decoding
// it would throw) is refused from its header, as frames are, and stops the
// run as an unreadable one does.
TEST_F(ReplayCli, KnownMoversMaskTooLargeToDecodeStopsTheRun) {
  ASSERT_NO_FATAL_FAILURE(writeMasks(seq_, cv::Size(seq_.camera.width, seq_.camera.height)));
  std::string ihdr("IHDR\0\0\x9c\x40\0\0\x9c\x40\x08\0\0\0\0", 17);  // 40000 x 40000, 8-bit grey
  std::uint32_t crc = 0xffffffffu;  // CRC-32 of the chunk's type and data, as PNG readers check it
  for (unsigned char c : ihdr) {
    crc ^= c;
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xedb88320u & (0u - (crc & 1u)));
  }
  crc = ~crc;
  std::string png("\x89PNG\r\n\x1a\n\0\0\0\x0d", 12);
  png += ihdr;
  for (int shift = 24; shift >= 0; shift -= 8) png += static_cast<char>((crc >> shift) & 0xff);
  writeFile(fs::path(seq_.directory) / "mask" / (seq_.colour_stamps[4].toSecondsString() + ".png"), png);
  const RunResult r = replaySequence({"--known-movers"});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.err, "no readable mask for frame 4")) << describe(r);
}

TEST_F(ReplayCli, KnownMoversOfTheWrongSizeAreBadInput) {
  ASSERT_NO_FATAL_FAILURE(writeMasks(seq_, cv::Size(seq_.camera.width / 2, seq_.camera.height / 2)));
  const RunResult r = replaySequence({"--known-movers"});
  EXPECT_EQ(r.exit_code, 1) << describe(r);
  EXPECT_TRUE(contains(r.out, "10 skipped (bad input)")) << describe(r);
  EXPECT_TRUE(contains(r.err, "movers mask size differs")) << describe(r);
}

}  // namespace
}  // namespace stillpoint
