// Pose-only optimisation (our LM against the Ceres reference) and local
// bundle adjustment on synthetic problems shaped like a real RGB-D frame:
// 30 % outliers, two thirds of the observations with depth, features spread
// over the pyramid levels, and a start as far off as a poor motion model.
#include <benchmark/benchmark.h>

#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include "optimizer.hpp"

namespace stillpoint::slam {
namespace {

constexpr int kLevels = 8;
constexpr double kScaleFactor = 1.2;

const CameraModel& benchmarkCamera() {
  static const CameraModel camera = *cameraPreset("fr3");
  return camera;
}

const LevelInfo& benchmarkLevels() {
  static const LevelInfo levels = [] {
    LevelInfo lv;
    lv.levels = kLevels;
    lv.scale_factor = kScaleFactor;
    lv.log_scale_factor = std::log(kScaleFactor);
    for (int l = 0; l < kLevels; ++l) {
      lv.scales.push_back(std::pow(kScaleFactor, l));
      lv.sigma2.push_back(lv.scales.back() * lv.scales.back());
      lv.inv_sigma2.push_back(1.0 / lv.sigma2.back());
    }
    return lv;
  }();
  return levels;
}

SE3 pose(const Vec3& rotation, const Vec3& translation) {
  SE3 T = SE3::Identity();
  T.linear() = expSO3(rotation);
  T.translation() = translation;
  return T;
}

// Pyramid levels as ORB assigns them: geometrically fewer features per level.
std::discrete_distribution<int> levelDistribution() {
  std::vector<double> weights;
  for (int l = 0; l < kLevels; ++l) weights.push_back(std::pow(1 / kScaleFactor, l));
  return std::discrete_distribution<int>(weights.begin(), weights.end());
}

struct PoseBenchmarkProblem {
  PoseProblem problem;
  SE3 initial, truth;  // T_c_w
};

PoseBenchmarkProblem makePoseProblem(int observations, std::uint32_t seed) {
  std::mt19937 rng(seed);
  const CameraModel& cam = benchmarkCamera();
  const SE3 T_true = pose(Vec3(0.05, -0.1, 0.02), Vec3(0.1, -0.05, 0.2));
  const SE3 T_w_true = T_true.inverse();
  std::uniform_real_distribution<double> u_any(0, cam.width), v_any(0, cam.height), depth(0.8, 4.5),
      unit(0, 1);
  std::normal_distribution<double> pixel_noise(0.0, 1.0);
  std::discrete_distribution<int> level = levelDistribution();
  PoseBenchmarkProblem out;
  out.problem.camera = &cam;
  while (static_cast<int>(out.problem.points_w.size()) < observations) {
    // A point seen at a random pixel and depth, so every point projects inside the image.
    const Vec2 uv(u_any(rng), v_any(rng));
    const double z = depth(rng);
    const Vec3 p_w = T_w_true * cam.unproject(uv, z);
    const double scale = std::pow(kScaleFactor, level(rng));
    const bool outlier = unit(rng) < 0.3;
    Observation o;
    o.inv_sigma = 1 / scale;
    o.u = outlier ? u_any(rng) : uv.x() + scale * pixel_noise(rng);
    o.v = outlier ? v_any(rng) : uv.y() + scale * pixel_noise(rng);
    if (out.problem.points_w.size() % 3 != 0) {
      const double z_measured = outlier ? depth(rng) : z * (1 + 0.01 * pixel_noise(rng));
      o.u_right = o.u - cam.bf() / z_measured;
    }
    out.problem.points_w.push_back(p_w);
    out.problem.observations.push_back(o);
  }
  out.truth = T_true;
  // About 3 degrees and 10 cm from the truth.
  out.initial = pose(Vec3(0.02, -0.05, 0.0), Vec3(0.05, -0.07, 0.14));
  return out;
}

template <PoseResult (*Optimise)(const PoseProblem&, const SE3&, int)>
void poseOptimisation(benchmark::State& state) {
  const PoseBenchmarkProblem p = makePoseProblem(static_cast<int>(state.range(0)), 7);
  PoseResult result;
  for (auto _ : state) {
    result = Optimise(p.problem, p.initial, 4);
    benchmark::DoNotOptimize(result.T_c_w.data());
  }
  state.counters["inliers"] = result.inliers;
  state.counters["error_mm"] = 1e3 * (result.T_c_w.translation() - p.truth.translation()).norm();
}

void BM_PoseOptimisation(benchmark::State& state) { poseOptimisation<optimizePose>(state); }
void BM_PoseOptimisationCeres(benchmark::State& state) { poseOptimisation<optimizePoseCeres>(state); }
BENCHMARK(BM_PoseOptimisation)->Arg(300)->Arg(600)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_PoseOptimisationCeres)->Arg(300)->Arg(600)->Unit(benchmark::kMillisecond);

// A map of keyframes along a sideways walk past a 3D point cloud; every
// keyframe observes the points that project into it (about 800 each). Poses
// and points start perturbed, and 3 % of the observations are outliers.
struct BaMap {
  Map map;
  std::vector<KeyFrame*> keyframes;
};

// `observe`: the share of the points in view a keyframe observes (a running
// map's keyframes see a few hundred points each, not all in view); `turn`
// and `climb`: radians and metres the camera turns and rises from one
// keyframe to the next.
std::unique_ptr<BaMap> makeBaMap(int n_keyframes, int n_points, std::uint32_t seed, double observe = 1.0,
                                 double turn = 0.02, double climb = 0.01) {
  std::mt19937 rng(seed);
  const CameraModel& cam = benchmarkCamera();
  const LevelInfo& levels = benchmarkLevels();
  std::uniform_real_distribution<double> x(-2.5, 2.5 + 0.1 * n_keyframes), y(-1.6, 1.6), z(1.0, 4.5), unit(0, 1);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::discrete_distribution<int> random_level = levelDistribution();
  std::vector<Vec3> truth;
  for (int i = 0; i < n_points; ++i) truth.emplace_back(x(rng), y(rng), z(rng));

  auto out = std::make_unique<BaMap>();
  std::vector<std::vector<int>> seen_by(static_cast<std::size_t>(n_keyframes));
  for (int k = 0; k < n_keyframes; ++k) {
    const SE3 T_c_w = pose(Vec3(0.0, -turn * k, 0.0), Vec3(-0.1 * k, climb * k, 0.0));
    Frame f;
    f.camera = &cam;
    f.levels = &levels;
    f.T_c_w = T_c_w;
    for (std::size_t i = 0; i < truth.size(); ++i) {
      const Vec3 p_c = T_c_w * truth[i];
      if (p_c.z() < 0.5) continue;
      const Vec2 uv = cam.project(p_c);
      if (uv.x() < 0 || uv.y() < 0 || uv.x() >= cam.width || uv.y() >= cam.height) continue;
      if (observe < 1.0 && unit(rng) >= observe) continue;
      const int level = random_level(rng);
      const double scale = levels.scales[static_cast<std::size_t>(level)];
      const bool outlier = unit(rng) < 0.03;
      cv::KeyPoint kp(static_cast<float>(outlier ? uv.x() + 30 * noise(rng) : uv.x() + scale * 0.5 * noise(rng)),
                      static_cast<float>(outlier ? uv.y() + 30 * noise(rng) : uv.y() + scale * 0.5 * noise(rng)),
                      static_cast<float>(31 * scale));
      kp.octave = level;
      f.keys.push_back(kp);
      f.un.push_back(kp.pt);
      const bool has_depth = f.keys.size() % 3 != 0;
      f.depth.push_back(has_depth ? static_cast<float>(p_c.z()) : -1.0f);
      f.u_right.push_back(has_depth ? static_cast<float>(kp.pt.x - cam.bf() / p_c.z() + scale * 0.5 * noise(rng))
                                    : -1.0f);
      seen_by[static_cast<std::size_t>(k)].push_back(static_cast<int>(i));
    }
    f.descriptors = cv::Mat::zeros(f.size(), 32, CV_8U);
    f.grid.build(f.un, cam.width, cam.height);
    f.clearMatches();
    out->keyframes.push_back(out->map.addKeyFrame(std::make_unique<KeyFrame>(k, f)));
  }
  std::vector<std::shared_ptr<MapPoint>> points(truth.size());
  for (int k = 0; k < n_keyframes; ++k) {
    KeyFrame* kf = out->keyframes[static_cast<std::size_t>(k)];
    const auto& seen = seen_by[static_cast<std::size_t>(k)];
    for (std::size_t j = 0; j < seen.size(); ++j) {
      auto& p = points[static_cast<std::size_t>(seen[j])];
      if (!p) p = out->map.createPoint(truth[static_cast<std::size_t>(seen[j])] + 0.01 * Vec3(noise(rng), noise(rng), noise(rng)), kf);
      kf->addObservation(p, static_cast<int>(j));
    }
  }
  for (auto& p : points)
    if (p) p->updateFromObservations();
  for (int k = 1; k < n_keyframes; ++k) {
    KeyFrame* kf = out->keyframes[static_cast<std::size_t>(k)];
    kf->T_c_w() = pose(0.005 * Vec3(noise(rng), noise(rng), noise(rng)), 0.01 * Vec3(noise(rng), noise(rng), noise(rng))) *
                  kf->T_c_w();
  }
  for (KeyFrame* kf : out->keyframes) kf->updateConnections();
  return out;
}

void reportBa(const LocalBaStats& stats, benchmark::State* state) {
  state->counters["keyframes"] = stats.keyframes;
  state->counters["fixed"] = stats.fixed_keyframes;
  state->counters["points"] = stats.points;
  state->counters["observations"] = stats.observations;
  state->counters["initial_cost"] = stats.initial_cost;
  state->counters["final_cost"] = stats.final_cost;
}

// range(0): keyframes in the optimised window; keyframe 0 (the gauge) sits
// outside it and is held fixed, as in a running map.
void BM_LocalBundleAdjustment(benchmark::State& state) {
  const int window = static_cast<int>(state.range(0));
  const int iterations = 10;  // MappingOptions::ba_iterations default
  LocalBaStats stats;
  double observations_per_keyframe = 0;
  for (auto _ : state) {
    state.PauseTiming();  // BA moves the map, so every run starts from a fresh copy
    auto ba = makeBaMap(window + 1, 1750, 11);
    observations_per_keyframe = 0;
    for (KeyFrame* kf : ba->keyframes) observations_per_keyframe += kf->trackedPoints(1);
    observations_per_keyframe /= static_cast<double>(ba->keyframes.size());
    state.ResumeTiming();
    stats = localBundleAdjustment(&ba->map, ba->keyframes.back(), window, iterations);
    // BA writes into the map, so it cannot be optimised away. (Not
    // DoNotOptimize(stats.final_cost): with benchmark 1.7.1 and GCC 12 its
    // "+m,r" constraint corrupts a double lvalue.)
    benchmark::ClobberMemory();
    state.PauseTiming();
    ba.reset();
    state.ResumeTiming();
  }
  reportBa(stats, &state);
  state.counters["obs_per_kf"] = observations_per_keyframe;
  state.counters["outliers_removed"] = stats.outliers_removed;
}
BENCHMARK(BM_LocalBundleAdjustment)->Arg(10)->Unit(benchmark::kMillisecond);

// The global BA after a loop (every keyframe free but the first) over maps
// of range(0) keyframes, 10 cm apart along a straight walk (the points keep their
// density: 1750 per 5 m; each keyframe observes 60 % of those in view,
// about 560, as a running map's keyframes do); range(1): its
// time limit in ms (0: none), as place.global_ba_max_s sets it in threaded
// runs; range(2): its keyframe cap (0: none), the part nearest the newest
// keyframe, as the loop closer's.
void BM_GlobalBundleAdjustment(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  GlobalBaOptions options;
  options.iterations = 10;  // the loop closer's
  options.max_seconds = static_cast<double>(state.range(1)) / 1000.0;
  options.max_keyframes = static_cast<int>(state.range(2));
  options.seeds = {n - 1};
  LocalBaStats stats;
  for (auto _ : state) {
    state.PauseTiming();
    auto ba = makeBaMap(n, static_cast<int>(1750 * (5.0 + 0.1 * n) / 5.0), 11, 0.6, 0.0, 0.0);
    ba->keyframes.front()->origin = true;
    state.ResumeTiming();
    stats = globalBundleAdjustment(&ba->map, &benchmarkCamera(), 0, options);
    benchmark::ClobberMemory();
    state.PauseTiming();
    ba.reset();
    state.ResumeTiming();
  }
  reportBa(stats, &state);
  state.counters["obs_per_kf"] = static_cast<double>(stats.observations) / (stats.keyframes + stats.fixed_keyframes);
  state.counters["out_of_time"] = stats.out_of_time;
}
BENCHMARK(BM_GlobalBundleAdjustment)
    ->Args({100, 0, 0})
    ->Args({400, 0, 0})
    ->Args({1600, 0, 0})
    ->Args({1600, 3000, 0})
    ->Args({1600, 3000, 400})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace stillpoint::slam
