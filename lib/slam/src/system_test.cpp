// SlamSystem through its public API: creation checks, input validation, and
// tracking of synthetic scenes with known camera motion (sequential mode, so
// every run is the same).
#include "stillpoint/slam/system.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "stillpoint/dataset/testing.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"

#include "test_helpers.hpp"

namespace stillpoint::slam {
namespace {

namespace fs = std::filesystem;

using testing::contains;

double degrees(double radians) { return radians * 180.0 / M_PI; }

struct Sequence {
  CameraModel camera;
  std::vector<RgbdInput> frames;
  std::vector<SE3> T_w_c;  // ground truth per frame, T_w_c[0] = identity
};

// A closed room of textured planes (back wall, floor, ceiling, side walls)
// with a box standing in it, ray-cast per pixel: exact grey images and depth
// for any camera pose, with depth discontinuities and varied depths so the
// pose is well conditioned (a single fronto-parallel plane nearly confuses a
// small rotation with a sideways translation).
class RoomScene {
 public:
  explicit RoomScene(std::uint64_t seed) {
    cv::RNG rng(seed);
    // origin, in-plane axes a and b (unit), extent along a and b (m).
    addPlane(Vec3(-1.6, -1.2, 3.0), Vec3(1, 0, 0), Vec3(0, 1, 0), 3.4, 2.2, rng);    // back wall z = 3
    addPlane(Vec3(-1.6, 1.0, -0.5), Vec3(1, 0, 0), Vec3(0, 0, 1), 3.4, 3.5, rng);    // floor y = 1
    addPlane(Vec3(-1.6, -1.2, -0.5), Vec3(1, 0, 0), Vec3(0, 0, 1), 3.4, 3.5, rng);   // ceiling y = -1.2
    addPlane(Vec3(-1.6, -1.2, -0.5), Vec3(0, 0, 1), Vec3(0, 1, 0), 3.5, 2.2, rng);   // left wall x = -1.6
    addPlane(Vec3(1.8, -1.2, -0.5), Vec3(0, 0, 1), Vec3(0, 1, 0), 3.5, 2.2, rng);    // right wall x = 1.8
    addPlane(Vec3(0.2, 0.2, 1.9), Vec3(1, 0, 0), Vec3(0, 1, 0), 0.7, 0.8, rng);      // box front z = 1.9
    addPlane(Vec3(0.2, 0.2, 1.9), Vec3(0, 0, 1), Vec3(0, 1, 0), 0.5, 0.8, rng);      // box left side x = 0.2
    addPlane(Vec3(0.2, 0.2, 1.9), Vec3(1, 0, 0), Vec3(0, 0, 1), 0.7, 0.5, rng);      // box top y = 0.2
  }

  static CameraModel camera() {
    CameraModel cam;
    cam.name = "synthetic-room";
    cam.width = 640;
    cam.height = 480;
    cam.fx = cam.fy = 525.0;
    cam.cx = 319.5;
    cam.cy = 239.5;
    return cam;
  }

  // A textured board (a moving object) with its lower-left corner at `origin`
  // facing the camera; render() shifts it by its `mover_offset`.
  void addMovingBoard(const Vec3& origin, double width, double height, std::uint64_t seed) {
    cv::RNG rng(seed);
    addPlane(origin, Vec3(1, 0, 0), Vec3(0, 1, 0), width, height, rng);
    planes_.back().moving = true;
  }

  // Grey image and depth (metres) seen from T_w_c; `mover_mask` (optional)
  // receives 255 where a moving board is seen.
  RgbdInput render(const CameraModel& cam, const SE3& T_w_c, Timestamp stamp, const Vec3& mover_offset = Vec3::Zero(),
                   cv::Mat* mover_mask = nullptr) const {
    RgbdInput out;
    out.stamp = stamp;
    out.gray.create(cam.height, cam.width, CV_8UC1);
    out.depth_m.create(cam.height, cam.width, CV_32FC1);
    if (mover_mask) *mover_mask = cv::Mat::zeros(cam.height, cam.width, CV_8UC1);
    const Mat3 R = T_w_c.linear();
    const Vec3 c = T_w_c.translation();
    for (int v = 0; v < cam.height; ++v) {
      for (int u = 0; u < cam.width; ++u) {
        const Vec3 ray = R * Vec3((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);  // camera z = 1
        double best_t = 1e9;
        const Plane* hit = nullptr;
        Vec2 hit_ab(0, 0);
        for (const Plane& p : planes_) {
          const double denom = p.normal.dot(ray);
          if (std::abs(denom) < 1e-9) continue;
          const Vec3 origin = p.moving ? Vec3(p.origin + mover_offset) : p.origin;
          const double t = p.normal.dot(origin - c) / denom;
          if (t <= 0 || t >= best_t) continue;
          const Vec3 rel = c + t * ray - origin;
          const double a = rel.dot(p.a), b = rel.dot(p.b);
          if (a < 0 || b < 0 || a > p.extent.x() || b > p.extent.y()) continue;
          best_t = t;
          hit = &p;
          hit_ab = Vec2(a, b);
        }
        // t is the camera depth because the ray has unit camera z.
        out.depth_m.at<float>(v, u) = hit ? static_cast<float>(best_t) : 0.0f;
        out.gray.at<std::uint8_t>(v, u) = hit ? sample(hit->texture, hit_ab / kTexel) : 0;
        if (mover_mask && hit && hit->moving) mover_mask->at<std::uint8_t>(v, u) = 255;
      }
    }
    return out;
  }

 private:
  static constexpr double kTexel = 0.004;  // m: about one pixel at 2 m
  static constexpr int kBlock = 10;        // texels per random block (4 cm)

  struct Plane {
    Vec3 origin, a, b, normal;
    Vec2 extent;
    cv::Mat texture;  // CV_8UC1, kTexel per texel
    bool moving = false;
  };

  void addPlane(const Vec3& origin, const Vec3& a, const Vec3& b, double extent_a, double extent_b, cv::RNG& rng) {
    Plane p{origin, a, b, a.cross(b).normalized(), Vec2(extent_a, extent_b), {}, false};
    const int cols = static_cast<int>(std::ceil(extent_a / kTexel)) + 2;
    const int rows = static_cast<int>(std::ceil(extent_b / kTexel)) + 2;
    cv::Mat coarse((rows + kBlock - 1) / kBlock, (cols + kBlock - 1) / kBlock, CV_8UC1);
    rng.fill(coarse, cv::RNG::UNIFORM, cv::Scalar(20), cv::Scalar(236));
    cv::resize(coarse, p.texture, cv::Size(coarse.cols * kBlock, coarse.rows * kBlock), 0, 0, cv::INTER_NEAREST);
    cv::GaussianBlur(p.texture, p.texture, cv::Size(5, 5), 1.2);
    planes_.push_back(std::move(p));
  }

  static std::uint8_t sample(const cv::Mat& texture, const Vec2& xy) {
    const int x0 = std::clamp(static_cast<int>(std::floor(xy.x())), 0, texture.cols - 2);
    const int y0 = std::clamp(static_cast<int>(std::floor(xy.y())), 0, texture.rows - 2);
    const double fx = std::clamp(xy.x() - x0, 0.0, 1.0), fy = std::clamp(xy.y() - y0, 0.0, 1.0);
    const double top = (1 - fx) * texture.at<std::uint8_t>(y0, x0) + fx * texture.at<std::uint8_t>(y0, x0 + 1);
    const double bottom = (1 - fx) * texture.at<std::uint8_t>(y0 + 1, x0) + fx * texture.at<std::uint8_t>(y0 + 1, x0 + 1);
    return cv::saturate_cast<std::uint8_t>((1 - fy) * top + fy * bottom);
  }

  std::vector<Plane> planes_;
};

SE3 pose(const Vec3& rotation, const Vec3& translation) {
  SE3 T = SE3::Identity();
  T.linear() = expSO3(rotation);
  T.translation() = translation;
  return T;
}

Timestamp frameStamp(int k) { return Timestamp::fromNanoseconds(1'000'000'000LL + k * 33'333'333LL); }

// A smooth hand-held-like path through the room at 30 Hz: in 60 frames about
// 1.5 m of travel and up to 14 degrees of rotation, up to 2.8 cm per frame.
Sequence roomSequence(int n_frames) {
  const RoomScene scene(5);
  Sequence out;
  out.camera = RoomScene::camera();
  for (int k = 0; k < n_frames; ++k) {
    const double s = static_cast<double>(k) / 15.0;  // path time runs at twice the frame clock
    const Vec3 rotation(0.08 * std::sin(1.3 * s), 0.25 * std::sin(0.9 * s), 0.06 * std::sin(0.7 * s));
    const Vec3 translation(0.5 * std::sin(0.8 * s), 0.1 * std::sin(1.1 * s), 0.4 * (1 - std::cos(0.9 * s)));
    const SE3 T_w_c = pose(rotation, translation);
    out.T_w_c.push_back(T_w_c);
    out.frames.push_back(scene.render(out.camera, T_w_c, frameStamp(k)));
  }
  return out;
}

SlamOptions sequentialOptions() {
  SlamOptions o;
  o.sequential = true;
  return o;
}

std::unique_ptr<SlamSystem> makeSystem(const CameraModel& camera, const SlamOptions& options = sequentialOptions()) {
  auto system = SlamSystem::create(camera, options);
  EXPECT_TRUE(system.ok()) << system.error();
  return system.ok() ? std::move(*system) : nullptr;
}

// Worst and RMS errors of estimated poses against the truth.
struct PoseErrors {
  double max_translation = 0, rms_translation = 0, max_rotation = 0;  // m, m, rad
  std::size_t worst_frame = 0;
};

PoseErrors compare(const std::vector<SE3>& estimated, const std::vector<SE3>& truth) {
  PoseErrors e;
  double sum2 = 0;
  for (std::size_t i = 0; i < estimated.size() && i < truth.size(); ++i) {
    const double t = (estimated[i].translation() - truth[i].translation()).norm();
    sum2 += t * t;
    if (t > e.max_translation) e.max_translation = t, e.worst_frame = i;
    e.max_rotation = std::max(e.max_rotation, rotationAngle(estimated[i].linear() * truth[i].linear().transpose()));
  }
  if (!estimated.empty()) e.rms_translation = std::sqrt(sum2 / static_cast<double>(estimated.size()));
  return e;
}

// Largest error of the motion between consecutive frames.
PoseErrors compareRelative(const std::vector<SE3>& estimated, const std::vector<SE3>& truth) {
  std::vector<SE3> est_rel, true_rel;
  for (std::size_t i = 1; i < estimated.size() && i < truth.size(); ++i) {
    est_rel.push_back(estimated[i - 1].inverse() * estimated[i]);
    true_rel.push_back(truth[i - 1].inverse() * truth[i]);
  }
  return compare(est_rel, true_rel);
}

std::vector<SE3> posesOf(const std::vector<TrajectoryPose>& trajectory) {
  std::vector<SE3> poses;
  for (const TrajectoryPose& p : trajectory) poses.push_back(p.T_w_c);
  return poses;
}

double pathLength(const std::vector<SE3>& poses) {
  double length = 0;
  for (std::size_t i = 1; i < poses.size(); ++i)
    length += (poses[i].translation() - poses[i - 1].translation()).norm();
  return length;
}

// --- creation -------------------------------------------------------------

TEST(SlamSystemCreate, RejectsInvalidCameraNamingTheField) {
  CameraModel camera = RoomScene::camera();
  camera.fx = 0;
  const auto no_focal = SlamSystem::create(camera, sequentialOptions());
  ASSERT_FALSE(no_focal.ok());
  EXPECT_TRUE(contains(no_focal.error(), "fx"));

  camera = RoomScene::camera();
  camera.width = 0;
  const auto no_width = SlamSystem::create(camera, sequentialOptions());
  ASSERT_FALSE(no_width.ok());
  EXPECT_TRUE(contains(no_width.error(), "width"));
}

TEST(SlamSystemCreate, RejectsInvalidOptionsNamingTheField) {
  SlamOptions options = sequentialOptions();
  options.orb.num_features = 10;
  const auto orb = SlamSystem::create(RoomScene::camera(), options);
  ASSERT_FALSE(orb.ok());
  EXPECT_TRUE(contains(orb.error(), "orb.num_features"));

  options = sequentialOptions();
  options.mapping.ba_iterations = 0;
  const auto mapping = SlamSystem::create(RoomScene::camera(), options);
  ASSERT_FALSE(mapping.ok());
  EXPECT_TRUE(contains(mapping.error(), "mapping.ba_iterations"));

  EXPECT_TRUE(SlamSystem::create(RoomScene::camera(), sequentialOptions()).ok());
}

// --- input validation and state -------------------------------------------

// The room seen from a few poses along a short path (rendered once).
class SlamSystemInputTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const RoomScene scene(5);
    camera_ = RoomScene::camera();
    for (int k = 0; k < 12; ++k) {
      const SE3 T_w_c = pose(Vec3(0, 0.004 * k, 0), Vec3(0.01 * k, 0, 0.005 * k));
      truth_.push_back(T_w_c);
      frames_.push_back(scene.render(camera_, T_w_c, frameStamp(k)));
    }
  }
  static void TearDownTestSuite() {
    frames_.clear();
    truth_.clear();
  }

  static CameraModel camera_;
  static std::vector<RgbdInput> frames_;
  static std::vector<SE3> truth_;
};
CameraModel SlamSystemInputTest::camera_;
std::vector<RgbdInput> SlamSystemInputTest::frames_;
std::vector<SE3> SlamSystemInputTest::truth_;

struct BadInput {
  const char* what;
  const char* message_part;  // the error must say what was wrong
  RgbdInput input;
};

std::vector<BadInput> badInputs(const RgbdInput& good) {
  const cv::Size size = good.gray.size();
  auto with = [&](cv::Mat gray, cv::Mat depth) { return RgbdInput{good.stamp, std::move(gray), std::move(depth)}; };
  cv::Mat bgr;
  cv::cvtColor(good.gray, bgr, cv::COLOR_GRAY2BGR);
  cv::Mat gray16, depth16, depth64;
  good.gray.convertTo(gray16, CV_16U);
  good.depth_m.convertTo(depth16, CV_16U, 5000);
  good.depth_m.convertTo(depth64, CV_64F);
  cv::Mat half_gray, half_depth;
  cv::resize(good.gray, half_gray, size / 2);
  cv::resize(good.depth_m, half_depth, size / 2, 0, 0, cv::INTER_NEAREST);
  auto withMovers = [&](cv::Mat movers) {
    RgbdInput in = good;
    in.movers = std::move(movers);
    return in;
  };
  return {
      {"empty grey image", "empty", with(cv::Mat(), good.depth_m)},
      {"grey image of the wrong size", "camera expects", with(half_gray, good.depth_m)},
      {"grey image transposed", "camera expects", with(good.gray.t(), good.depth_m.t())},
      {"colour instead of grey", "8-bit single channel", with(bgr, good.depth_m)},
      {"16-bit grey image", "8-bit single channel", with(gray16, good.depth_m)},
      {"depth of the wrong size", "depth", with(good.gray, half_depth)},
      {"raw 16-bit depth", "depth", with(good.gray, depth16)},
      {"double-precision depth", "depth", with(good.gray, depth64)},
      {"movers mask of the wrong size", "movers", withMovers(cv::Mat::zeros(size / 2, CV_8UC1))},
      {"floating-point movers mask", "movers", withMovers(cv::Mat::zeros(size, CV_32FC1))},
  };
}

TEST_F(SlamSystemInputTest, BadInputIsAnErrorAndTheSystemKeepsTracking) {
  auto system = makeSystem(camera_);
  ASSERT_TRUE(system);
  std::size_t next = 0;
  std::vector<SE3> estimated;
  // The first bad input comes before initialisation; after each, a good frame follows.
  for (const BadInput& bad : badInputs(frames_[0])) {
    SCOPED_TRACE(bad.what);
    const auto rejected = system->track(bad.input);
    ASSERT_FALSE(rejected.ok());
    EXPECT_TRUE(contains(rejected.error(), bad.message_part));
    ASSERT_LT(next, frames_.size());
    const auto good = system->track(frames_[next]);
    ASSERT_TRUE(good.ok()) << good.error();
    EXPECT_EQ(good->state, TrackingState::kOk);
    estimated.push_back(good->T_w_c);
    ++next;
  }
  // Rejected frames leave no trace: the trajectory holds the good frames only,
  // and they follow the true motion.
  system->finish();
  const auto trajectory = system->trajectory();
  ASSERT_EQ(trajectory.size(), next);
  for (std::size_t i = 0; i < next; ++i) EXPECT_EQ(trajectory[i].stamp, frames_[i].stamp);
  const std::vector<SE3> truth(truth_.begin(), truth_.begin() + static_cast<std::ptrdiff_t>(next));
  const PoseErrors online = compare(estimated, truth);
  EXPECT_LT(online.max_translation, 0.005) << "frame " << online.worst_frame;
  EXPECT_LT(degrees(online.max_rotation), 0.2);
}

TEST_F(SlamSystemInputTest, TrackAfterFinishIsAnError) {
  auto system = makeSystem(camera_);
  ASSERT_TRUE(system);
  const auto first = system->track(frames_[0]);
  ASSERT_TRUE(first.ok()) << first.error();
  system->finish();
  const auto after = system->track(frames_[1]);
  ASSERT_FALSE(after.ok());
  EXPECT_TRUE(contains(after.error(), "finish"));
  EXPECT_EQ(system->trajectory().size(), 1u);  // still readable after finish()
}

TEST_F(SlamSystemInputTest, FramesWithoutDepthDoNotInitialise) {
  auto system = makeSystem(camera_);
  ASSERT_TRUE(system);
  // New matrices, never `depth_m = cv::Mat::zeros(...)`: assigning an
  // expression to a copied header would overwrite the shared fixture frame.
  RgbdInput zero_depth = frames_[0];
  zero_depth.depth_m = cv::Mat(frames_[0].depth_m.size(), CV_32FC1, cv::Scalar(0));
  RgbdInput no_depth = frames_[0];
  no_depth.depth_m = cv::Mat();  // allowed: a frame with no depth image at all
  RgbdInput out_of_range = frames_[0];
  out_of_range.depth_m = cv::Mat(frames_[0].depth_m.size(), CV_32FC1, cv::Scalar(camera_.max_depth + 1));
  for (const RgbdInput* input : {&zero_depth, &no_depth, &out_of_range}) {
    const auto out = system->track(*input);
    ASSERT_TRUE(out.ok()) << out.error();
    EXPECT_EQ(out->state, TrackingState::kInitialising);
    EXPECT_GT(out->features, 0);  // the image itself is fine
    EXPECT_EQ(out->tracked, 0);
    EXPECT_EQ(out->keyframes, 0u);
  }
  // The first frame with depth starts the map at the origin.
  const auto good = system->track(frames_[1]);
  ASSERT_TRUE(good.ok()) << good.error();
  EXPECT_EQ(good->state, TrackingState::kOk);
  EXPECT_TRUE(good->new_keyframe);
  EXPECT_TRUE(good->T_w_c.isApprox(SE3::Identity()));
  system->finish();
  EXPECT_EQ(system->trajectory().size(), 1u);
}

TEST_F(SlamSystemInputTest, IdenticalFramesKeepThePoseStill) {
  auto system = makeSystem(camera_);
  ASSERT_TRUE(system);
  constexpr int kRepeats = 30;
  double max_translation = 0, max_rotation = 0;
  for (int k = 0; k < kRepeats; ++k) {
    RgbdInput input = frames_[0];
    input.stamp = frameStamp(k);
    const auto out = system->track(input);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << k;
    max_translation = std::max(max_translation, out->T_w_c.translation().norm());
    max_rotation = std::max(max_rotation, rotationAngle(out->T_w_c.linear()));
    EXPECT_EQ(out->keyframes, 1u) << "a still camera needs no new keyframe (frame " << k << ")";
  }
  system->finish();
  const auto trajectory = system->trajectory();
  ASSERT_EQ(trajectory.size(), static_cast<std::size_t>(kRepeats));
  for (const TrajectoryPose& p : trajectory) {
    max_translation = std::max(max_translation, p.T_w_c.translation().norm());
    max_rotation = std::max(max_rotation, rotationAngle(p.T_w_c.linear()));
  }
  std::printf("identical frames: pose moved at most %.2e mm, %.2e deg\n", max_translation * 1e3,
              degrees(max_rotation));
  EXPECT_LT(max_translation, 1e-4);
  EXPECT_LT(degrees(max_rotation), 0.005);
}

// A long-running process keeps a bounded number of per-frame poses: the most
// recent N (the same poses an unbounded run reports for those frames), or none.
TEST_F(SlamSystemInputTest, TrajectoryRecordsAreBoundedByTheOption) {
  auto run = [&](int records) {
    SlamOptions options = sequentialOptions();
    options.tracking.trajectory_records = records;
    auto system = makeSystem(camera_, options);
    EXPECT_TRUE(system);
    if (!system) return std::pair<std::vector<TrajectoryPose>, MapStats>{};
    for (const RgbdInput& frame : frames_) {
      const auto out = system->track(frame);
      EXPECT_TRUE(out.ok() && out->state == TrackingState::kOk);
    }
    system->finish();
    return std::pair{system->trajectory(), system->mapStats()};
  };
  const auto [all, all_stats] = run(-1);
  ASSERT_EQ(all.size(), frames_.size());
  EXPECT_EQ(all_stats.trajectory_records, frames_.size());

  const auto [last5, last5_stats] = run(5);
  ASSERT_EQ(last5.size(), 5u);
  EXPECT_EQ(last5_stats.trajectory_records, 5u);
  for (std::size_t k = 0; k < 5; ++k) {
    const TrajectoryPose& expected = all[all.size() - 5 + k];
    EXPECT_EQ(last5[k].stamp, expected.stamp);
    EXPECT_TRUE(last5[k].T_w_c.isApprox(expected.T_w_c, 1e-12)) << "frame " << k;
  }

  const auto [none, none_stats] = run(0);
  EXPECT_TRUE(none.empty());
  EXPECT_EQ(none_stats.trajectory_records, 0u);
  EXPECT_EQ(none_stats.keyframes, all_stats.keyframes) << "tracking does not depend on the records kept";
}

// --- tracking accuracy ----------------------------------------------------

struct TrackingRun {
  std::vector<SE3> online;                 // TrackOutput::T_w_c of each tracked frame
  std::vector<TrajectoryPose> trajectory;  // after finish(), refined by bundle adjustment
  MapStats stats;
  int tracked_frames = 0;
};

// Tracks every frame of `seq`; each must come back kOk.
TrackingRun trackSequence(const Sequence& seq, const SlamOptions& options) {
  TrackingRun run;
  auto system = makeSystem(seq.camera, options);
  if (!system) return run;
  for (std::size_t i = 0; i < seq.frames.size(); ++i) {
    const auto out = system->track(seq.frames[i]);
    EXPECT_TRUE(out.ok()) << out.error();
    if (!out.ok()) continue;
    EXPECT_EQ(out->state, TrackingState::kOk) << "frame " << i << " is " << toString(out->state);
    if (out->state != TrackingState::kOk) continue;
    ++run.tracked_frames;
    run.online.push_back(out->T_w_c);
  }
  system->finish();
  run.trajectory = system->trajectory();
  run.stats = system->mapStats();
  return run;
}

struct Accuracy {
  PoseErrors online, trajectory, frame_to_frame;
};

Accuracy measure(const char* name, const TrackingRun& run, const Sequence& seq) {
  Accuracy a;
  a.online = compare(run.online, seq.T_w_c);
  a.trajectory = compare(posesOf(run.trajectory), seq.T_w_c);
  a.frame_to_frame = compareRelative(posesOf(run.trajectory), seq.T_w_c);
  std::printf("%s: %d of %zu frames tracked, %zu keyframes, %zu points, %d local BAs, path %.2f m\n", name,
              run.tracked_frames, seq.frames.size(), run.stats.keyframes, run.stats.points, run.stats.local_ba_runs,
              pathLength(seq.T_w_c));
  for (const auto& [label, e] : {std::pair<const char*, const PoseErrors&>{"online", a.online},
                                 {"trajectory", a.trajectory},
                                 {"frame to frame", a.frame_to_frame}})
    std::printf("  %-15s max %.2f mm (frame %zu), rms %.2f mm, max %.3f deg\n", label, e.max_translation * 1e3,
                e.worst_frame, e.rms_translation * 1e3, degrees(e.max_rotation));
  return a;
}

TEST(SlamSystemTracking, RoomSequenceFollowsTheTrueMotion) {
  const Sequence seq = roomSequence(60);
  // The motion is large enough that a system which lost scale, sign or
  // rotation would be far outside the bounds below.
  ASSERT_GT(pathLength(seq.T_w_c), 1.0);

  const TrackingRun run = trackSequence(seq, sequentialOptions());
  ASSERT_EQ(run.tracked_frames, static_cast<int>(seq.frames.size()));
  ASSERT_EQ(run.trajectory.size(), seq.frames.size());
  const Accuracy a = measure("room, sequential", run, seq);

  // Mapping was exercised: keyframes were added and bundle-adjusted.
  EXPECT_GE(run.stats.keyframes, 4u);
  EXPECT_GE(run.stats.local_ba_runs, 2);
  // Measured on this scene (VGA): online max 7.5-8.2 mm / 0.21 deg,
  // trajectory max 3.2-3.9 mm / 0.11 deg, rms 2.5 mm, frame to frame max
  // 3.1-3.7 mm / 0.07 deg. The bounds leave about a factor of two.
  EXPECT_LT(a.online.max_translation, 0.015) << "frame " << a.online.worst_frame;
  EXPECT_LT(degrees(a.online.max_rotation), 0.4);
  EXPECT_LT(a.trajectory.max_translation, 0.008) << "frame " << a.trajectory.worst_frame;
  EXPECT_LT(a.trajectory.rms_translation, 0.005);
  EXPECT_LT(degrees(a.trajectory.max_rotation), 0.3);
  EXPECT_LT(a.frame_to_frame.max_translation, 0.007);
  EXPECT_LT(degrees(a.frame_to_frame.max_rotation), 0.15);
}

// keyframes.tracked_ratio sets how far tracking may fall behind the reference
// keyframe before a new one is made: the default (0.6, for accuracy on real
// data) makes keyframes more often than the old 0.4.
TEST(SlamSystemTracking, TrackedRatioSetsHowOftenKeyFramesAreMade) {
  const Sequence seq = roomSequence(40);
  SlamOptions sparse = sequentialOptions();
  sparse.keyframes.tracked_ratio = 0.4;
  const TrackingRun few = trackSequence(seq, sparse);
  const TrackingRun many = trackSequence(seq, sequentialOptions());
  ASSERT_EQ(many.tracked_frames, static_cast<int>(seq.frames.size()));
  std::printf("keyframes over %zu frames: %zu at tracked_ratio 0.4, %zu at the default %.2f\n", seq.frames.size(),
              few.stats.keyframes, many.stats.keyframes, SlamOptions{}.keyframes.tracked_ratio);
  EXPECT_EQ(SlamOptions{}.keyframes.tracked_ratio, 0.6);
  EXPECT_GT(many.stats.keyframes, few.stats.keyframes);
}

// A keyframe's pose in keyframes() is the map's: the trajectory pose of the
// frame it was made from (that frame's reference is the keyframe itself), and
// near the truth (the room test bounds the accuracy; this one the bookkeeping).
TEST(SlamSystemTracking, KeyFramePosesMatchTheTrajectory) {
  const Sequence seq = roomSequence(30);
  auto system = makeSystem(seq.camera);
  ASSERT_TRUE(system);
  for (const RgbdInput& frame : seq.frames) ASSERT_TRUE(system->track(frame).ok());
  system->finish();
  const auto trajectory = system->trajectory();
  const auto keyframes = system->keyframes();
  ASSERT_GE(keyframes.size(), 2u);
  for (const KeyFrameView& kf : keyframes) {
    if (kf.bad) continue;
    const auto at = std::find_if(trajectory.begin(), trajectory.end(),
                                 [&](const TrajectoryPose& p) { return p.stamp == kf.stamp; });
    ASSERT_NE(at, trajectory.end()) << "keyframe " << kf.id;
    EXPECT_LT((at->T_w_c.translation() - kf.T_w_c.translation()).norm(), 1e-9) << "keyframe " << kf.id;
    EXPECT_LT(rotationAngle(at->T_w_c.linear() * kf.T_w_c.linear().transpose()), 1e-9) << "keyframe " << kf.id;
    const std::size_t k = static_cast<std::size_t>(at - trajectory.begin());
    EXPECT_LT((kf.T_w_c.translation() - seq.T_w_c[k].translation()).norm(), 0.03) << "keyframe " << kf.id;
  }
}

// A board in front of the camera moves sideways at 0.45 m/s while the camera
// moves slowly: the geometry module must flag the board's features (and only
// them) and keep the pose on the static room.
struct MovingBoardSequence {
  Sequence seq;
  std::vector<cv::Mat> masks;
};

// The board over the room seen along the slow camera path, shifted by
// offset(k) in frame k.
template <typename Offset>
MovingBoardSequence boardSequence(int n_frames, Offset offset) {
  RoomScene scene(5);
  scene.addMovingBoard(Vec3(-0.9, -0.5, 1.3), 0.6, 0.7, 77);
  MovingBoardSequence out;
  out.seq.camera = RoomScene::camera();
  for (int k = 0; k < n_frames; ++k) {
    const double s = static_cast<double>(k) / 30.0;
    const SE3 T_w_c = pose(Vec3(0.02 * std::sin(2 * s), 0.05 * std::sin(1.5 * s), 0), Vec3(0.15 * s, 0.02 * s, 0.05 * s));
    cv::Mat mask;
    out.seq.T_w_c.push_back(T_w_c);
    out.seq.frames.push_back(scene.render(out.seq.camera, T_w_c, frameStamp(k), offset(k), &mask));
    out.masks.push_back(mask);
  }
  return out;
}

MovingBoardSequence movingBoardSequence(int n_frames) {
  // Still for the first 10 frames (it enters the map), then it moves.
  return boardSequence(n_frames, [](int k) { return Vec3(k < 10 ? 0.0 : 0.015 * (k - 10), 0, 0); });
}

// Judged features against the board's mask, counted from its first moving frame.
struct BoardScore {
  int true_positive = 0, false_positive = 0, false_negative = 0;
  void add(const cv::Mat& mask, const JudgedFeature& f) {
    const bool on_board = mask.at<std::uint8_t>(cvRound(f.v), cvRound(f.u)) != 0;
    true_positive += on_board && f.dynamic;
    false_positive += !on_board && f.dynamic;
    false_negative += on_board && !f.dynamic;
  }
  double precision() const { return true_positive / std::max(1.0, double(true_positive + false_positive)); }
  double recall() const { return true_positive / std::max(1.0, double(true_positive + false_negative)); }
};

// Tracks the board sequence with `options` (every frame must track) and
// scores the judged features from `first_scored` on (by default the board's
// first moving frame).
struct BoardRun {
  BoardScore score;
  PoseErrors errors;  // online poses against the truth
  // Reported features of dynamic clusters over all frames, on and off the
  // board, and of those the ones released (reported static).
  int dynamic_on_board = 0, dynamic_off_board = 0;
  int released_on_board = 0, released_off_board = 0;
  int consensus_frames = 0;  // judged under the consensus pose
};

void runBoard(const MovingBoardSequence& data, const SlamOptions& options, BoardRun* run,
              std::size_t first_scored = 10) {
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  std::vector<SE3> online;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    const auto out = system->track(data.seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    online.push_back(out->T_w_c);
    run->consensus_frames += out->geometry.consensus_pose;
    for (const JudgedFeature& f : out->geometry.judged) {
      if (out->geometry.scores[f.cluster].dynamic) {
        const bool on_board = data.masks[i].at<std::uint8_t>(cvRound(f.v), cvRound(f.u)) != 0;
        ++(on_board ? run->dynamic_on_board : run->dynamic_off_board);
        if (!f.dynamic) ++(on_board ? run->released_on_board : run->released_off_board);
      }
      if (i >= first_scored) run->score.add(data.masks[i], f);
    }
  }
  system->finish();
  run->errors = compare(online, data.seq.T_w_c);
}

// One line per run for the logs: its score, the releases from dynamic
// clusters on and off the board, and the online pose error.
void printRun(const std::string& label, const BoardRun& run) {
  std::printf("%s: precision %.3f recall %.3f, released %d of %d static and %d of %d board features of dynamic "
              "clusters, online rms %.2f mm, max %.2f mm\n",
              label.c_str(), run.score.precision(), run.score.recall(), run.released_off_board, run.dynamic_off_board,
              run.released_on_board, run.dynamic_on_board, run.errors.rms_translation * 1e3,
              run.errors.max_translation * 1e3);
}

// The board stays flagged with the photometric test on: recall and precision
// at least 0.9, and the test frees under 5 % of its features of dynamic
// clusters (chance matches of its alike edges).
void expectBoardKeptFlagged(const BoardRun& run) {
  EXPECT_GE(run.score.recall(), 0.9);
  EXPECT_GE(run.score.precision(), 0.9);
  EXPECT_LT(run.released_on_board, 0.05 * run.dynamic_on_board);
}

TEST(SlamSystemGeometry, MovingBoardIsFlaggedAndKeptOutOfThePose) {
  const MovingBoardSequence data = movingBoardSequence(45);
  const Sequence& seq = data.seq;
  std::vector<SE3> online[2];
  BoardScore score;
  int static_flags_before_motion = 0;
  for (int module = 0; module < 2; ++module) {
    SlamOptions options = sequentialOptions();
    options.geometry.enabled = module == 1;
    auto system = makeSystem(seq.camera, options);
    ASSERT_TRUE(system);
    for (std::size_t i = 0; i < seq.frames.size(); ++i) {
      const auto out = system->track(seq.frames[i]);
      ASSERT_TRUE(out.ok()) << out.error();
      ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
      online[module].push_back(out->T_w_c);
      if (!module) continue;
      EXPECT_EQ(out->geometry.ran, i > 0) << "frame " << i;
      if (i > 0) {
        EXPECT_EQ(out->geometry.clusters, 24);
      }
      for (const JudgedFeature& f : out->geometry.judged) {
        if (i < 10) {
          static_flags_before_motion += f.dynamic;
          continue;
        }
        score.add(data.masks[i], f);
      }
    }
    system->finish();
  }
  const double precision = score.precision(), recall = score.recall();
  const PoseErrors off = compare(online[0], seq.T_w_c), on = compare(online[1], seq.T_w_c);
  std::printf("moving board: precision %.3f recall %.3f (%d/%d/%d), flags while still %d\n", precision, recall,
              score.true_positive, score.false_positive, score.false_negative, static_flags_before_motion);
  std::printf("  online error: module off max %.2f mm rms %.2f mm; on max %.2f mm rms %.2f mm\n",
              off.max_translation * 1e3, off.rms_translation * 1e3, on.max_translation * 1e3,
              on.rms_translation * 1e3);
  EXPECT_GE(recall, 0.9);
  EXPECT_GE(precision, 0.9);
  EXPECT_LT(on.rms_translation, off.rms_translation);
}

// tracking.motion_prior_sigma_m: the board covers few features (8 % of the
// matches) but, 1.3 m away in front of a room 3 m deep, most of what fixes the
// translation; without a prior stage 1 follows its first 15 mm step (20 mm
// error at frame 11, 50 mm at 12 with 3 levels), the module sees only part of
// the motion and flags the room instead (precision 0.87). The motion model's
// prediction as a 2 mm prior holds stage 1 in place.
TEST(SlamSystemGeometry, MotionPriorHoldsStageOneOffTheBoard) {
  SlamOptions options = sequentialOptions();
  options.orb.num_levels = 3;
  options.tracking.motion_prior_sigma_m = 0.002;
  options.tracking.motion_prior_sigma_deg = 1.0;
  BoardRun run;
  ASSERT_NO_FATAL_FAILURE(runBoard(movingBoardSequence(45), options, &run));
  std::printf("moving board, 3 levels, motion prior: precision %.3f recall %.3f, online rms %.2f mm, max %.2f mm\n",
              run.score.precision(), run.score.recall(), run.errors.rms_translation * 1e3,
              run.errors.max_translation * 1e3);
  EXPECT_GE(run.score.recall(), 0.9);
  EXPECT_GE(run.score.precision(), 0.9);
  EXPECT_LT(run.errors.max_translation, 0.01);
}

// geometry.consensus_ratio: a board that starts from rest (0.45 m/s^2, as a
// person sets off) moves a fraction of a pixel a frame at first, and with 3
// levels stage 1 follows it into a compromise under which the board and the
// room both pass the gate; judged under that pose, the module flags the room
// (consensus off: precision 0.65, online rms 23 mm, max 84 mm). Judged under
// the consensus pose of the anchor matches, the board is what disagrees.
TEST(SlamSystemGeometry, ConsensusPoseCatchesABoardStartingFromRest) {
  const MovingBoardSequence data = boardSequence(45, [](int k) {
    const double t = k < 10 ? 0.0 : (k - 10) / 30.0;
    return Vec3(0.5 * 0.45 * t * t, 0, 0);
  });
  BoardRun runs[2];
  for (int consensus = 0; consensus < 2; ++consensus) {
    SlamOptions options = sequentialOptions();
    options.orb.num_levels = 3;
    options.geometry.consensus_ratio = consensus ? 0.9 : 0.0;
    ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &runs[consensus]));
    printRun(consensus ? "board from rest, consensus pose" : "board from rest, initial pose", runs[consensus]);
  }
  const BoardRun& run = runs[1];
  std::printf("  judged under the consensus pose in %d of 44 frames\n", run.consensus_frames);
  EXPECT_EQ(runs[0].consensus_frames, 0);
  EXPECT_GT(run.consensus_frames, 0);
  EXPECT_GE(run.score.precision(), 0.95);
  EXPECT_GE(run.score.recall(), runs[0].score.recall());
  EXPECT_LT(run.errors.rms_translation, 0.01);
  EXPECT_LT(run.errors.rms_translation, 0.5 * runs[0].errors.rms_translation);
  // The scene is one the initial pose fails on.
  EXPECT_LT(runs[0].score.precision(), 0.9);
}

// Free space, the dense evidence: once the board has moved over the anchor
// baseline (5 frames, 7.5 cm), the depth samples along its leading edge lie
// where the anchor frame saw the room behind it. Clusters on the board must
// show that; clusters without any board sample must not (clean depth, a
// tracked pose).
TEST(SlamSystemGeometry, FreeSpaceSeesTheMovingBoard) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  ASSERT_EQ(options.geometry.freespace_flag, 0.2);  // the default: such clusters are dynamic
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  int board_frames = 0, board_seen = 0, static_tested = 0;
  float static_max = 0, board_best_sum = 0;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    const auto out = system->track(data.seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    const GeometryOutput& g = out->geometry;
    if (!g.ran) continue;
    ASSERT_TRUE(g.labels);
    ASSERT_EQ(g.freespace.size(), static_cast<std::size_t>(g.clusters));
    const geometry::DepthClusters& c = *g.labels;
    std::vector<int> on_board(c.clusters, 0), total(c.clusters, 0);
    for (int r = 0; r < c.labels.rows; ++r)
      for (int col = 0; col < c.labels.cols; ++col) {
        const int j = c.labels.at<std::int16_t>(r, col);
        if (j < 0) continue;
        ++total[j];
        on_board[j] += data.masks[i].at<std::uint8_t>(r * c.step + c.step / 2, col * c.step + c.step / 2) != 0;
      }
    float board_best = -1;
    for (int j = 0; j < c.clusters; ++j) {
      if (g.freespace[j] >= 0.2f) {
        EXPECT_TRUE(g.scores[j].dynamic) << "frame " << i << " cluster " << j;
      }
      if (g.freespace[j] < 0) continue;
      if (on_board[j] == 0) {
        static_max = std::max(static_max, g.freespace[j]);
        ++static_tested;
      } else if (2 * on_board[j] > total[j]) {
        board_best = std::max(board_best, g.freespace[j]);
      }
    }
    if (i < 15 || board_best < 0) continue;
    ++board_frames;
    board_seen += board_best >= 0.1f;
    board_best_sum += board_best;
  }
  system->finish();
  std::printf("free space: board clusters best share mean %.3f, >= 0.1 in %d of %d frames; static clusters max %.3f (%d tested)\n",
              board_best_sum / std::max(1, board_frames), board_seen, board_frames, static_max, static_tested);
  ASSERT_GT(board_frames, 20);
  EXPECT_GE(board_seen, board_frames * 9 / 10);
  EXPECT_GT(static_tested, 500);
  EXPECT_LT(static_max, 0.02f);
}

// geometry.freespace_split_keep (off by default): a dynamic cluster is split
// by the surface grown from its free-space violations. The board is one
// surface, so it stays found; a feature is only ever released from a dynamic
// cluster, and never when its own evidence disagrees with the pose.
TEST(SlamSystemGeometry, FreeSpaceSplitKeepsTheBoardAndItsDisagreeingFeatures) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  options.geometry.photo_release_ncc = 0;  // every release counted here is this test's own
  options.geometry.freespace_split_keep = 0.8;
  options.geometry.lone_moving_chi2 = 0;  // every feature outside a dynamic cluster is static (own test)
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  BoardScore score;
  int in_dynamic = 0, released = 0;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    const auto out = system->track(data.seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    for (const JudgedFeature& f : out->geometry.judged) {
      const bool cluster_dynamic = out->geometry.scores[f.cluster].dynamic;
      EXPECT_FALSE(f.dynamic && !cluster_dynamic) << "frame " << i;
      if (cluster_dynamic && !f.dynamic) {
        ++released;
        EXPECT_LE(f.chi2, options.geometry.freespace_split_protect_chi2) << "frame " << i;
      }
      in_dynamic += cluster_dynamic;
      if (i >= 10) score.add(data.masks[i], f);
    }
  }
  system->finish();
  std::printf("moving board, free-space split: precision %.3f recall %.3f, %d of %d features of dynamic clusters released\n",
              score.precision(), score.recall(), released, in_dynamic);
  EXPECT_GT(in_dynamic, 0);
  EXPECT_GE(score.recall(), 0.9);
  EXPECT_GE(score.precision(), 0.9);
}

// geometry.near_anchor_frames and geometry.lone_moving_chi2, on
// by default, each only where it belongs: a feature judged by a nearer anchor
// lies in a cluster with fewer than min_features matches to the frame's
// anchor itself, and a feature flagged outside a dynamic cluster lies in a
// cluster too small to judge, its carried evidence above the limit. The board
// is still found and the room kept.
TEST(SlamSystemGeometry, NearerAnchorsAndLoneFeaturesOnlyWhereTheClusterVerdictCannotReach) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  options.geometry.photo_release_ncc = 0;     // nothing released: every flag is the verdict's or a lone feature's
  options.geometry.freespace_split_keep = 0;  // (both have their own tests)
  const int min_features = options.geometry.verdict.min_features;
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  BoardScore score;
  int nearer = 0, lone = 0;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    const auto out = system->track(data.seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    const GeometryOutput& g = out->geometry;
    int anchor_baseline = 0;  // the anchor frame's (fewer frames back while the history is short)
    for (const JudgedFeature& f : g.judged) anchor_baseline = std::max(anchor_baseline, f.baseline);
    std::vector<int> at_anchor(g.scores.size(), 0), at_nearer(g.scores.size(), 0);
    for (const JudgedFeature& f : g.judged) {
      ASSERT_GE(f.cluster, 0);
      ASSERT_LT(f.cluster, static_cast<int>(g.scores.size()));
      if (f.evidence == JudgedFeature::Evidence::kAnchor) {
        EXPECT_GE(f.baseline, 1) << "frame " << i;
        EXPECT_LE(f.baseline, options.geometry.anchor_frames) << "frame " << i;
        ++(f.baseline == anchor_baseline ? at_anchor : at_nearer)[f.cluster];
      } else {
        EXPECT_EQ(f.baseline, 0) << "frame " << i;
      }
      const geometry::ClusterScore& c = g.scores[f.cluster];
      if (f.dynamic && !c.dynamic) {
        ++lone;
        EXPECT_FALSE(c.judged) << "frame " << i;
        EXPECT_EQ(f.evidence, JudgedFeature::Evidence::kCarried) << "frame " << i;
        EXPECT_TRUE(f.inherited) << "frame " << i;
        EXPECT_GT(f.chi2, options.geometry.lone_moving_chi2) << "frame " << i;
      }
      if (i >= 10) score.add(data.masks[i], f);
    }
    for (std::size_t c = 0; c < g.scores.size(); ++c) {
      if (at_nearer[c] == 0) continue;
      nearer += at_nearer[c];
      EXPECT_LT(at_anchor[c], min_features) << "frame " << i << " cluster " << c;
      EXPECT_GE(at_anchor[c] + at_nearer[c], min_features) << "frame " << i << " cluster " << c;
    }
  }
  system->finish();
  std::printf("moving board, nearer anchors and lone features: precision %.3f recall %.3f, %d features judged by "
              "a nearer anchor, %d lone features flagged\n",
              score.precision(), score.recall(), nearer, lone);
  EXPECT_GT(nearer, 0);  // both were exercised
  EXPECT_GT(lone, 0);
  EXPECT_GE(score.recall(), 0.9);
  EXPECT_GE(score.precision(), 0.9);
}

// Evidence that geometry.static_match_margin sets aside (another copy of the
// pattern explains the feature as static) stays out of the verdict, but the
// feature is still reported with its outcome, so that a score counts it:
// every matched feature of the frame is scored, not only those the verdict used.
TEST(SlamSystemGeometry, SetAsideEvidenceIsStillReported) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  options.geometry.photo_release_ncc = 0;  // every release counted here is this test's own
  options.geometry.static_match_margin = 40;  // wide, so that the board's texture sets some aside
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  int set_aside = 0, set_aside_dynamic = 0;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    const auto out = system->track(data.seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    for (const JudgedFeature& f : out->geometry.judged) {
      if (!f.explained) continue;
      ++set_aside;
      set_aside_dynamic += f.dynamic;
      EXPECT_GT(f.chi2, options.geometry.verdict.rho_cap) << "frame " << i;  // only disagreeing evidence
      ASSERT_GE(f.cluster, 0);
      // Its outcome is its cluster's: nothing releases it.
      EXPECT_EQ(f.dynamic, out->geometry.scores[f.cluster].dynamic) << "frame " << i;
    }
  }
  system->finish();
  std::printf("moving board, static_match_margin 40: %d features set aside, %d of them dynamic\n", set_aside,
              set_aside_dynamic);
  EXPECT_GT(set_aside, 0);
}

// geometry.photo_release_ncc (on by default): the static hypothesis tested on
// pixels frees features of dynamic clusters. On the board scene, whose
// texture of colour blocks is all alike edges, it must leave the board
// flagged and the pose on the room.
TEST(SlamSystemGeometry, PhotometricReleaseKeepsTheBoardFlagged) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  ASSERT_GT(options.geometry.photo_release_ncc, 0);
  BoardRun run;
  ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run));
  printRun("moving board, photometric release", run);
  expectBoardKeptFlagged(run);
}

// The photometric test is judged under the pose fitted without the dynamic
// clusters. Judged under the initial pose it confirmed a mover stage 1 had
// followed: with 3 levels (stage 1 half follows the board's first steps,
// MotionPriorHoldsStageOneOffTheBoard) and anchored features free to go, it
// freed board features and the pose stepped 20 mm. The consensus pose is off
// here: it judges the board's first step (frame 11) under a pose that did not
// follow it, which flags 12 more board features there, and the release test
// frees 11 of them (the board moves along its blocks' edges, where a patch
// looks the same); the run otherwise is identical (recall 0.923 against
// 0.922, the same poses), but 70 of 1278 board features freed against 59 of
// 1266 would fail the 5 % bound below, which is about a pose that followed
// the board, the case this test builds.
TEST(SlamSystemGeometry, PhotometricReleaseDoesNotConfirmAPoseThatFollowedTheBoard) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  options.orb.num_levels = 3;
  options.tracking.motion_prior_sigma_m = 0.002;
  options.tracking.motion_prior_sigma_deg = 1.0;
  options.geometry.photo_release_ncc = 0.6;
  options.geometry.photo_release_anchored = true;
  options.geometry.photo_frames_back = 5;  // the frames it was seen failing with
  options.geometry.photo_frames = 2;
  options.geometry.photo_fallback = false;
  options.geometry.consensus_ratio = 0;
  BoardRun run;
  ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run));
  printRun("moving board, 3 levels, photometric release of anchored features too", run);
  expectBoardKeptFlagged(run);
  EXPECT_LT(run.errors.max_translation, 0.01);
}

// A board sliding 10 cm in front of the back wall shares its clusters with the
// wall: the wall's features there are dropped with them. The photometric test
// frees most of those (their pixels match at the static hypothesis) and
// almost none of the board's; the few it frees (about 2 %: where the board's
// texture matched by chance in both frames) may cost that much recall.
TEST(SlamSystemGeometry, PhotometricReleaseFreesTheWallBehindABoard) {
  RoomScene scene(5);
  scene.addMovingBoard(Vec3(-0.9, -0.6, 2.9), 0.8, 0.8, 77);
  MovingBoardSequence data;
  data.seq.camera = RoomScene::camera();
  for (int k = 0; k < 45; ++k) {
    const double s = static_cast<double>(k) / 30.0;
    const SE3 T_w_c = pose(Vec3(0.02 * std::sin(2 * s), 0.05 * std::sin(1.5 * s), 0), Vec3(0.15 * s, 0.02 * s, 0.05 * s));
    cv::Mat mask;
    data.seq.T_w_c.push_back(T_w_c);
    data.seq.frames.push_back(
        scene.render(data.seq.camera, T_w_c, frameStamp(k), Vec3(k < 10 ? 0.0 : 0.015 * (k - 10), 0, 0), &mask));
    data.masks.push_back(mask);
  }
  BoardRun run[2];
  for (int photo = 0; photo < 2; ++photo) {
    SlamOptions options = sequentialOptions();
    options.geometry.photo_release_ncc = photo ? 0.6 : 0.0;
    options.geometry.photo_release_anchored = true;
    ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run[photo]));
    printRun(std::string("board at the wall, photometric release ") + (photo ? "on" : "off"), run[photo]);
  }
  EXPECT_GE(run[1].score.recall(), run[0].score.recall() - 0.03);
  EXPECT_GT(run[1].score.precision(), run[0].score.precision());
  EXPECT_LT(run[1].errors.rms_translation, run[0].errors.rms_translation);
  EXPECT_GT(run[1].released_off_board, run[0].released_off_board + run[1].dynamic_off_board / 3);
  EXPECT_LT(run[1].released_on_board, 0.05 * run[1].dynamic_on_board);
}

// The same loop from the other side: a verdict that flags most of the room
// (floor 0.5, factor 1) and no anchor matches. Judged under the initial pose,
// the test freed the board, the pose followed it and recall fell to 0.03.
// Under the pose fitted without the dynamic clusters, and only while that
// pose rests on most of the view (geometry.max_dynamic_fraction), it frees
// the room, far more of it than of the board, and the pose is better for it
// (measured: max error 339 -> 211 mm, recall 0.74 -> 0.81; without the
// fraction check the pose once followed the board again, 862 mm). The lone
// features (geometry.lone_moving_chi2) are off in both runs, so that the
// release is the only difference: with them on, the release-off run is
// already near the board's truth (recall 0.948, rms 55 mm, max 116 mm), and
// the release lowers the rms to 32 mm but not the max (126 mm).
TEST(SlamSystemGeometry, PhotometricReleaseHoldsUnderAVerdictThatFlagsTheRoom) {
  const MovingBoardSequence data = movingBoardSequence(45);
  BoardRun run[2];
  for (int photo = 0; photo < 2; ++photo) {
    SlamOptions options = sequentialOptions();
    options.geometry.verdict.absolute_floor = 0.5;
    options.geometry.verdict.relative_factor = 1.0;
    options.geometry.anchor_frames = 0;
    options.geometry.lone_moving_chi2 = 0;
    options.geometry.photo_release_ncc = photo ? 0.6 : 0.0;
    ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run[photo]));
    printRun(std::string("moving board, eager verdict, no anchors, photometric release ") + (photo ? "on" : "off"),
             run[photo]);
  }
  EXPECT_GT(run[1].score.recall(), run[0].score.recall());
  EXPECT_GT(run[1].score.precision(), run[0].score.precision());
  EXPECT_LT(run[1].released_on_board, 0.1 * run[1].released_off_board);
  EXPECT_LT(run[1].errors.max_translation, run[0].errors.max_translation);
}

// geometry.evidence_ratio: ambiguous projection matches are not judged (every
// reported non-anchor feature passed the ratio), and the board is still found.
TEST(SlamSystemGeometry, RatioTestedEvidenceKeepsTheBoardFlagged) {
  const MovingBoardSequence data = movingBoardSequence(45);
  const Sequence& seq = data.seq;
  SlamOptions options = sequentialOptions();
  options.geometry.evidence_ratio = 0.9;
  auto system = makeSystem(seq.camera, options);
  ASSERT_TRUE(system);
  BoardScore score;
  int ratio_reported = 0;
  std::vector<SE3> online;
  for (std::size_t i = 0; i < seq.frames.size(); ++i) {
    const auto out = system->track(seq.frames[i]);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    online.push_back(out->T_w_c);
    for (const JudgedFeature& f : out->geometry.judged) {
      if (f.evidence != JudgedFeature::Evidence::kAnchor) {
        EXPECT_LE(f.ratio, 0.9f) << "frame " << i;
        ratio_reported += f.ratio > 0;
      }
      if (i < 10) continue;
      score.add(data.masks[i], f);
    }
  }
  system->finish();
  const double precision = score.precision(), recall = score.recall();
  const PoseErrors on = compare(online, seq.T_w_c);
  std::printf("moving board, ratio-tested evidence: precision %.3f recall %.3f (%d/%d/%d), rms %.2f mm\n", precision,
              recall, score.true_positive, score.false_positive, score.false_negative, on.rms_translation * 1e3);
  EXPECT_GT(ratio_reported, 0);  // the motion model's matches carry their ratio
  EXPECT_GE(recall, 0.9);
  EXPECT_GE(precision, 0.9);
  EXPECT_LT(on.rms_translation, 0.01);
}

// geometry.evidence_depth_max_m: real sensors' far depth is off by decimetres
// to a metre from frame to frame (the real excerpt's background at 5 m), and
// as evidence that flagged static clusters. Here the room's back wall (3 m)
// gets such noise, fresh in every frame, in 16 px blocks: with the limit below
// it, the wall's features are judged by the image alone and stay static. Free
// space is off: the noise also puts wall samples in front of where the anchor
// saw the wall, which is the free-space test's tolerance, not this rule.
TEST(SlamSystemGeometry, FarDepthNoiseIsNoEvidence) {
  MovingBoardSequence data = boardSequence(40, [](int) { return Vec3::Zero(); });
  cv::RNG rng(11);
  for (RgbdInput& frame : data.seq.frames) {
    cv::Mat noise(frame.depth_m.rows / 16, frame.depth_m.cols / 16, CV_32F);
    rng.fill(noise, cv::RNG::UNIFORM, -1.0, 1.0);
    cv::resize(noise, noise, frame.depth_m.size(), 0, 0, cv::INTER_NEAREST);
    cv::Mat far = frame.depth_m > 2.6;
    cv::add(frame.depth_m, noise, frame.depth_m, far);
  }
  int far_judged[2] = {0, 0}, far_flagged[2] = {0, 0};
  for (int limited = 0; limited < 2; ++limited) {
    SlamOptions options = sequentialOptions();
    options.geometry.freespace_flag = 0;
    options.geometry.freespace_split_keep = 0;
    options.geometry.evidence_depth_max_m = limited ? 2.5 : 0.0;
    auto system = makeSystem(data.seq.camera, options);
    ASSERT_TRUE(system);
    for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
      const auto out = system->track(data.seq.frames[i]);
      ASSERT_TRUE(out.ok()) << out.error();
      ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
      for (const JudgedFeature& f : out->geometry.judged) {
        if (f.depth < 2.6f) continue;
        ++far_judged[limited];
        far_flagged[limited] += f.dynamic;
      }
    }
    system->finish();
  }
  const double share_off = far_flagged[0] / std::max(1.0, double(far_judged[0]));
  const double share_on = far_flagged[1] / std::max(1.0, double(far_judged[1]));
  std::printf("noisy far wall: flagged %d/%d without the limit (%.3f), %d/%d with it (%.3f)\n", far_flagged[0],
              far_judged[0], share_off, far_flagged[1], far_judged[1], share_on);
  ASSERT_GT(far_judged[1], 500);
  EXPECT_GT(share_off, 0.1);  // the noise is evidence enough to flag without the limit
  EXPECT_LT(share_on, 0.02);
}

// A board that appears in front of the wall at frame 10 (before it is hidden
// behind the wall) and starts to move at once, eased: slower than the
// evidence noise at first, so keyframes map it as new ground before it is
// flagged (the poster-walk overlay's failure, docs/dynamic-objects.md).
MovingBoardSequence appearingBoardSequence(int n_frames) {
  return boardSequence(n_frames, [](int k) {
    const double t = std::clamp((k - 10) / 40.0, 0.0, 1.0);  // 0.4 m over 40 frames
    return k < 10 ? Vec3(0, 0, 50) : Vec3(0.2 * (1 - std::cos(M_PI * t)), 0, 0);
  });
}

// geometry.probation_frames: map points made by keyframes stay out of the
// pose fits until they have been matched consistently with a pose fitted
// without them. The board mapped while it went unflagged pulls the pose less
// (online rms 4.15 mm against 4.53 mm without), tracking never fails although
// every new point waits, and the board is still found.
TEST(SlamSystemGeometry, ProbationKeepsAnAppearingBoardOutOfThePose) {
  const MovingBoardSequence data = appearingBoardSequence(55);
  BoardRun runs[2];
  for (int probation = 0; probation < 2; ++probation) {
    SlamOptions options = sequentialOptions();
    options.geometry.probation_frames = probation ? 3 : 0;
    BoardRun& run = runs[probation];
    ASSERT_NO_FATAL_FAILURE(runBoard(data, options, &run, 0));
    std::printf("appearing board, probation %d: precision %.3f recall %.3f (%d/%d/%d), max %.2f mm rms %.2f mm\n",
                probation ? 3 : 0, run.score.precision(), run.score.recall(), run.score.true_positive,
                run.score.false_positive, run.score.false_negative, run.errors.max_translation * 1e3,
                run.errors.rms_translation * 1e3);
  }
  EXPECT_GE(runs[1].score.precision(), 0.95);
  EXPECT_GE(runs[1].score.recall(), 0.8);
  EXPECT_LT(runs[1].errors.rms_translation, runs[0].errors.rms_translation);
  EXPECT_LT(runs[1].errors.rms_translation, 0.005);
}

// Tracks the board sequence with `options`, frame i given movers(i) as its
// known movers (an empty mask: none); every frame must track. Returns the
// online poses' errors and the keyframes.
void trackBoardWithMovers(const MovingBoardSequence& data, const SlamOptions& options,
                          const std::function<cv::Mat(std::size_t)>& movers, PoseErrors* errors,
                          std::vector<KeyFrameView>* keyframes) {
  auto system = makeSystem(data.seq.camera, options);
  ASSERT_TRUE(system);
  std::vector<SE3> online;
  for (std::size_t i = 0; i < data.seq.frames.size(); ++i) {
    RgbdInput input = data.seq.frames[i];
    input.movers = movers(i);
    const auto out = system->track(input);
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_EQ(out->state, TrackingState::kOk) << "frame " << i;
    online.push_back(out->T_w_c);
  }
  system->finish();
  *errors = compare(online, data.seq.T_w_c);
  *keyframes = system->keyframes();
}

// The index of the frame a keyframe was made from.
std::size_t frameOf(const MovingBoardSequence& data, const KeyFrameView& kf) {
  const auto it = std::find_if(data.seq.frames.begin(), data.seq.frames.end(),
                               [&](const RgbdInput& f) { return f.stamp == kf.stamp; });
  return static_cast<std::size_t>(it - data.seq.frames.begin());
}

// Known movers (RgbdInput::movers, e.g. a detector in another process): with
// the dynamic-object modules off, the board's own masks keep its features
// out of the pose and out of the map, 8-bit and 16-bit masks alike.
TEST(SlamSystemKnownMovers, MasksKeepTheBoardOutOfThePoseAndTheMap) {
  const MovingBoardSequence data = movingBoardSequence(45);
  SlamOptions options = sequentialOptions();
  options.geometry.enabled = false;
  PoseErrors errors[3];
  for (int run = 0; run < 3; ++run) {  // 0: no masks, 1: 8-bit masks, 2: 16-bit masks
    std::vector<KeyFrameView> keyframes;
    const auto movers = [&](std::size_t i) {
      cv::Mat m;
      if (run == 1) m = data.masks[i];
      if (run == 2) data.masks[i].convertTo(m, CV_16U, 300);
      return m;
    };
    ASSERT_NO_FATAL_FAILURE(trackBoardWithMovers(data, options, movers, &errors[run], &keyframes));
    std::printf("moving board, geometry module off, %s: online rms %.2f mm, max %.2f mm\n",
                run == 0 ? "no masks" : run == 1 ? "8-bit masks" : "16-bit masks", errors[run].rms_translation * 1e3,
                errors[run].max_translation * 1e3);
    if (run == 0) continue;
    // No keyframe holds a map point inside its frame's mask.
    int inside = 0, mapped_inside = 0;
    for (const KeyFrameView& kf : keyframes) {
      if (kf.bad) continue;
      const std::size_t k = frameOf(data, kf);
      ASSERT_LT(k, data.masks.size());
      for (const KeyFrameFeature& f : kf.features) {
        if (!data.masks[k].at<std::uint8_t>(cvRound(f.v), cvRound(f.u))) continue;
        ++inside;
        mapped_inside += f.mapped;
      }
    }
    EXPECT_GT(inside, 0);
    EXPECT_EQ(mapped_inside, 0);
  }
  // Without masks the pose follows the board (rms 181 mm); with them it stays
  // on the room (rms 3.1 mm, max 4.8 mm).
  EXPECT_LT(errors[1].rms_translation, errors[0].rms_translation);
  EXPECT_LT(errors[1].rms_translation, 0.005);
  EXPECT_LT(errors[1].max_translation, 0.01);
  EXPECT_NEAR(errors[2].rms_translation, errors[1].rms_translation, 1e-9);
}

// Once the board's features are known to move, later frames spend less of the
// feature budget on it and more on the room (tracking.mover_cells_*), and the
// room is still tracked as well. The board holds 6-10 % of the features: under
// a minimum share of 20 % it keeps them all.
TEST(SlamSystemKnownMovers, MoversGetLessOfTheFeatureBudget) {
  const MovingBoardSequence data = movingBoardSequence(30);
  SlamOptions options = sequentialOptions();
  options.geometry.enabled = false;
  options.mapping.keep_culled_keyframes = true;
  constexpr int kRuns = 3;  // every cell alike; movers 4x sparser from a share of 20 %; ... of any share
  int inside[kRuns] = {}, outside[kRuns] = {};
  PoseErrors errors[kRuns];
  for (int run = 0; run < kRuns; ++run) {
    options.tracking.mover_cells_every = run == 0 ? 1 : 4;
    options.tracking.mover_cells_min_share = run == 2 ? 0.0 : 0.2;
    std::vector<KeyFrameView> keyframes;
    ASSERT_NO_FATAL_FAILURE(trackBoardWithMovers(
        data, options, [&](std::size_t i) { return data.masks[i]; }, &errors[run], &keyframes));
    for (const KeyFrameView& kf : keyframes) {
      const std::size_t k = frameOf(data, kf);
      ASSERT_LT(k, data.masks.size());
      if (k <= 10) continue;  // the board starts moving (and so masked) in frame 10
      for (const KeyFrameFeature& f : kf.features)
        (data.masks[k].at<std::uint8_t>(cvRound(f.v), cvRound(f.u)) ? inside : outside)[run]++;
    }
    std::printf("mover_cells_every %d, min share %.2f: keyframe features on the board %d, off it %d; online rms "
                "%.2f mm\n",
                options.tracking.mover_cells_every, options.tracking.mover_cells_min_share, inside[run], outside[run],
                errors[run].rms_translation * 1e3);
  }
  ASSERT_GT(inside[0], 0);
  EXPECT_EQ(inside[1], inside[0]);
  EXPECT_EQ(outside[1], outside[0]);
  // Keyframes may differ in number: compare the board's share of their features.
  const auto share = [&](int run) { return double(inside[run]) / std::max(1, inside[run] + outside[run]); };
  EXPECT_LT(share(2), 0.5 * share(0));
  EXPECT_LT(errors[2].rms_translation, 0.005);
}

// The sequence other modules' tests use, read back through TumDataset (the
// replay path: colour PNG to grey, 16-bit depth to metres). One
// fronto-parallel plane is a weak scene: a small tilt and a sideways shift
// look alike, so it is held to a looser bound than the room.
TEST(SlamSystemTracking, DatasetWriterSequenceIsTracked) {
  const fs::path dir = fs::temp_directory_path() / ("stillpoint_system_test_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  dataset::testing::SyntheticDatasetOptions options;
  options.n_frames = 40;
  options.width = 640;
  options.height = 480;
  options.lateral_velocity_m_s = Vec2(0.3, 0.1);
  const auto written = dataset::testing::writeSyntheticTumDataset(dir.string(), options);
  ASSERT_TRUE(written.ok()) << written.error();
  const auto tum = dataset::TumDataset::open(dir.string());
  ASSERT_TRUE(tum.ok()) << tum.error();
  ASSERT_EQ(tum->size(), written->T_w_c.size());
  Sequence seq;
  seq.camera = written->camera;
  seq.T_w_c = written->T_w_c;
  for (std::size_t i = 0; i < tum->size(); ++i) {
    const auto frame = tum->load(i);
    ASSERT_TRUE(frame.ok()) << frame.error();
    seq.frames.push_back({frame->stamp, frame->gray, frame->depth_m});
  }
  fs::remove_all(dir);
  ASSERT_GT(pathLength(seq.T_w_c), 0.3);

  const TrackingRun run = trackSequence(seq, sequentialOptions());
  ASSERT_EQ(run.tracked_frames, static_cast<int>(seq.frames.size()));
  ASSERT_EQ(run.trajectory.size(), seq.frames.size());
  const Accuracy a = measure("dataset writer plane, sequential", run, seq);
  EXPECT_LT(a.online.max_translation, 0.01) << "frame " << a.online.worst_frame;
  EXPECT_LT(a.trajectory.max_translation, 0.01) << "frame " << a.trajectory.worst_frame;
  EXPECT_LT(degrees(a.trajectory.max_rotation), 0.3);
}

}  // namespace
}  // namespace stillpoint::slam

