// Geometric exactness of the rasteriser: depth, silhouettes and texture
// placement agree with the pinhole model to within a pixel / 0.1 mm.
#include <gtest/gtest.h>

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "stillpoint/synth/raster.hpp"

namespace stillpoint::synth {
namespace {

CameraModel smallCamera() {
  CameraModel c;
  c.width = 160;
  c.height = 120;
  c.fx = 150.0;
  c.fy = 152.0;
  c.cx = 79.3;
  c.cy = 60.7;
  return c;
}

Texture halves() {  // left half red, right half blue (BGR)
  cv::Mat img(64, 64, CV_8UC3, cv::Scalar(0, 0, 255));
  img(cv::Rect(32, 0, 32, 64)).setTo(cv::Scalar(255, 0, 0));
  return Texture(img, false);
}

// Plane through p0 with normal n, seen by a camera at the origin (T_w_c = I).
double rayPlaneDepth(const CameraModel& cam, int x, int y, const Vec3& p0, const Vec3& n) {
  const Vec3 ray = cam.unproject(Vec2(x, y), 1.0);  // z = 1
  return n.dot(p0) / n.dot(ray);
}

TEST(Raster, TiltedQuadDepthMatchesPlane) {
  const CameraModel cam = smallCamera();
  const Texture tex = halves();
  // A 1.2 x 0.9 m quad 2 m ahead, turned 35 deg about y and 20 deg about x.
  SE3 T = SE3::Identity();
  T.linear() = (Eigen::AngleAxisd(0.6, Vec3::UnitY()) * Eigen::AngleAxisd(0.35, Vec3::UnitX())).toRotationMatrix();
  T.translation() = Vec3(0.1, -0.05, 2.0);
  auto P = [&](double x, double y) { return Vec3(T * Vec3(x, y, 0)); };
  Mesh mesh;
  addQuad(&mesh, {P(-0.6, -0.45), P(0.6, -0.45), P(0.6, 0.45), P(-0.6, 0.45)}, &tex, 3);
  RenderTarget target = RenderTarget::blank(cam.width, cam.height);
  const RasterStats stats = render(mesh, SE3::Identity(), cam, &target);
  EXPECT_EQ(stats.triangles_drawn, 2);
  const Vec3 n = T.linear().col(2);
  int covered = 0;
  double worst = 0;
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      if (target.id.at<std::uint16_t>(y, x) == 0) {
        EXPECT_TRUE(std::isinf(target.depth.at<float>(y, x)));
        continue;
      }
      ++covered;
      EXPECT_EQ(target.id.at<std::uint16_t>(y, x), 3);
      const double truth = rayPlaneDepth(cam, x, y, T.translation(), n);
      worst = std::max(worst, std::abs(target.depth.at<float>(y, x) - truth));
    }
  }
  EXPECT_GT(covered, 2000);
  EXPECT_LT(worst, 1e-4);
  // Each pixel is covered exactly when its ray hits the quad (1 px tolerance at the rim).
  int disagreements = 0;
  for (int y = 1; y + 1 < cam.height; ++y) {
    for (int x = 1; x + 1 < cam.width; ++x) {
      const double z = rayPlaneDepth(cam, x, y, T.translation(), n);
      const Vec3 local = T.inverse() * cam.unproject(Vec2(x, y), z);
      const bool inside = std::abs(local.x()) < 0.6 - 0.01 && std::abs(local.y()) < 0.45 - 0.01;
      const bool outside = std::abs(local.x()) > 0.6 + 0.01 || std::abs(local.y()) > 0.45 + 0.01;
      const bool drawn = target.id.at<std::uint16_t>(y, x) != 0;
      if ((inside && !drawn) || (outside && drawn)) ++disagreements;
    }
  }
  EXPECT_EQ(disagreements, 0);
}

TEST(Raster, TextureSeamProjectsWhereCameraSays) {
  const CameraModel cam = smallCamera();
  const Texture tex = halves();
  SE3 T = SE3::Identity();
  T.linear() = Eigen::AngleAxisd(-0.5, Vec3::UnitY()).toRotationMatrix();
  T.translation() = Vec3(-0.05, 0.02, 1.5);
  auto P = [&](double x, double y) { return Vec3(T * Vec3(x, y, 0)); };
  Mesh mesh;
  // Texture u runs along local x: the red/blue seam is the local line x = 0.
  addQuad(&mesh, {P(-0.5, -0.4), P(0.5, -0.4), P(0.5, 0.4), P(-0.5, 0.4)}, &tex, 1);
  RenderTarget target = RenderTarget::blank(cam.width, cam.height);
  render(mesh, SE3::Identity(), cam, &target);
  int checked = 0;
  for (double ly = -0.35; ly <= 0.35; ly += 0.05) {
    const Vec2 seam = cam.project(T * Vec3(0, ly, 0));
    const int y = static_cast<int>(std::lround(seam.y()));
    const int left = static_cast<int>(std::floor(seam.x())) - 1;
    const int right = static_cast<int>(std::ceil(seam.x())) + 1;
    ASSERT_GE(left, 0);
    ASSERT_LT(right, cam.width);
    const cv::Vec3b l = target.colour.at<cv::Vec3b>(y, left), r = target.colour.at<cv::Vec3b>(y, right);
    EXPECT_GT(l[2], 150) << "row " << y;  // red left of the projected seam
    EXPECT_LT(l[0], 100) << "row " << y;
    EXPECT_GT(r[0], 150) << "row " << y;  // blue right of it
    EXPECT_LT(r[2], 100) << "row " << y;
    ++checked;
  }
  EXPECT_GT(checked, 10);
}

TEST(Raster, BoxFrontFaceDepthAndSilhouette) {
  const CameraModel cam = smallCamera();
  const Texture tex = halves();
  SE3 T = SE3::Identity();
  T.translation() = Vec3(0.05, 0.0, 2.0);
  const Vec3 half(0.3, 0.2, 0.25);
  Mesh mesh;
  addBox(&mesh, T, half, &tex, 9);
  EXPECT_EQ(mesh.triangles.size(), 12u);
  RenderTarget target = RenderTarget::blank(cam.width, cam.height);
  render(mesh, SE3::Identity(), cam, &target);
  const double front = 2.0 - 0.25;
  // Front face corners project to the silhouette corners.
  const Vec2 tl = cam.project(Vec3(0.05 - 0.3, -0.2, front));
  const Vec2 br = cam.project(Vec3(0.05 + 0.3, 0.2, front));
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      const bool inside = x > tl.x() + 0.5 && x < br.x() - 0.5 && y > tl.y() + 0.5 && y < br.y() - 0.5;
      const bool outside = x < tl.x() - 0.5 || x > br.x() + 0.5 || y < tl.y() - 0.5 || y > br.y() + 0.5;
      const std::uint16_t id = target.id.at<std::uint16_t>(y, x);
      if (inside) {
        ASSERT_EQ(id, 9) << x << "," << y;
        EXPECT_NEAR(target.depth.at<float>(y, x), front, 1e-5);
      }
      if (outside) {
        ASSERT_EQ(id, 0) << x << "," << y;
      }
    }
  }
}

TEST(Raster, ZTestAgainstExistingDepth) {
  const CameraModel cam = smallCamera();
  const Texture tex = halves();
  RenderTarget target = RenderTarget::blank(cam.width, cam.height);
  target.depth(cv::Rect(0, 0, 80, 120)).setTo(1.0f);  // a real surface at 1 m on the left
  Mesh mesh;
  addQuad(&mesh, {Vec3(-2, -2, 1.5), Vec3(2, -2, 1.5), Vec3(2, 2, 1.5), Vec3(-2, 2, 1.5)}, &tex, 4);
  render(mesh, SE3::Identity(), cam, &target);
  EXPECT_EQ(cv::countNonZero(target.id(cv::Rect(0, 0, 80, 120))), 0);
  EXPECT_EQ(cv::countNonZero(target.id(cv::Rect(80, 0, 80, 120))), 80 * 120);
  EXPECT_FLOAT_EQ(target.depth.at<float>(60, 100), 1.5f);
}

TEST(Raster, ClipsGeometryBehindTheCamera) {
  const CameraModel cam = smallCamera();
  const Texture tex = halves();
  // A floor 1 m below the camera reaching from 5 m behind to 10 m ahead.
  Mesh mesh;
  addQuad(&mesh, {Vec3(-3, 1, 10), Vec3(3, 1, 10), Vec3(3, 1, -5), Vec3(-3, 1, -5)}, &tex, 2);
  RenderTarget target = RenderTarget::blank(cam.width, cam.height);
  render(mesh, SE3::Identity(), cam, &target, 0.05);
  const int covered = cv::countNonZero(target.id);
  EXPECT_GT(covered, cam.width * cam.height / 3);
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      if (!target.id.at<std::uint16_t>(y, x)) continue;
      // Below the horizon the floor depth is fy / (y - cy).
      ASSERT_GT(y, cam.cy);
      EXPECT_NEAR(target.depth.at<float>(y, x), cam.fy * 1.0 / (y - cam.cy), 1e-3 * cam.fy / (y - cam.cy));
    }
  }
}

TEST(Raster, CameraPoseMovesTheImage) {
  // The same point seen from a translated and rotated camera lands where project() says.
  const CameraModel cam = smallCamera();
  const Texture tex = halves();
  SE3 T_w_c = SE3::Identity();
  T_w_c.linear() = Eigen::AngleAxisd(0.2, Vec3::UnitY()).toRotationMatrix();
  T_w_c.translation() = Vec3(0.3, -0.1, -0.5);
  const Vec3 centre_w(0.5, 0.0, 2.0);
  Mesh mesh;
  const double h = 0.02;
  SE3 T = SE3::Identity();
  T.translation() = centre_w;
  addBox(&mesh, T, Vec3(h, h, h), &tex, 5);
  RenderTarget target = RenderTarget::blank(cam.width, cam.height);
  render(mesh, T_w_c, cam, &target);
  cv::Moments m = cv::moments(target.id != 0, true);
  ASSERT_GT(m.m00, 4);
  const Vec2 expected = cam.project(T_w_c.inverse() * centre_w);
  EXPECT_NEAR(m.m10 / m.m00, expected.x(), 0.75);
  EXPECT_NEAR(m.m01 / m.m00, expected.y(), 0.75);
}

TEST(Raster, CutOutTextureIsTransparentOutsideItsMask) {
  const CameraModel cam = smallCamera();
  // Keep the texture's left half only (the mask is at another size: it is resized).
  cv::Mat keep(40, 40, CV_8UC1, cv::Scalar(0));
  keep(cv::Rect(0, 0, 20, 40)).setTo(255);
  const Texture whole = halves();
  const Texture cut(whole.level(0), false, keep);
  ASSERT_TRUE(cut.cutout());
  ASSERT_FALSE(whole.cutout());
  // A 1.2 x 0.9 m quad facing the camera 2 m ahead; behind it, a wall at 3 m.
  auto quad = [](Mesh* mesh, const Texture* tex, double z, double hw, double hh, std::uint16_t id) {
    addQuad(mesh, {Vec3(-hw, -hh, z), Vec3(hw, -hh, z), Vec3(hw, hh, z), Vec3(-hw, hh, z)}, tex, id);
  };
  Mesh mesh;
  quad(&mesh, &cut, 2.0, 0.6, 0.45, 1);
  quad(&mesh, &whole, 3.0, 3.0, 3.0, 2);
  RenderTarget target = RenderTarget::blank(cam.width, cam.height);
  render(mesh, SE3::Identity(), cam, &target);
  int left = 0, right = 0, misplaced = 0;
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      const Vec3 on_quad = cam.unproject(Vec2(x, y), 2.0);
      if (std::abs(on_quad.y()) > 0.44 || std::abs(on_quad.x()) > 0.59 || std::abs(on_quad.x()) < 0.01) continue;
      const std::uint16_t id = target.id.at<std::uint16_t>(y, x);
      if (on_quad.x() < 0) {
        left += id == 1;
        misplaced += id != 1;
      } else {  // the wall shows through the cut-out, at its own depth
        right += id == 2 && std::abs(target.depth.at<float>(y, x) - 3.0f) < 1e-3f;
        misplaced += id != 2;
      }
    }
  }
  EXPECT_GT(left, 500);
  EXPECT_GT(right, 500);
  EXPECT_EQ(misplaced, 0);
}

}  // namespace
}  // namespace stillpoint::synth
