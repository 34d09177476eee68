#include "stillpoint/dataset/tum_dataset.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stillpoint/dataset/testing.hpp"

namespace stillpoint::dataset {
namespace {

namespace fs = std::filesystem;

constexpr int kFrames = 6;
constexpr int kWidth = 40;
constexpr int kHeight = 30;

void writeFile(const fs::path& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << bytes;
}

void writePng(const fs::path& path, const cv::Mat& image) {
  ASSERT_TRUE(cv::imwrite(path.string(), image)) << path;
}

std::string readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

Timestamp seconds(const char* text) { return *Timestamp::parseSeconds(text); }

::testing::AssertionResult contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "\"" << text << "\" does not contain \"" << part << "\"";
}

// Each test gets a fresh synthetic sequence in its own temporary folder.
class TumDatasetTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() /
           ("stillpoint_dataset_test_" + std::to_string(::getpid()) + "_" + info->name());
    fs::remove_all(dir_);
    testing::SyntheticDatasetOptions options;
    options.n_frames = kFrames;
    options.width = kWidth;
    options.height = kHeight;
    auto written = testing::writeSyntheticTumDataset(dir_.string(), options);
    ASSERT_TRUE(written.ok()) << written.error();
    synthetic_ = std::move(written.value());
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  TumDataset openOrDie(const DatasetOptions& options = {}) {
    auto dataset = TumDataset::open(dir_.string(), options);
    EXPECT_TRUE(dataset.ok()) << dataset.error();
    return std::move(dataset.value());
  }
  // Path of colour/depth image k as written by the synthetic writer.
  fs::path rgbFile(int k) const {
    const Timestamp t = synthetic_.colour_stamps[static_cast<std::size_t>(k)];
    return dir_ / ("rgb/" + t.toSecondsString() + ".png");
  }
  fs::path depthFile(int k) const {
    const Timestamp t = synthetic_.depth_stamps[static_cast<std::size_t>(k)];
    return dir_ / ("depth/" + t.toSecondsString() + ".png");
  }
  // Loads frame i expecting failure; checks the message names `file` and `why`.
  void expectLoadFails(std::size_t i, const fs::path& file, const std::string& why,
                       SkipReason expected_reason, const DatasetOptions& options = {}) {
    const TumDataset dataset = openOrDie(options);
    SkipReason reason = SkipReason::kNoDepthMatch;
    auto frame = dataset.load(i, &reason);
    ASSERT_FALSE(frame.ok());
    EXPECT_TRUE(contains(frame.error(), file.string()));
    EXPECT_TRUE(contains(frame.error(), why));
    EXPECT_EQ(reason, expected_reason) << toString(reason) << ": " << frame.error();
  }
  // The last synthetic frame, untouched by the tests, still loads.
  void expectLastFrameLoads() {
    auto frame = openOrDie().load(kFrames - 1);
    EXPECT_TRUE(frame.ok()) << frame.error();
  }
  void expectOpenFails(const std::string& what1, const std::string& what2 = "") {
    auto dataset = TumDataset::open(dir_.string());
    ASSERT_FALSE(dataset.ok());
    EXPECT_TRUE(contains(dataset.error(), what1));
    EXPECT_TRUE(contains(dataset.error(), what2));
  }

  fs::path dir_;
  testing::SyntheticDataset synthetic_;
};

TEST_F(TumDatasetTest, LoadsSyntheticFramesWithTypesStampsAndMetres) {
  const TumDataset dataset = openOrDie({.expected_width = kWidth, .expected_height = kHeight});
  ASSERT_EQ(dataset.size(), static_cast<std::size_t>(kFrames));
  EXPECT_EQ(dataset.unassociatedColourFrames(), 0u);
  EXPECT_EQ(dataset.directory(), dir_.string());
  EXPECT_TRUE(dataset.hasGroundTruth());
  EXPECT_EQ(dataset.groundTruthPath(), (dir_ / "groundtruth.txt").string());
  for (int k = 0; k < kFrames; ++k) {
    auto frame = dataset.load(static_cast<std::size_t>(k));
    ASSERT_TRUE(frame.ok()) << frame.error();
    EXPECT_EQ(frame->index, static_cast<std::size_t>(k));
    EXPECT_EQ(frame->stamp, synthetic_.colour_stamps[static_cast<std::size_t>(k)]);
    EXPECT_EQ(frame->depth_stamp, synthetic_.depth_stamps[static_cast<std::size_t>(k)]);
    EXPECT_EQ(frame->rgb_path, rgbFile(k).string());
    EXPECT_EQ(frame->depth_path, depthFile(k).string());
    EXPECT_EQ(frame->bgr.type(), CV_8UC3);
    EXPECT_EQ(frame->gray.type(), CV_8UC1);
    EXPECT_EQ(frame->depth_m.type(), CV_32FC1);
    EXPECT_EQ(frame->bgr.size(), cv::Size(kWidth, kHeight));
    EXPECT_EQ(frame->gray.size(), cv::Size(kWidth, kHeight));
    EXPECT_EQ(frame->depth_m.size(), cv::Size(kWidth, kHeight));
    double lo = 0, hi = 0;
    cv::minMaxLoc(frame->depth_m, &lo, &hi);
    EXPECT_NEAR(lo, 1.5, 1e-6);  // the synthetic plane: 7500 / 5000
    EXPECT_NEAR(hi, 1.5, 1e-6);
  }
}

TEST_F(TumDatasetTest, DepthFactorAndZeroPixelsConvertToMetres) {
  cv::Mat raw(kHeight, kWidth, CV_16UC1, cv::Scalar(1000));
  raw.at<std::uint16_t>(0, 0) = 0;
  raw.at<std::uint16_t>(1, 2) = 65535;
  writePng(depthFile(0), raw);
  const TumDataset dataset = openOrDie({.depth_factor = 1000.0});
  auto frame = dataset.load(0);
  ASSERT_TRUE(frame.ok()) << frame.error();
  EXPECT_FLOAT_EQ(frame->depth_m.at<float>(0, 0), 0.0f);  // 0 stays "no measurement"
  EXPECT_FLOAT_EQ(frame->depth_m.at<float>(1, 2), 65.535f);
  EXPECT_FLOAT_EQ(frame->depth_m.at<float>(5, 5), 1.0f);
}

TEST_F(TumDatasetTest, AssociationPicksNearestDepthWithinTolerance) {
  const std::string rgb = "rgb/" + synthetic_.colour_stamps[0].toSecondsString() + ".png";
  const std::string depth = "depth/" + synthetic_.depth_stamps[0].toSecondsString() + ".png";
  writeFile(dir_ / "depth.txt", "1.000 " + depth + "\n1.010 " + depth + "\n1.030 " + depth +
                                    "\n2.000 " + depth + "\n");
  auto writeColourList = [&](const std::string& last_stamp) {
    writeFile(dir_ / "rgb.txt",
              "# colour\n"
              "1.008 " + rgb + "\n"  // nearest 1.010 (2 ms), not 1.000
              "1.050 " + rgb + "\n"  // 1.030 exactly 20 ms away: accepted
              "1.500 " + rgb + "\n"  // 470 ms from anything: rejected
              "2.019 " + rgb + "\n"  // 2.000, 19 ms
              "2.021 " + rgb + "\n"  // 2.000 again but 21 ms: rejected
              + last_stamp + " " + rgb + "\n");
  };
  writeColourList("0.500");  // out of order
  expectOpenFails((dir_ / "rgb.txt").string() + ":7:", "not after the previous");
  writeColourList("3.000");  // after all depth, 1 s away: rejected

  const TumDataset dataset = openOrDie();
  ASSERT_EQ(dataset.size(), 3u);
  EXPECT_EQ(dataset.unassociatedColourFrames(), 3u);
  const std::vector<std::pair<const char*, const char*>> expected = {
      {"1.008", "1.010"}, {"1.050", "1.030"}, {"2.019", "2.000"}};
  for (std::size_t i = 0; i < expected.size(); ++i) {
    auto frame = dataset.load(i);
    ASSERT_TRUE(frame.ok()) << frame.error();
    EXPECT_EQ(frame->stamp, seconds(expected[i].first));
    EXPECT_EQ(frame->depth_stamp, seconds(expected[i].second));
  }

  // A tighter tolerance drops the 19 ms and 20 ms pairs too.
  const TumDataset tight = openOrDie({.max_association_dt = 0.005});
  EXPECT_EQ(tight.size(), 1u);
  EXPECT_EQ(tight.unassociatedColourFrames(), 5u);
}

TEST_F(TumDatasetTest, NoAssociatedPairIsAnError) {
  writeFile(dir_ / "depth.txt", "5.0 depth/a.png\n");
  writeFile(dir_ / "rgb.txt", "1.0 rgb/a.png\n2.0 rgb/b.png\n");
  expectOpenFails("none of the 2 colour frames", "0.02");
}

TEST_F(TumDatasetTest, MissingImagesNameThePath) {
  fs::remove(rgbFile(1));
  expectLoadFails(1, rgbFile(1), "does not exist", SkipReason::kUnreadableColour);
  fs::remove(depthFile(2));
  expectLoadFails(2, depthFile(2), "does not exist", SkipReason::kUnreadableDepth);
  expectLastFrameLoads();
}

TEST_F(TumDatasetTest, CorruptTruncatedAndEmptyPngsAreRejected) {
  writeFile(rgbFile(0), "this is not a png at all");
  expectLoadFails(0, rgbFile(0), "could not be decoded", SkipReason::kUnreadableColour);

  const std::string png = readFile(depthFile(1));
  ASSERT_GT(png.size(), 60u);
  writeFile(depthFile(1), png.substr(0, png.size() / 2));
  expectLoadFails(1, depthFile(1), "could not be decoded", SkipReason::kUnreadableDepth);

  writeFile(rgbFile(2), "");
  expectLoadFails(2, rgbFile(2), "could not be decoded", SkipReason::kUnreadableColour);

  // A valid PNG signature and header, then nothing.
  const std::string colour_png = readFile(rgbFile(3));
  writeFile(rgbFile(3), colour_png.substr(0, 33));
  expectLoadFails(3, rgbFile(3), "could not be decoded", SkipReason::kUnreadableColour);
  expectLastFrameLoads();

  fs::create_directory(dir_ / "rgb" / "dir.png");
  writeFile(dir_ / "rgb.txt", "1000.0 rgb/dir.png\n");
  writeFile(dir_ / "depth.txt", "1000.0 " + fs::relative(depthFile(0), dir_).string() + "\n");
  expectLoadFails(0, dir_ / "rgb" / "dir.png", "not a regular file", SkipReason::kUnreadableColour);
}

TEST_F(TumDatasetTest, WrongSizeIsRejected) {
  expectLoadFails(0, rgbFile(0), "expected 640x480", SkipReason::kWrongSize,
                  {.expected_width = 640, .expected_height = 480});
  expectLoadFails(0, rgbFile(0), "expected anyx31", SkipReason::kWrongSize,
                  {.expected_height = 31});

  writePng(depthFile(2), cv::Mat(kHeight, kWidth + 1, CV_16UC1, cv::Scalar(5000)));
  expectLoadFails(2, depthFile(2), "is 41x30 but colour image", SkipReason::kWrongSize);
  expectLastFrameLoads();
}

// A PNG whose header promises 20000x20000 pixels (such a file can be 1 MB
// and decode to 1.2 GB) is refused from its header, before decoding.
TEST_F(TumDatasetTest, OversizedPngsAreRefusedFromTheirHeader) {
  std::string bomb("\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR\0\0\x4e\x20\0\0\x4e\x20\x08\x02\0\0\0", 29);
  bomb += std::string(64, '\0');  // no image data: decoding it would fail with another message
  writeFile(rgbFile(0), bomb);
  expectLoadFails(0, rgbFile(0), "is 20000x20000: larger than any camera's", SkipReason::kWrongSize);
  // Within the limit but not the camera's size: refused from the header too.
  std::string wrong = bomb;
  wrong.replace(16, 8, std::string("\0\0\x02\xbc\0\0\x01\xf4", 8));  // 700x500
  writeFile(depthFile(1), wrong);
  expectLoadFails(1, depthFile(1), "is 700x500; expected 40x30", SkipReason::kWrongSize,
                  {.expected_width = kWidth, .expected_height = kHeight});
  expectLastFrameLoads();
}

// The same for a JPEG colour image: its frame header's size is read before
// decoding, past the segments before it; a real JPEG of the camera's size
// loads.
TEST_F(TumDatasetTest, OversizedJpegsAreRefusedFromTheirHeader) {
  std::string bomb("\xff\xd8\xff\xe0\0\x10JFIF\0\x01\x01\0\0\x01\0\x01\0\0", 20);  // SOI, APP0
  bomb += std::string("\xff\xff\xc0\0\x11\x08\x4e\x20\x4e\x20\x03", 11);         // fill byte, SOF0
  bomb += std::string(64, '\0');
  writeFile(rgbFile(0), bomb);
  expectLoadFails(0, rgbFile(0), "is 20000x20000: larger than any camera's", SkipReason::kWrongSize);

  std::vector<unsigned char> jpeg;
  ASSERT_TRUE(cv::imencode(".jpg", cv::Mat(kHeight + 2, kWidth, CV_8UC3, cv::Scalar(40, 90, 160)), jpeg));
  writeFile(rgbFile(1), std::string(jpeg.begin(), jpeg.end()));
  expectLoadFails(1, rgbFile(1), "is 40x32; expected 40x30", SkipReason::kWrongSize,
                  {.expected_width = kWidth, .expected_height = kHeight});
  ASSERT_TRUE(cv::imencode(".jpg", cv::Mat(kHeight, kWidth, CV_8UC3, cv::Scalar(40, 90, 160)), jpeg));
  writeFile(rgbFile(1), std::string(jpeg.begin(), jpeg.end()));
  const auto frame = openOrDie({.expected_width = kWidth, .expected_height = kHeight}).load(1);
  ASSERT_TRUE(frame.ok()) << frame.error();
  EXPECT_EQ(frame->bgr.size(), cv::Size(kWidth, kHeight));
}

TEST_F(TumDatasetTest, EightBitDepthIsRejected) {
  writePng(depthFile(0), cv::Mat(kHeight, kWidth, CV_8UC1, cv::Scalar(100)));
  expectLoadFails(0, depthFile(0), "expected 16-bit single channel", SkipReason::kUnreadableDepth);
  writePng(depthFile(1), cv::Mat(kHeight, kWidth, CV_16UC3, cv::Scalar::all(100)));
  expectLoadFails(1, depthFile(1), "16UC3", SkipReason::kUnreadableDepth);
  expectLastFrameLoads();
}

TEST_F(TumDatasetTest, AllZeroDepthIsAFrame) {
  // A covered camera's frame loads; tracking reports it as without depth.
  writePng(depthFile(3), cv::Mat::zeros(kHeight, kWidth, CV_16UC1));
  auto frame = openOrDie().load(3);
  ASSERT_TRUE(frame) << frame.error();
  EXPECT_EQ(cv::countNonZero(frame->depth_m), 0);
  expectLastFrameLoads();
}

TEST_F(TumDatasetTest, ColourPixelFormats) {
  // 16-bit colour is refused rather than silently scaled.
  writePng(rgbFile(0), cv::Mat(kHeight, kWidth, CV_16UC3, cv::Scalar::all(9000)));
  expectLoadFails(0, rgbFile(0), "expected 8-bit colour", SkipReason::kUnreadableColour);

  // Grayscale and BGRA PNGs become BGR.
  writePng(rgbFile(1), cv::Mat(kHeight, kWidth, CV_8UC1, cv::Scalar(77)));
  writePng(rgbFile(2), cv::Mat(kHeight, kWidth, CV_8UC4, cv::Scalar(10, 20, 30, 40)));
  const TumDataset dataset = openOrDie();
  auto gray = dataset.load(1);
  ASSERT_TRUE(gray.ok()) << gray.error();
  EXPECT_EQ(gray->bgr.type(), CV_8UC3);
  EXPECT_EQ(gray->bgr.at<cv::Vec3b>(3, 4), cv::Vec3b(77, 77, 77));
  EXPECT_EQ(gray->gray.at<std::uint8_t>(3, 4), 77);
  auto bgra = dataset.load(2);
  ASSERT_TRUE(bgra.ok()) << bgra.error();
  EXPECT_EQ(bgra->bgr.type(), CV_8UC3);
  EXPECT_EQ(bgra->bgr.at<cv::Vec3b>(3, 4), cv::Vec3b(10, 20, 30));
}

TEST_F(TumDatasetTest, OutOfOrderAndDuplicateTimestampsNameFileAndLine) {
  writeFile(dir_ / "depth.txt", "# depth\n\n1.0 depth/a.png\n1.1 depth/b.png\n1.05 depth/c.png\n");
  expectOpenFails("depth.txt:5:", "timestamp 1.05 is not after the previous one (1.100000)");
  writeFile(dir_ / "depth.txt", "1.0 depth/a.png\n1.000000000 depth/b.png\n");
  expectOpenFails("depth.txt:2:", "not after the previous");
}

TEST_F(TumDatasetTest, MalformedLinesNameFileAndLine) {
  const std::string good = readFile(dir_ / "rgb.txt");  // 3 comment lines, then frames
  writeFile(dir_ / "rgb.txt", good + "1999.0 rgb/x.png extra\n");
  expectOpenFails("rgb.txt:" + std::to_string(4 + kFrames) + ":", "got 3 field(s)");
  writeFile(dir_ / "rgb.txt", good + "1999.0\n");
  expectOpenFails("rgb.txt:" + std::to_string(4 + kFrames) + ":", "got 1 field(s)");
  writeFile(dir_ / "rgb.txt", "# c\n12.3.4 rgb/x.png\n");
  expectOpenFails("rgb.txt:2:", "bad timestamp '12.3.4'");
  writeFile(dir_ / "rgb.txt", "1e9 rgb/x.png\n");
  expectOpenFails("rgb.txt:1:", "bad timestamp '1e9'");
  writeFile(dir_ / "rgb.txt", std::string("1.0\0 rgb/x.png\n", 15));
  expectOpenFails("rgb.txt:1:", "bad timestamp");
  writeFile(dir_ / "rgb.txt", "9999999999.0 rgb/x.png\n");
  expectOpenFails("rgb.txt:1:", "timestamp '9999999999.0' is out of range");

  // Tabs, CRLF line ends, blank lines and comments are fine.
  writeFile(dir_ / "rgb.txt",
            "# c\r\n\r\n  \t\n1000.000000\t" + fs::relative(rgbFile(0), dir_).string() + "\r\n");
  const TumDataset dataset = openOrDie();
  EXPECT_EQ(dataset.size(), 1u);
  EXPECT_TRUE(dataset.load(0).ok());
}

TEST_F(TumDatasetTest, MissingOrEmptyListsAndFolder) {
  const std::string rgb_list = readFile(dir_ / "rgb.txt");
  fs::remove(dir_ / "rgb.txt");
  expectOpenFails((dir_ / "rgb.txt").string(), "does not exist");
  writeFile(dir_ / "rgb.txt", rgb_list);
  fs::remove(dir_ / "depth.txt");
  expectOpenFails((dir_ / "depth.txt").string(), "does not exist");
  writeFile(dir_ / "depth.txt", "# only comments\n\n");
  expectOpenFails((dir_ / "depth.txt").string(), "has no entries");

  auto missing = TumDataset::open((dir_ / "nope").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_TRUE(contains(missing.error(), (dir_ / "nope").string()));
  EXPECT_TRUE(contains(missing.error(), "does not exist"));
  auto file = TumDataset::open((dir_ / "rgb.txt").string());
  ASSERT_FALSE(file.ok());
  EXPECT_TRUE(contains(file.error(), "is not a directory"));
}

TEST_F(TumDatasetTest, InvalidOptionsAndIndexAreErrors) {
  auto bad = TumDataset::open(dir_.string(), {.depth_factor = 0});
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(contains(bad.error(), "depth_factor"));
  bad = TumDataset::open(dir_.string(), {.max_association_dt = -1});
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(contains(bad.error(), "max_association_dt"));
  bad = TumDataset::open(dir_.string(), {.expected_width = -3});
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(contains(bad.error(), "expected_width"));

  const TumDataset dataset = openOrDie();
  SkipReason reason = SkipReason::kNoDepthMatch;
  auto frame = dataset.load(kFrames, &reason);
  ASSERT_FALSE(frame.ok());
  EXPECT_TRUE(contains(frame.error(), "out of range"));
  EXPECT_EQ(reason, SkipReason::kIndexOutOfRange);
}

TEST_F(TumDatasetTest, NoGroundTruthFileIsReported) {
  fs::remove(dir_ / "groundtruth.txt");
  const TumDataset dataset = openOrDie();
  EXPECT_FALSE(dataset.hasGroundTruth());
  EXPECT_EQ(dataset.groundTruthPath(), "");
}

// The writer's images must agree with its ground truth, or tracking tests built on it lie.
TEST_F(TumDatasetTest, SyntheticImagesMatchGroundTruthMotion) {
  testing::SyntheticDatasetOptions options;
  options.n_frames = 8;
  options.width = 96;
  options.height = 64;
  options.lateral_velocity_m_s = Vec2(0.4, -0.2);
  const fs::path dir = dir_ / "moving";
  auto written = testing::writeSyntheticTumDataset(dir.string(), options);
  ASSERT_TRUE(written.ok()) << written.error();
  ASSERT_EQ(written->T_w_c.size(), 8u);
  EXPECT_TRUE(written->T_w_c[0].isApprox(SE3::Identity()));

  auto dataset = TumDataset::open(dir.string());
  ASSERT_TRUE(dataset.ok()) << dataset.error();
  ASSERT_EQ(dataset->size(), 8u);
  auto first = dataset->load(0);
  auto last = dataset->load(7);
  ASSERT_TRUE(first.ok() && last.ok());
  const CameraModel& cam = written->camera;
  const Vec3 t = written->T_w_c[7].translation();
  const double du = cam.fx * t.x() / 1.5;
  const double dv = cam.fy * t.y() / 1.5;
  ASSERT_GT(std::abs(du), 3.0);  // a visible motion

  // last(u, v) = first(u + du, v + dv) where both are inside the image.
  cv::Mat first_f, last_f, predicted;
  first->gray.convertTo(first_f, CV_32F);
  last->gray.convertTo(last_f, CV_32F);
  cv::warpAffine(first_f, predicted, cv::Matx23d(1, 0, du, 0, 1, dv), first_f.size(),
                 cv::INTER_LINEAR | cv::WARP_INVERSE_MAP);
  const cv::Rect inner(8, 8, options.width - 16, options.height - 16);
  const double aligned = cv::mean(cv::abs(predicted(inner) - last_f(inner)))[0];
  const double unaligned = cv::mean(cv::abs(first_f(inner) - last_f(inner)))[0];
  EXPECT_LT(aligned, 0.25 * unaligned) << "aligned " << aligned << " unaligned " << unaligned;

  const std::string gt = readFile(dir / "groundtruth.txt");
  const std::string first_pose = " 0.000000 0.000000 0.000000 0 0 0 1";
  EXPECT_TRUE(contains(gt, written->colour_stamps[0].toSecondsString() + first_pose));

  options.jitter_s = 0.01;  // 4 * 10 ms >= 33 ms: stamps could reorder
  auto rejected = testing::writeSyntheticTumDataset(dir.string(), options);
  ASSERT_FALSE(rejected.ok());
  EXPECT_TRUE(contains(rejected.error(), "jitter_s"));
}

TEST(TumDatasetRealData, OpensTumFr3Teddy200) {
  const fs::path dir = fs::path(STILLPOINT_DATA_DIR) / "tum_fr3_teddy_200";
  if (!fs::is_directory(dir)) {
    GTEST_SKIP() << "real sequence not found at " << dir << " (set STILLPOINT_DATA_DIR)";
  }
  auto dataset = TumDataset::open(dir.string(), {.expected_width = 640, .expected_height = 480});
  ASSERT_TRUE(dataset.ok()) << dataset.error();
  // 200 colour and 200 depth frames, but the sensor dropped some depth frames:
  // 7 colour frames have no depth within 20 ms (checked independently).
  EXPECT_EQ(dataset->size(), 193u);
  EXPECT_EQ(dataset->unassociatedColourFrames(), 7u);
  EXPECT_TRUE(dataset->hasGroundTruth());
  auto frame = dataset->load(0);
  ASSERT_TRUE(frame.ok()) << frame.error();
  EXPECT_EQ(frame->bgr.cols, 640);
  EXPECT_EQ(frame->bgr.rows, 480);
  EXPECT_EQ(frame->stamp, seconds("1341841873.273798"));
  EXPECT_EQ(frame->depth_stamp, seconds("1341841873.273820"));
  double lo = 0, hi = 0;
  cv::minMaxLoc(frame->depth_m, &lo, &hi);
  EXPECT_EQ(lo, 0.0);  // holes exist
  EXPECT_GT(hi, 0.5);
  EXPECT_LT(hi, 10.0);
}

}  // namespace
}  // namespace stillpoint::dataset
