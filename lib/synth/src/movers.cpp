#include "stillpoint/synth/movers.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "stillpoint/synth/textures.hpp"
#include "stillpoint/synth/video_walker.hpp"

namespace stillpoint::synth {
namespace {

constexpr double kPi = std::numbers::pi;

double ease(double f) { return 0.5 - 0.5 * std::cos(kPi * std::clamp(f, 0.0, 1.0)); }

// Distance covered along a back-and-forth path of length L after `moved` metres
// of progress -> position along the segment and direction sign.
void pingPong(double moved, double length, double* along, double* sign) {
  if (length <= 0) {
    *along = 0;
    *sign = 1;
    return;
  }
  const double m = std::fmod(std::max(0.0, moved), 2 * length);
  if (m <= length) {
    *along = m;
    *sign = 1;
  } else {
    *along = 2 * length - m;
    *sign = -1;
  }
}

// Progress (m) of eased legs of `leg_s` seconds each, moving `leg_m` metres per leg,
// with `pause_s` of rest after each leg.
double legProgress(double t, double leg_s, double leg_m, double pause_s) {
  if (t <= 0 || leg_s <= 0) return 0;
  const double cycle = leg_s + pause_s;
  const double n = std::floor(t / cycle);
  const double tau = t - n * cycle;
  return leg_m * (n + ease(tau / leg_s));
}

Vec3 positionAt(const PathSpec& p, double t) {
  const Vec3 d = p.end - p.start;
  const double L = d.norm();
  const Vec3 dir = L > 0 ? Vec3(d / L) : Vec3::Zero();
  const double speed = std::max(1e-6, p.speed_m_s);
  double moved = 0;
  switch (p.type) {
    case PathType::kStatic:
      return p.start;
    case PathType::kOscillate:
      return p.start + 0.5 * d * (1 - std::cos(2 * kPi * t / std::max(1e-6, p.period_s)));
    case PathType::kWalk:
      moved = legProgress(t, L / speed, L, 0.0);
      break;
    case PathType::kStopAndGo:
      moved = legProgress(t, p.go_s, speed * p.go_s, p.stop_s);
      break;
    case PathType::kStaticThenMove:
      moved = legProgress(t - p.hold_s, L / speed, L, 0.0);
      break;
  }
  double along = 0, sign = 1;
  pingPong(moved, L, &along, &sign);
  return p.start + dir * along;
}

SE3 yawPose(const SE3& T_w_s, const Vec3& position, double yaw) {
  SE3 T = SE3::Identity();
  T.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
  T.translation() = position;
  return T_w_s * T;
}

// A limb segment hanging from `joint` (in body frame B), rotated by `angle`
// about the body x axis (positive = swings forward).
void addLimb(Mesh* mesh, const SE3& T_w_b, const Vec3& joint, double angle, double length,
             double thickness, const Texture* tex, std::uint16_t id, Vec3* end_out = nullptr) {
  SE3 T = SE3::Identity();
  T.linear() = Eigen::AngleAxisd(angle, Vec3::UnitX()).toRotationMatrix();
  T.translation() = joint;
  const Vec3 centre_offset(0, 0, -0.5 * length);
  SE3 seg = T;
  seg.translation() = joint + T.linear() * centre_offset;
  addBox(mesh, T_w_b * seg, Vec3(0.5 * thickness, 0.5 * thickness, 0.5 * length), tex, id);
  if (end_out) *end_out = joint + T.linear() * Vec3(0, 0, -length);
}

void addWalker(Mesh* mesh, const MoverSpec& spec, const MoverTextures& tx, const SE3& T_w_s,
               double t, std::uint16_t id) {
  const PathState s = evaluatePath(spec.path, t);
  const double H = spec.size.y(), W = spec.size.x(), D = spec.size.z();
  const double yaw = std::atan2(-s.heading.x(), s.heading.y());  // body y along the heading
  const SE3 T_w_b = yawPose(T_w_s, s.position, yaw);
  const Texture* shirt = tx.textures[0].get();
  const Texture* trousers = tx.textures[1].get();
  const Texture* skin = tx.textures[2].get();
  const Texture* shoes = tx.textures[3].get();

  const double stride = 0.8 * H;  // one gait cycle = two steps
  const double phase = 2 * kPi * s.travelled_m / stride;
  const double moving = std::clamp(s.velocity.norm() / 0.3, 0.0, 1.0);
  const double swing = (0.2 + 0.25 * moving) * std::sin(phase);
  const double hip_z = 0.5 * H, thigh = 0.245 * H, shin = 0.235 * H;
  const double torso_h = 0.3 * H, shoulder_z = hip_z + torso_h - 0.02 * H;

  // Torso and head.
  SE3 torso = SE3::Identity();
  torso.translation() = Vec3(0, 0, hip_z + 0.5 * torso_h);
  addBox(mesh, T_w_b * torso, Vec3(0.5 * W * 0.8, 0.5 * D, 0.5 * torso_h), shirt, id);
  SE3 head = SE3::Identity();
  head.translation() = Vec3(0, 0, hip_z + torso_h + 0.075 * H);
  addBox(mesh, T_w_b * head, Vec3(0.055 * H, 0.06 * H, 0.065 * H), skin, id);

  for (int side = -1; side <= 1; side += 2) {
    const double leg = side * swing;
    const double knee = (0.15 + 0.5 * moving) * std::max(0.0, std::sin(phase * 1.0 + side * kPi / 2 + 0.6));
    Vec3 knee_joint;
    addLimb(mesh, T_w_b, Vec3(side * 0.22 * W, 0, hip_z), leg, thigh, 0.13 * H * 0.55, trousers, id,
            &knee_joint);
    Vec3 ankle;
    addLimb(mesh, T_w_b, knee_joint, leg - knee, shin, 0.11 * H * 0.55, trousers, id, &ankle);
    SE3 foot = SE3::Identity();
    foot.translation() = ankle + Vec3(0, 0.04 * H, 0.02 * H);
    addBox(mesh, T_w_b * foot, Vec3(0.03 * H, 0.06 * H, 0.02 * H), shoes, id);

    const double arm = -side * swing * 0.8;
    Vec3 elbow;
    addLimb(mesh, T_w_b, Vec3(side * (0.5 * W * 0.8 + 0.035 * H), 0, shoulder_z), arm, 0.17 * H,
            0.05 * H, shirt, id, &elbow);
    Vec3 wrist;
    addLimb(mesh, T_w_b, elbow, arm + 0.25 + 0.2 * moving, 0.15 * H, 0.045 * H, shirt, id, &wrist);
    SE3 hand = SE3::Identity();
    hand.translation() = wrist + Vec3(0, 0, -0.03 * H);
    addBox(mesh, T_w_b * hand, Vec3(0.02 * H, 0.025 * H, 0.035 * H), skin, id);
  }
}

}  // namespace

PathState evaluatePath(const PathSpec& path, double t_in) {
  const double t = t_in + path.phase_s;
  PathState s;
  s.position = positionAt(path, t);
  constexpr double h = 1e-3;
  const Vec3 ahead = positionAt(path, t + h);
  s.velocity = (ahead - positionAt(path, t - h)) / (2 * h);
  // Heading: the direction of the latest motion; the start->end direction before any.
  Vec3 dir = path.end - path.start;
  dir.z() = 0;
  if (dir.norm() < 1e-9) dir = Vec3::UnitY();
  s.heading = dir.normalized();
  constexpr double step = 0.02;
  Vec3 prev = positionAt(path, path.phase_s);
  for (double tau = path.phase_s + step; tau <= t + 1e-12; tau += step) {
    const Vec3 p = positionAt(path, tau);
    Vec3 d = p - prev;
    s.travelled_m += d.norm();
    d.z() = 0;
    if (d.norm() > 1e-5) s.heading = d.normalized();
    prev = p;
  }
  s.travelled_m += (s.position - prev).norm();
  return s;
}

double moverSpeed(const MoverSpec& spec, double t) {
  const double spin = spec.shape == MoverShape::kWalker ? 0.0 : std::abs(spec.yaw_rate_deg_s) * kPi / 180.0;
  return evaluatePath(spec.path, t).velocity.norm() + spin * 0.5 * spec.size.x();
}

Result<MoverTextures> makeMoverTextures(const MoverSpec& spec, const std::string& base_dir,
                                        std::uint64_t seed) {
  MoverTextures out;
  auto photoOrStyle = [&](const std::string& name, TextureStyle fallback, int w, int h,
                          std::uint64_t s) -> Result<TexturePtr> {
    if (name.empty()) return std::make_shared<const Texture>(makeTexture(fallback, w, h, s), false);
    if (Result<TextureStyle> style = parseTextureStyle(name); style.ok()) {
      return std::make_shared<const Texture>(makeTexture(*style, w, h, s), false);
    }
    std::filesystem::path p(name);
    if (p.is_relative() && !base_dir.empty()) p = std::filesystem::path(base_dir) / p;
    Result<cv::Mat> photo = loadPhoto(p.string());
    if (!photo.ok()) return Error{"mover '" + spec.name + "': " + photo.error()};
    return std::make_shared<const Texture>(*photo, false);
  };
  if (spec.shape == MoverShape::kWalker) {
    Result<TexturePtr> shirt = photoOrStyle(spec.texture, TextureStyle::kFabric, 256, 256, seed);
    if (!shirt.ok()) return Error{shirt.error()};
    out.textures.push_back(*shirt);
    out.textures.push_back(std::make_shared<const Texture>(
        makeTexture(TextureStyle::kFabric, 128, 256, seed + 1), false));
    out.textures.push_back(std::make_shared<const Texture>(
        makeTexture(TextureStyle::kSkin, 64, 64, seed + 2), false));
    out.textures.push_back(std::make_shared<const Texture>(
        makeTexture(TextureStyle::kStone, 64, 64, seed + 3), false));
  } else if (!spec.video.empty()) {
    std::filesystem::path p(spec.video);
    if (p.is_relative() && !base_dir.empty()) p = std::filesystem::path(base_dir) / p;
    Result<WalkerClip> clip = cutWalkerFromVideo(p.string());
    if (!clip.ok()) return Error{"mover '" + spec.name + "': " + clip.error()};
    for (std::size_t i = 0; i < clip->colour.size(); ++i)
      out.video_frames.push_back(std::make_shared<const Texture>(clip->colour[i], false, clip->keep[i]));
    out.video_fps = clip->fps;
    out.textures.push_back(out.video_frames.front());
  } else {
    Result<TexturePtr> main = photoOrStyle(spec.texture, TextureStyle::kPaper, 512, 512, seed);
    if (!main.ok()) return Error{main.error()};
    // The part of an image `crop` names (fractions of its size, the same
    // place in the photo and in its mask whatever their sizes).
    const auto part = [&spec](const cv::Mat& image) {
      const auto& c = spec.crop;
      const int x0 = static_cast<int>(std::lround(c[0] * image.cols));
      const int y0 = static_cast<int>(std::lround(c[1] * image.rows));
      const int x1 = std::max(x0 + 1, static_cast<int>(std::lround(c[2] * image.cols)));
      const int y1 = std::max(y0 + 1, static_cast<int>(std::lround(c[3] * image.rows)));
      return image(cv::Rect(x0, y0, std::min(x1, image.cols) - x0, std::min(y1, image.rows) - y0)).clone();
    };
    const bool cropped = spec.cropped();
    const cv::Mat image = cropped ? part((*main)->level(0)) : (*main)->level(0);
    if (spec.cutout.empty()) {
      out.textures.push_back(cropped ? std::make_shared<const Texture>(image, false) : *main);
    } else {
      std::filesystem::path p(spec.cutout);
      if (p.is_relative() && !base_dir.empty()) p = std::filesystem::path(base_dir) / p;
      Result<cv::Mat> keep = loadMask(p.string());
      if (!keep.ok()) return Error{"mover '" + spec.name + "': cutout: " + keep.error()};
      cv::Mat kept = cropped ? part(*keep) : *keep;
      if (cropped) {
        // One person of a photo of several: the largest part of the mask
        // inside the crop, not the pieces of others it cuts into.
        cv::Mat labels, stats, centroids;
        const int n = cv::connectedComponentsWithStats(kept >= 128, labels, stats, centroids, 8, CV_32S);
        if (n < 2) return Error{"mover '" + spec.name + "': cutout: nothing kept inside the crop"};
        int largest = 1;
        for (int k = 2; k < n; ++k)
          if (stats.at<int>(k, cv::CC_STAT_AREA) > stats.at<int>(largest, cv::CC_STAT_AREA)) largest = k;
        cv::Mat one;
        cv::compare(labels, largest, one, cv::CMP_EQ);
        kept = one;
      }
      out.textures.push_back(std::make_shared<const Texture>(image, false, kept));
    }
  }
  return out;
}

void addMover(Mesh* mesh, const MoverSpec& spec, const MoverTextures& tx, const SE3& T_w_s, double t,
              std::uint16_t id, const Vec3& camera_w) {
  if (spec.shape == MoverShape::kWalker) {
    addWalker(mesh, spec, tx, T_w_s, t, id);
    return;
  }
  const PathState s = evaluatePath(spec.path, t);
  double yaw = (spec.yaw_deg + spec.yaw_rate_deg_s * t) * kPi / 180.0;
  if (spec.face_camera && spec.shape == MoverShape::kPoster) {
    // The poster's normal is its -y axis, (sin yaw, -cos yaw) after the yaw:
    // point it at the camera, seen from above in the stage frame.
    const Vec3 d = T_w_s.inverse() * camera_w - s.position;
    if (std::hypot(d.x(), d.y()) > 1e-6) yaw += std::atan2(d.x(), -d.y());
  }
  const SE3 T_w_m = yawPose(T_w_s, s.position, yaw);
  const Texture* tex = tx.textures[0].get();
  if (!tx.video_frames.empty()) {
    const auto k = static_cast<std::size_t>(std::max(0.0, std::floor(t * tx.video_fps)));
    tex = tx.video_frames[k % tx.video_frames.size()].get();
  }
  if (spec.shape == MoverShape::kPoster) {
    const double hw = 0.5 * spec.size.x(), hh = 0.5 * spec.size.y();
    // Normal along -y (towards the first camera); texture top-left at (-x, +z).
    auto P = [&](double x, double z) { return Vec3(T_w_m * Vec3(x, 0, z)); };
    addQuad(mesh, {P(-hw, hh), P(hw, hh), P(hw, -hh), P(-hw, -hh)}, tex, id, 1.0, 1.0, 2, 2);
  } else {
    addBox(mesh, T_w_m, Vec3(0.5 * spec.size.x(), 0.5 * spec.size.z(), 0.5 * spec.size.y()), tex, id);
  }
}

SE3 stageFromCamera(const SE3& T_w_c0) {
  Vec3 forward = T_w_c0.linear().col(2);
  forward.z() = 0;
  if (forward.norm() < 1e-6) forward = -Vec3(T_w_c0.linear().col(1)).cwiseProduct(Vec3(1, 1, 0));
  if (forward.norm() < 1e-6) forward = Vec3::UnitY();
  forward.normalize();
  const Vec3 up = Vec3::UnitZ();
  const Vec3 right = forward.cross(up);
  SE3 T = SE3::Identity();
  T.linear().col(0) = right;
  T.linear().col(1) = forward;
  T.linear().col(2) = up;
  T.translation() = Vec3(T_w_c0.translation().x(), T_w_c0.translation().y(), 0.0);
  return T;
}

const char* toString(PathType type) {
  switch (type) {
    case PathType::kStatic: return "static";
    case PathType::kOscillate: return "oscillate";
    case PathType::kWalk: return "walk";
    case PathType::kStopAndGo: return "stop_and_go";
    case PathType::kStaticThenMove: return "static_then_move";
  }
  return "?";
}

const char* toString(MoverShape shape) {
  switch (shape) {
    case MoverShape::kPoster: return "poster";
    case MoverShape::kBox: return "box";
    case MoverShape::kWalker: return "walker";
  }
  return "?";
}

}  // namespace stillpoint::synth
