#include "stillpoint/synth/room.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>

#include "stillpoint/synth/textures.hpp"

namespace stillpoint::synth {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kX0 = -3.0, kX1 = 3.0, kY0 = -1.5, kY1 = 4.6, kZ1 = 2.7;

SE3 lookAt(const Vec3& centre, const Vec3& target) {
  const Vec3 z = (target - centre).normalized();
  Vec3 x = z.cross(Vec3::UnitZ());
  if (x.norm() < 1e-9) x = Vec3::UnitX();
  x.normalize();
  const Vec3 y = z.cross(x);
  SE3 T = SE3::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.translation() = centre;
  return T;
}

constexpr double kLoopPeriodS = 20.0;  // one lap of the `loop` motion

int tiles(double length_m) { return std::max(1, static_cast<int>(std::ceil(length_m / 0.5))); }

}  // namespace

CameraModel roomCamera(int width, int height) {
  CameraModel c;
  c.name = "synthetic_fr3";
  c.width = width;
  c.height = height;
  const double sx = width / 640.0, sy = height / 480.0;
  c.fx = 535.4 * sx;
  c.fy = 539.2 * sy;
  c.cx = 320.1 * sx;
  c.cy = 247.6 * sy;
  c.depth_factor = 5000.0;
  return c;
}

SE3 roomCameraPose(CameraMotion motion, double t) {
  const Vec3 c0(0.0, 0.2, 1.3), target(0.0, 3.5, 1.0);
  const SE3 base = lookAt(c0, target);
  const double w = 2 * kPi;
  switch (motion) {
    case CameraMotion::kStatic: {
      SE3 T = base;
      T.translation() += 0.0005 * Vec3(std::sin(1.3 * t), std::sin(1.7 * t), std::sin(0.9 * t));
      return T;
    }
    case CameraMotion::kXyz: {
      SE3 T = base;
      const Vec3 offset(0.3 * std::sin(w * t / 7.0), 0.2 * std::sin(w * t / 5.0), 0.3 * std::sin(w * t / 9.0));
      T.translation() += base.linear() * offset;
      return T;
    }
    case CameraMotion::kRpy: {
      const double deg = kPi / 180.0;
      const Mat3 R = Eigen::AngleAxisd(12 * deg * std::sin(w * t / 6.0), Vec3::UnitZ()).toRotationMatrix() *
                     Eigen::AngleAxisd(12 * deg * std::sin(w * t / 5.0), Vec3::UnitX()).toRotationMatrix() *
                     Eigen::AngleAxisd(18 * deg * std::sin(w * t / 8.0), Vec3::UnitY()).toRotationMatrix();
      SE3 T = base;
      T.linear() = base.linear() * R;
      return T;
    }
    case CameraMotion::kHalfsphere: {
      const Vec3 centre(0.0, 2.8, 1.0);
      const double r = 2.0;
      const double az = 0.7 * std::sin(w * t / 12.0);
      const double el = 0.25 + 0.2 * std::sin(w * t / 8.0);
      const Vec3 p = centre + r * Vec3(std::sin(az) * std::cos(el), -std::cos(az) * std::cos(el), std::sin(el));
      return lookAt(p, centre);
    }
    case CameraMotion::kLoop: {
      // Round the middle of the room every kLoopPeriodS, looking out at the
      // walls and ahead: each lap revisits the places of the one before,
      // the test of loop closing.
      const Vec3 centre(0.0, 1.5, 1.3);
      const double a = w * t / kLoopPeriodS;
      const Vec3 p = centre + Vec3(1.1 * std::cos(a), 0.9 * std::sin(a), 0.08 * std::sin(3 * a));
      const Vec3 out(std::cos(a + 0.5), std::sin(a + 0.5), -0.25);
      return lookAt(p, p + out);
    }
  }
  return base;
}

Result<Room> buildRoom(const RoomOptions& options, const std::string& base_dir, std::uint64_t seed) {
  Room room;
  // Texel density follows the image resolution (2048 texels across the back wall at 640 px).
  const double scale = std::clamp(options.width / 640.0, 0.125, 2.0);
  auto tex = [&](TextureStyle style, int w, int h, std::uint64_t s, bool repeat) {
    const int sw = std::max(16, static_cast<int>(w * scale)), sh = std::max(16, static_cast<int>(h * scale));
    room.textures.push_back(std::make_shared<const Texture>(makeTexture(style, sw, sh, seed * 1000 + s), repeat));
    return room.textures.back().get();
  };
  Mesh& m = room.mesh;
  const double W = kX1 - kX0, D = kY1 - kY0;
  // Walls, seen from inside, corners from top-left.
  addQuad(&m, {Vec3(kX0, kY1, kZ1), Vec3(kX1, kY1, kZ1), Vec3(kX1, kY1, 0), Vec3(kX0, kY1, 0)},
          tex(TextureStyle::kPaper, 2048, 1024, 1, false), 0, 1, 1, tiles(W), tiles(kZ1));
  addQuad(&m, {Vec3(kX0, kY0, kZ1), Vec3(kX0, kY1, kZ1), Vec3(kX0, kY1, 0), Vec3(kX0, kY0, 0)},
          tex(TextureStyle::kStone, 2048, 1024, 2, false), 0, 1, 1, tiles(D), tiles(kZ1));
  addQuad(&m, {Vec3(kX1, kY1, kZ1), Vec3(kX1, kY0, kZ1), Vec3(kX1, kY0, 0), Vec3(kX1, kY1, 0)},
          tex(TextureStyle::kPaper, 2048, 1024, 3, false), 0, 1, 1, tiles(D), tiles(kZ1));
  addQuad(&m, {Vec3(kX1, kY0, kZ1), Vec3(kX0, kY0, kZ1), Vec3(kX0, kY0, 0), Vec3(kX1, kY0, 0)},
          tex(TextureStyle::kStone, 1024, 512, 4, false), 0, 1, 1, tiles(W), tiles(kZ1));
  addQuad(&m, {Vec3(kX0, kY1, 0), Vec3(kX1, kY1, 0), Vec3(kX1, kY0, 0), Vec3(kX0, kY0, 0)},
          tex(TextureStyle::kWood, 1024, 1024, 5, true), 0, 3, 3, tiles(W), tiles(D));
  addQuad(&m, {Vec3(kX0, kY0, kZ1), Vec3(kX1, kY0, kZ1), Vec3(kX1, kY1, kZ1), Vec3(kX0, kY1, kZ1)},
          tex(TextureStyle::kStone, 1024, 1024, 6, true), 0, 2, 2, tiles(W), tiles(D));

  // Furniture: table with things on it, a shelf, a cabinet, a sofa-like block.
  auto boxAt = [&](const Vec3& centre, const Vec3& size, const Texture* t, double yaw = 0) {
    SE3 T = SE3::Identity();
    T.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
    T.translation() = centre;
    addBox(&m, T, 0.5 * size, t, 0);
  };
  const Texture* wood = tex(TextureStyle::kWood, 512, 512, 7, false);
  boxAt({0.7, 3.3, 0.72}, {1.4, 0.8, 0.06}, wood);  // table top and legs
  for (double dx : {-0.62, 0.62}) {
    for (double dy : {-0.33, 0.33}) boxAt({0.7 + dx, 3.3 + dy, 0.345}, {0.06, 0.06, 0.69}, wood);
  }
  boxAt({0.4, 3.3, 0.87}, {0.3, 0.22, 0.24}, tex(TextureStyle::kPaper, 256, 256, 8, false), 0.3);
  boxAt({1.0, 3.4, 0.80}, {0.35, 0.25, 0.1}, tex(TextureStyle::kFabric, 256, 256, 9, false), -0.2);
  boxAt({-2.2, 4.6, 0.95}, {1.2, 0.35, 1.9}, tex(TextureStyle::kPaper, 512, 1024, 10, false));
  boxAt({2.5, 2.6, 0.6}, {0.6, 1.0, 1.2}, tex(TextureStyle::kFabric, 512, 512, 11, false));
  boxAt({-2.3, 2.2, 0.4}, {0.9, 1.8, 0.8}, tex(TextureStyle::kFabric, 512, 512, 12, false), 0.05);

  // Pictures on the walls, a few millimetres in front of them.
  const std::array<std::array<Vec3, 4>, 3> frames = {{
      {Vec3(-1.6, kY1 - 0.01, 2.0), Vec3(-0.6, kY1 - 0.01, 2.0), Vec3(-0.6, kY1 - 0.01, 1.0), Vec3(-1.6, kY1 - 0.01, 1.0)},
      {Vec3(kX0 + 0.01, 0.8, 1.9), Vec3(kX0 + 0.01, 1.8, 1.9), Vec3(kX0 + 0.01, 1.8, 1.1), Vec3(kX0 + 0.01, 0.8, 1.1)},
      {Vec3(kX1 - 0.01, 4.0, 1.9), Vec3(kX1 - 0.01, 3.0, 1.9), Vec3(kX1 - 0.01, 3.0, 1.1), Vec3(kX1 - 0.01, 4.0, 1.1)},
  }};
  for (std::size_t i = 0; i < options.photos.size() && i < frames.size(); ++i) {
    std::filesystem::path p(options.photos[i]);
    if (p.is_relative() && !base_dir.empty()) p = std::filesystem::path(base_dir) / p;
    Result<cv::Mat> photo = loadPhoto(p.string());
    if (!photo.ok()) return Error{"room.photos[" + std::to_string(i) + "]: " + photo.error()};
    room.textures.push_back(std::make_shared<const Texture>(*photo, false));
    addQuad(&m, frames[i], room.textures.back().get(), 0, 1, 1, 2, 2);
  }
  return room;
}

}  // namespace stillpoint::synth
