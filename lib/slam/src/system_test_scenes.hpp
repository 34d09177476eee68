#pragma once
// Synthetic scenes and run helpers shared by the SlamSystem tests: a ray-cast
// textured room, a moving board in it, pose comparisons, and board runs
// scored against the board's mask.
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

namespace fs = std::filesystem;

using testing::contains;

inline double degrees(double radians) { return radians * 180.0 / M_PI; }

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

inline SE3 pose(const Vec3& rotation, const Vec3& translation) {
  SE3 T = SE3::Identity();
  T.linear() = expSO3(rotation);
  T.translation() = translation;
  return T;
}

inline Timestamp frameStamp(int k) { return Timestamp::fromNanoseconds(1'000'000'000LL + k * 33'333'333LL); }

// A smooth hand-held-like path through the room at 30 Hz: in 60 frames about
// 1.5 m of travel and up to 14 degrees of rotation, up to 2.8 cm per frame.
inline SE3 roomPath(int k) {
  const double s = static_cast<double>(k) / 15.0;  // path time runs at twice the frame clock
  const Vec3 rotation(0.08 * std::sin(1.3 * s), 0.25 * std::sin(0.9 * s), 0.06 * std::sin(0.7 * s));
  const Vec3 translation(0.5 * std::sin(0.8 * s), 0.1 * std::sin(1.1 * s), 0.4 * (1 - std::cos(0.9 * s)));
  return pose(rotation, translation);
}

// The room seen along roomPath.
inline Sequence roomSequence(int n_frames) {
  const RoomScene scene(5);
  Sequence out;
  out.camera = RoomScene::camera();
  for (int k = 0; k < n_frames; ++k) {
    const SE3 T_w_c = roomPath(k);
    out.T_w_c.push_back(T_w_c);
    out.frames.push_back(scene.render(out.camera, T_w_c, frameStamp(k)));
  }
  return out;
}

inline SlamOptions sequentialOptions() {
  SlamOptions o;
  o.sequential = true;
  o.geometry.report_features = true;  // the tests score the judged features
  return o;
}

inline std::unique_ptr<SlamSystem> makeSystem(const CameraModel& camera, const SlamOptions& options = sequentialOptions()) {
  auto system = SlamSystem::create(camera, options);
  EXPECT_TRUE(system.ok()) << system.error();
  return system.ok() ? std::move(*system) : nullptr;
}

// Worst and RMS errors of estimated poses against the truth.
struct PoseErrors {
  double max_translation = 0, rms_translation = 0, max_rotation = 0;  // m, m, rad
  std::size_t worst_frame = 0;
};

inline PoseErrors compare(const std::vector<SE3>& estimated, const std::vector<SE3>& truth) {
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
inline PoseErrors compareRelative(const std::vector<SE3>& estimated, const std::vector<SE3>& truth) {
  std::vector<SE3> est_rel, true_rel;
  for (std::size_t i = 1; i < estimated.size() && i < truth.size(); ++i) {
    est_rel.push_back(estimated[i - 1].inverse() * estimated[i]);
    true_rel.push_back(truth[i - 1].inverse() * truth[i]);
  }
  return compare(est_rel, true_rel);
}

inline std::vector<SE3> posesOf(const std::vector<TrajectoryPose>& trajectory) {
  std::vector<SE3> poses;
  for (const TrajectoryPose& p : trajectory) poses.push_back(p.T_w_c);
  return poses;
}

inline double pathLength(const std::vector<SE3>& poses) {
  double length = 0;
  for (std::size_t i = 1; i < poses.size(); ++i)
    length += (poses[i].translation() - poses[i - 1].translation()).norm();
  return length;
}

// --- creation -------------------------------------------------------------

// --- tracking accuracy ----------------------------------------------------

struct TrackingRun {
  std::vector<SE3> online;                 // TrackOutput::T_w_c of each tracked frame
  std::vector<TrajectoryPose> trajectory;  // after finish(), refined by bundle adjustment
  MapStats stats;
  int tracked_frames = 0;
};

// Tracks every frame of `seq`; each must come back kOk.
inline TrackingRun trackSequence(const Sequence& seq, const SlamOptions& options) {
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

inline Accuracy measure(const char* name, const TrackingRun& run, const Sequence& seq) {
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
inline MovingBoardSequence boardSequence(int n_frames, Offset offset) {
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

inline MovingBoardSequence movingBoardSequence(int n_frames) {
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

inline void runBoard(const MovingBoardSequence& data, const SlamOptions& options, BoardRun* run,
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
inline void printRun(const std::string& label, const BoardRun& run) {
  std::printf("%s: precision %.3f recall %.3f, released %d of %d static and %d of %d board features of dynamic "
              "clusters, online rms %.2f mm, max %.2f mm\n",
              label.c_str(), run.score.precision(), run.score.recall(), run.released_off_board, run.dynamic_off_board,
              run.released_on_board, run.dynamic_on_board, run.errors.rms_translation * 1e3,
              run.errors.max_translation * 1e3);
}

// The board stays flagged with the photometric test on: recall and precision
// at least 0.9, and the test frees under 5 % of its features of dynamic
// clusters (chance matches of its alike edges).
inline void expectBoardKeptFlagged(const BoardRun& run) {
  EXPECT_GE(run.score.recall(), 0.9);
  EXPECT_GE(run.score.precision(), 0.9);
  EXPECT_LT(run.released_on_board, 0.05 * run.dynamic_on_board);
}

// A board that appears in front of the wall at frame 10 (before it is hidden
// behind the wall) and starts to move at once, eased: slower than the
// evidence noise at first, so keyframes map it as new ground before it is
// flagged (the poster-walk overlay's failure, docs/dynamic-objects.md).
inline MovingBoardSequence appearingBoardSequence(int n_frames) {
  return boardSequence(n_frames, [](int k) {
    const double t = std::clamp((k - 10) / 40.0, 0.0, 1.0);  // 0.4 m over 40 frames
    return k < 10 ? Vec3(0, 0, 50) : Vec3(0.2 * (1 - std::cos(M_PI * t)), 0, 0);
  });
}
// The index of the frame a keyframe was made from.
inline std::size_t frameOf(const MovingBoardSequence& data, const KeyFrameView& kf) {
  const auto it = std::find_if(data.seq.frames.begin(), data.seq.frames.end(),
                               [&](const RgbdInput& f) { return f.stamp == kf.stamp; });
  return static_cast<std::size_t>(it - data.seq.frames.begin());
}

}  // namespace stillpoint::slam
