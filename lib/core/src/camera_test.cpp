#include "stillpoint/core/camera.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

namespace stillpoint {
namespace {

TEST(Camera, ProjectUnprojectRoundTrip) {
  const CameraModel cam = *cameraPreset("fr3");
  for (double z : {0.3, 1.0, 4.5}) {
    for (const Vec2& uv : {Vec2(10.5, 20.25), Vec2(320, 240), Vec2(630, 470)}) {
      const Vec3 p = cam.unproject(uv, z);
      EXPECT_NEAR(p.z(), z, 1e-12);
      EXPECT_LT((cam.project(p) - uv).norm(), 1e-9);
    }
  }
}

TEST(Camera, DistortionRoundTripOverTheImage) {
  for (const char* preset : {"fr1", "fr2"}) {
    const CameraModel cam = *cameraPreset(preset);
    ASSERT_TRUE(cam.hasDistortion());
    double worst = 0;
    for (int v = 0; v < cam.height; v += 40) {
      for (int u = 0; u < cam.width; u += 40) {
        const Vec2 undist(u, v);
        const Vec2 dist = cam.distortPixel(undist);
        worst = std::max(worst, (cam.undistortPixel(dist) - undist).norm());
      }
    }
    EXPECT_LT(worst, 1e-4) << preset;
  }
}

TEST(Camera, DistortionMovesPixelsAwayFromCentre) {
  const CameraModel cam = *cameraPreset("fr1");
  // fr1 has positive k1: a corner pixel moves noticeably.
  const Vec2 corner(5, 5);
  EXPECT_GT((cam.distortPixel(corner) - corner).norm(), 1.0);
  const Vec2 centre(cam.cx, cam.cy);
  EXPECT_LT((cam.distortPixel(centre) - centre).norm(), 1e-9);
}

// A radial distortion that turns back before the image's corners has no
// single inverse there (undistortPixel would give any of two answers): such a
// camera is refused; the TUM lenses are not.
TEST(Camera, DistortionThatFoldsBackBeforeTheCornersIsRefused) {
  for (const char* preset : {"fr1", "fr2", "fr3"}) EXPECT_TRUE(cameraPreset(preset)->validate().ok()) << preset;
  CameraModel cam = *cameraPreset("fr3");
  cam.dist = {-1, 0, 0, 0, 0};  // r (1 - r^2) turns at r 0.58, radius 0.38; the corners lie at 0.76
  const Status s = cam.validate();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().find("one to one"), std::string::npos) << s.error();
  cam.dist = {-0.1, 0, 0, 0, 0};  // turns at r 1.83: the whole image is one to one
  EXPECT_TRUE(cam.validate().ok());
  double worst = 0;
  for (int v = 0; v <= cam.height; v += 40)
    for (int u = 0; u <= cam.width; u += 40)
      worst = std::max(worst, (cam.distortPixel(cam.undistortPixel(Vec2(u, v))) - Vec2(u, v)).norm());
  EXPECT_LT(worst, 1e-4);
}

class CameraYaml : public ::testing::Test {
 protected:
  std::filesystem::path dir_ = std::filesystem::temp_directory_path() /
                               ("sp_cam_" + std::to_string(::getpid()));
  void SetUp() override { std::filesystem::create_directories(dir_); }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string write(const std::string& text) {
    const auto p = dir_ / "cam.yaml";
    std::ofstream(p) << text;
    return p.string();
  }
};

TEST_F(CameraYaml, LoadsAllFields) {
  const auto r = loadCameraYaml(write(
      "width: 640\nheight: 480\nfx: 500\nfy: 501\ncx: 319.5\ncy: 239.5\n"
      "distortion: [0.1, -0.2, 0.001, 0.002, 0.3]\ndepth_factor: 1000\n"));
  ASSERT_TRUE(r.ok()) << r.error();
  EXPECT_DOUBLE_EQ(r->fy, 501);
  EXPECT_DOUBLE_EQ(r->dist[4], 0.3);
  EXPECT_DOUBLE_EQ(r->depth_factor, 1000);
}

TEST_F(CameraYaml, NamesMissingField) {
  const auto r = loadCameraYaml(write("width: 640\nheight: 480\nfx: 500\ncx: 1\ncy: 1\n"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("'fy'"), std::string::npos) << r.error();
}

// "depth_factr: 1000" used to keep the default 5000 silently.
TEST_F(CameraYaml, UnknownDuplicateAndOddKeysAreErrors) {
  const std::string base = "width: 640\nheight: 480\nfx: 500\nfy: 500\ncx: 320\ncy: 240\n";
  auto r = loadCameraYaml(write(base + "depth_factr: 1000\n"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("unknown field 'depth_factr'"), std::string::npos) << r.error();
  EXPECT_NE(r.error().find("line 7"), std::string::npos) << r.error();
  r = loadCameraYaml(write(base + "fx: 600\n"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("duplicate field 'fx'"), std::string::npos) << r.error();
  r = loadCameraYaml(write(base + "? [a, b]\n: 1\n"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("plain names"), std::string::npos) << r.error();
  EXPECT_TRUE(loadCameraYaml(write(base + "depth_factor: 1000\n")).ok());
}

// A directory opens as a file on Linux and throws while it is read; found
// by the parser fuzzer (test/fuzz_parsers.cpp).
TEST_F(CameraYaml, ADirectoryIsAnErrorNotAnException) {
  const auto r = loadCameraYaml(std::filesystem::temp_directory_path().string());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find(std::filesystem::temp_directory_path().string()), std::string::npos) << r.error();
}

TEST_F(CameraYaml, NamesBadValueAndLine) {
  const auto r = loadCameraYaml(write("width: 640\nheight: 480\nfx: banana\nfy: 1\ncx: 1\ncy: 1\n"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("'fx'"), std::string::npos) << r.error();
  EXPECT_NE(r.error().find("line 3"), std::string::npos) << r.error();
}

TEST_F(CameraYaml, RejectsNegativeFocalLength) {
  const auto r = loadCameraYaml(write("width: 640\nheight: 480\nfx: -5\nfy: 1\ncx: 1\ncy: 1\n"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("fx"), std::string::npos);
}

TEST_F(CameraYaml, ReportsSyntaxErrorsAndMissingFiles) {
  EXPECT_FALSE(loadCameraYaml(write("width: [640\n")).ok());
  const auto r = loadCamera((dir_ / "nope.yaml").string());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("nope.yaml"), std::string::npos);
  EXPECT_FALSE(loadCamera("fr9").ok());
}

}  // namespace
}  // namespace stillpoint
