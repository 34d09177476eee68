#include "optimizer.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <functional>
#include <mutex>
#include <random>

namespace stillpoint::slam {
namespace {

CameraModel testCamera() { return *cameraPreset("fr3"); }

LevelInfo testLevels() {
  LevelInfo lv;
  lv.levels = 8;
  lv.scale_factor = 1.2;
  lv.log_scale_factor = std::log(1.2);
  for (int l = 0; l < 8; ++l) {
    lv.scales.push_back(std::pow(1.2, l));
    lv.sigma2.push_back(lv.scales.back() * lv.scales.back());
    lv.inv_sigma2.push_back(1.0 / lv.sigma2.back());
  }
  return lv;
}

// Points spread in front of the camera at 1-4 m.
std::vector<Vec3> randomPoints(int n, std::mt19937* rng) {
  std::uniform_real_distribution<double> xy(-1.5, 1.5), z(1.0, 4.0);
  std::vector<Vec3> pts;
  for (int i = 0; i < n; ++i) pts.emplace_back(xy(*rng), xy(*rng), z(*rng));
  return pts;
}

SE3 pose(double rx, double ry, double rz, double tx, double ty, double tz) {
  SE3 T = SE3::Identity();
  T.linear() = expSO3(Vec3(rx, ry, rz));
  T.translation() = Vec3(tx, ty, tz);
  return T;
}

// A keyframe at T_c_w seeing point i of `world` as its feature i, at level 0,
// `noise()` added to each pixel coordinate; the first `measured` points with
// their depth (and virtual right coordinate), the others without.
KeyFrame* addKeyFrameSeeing(Map* map, std::int64_t id, const CameraModel& cam, const LevelInfo& levels,
                            const SE3& T_c_w, const std::vector<Vec3>& world, const std::function<double()>& noise,
                            std::size_t measured) {
  Frame f;
  f.camera = &cam;
  f.levels = &levels;
  f.T_c_w = T_c_w;
  for (std::size_t i = 0; i < world.size(); ++i) {
    const Vec3 p_c = T_c_w * world[i];
    const Vec2 uv = cam.project(p_c);
    const double du = noise();
    cv::KeyPoint kp(static_cast<float>(uv.x() + du), static_cast<float>(uv.y() + noise()), 31);
    kp.octave = 0;
    f.keys.push_back(kp);
    f.un.push_back(kp.pt);
    const bool with_depth = i < measured;
    f.depth.push_back(with_depth ? static_cast<float>(p_c.z()) : -1.0f);
    f.u_right.push_back(with_depth ? static_cast<float>(kp.pt.x - cam.bf() / p_c.z() + noise()) : -1.0f);
  }
  f.descriptors = cv::Mat::zeros(static_cast<int>(world.size()), 32, CV_8U);
  f.grid.build(f.un, cam.width, cam.height);
  f.clearMatches();
  return map->addKeyFrame(std::make_unique<KeyFrame>(id, f));
}

TEST(PoseOptimisation, RecoversKnownPoseWith30PercentOutliers) {
  std::mt19937 rng(7);
  const CameraModel cam = testCamera();
  const SE3 T_true = pose(0.05, -0.1, 0.02, 0.1, -0.05, 0.2);
  PoseProblem problem;
  problem.camera = &cam;
  std::normal_distribution<double> noise(0.0, 0.5);
  std::uniform_real_distribution<double> anywhere_u(0, cam.width), anywhere_v(0, cam.height);
  std::vector<char> is_outlier;
  for (const Vec3& p_w : randomPoints(300, &rng)) {
    const Vec3 p_c = T_true * p_w;
    if (p_c.z() <= 0.2) continue;
    Observation o;
    const Vec2 uv = cam.project(p_c);
    const bool outlier = std::uniform_real_distribution<double>(0, 1)(rng) < 0.3;
    o.u = outlier ? anywhere_u(rng) : uv.x() + noise(rng);
    o.v = outlier ? anywhere_v(rng) : uv.y() + noise(rng);
    // Half the points carry depth (as the virtual right coordinate).
    if (problem.points_w.size() % 2 == 0) o.u_right = o.u - cam.bf() / p_c.z() + (outlier ? 0 : noise(rng) * 0.5);
    problem.points_w.push_back(p_w);
    problem.observations.push_back(o);
    is_outlier.push_back(outlier);
  }
  const SE3 initial = pose(0.0, -0.05, 0.0, 0.0, 0.0, 0.1);  // ~3 deg and 15 cm off
  for (const PoseResult& r : {optimizePose(problem, initial), optimizePoseCeres(problem, initial)}) {
  EXPECT_LT((r.T_c_w.translation() - T_true.translation()).norm(), 0.01);
  EXPECT_LT(rotationAngle(r.T_c_w.linear() * T_true.linear().transpose()), 0.2 * M_PI / 180);
  int correctly_classified = 0;
  for (std::size_t i = 0; i < is_outlier.size(); ++i) correctly_classified += (r.inlier[i] != is_outlier[i]);
  EXPECT_GT(correctly_classified, static_cast<int>(0.95 * is_outlier.size()));
  }
}

TEST(PoseOptimisation, AgreesWithCeresReference) {
  std::mt19937 rng(3);
  const CameraModel cam = testCamera();
  const SE3 T_true = pose(-0.03, 0.08, 0.01, -0.2, 0.05, 0.1);
  PoseProblem problem;
  problem.camera = &cam;
  std::normal_distribution<double> noise(0.0, 1.0);
  for (const Vec3& p_w : randomPoints(200, &rng)) {
    const Vec3 p_c = T_true * p_w;
    if (p_c.z() <= 0.2) continue;
    const Vec2 uv = cam.project(p_c);
    Observation o{uv.x() + noise(rng), uv.y() + noise(rng), -1, 1.0};
    if (problem.points_w.size() % 3 != 0) o.u_right = o.u - cam.bf() / p_c.z() + noise(rng);
    problem.points_w.push_back(p_w);
    problem.observations.push_back(o);
  }
  const SE3 initial = pose(0, 0, 0, 0, 0, 0);
  const PoseResult ours = optimizePose(problem, initial);
  const PoseResult ceres = optimizePoseCeres(problem, initial);
  EXPECT_LT((ours.T_c_w.translation() - ceres.T_c_w.translation()).norm(), 1e-4);
  EXPECT_LT(rotationAngle(ours.T_c_w.linear() * ceres.T_c_w.linear().transpose()), 1e-4);
  EXPECT_EQ(ours.inliers, ceres.inliers);
}

// The covariance poseCovarianceInMap predicts is the spread of the poses the
// optimisation finds under that noise: a camera turned half a radian, a
// narrow strip of points, most without depth, pixel noise of half a pixel at the points' own levels, 400 draws.
TEST(PoseCovariance, PredictsTheSpreadOfTheOptimisedPose) {
  std::mt19937 rng(11);
  const CameraModel cam = testCamera();
  const SE3 T_true = pose(0.1, 0.5, -0.2, 0.3, -0.1, 0.4);
  const double sigma = 0.5;
  std::uniform_real_distribution<double> x(-0.15, 0.15), y(-1.0, 1.0), z(3.0, 5.0);
  std::uniform_int_distribution<int> level(0, 3);
  PoseProblem truth;
  truth.camera = &cam;
  while (truth.points_w.size() < 60) {
    const Vec3 p_c(x(rng), y(rng), z(rng));
    const Vec2 uv = cam.project(p_c);
    Observation o{uv.x(), uv.y(), -1, 1.0 / std::pow(1.2, level(rng))};
    if (truth.points_w.size() % 10 == 0) o.u_right = o.u - cam.bf() / p_c.z();
    truth.points_w.push_back(T_true.inverse() * p_c);
    truth.observations.push_back(o);
  }
  const Eigen::Matrix<double, 6, 6> predicted =
      poseCovarianceInMap(poseInformation(truth, T_true), T_true, sigma);
  const SE3 T_w_c_true = T_true.inverse();
  std::normal_distribution<double> unit(0.0, 1.0);
  std::vector<Eigen::Matrix<double, 6, 1>> errors;
  for (int draw = 0; draw < 400; ++draw) {
    PoseProblem noisy = truth;
    for (Observation& o : noisy.observations) {
      const double s = sigma / o.inv_sigma;  // the level's pixel sigma
      o.u += s * unit(rng);
      o.v += s * unit(rng);
      if (o.u_right >= 0) o.u_right += s * unit(rng);
    }
    const PoseResult r = optimizePose(noisy, T_true);
    ASSERT_EQ(r.inliers, 60);
    const SE3 T_w_c = r.T_c_w.inverse();
    Eigen::Matrix<double, 6, 1> e;
    e.head<3>() = T_w_c.translation() - T_w_c_true.translation();
    e.tail<3>() = logSO3(T_w_c.linear() * T_w_c_true.linear().transpose());
    errors.push_back(e);
  }
  Eigen::Matrix<double, 6, 6> spread = Eigen::Matrix<double, 6, 6>::Zero();
  double nees = 0;
  for (const auto& e : errors) {
    spread += e * e.transpose() / static_cast<double>(errors.size());
    nees += e.dot(predicted.ldlt().solve(e)) / static_cast<double>(errors.size());
  }
  for (int k = 0; k < 6; ++k) {
    EXPECT_GT(spread(k, k), 0.75 * predicted(k, k)) << "state " << k;
    EXPECT_LT(spread(k, k), 1.33 * predicted(k, k)) << "state " << k;
  }
  // Six degrees of freedom: the normalised squared error averages 6 when the
  // correlations are right too (its standard error over 400 draws: 0.17).
  EXPECT_NEAR(nees, 6.0, 0.6);
  // The same covariance left in the camera's axes does not fit: the test
  // tells the frames apart.
  Eigen::Matrix<double, 6, 6> B = Eigen::Matrix<double, 6, 6>::Zero();
  B.topLeftCorner<3, 3>() = B.bottomRightCorner<3, 3>() = T_true.linear();
  const Eigen::Matrix<double, 6, 6> in_camera = B * predicted * B.transpose();
  double nees_camera = 0;
  for (const auto& e : errors) nees_camera += e.dot(in_camera.ldlt().solve(e)) / static_cast<double>(errors.size());
  EXPECT_GT(nees_camera, 8.0);
}

// The motion model's prior: weighed against the observations by its sigma.
// Exact observations of pose A, a prior at B 2 mm away: a tight prior gives
// B, a loose one A, one of the observations' strength a pose in between.
TEST(PoseOptimisation, PriorIsWeighedAgainstTheObservations) {
  std::mt19937 rng(5);
  const CameraModel cam = testCamera();
  const SE3 A = pose(0.02, -0.03, 0.01, 0.05, -0.02, 0.1);
  SE3 B = A;
  B.translation() += Vec3(0.002, 0, 0);
  PoseProblem problem;
  problem.camera = &cam;
  for (const Vec3& p_w : randomPoints(40, &rng)) {
    const Vec3 p_c = A * p_w;
    if (p_c.z() <= 0.2) continue;
    const Vec2 uv = cam.project(p_c);
    problem.points_w.push_back(p_w);
    problem.observations.push_back({uv.x(), uv.y(), -1, 1.0});
  }
  problem.prior = B;
  const auto solve = [&](double sigma_m) {
    problem.prior_sqrt_information.head<3>().setConstant(1.0 / (0.1 * M_PI / 180));
    problem.prior_sqrt_information.tail<3>().setConstant(1.0 / sigma_m);
    const PoseResult r = optimizePose(problem, A);
    return Vec3(r.T_c_w.translation());
  };
  problem.prior_sqrt_information.setZero();
  const PoseResult no_prior = optimizePose(problem, B);
  EXPECT_LT((no_prior.T_c_w.translation() - A.translation()).norm(), 1e-6);
  EXPECT_LT((solve(1e-6) - B.translation()).norm(), 1e-4);
  EXPECT_LT((solve(10.0) - A.translation()).norm(), 1e-5);
  const Vec3 between = solve(0.0005);
  EXPECT_GT((between - A.translation()).norm(), 2e-4);
  EXPECT_GT((between - B.translation()).norm(), 2e-4);
  EXPECT_LT((between - A.translation()).norm() + (between - B.translation()).norm(), 0.0025);
}

TEST(PoseOptimisation, FewPointsAreReportedNotInvented) {
  const CameraModel cam = testCamera();
  PoseProblem problem;
  problem.camera = &cam;
  problem.points_w = {Vec3(0, 0, 2), Vec3(0.1, 0, 2)};
  problem.observations.resize(2);
  const PoseResult r = optimizePose(problem, SE3::Identity());
  EXPECT_EQ(r.inliers, 0);
}

// A room seen from T_true: a near wall in four patches (0.7-0.9 m), a table
// (1.5-2.5 m) and a far wall (5 m), each patch one group; and, when `moved`
// is not zero, a poster at 1.2 m in two patches that moved by `moved` (world
// frame) after its world points were taken: a sixth of the matches.
struct ConsensusScene {
  ConsensusProblem problem;
  std::vector<char> mover;
};

ConsensusScene consensusScene(const CameraModel& cam, const SE3& T_true, const Vec3& moved, std::mt19937* rng) {
  ConsensusScene scene;
  ConsensusProblem& p = scene.problem;
  p.pose.camera = &cam;
  p.seed = 3;
  std::normal_distribution<double> pixel(0.0, 0.7), depth(0.0, 0.005);
  const auto patch = [&](int group, int n, Vec3 centre, double half, bool is_mover) {
    std::uniform_real_distribution<double> offset(-half, half);
    for (int k = 0; k < n; ++k) {
      // Points are placed in the camera frame of T_true, then taken to the world.
      const Vec3 p_c = centre + Vec3(offset(*rng), offset(*rng), 0.05 * offset(*rng));
      const Vec3 p_w = T_true.inverse() * p_c;
      const Vec3 now_c = T_true * (is_mover ? Vec3(p_w + moved) : p_w);
      const Vec2 uv = cam.project(now_c);
      Observation o;
      o.u = uv.x() + pixel(*rng);
      o.v = uv.y() + pixel(*rng);
      const bool measured = now_c.z() < 3.2;  // far depth is image-only, as in the tracker
      o.u_right = measured ? o.u - cam.bf() / now_c.z() + pixel(*rng) : -1;
      p.pose.points_w.push_back(p_w);
      p.pose.observations.push_back(o);
      p.seen.push_back(now_c + Vec3(0, 0, depth(*rng) * now_c.z() * now_c.z()));
      p.sampleable.push_back(measured);
      p.group.push_back(group);
      scene.mover.push_back(is_mover);
    }
  };
  patch(0, 20, Vec3(-0.25, -0.15, 0.75), 0.12, false);
  patch(1, 20, Vec3(0.25, -0.15, 0.8), 0.12, false);
  patch(2, 20, Vec3(-0.25, 0.2, 0.85), 0.12, false);
  patch(3, 20, Vec3(0.3, 0.2, 0.9), 0.12, false);
  patch(4, 15, Vec3(0.0, 0.3, 2.0), 0.4, false);
  patch(5, 10, Vec3(-1.0, -0.6, 5.0), 0.5, false);
  patch(6, 10, Vec3(1.0, -0.6, 5.0), 0.5, false);
  if (moved.norm() > 0) {
    patch(7, 12, Vec3(-0.1, 0.0, 1.2), 0.15, true);
    patch(8, 12, Vec3(0.15, 0.0, 1.2), 0.15, true);
  }
  return scene;
}

double rotationDegrees(const SE3& a, const SE3& b) {
  return Eigen::AngleAxisd(a.linear() * b.linear().transpose()).angle() * 180.0 / M_PI;
}

// The onset of a poster that starts to move in front of a near wall: stage 1
// followed it (drifting along with it and turning back, which the near wall
// cannot tell from the truth; only the table and the far wall can), a pose
// under which the poster's matches and the wall's both pass the chi-square
// gate. The consensus finds the room's pose and rejects the poster.
TEST(ConsensusPose, LeavesTheCompromiseThatAMovingMinorityPulledThePoseInto) {
  std::mt19937 rng(11);
  const CameraModel cam = testCamera();
  const SE3 T_true = pose(0.02, -0.05, 0.01, 0.1, 0.05, -0.2);
  const Vec3 moved = T_true.linear().transpose() * Vec3(0.01, 0, 0);  // 1 cm along the image's x: ~4.5 px
  ConsensusScene scene = consensusScene(cam, T_true, moved, &rng);
  const PoseProblem& all = scene.problem.pose;
  // The compromise: the pose fitted to the near wall and the poster.
  PoseProblem near;
  near.camera = &cam;
  for (std::size_t k = 0; k < all.points_w.size(); ++k)
    if (scene.problem.group[k] <= 3 || scene.mover[k]) {
      near.points_w.push_back(all.points_w[k]);
      near.observations.push_back(all.observations[k]);
    }
  const SE3 compromise = optimizePose(near, T_true, 1).T_c_w;
  const auto passing = [&](const SE3& T, bool movers) {
    int n = 0;
    for (std::size_t k = 0; k < all.points_w.size(); ++k)
      n += scene.mover[k] == movers && reprojectionChi2(cam, T, all.points_w[k], all.observations[k]) < kChi2Stereo;
    return n;
  };
  ASSERT_GE(passing(compromise, true), 18) << "of 24: stage 1 must have followed the poster";
  ASSERT_GT((compromise.translation() - T_true.translation()).norm(), 0.01);

  const ConsensusResult r = consensusPose(scene.problem, compromise);
  EXPECT_LT(r.cost, 0.9 * r.initial_cost);
  EXPECT_LT((r.T_c_w.translation() - T_true.translation()).norm(), 0.003);
  EXPECT_LT(rotationDegrees(r.T_c_w, T_true), 0.1);
  EXPECT_LE(passing(r.T_c_w, true), 2) << "of 24";
  EXPECT_GE(passing(r.T_c_w, false), 0.9 * (all.points_w.size() - 24));
  // Deterministic for one seed.
  EXPECT_TRUE(consensusPose(scene.problem, compromise).T_c_w.isApprox(r.T_c_w));
  // Asked for more matches under the initial pose than pass it: no search.
  ConsensusProblem strict = scene.problem;
  int initial_inliers = 0;
  truncatedPoseCost(all, compromise, strict.cap, &initial_inliers);
  strict.min_initial_inliers = initial_inliers + 1;
  const ConsensusResult none = consensusPose(strict, compromise);
  EXPECT_TRUE(none.T_c_w.isApprox(compromise));
  EXPECT_DOUBLE_EQ(none.cost, none.initial_cost);
  EXPECT_EQ(none.initial_inliers, initial_inliers);
}

// Under the right pose of a static room nothing explains the matches
// clearly better: the tracker keeps its pose (ratio 0.9).
TEST(ConsensusPose, KeepsTheRightPoseOfAStaticRoom) {
  std::mt19937 rng(5);
  const CameraModel cam = testCamera();
  const SE3 T_true = pose(-0.03, 0.04, 0.0, -0.05, 0.1, 0.1);
  for (int trial = 0; trial < 5; ++trial) {
    ConsensusScene scene = consensusScene(cam, T_true, Vec3::Zero(), &rng);
    scene.problem.seed = trial;
    const ConsensusResult r = consensusPose(scene.problem, T_true);
    EXPECT_GE(r.cost, 0.9 * r.initial_cost) << "trial " << trial;
    EXPECT_LT((r.T_c_w.translation() - T_true.translation()).norm(), 0.003) << "trial " << trial;
  }
}

// The anchor frame's own pose is a few millimetres off: near surfaces show
// it as a coherent shift of several sigma, which a hypothesis from three
// noisy depth samples rarely beats. The initial pose, refitted on its own
// inliers, is the local search that corrects it (no hypothesis is sampled
// here, so only that refit can).
TEST(ConsensusPose, RefitsAnInitialPoseAFewMillimetresOff) {
  std::mt19937 rng(7);
  const CameraModel cam = testCamera();
  const SE3 T_true = pose(0.02, -0.03, 0.01, 0.05, -0.02, 0.1);
  for (int trial = 0; trial < 5; ++trial) {
    ConsensusScene scene = consensusScene(cam, T_true, Vec3::Zero(), &rng);
    scene.problem.samples = 0;
    SE3 off = SE3::Identity();
    off.translation() = Vec3(0.003, -0.001, 0.002);
    const SE3 initial = off * T_true;
    const ConsensusResult r = consensusPose(scene.problem, initial);
    std::printf("trial %d: cost %.1f of %.1f, %.2f mm off\n", trial, r.cost, r.initial_cost,
                1e3 * (r.T_c_w.translation() - T_true.translation()).norm());
    EXPECT_LT(r.cost, 0.9 * r.initial_cost) << "trial " << trial;
    EXPECT_LT((r.T_c_w.translation() - T_true.translation()).norm(), 0.001) << "trial " << trial;
  }
}

// Too few depth-measured matches to sample: the initial pose, at its cost.
TEST(ConsensusPose, WithoutThreeMeasuredMatchesReturnsTheInitialPose) {
  const CameraModel cam = testCamera();
  ConsensusProblem p;
  p.pose.camera = &cam;
  for (int k = 0; k < 10; ++k) {
    p.pose.points_w.emplace_back(0.1 * k, 0, 5);
    Observation o;
    o.u = cam.project(p.pose.points_w.back()).x() + 3;
    o.v = cam.cy;
    p.pose.observations.push_back(o);
    p.seen.push_back(p.pose.points_w.back());
    p.sampleable.push_back(k < 2);
    p.group.push_back(k);
  }
  const ConsensusResult r = consensusPose(p, SE3::Identity());
  EXPECT_TRUE(r.T_c_w.isApprox(SE3::Identity()));
  EXPECT_DOUBLE_EQ(r.cost, r.initial_cost);
  EXPECT_GT(r.cost, 0);
}

// A small map of keyframes observing shared points; BA must pull perturbed
// keyframes and points back towards consistency.
TEST(LocalBundleAdjustment, ReducesReprojectionErrorAndRecoversPoses) {
  std::mt19937 rng(11);
  const CameraModel cam = testCamera();
  const LevelInfo levels = testLevels();
  const std::vector<Vec3> truth = randomPoints(400, &rng);
  std::vector<SE3> true_poses;
  for (int k = 0; k < 5; ++k) true_poses.push_back(pose(0.0, 0.03 * k, 0.0, -0.1 * k, 0.02 * k, 0.0));

  Map map;
  std::normal_distribution<double> pixel_noise(0.0, 0.3), perturb(0.0, 0.01);
  std::vector<KeyFrame*> kfs;
  for (int k = 0; k < 5; ++k)
    kfs.push_back(addKeyFrameSeeing(&map, k, cam, levels, true_poses[k], truth, [&] { return pixel_noise(rng); },
                                    truth.size()));
  for (std::size_t i = 0; i < truth.size(); ++i) {
    auto p = map.createPoint(truth[i] + Vec3(perturb(rng), perturb(rng), perturb(rng)), kfs[0]);
    for (KeyFrame* kf : kfs) kf->addObservation(p, static_cast<int>(i));
    p->updateFromObservations();
  }
  // Perturb every keyframe but the first (the gauge).
  for (int k = 1; k < 5; ++k) kfs[k]->T_c_w() = pose(0.01, -0.01, 0.005, 0.02, -0.01, 0.015) * kfs[k]->T_c_w();
  for (KeyFrame* kf : kfs) kf->updateConnections();

  auto totalChi2 = [&] {
    double sum = 0;
    for (KeyFrame* kf : kfs)
      for (int i = 0; i < kf->frame.size(); ++i) {
        const auto& p = kf->frame.points[i];
        if (!p) continue;
        Observation o{kf->frame.un[i].x, kf->frame.un[i].y, kf->frame.u_right[i], 1.0};
        sum += reprojectionChi2(cam, kf->T_c_w(), p->position, o);
      }
    return sum;
  };
  const double before = totalChi2();
  const LocalBaStats stats = localBundleAdjustment(&map, kfs[4], 10, 10);
  const double after = totalChi2();
  EXPECT_EQ(stats.keyframes + stats.fixed_keyframes, 5);
  EXPECT_LT(after, 0.05 * before) << before << " -> " << after;
  for (int k = 1; k < 5; ++k) {
    // Errors relative to keyframe 0, which BA held fixed.
    const SE3 rel_est = kfs[k]->T_c_w() * kfs[0]->T_c_w().inverse();
    const SE3 rel_true = true_poses[k] * true_poses[0].inverse();
    EXPECT_LT((rel_est.translation() - rel_true.translation()).norm(), 0.005) << "keyframe " << k;
  }
}

// A young map's second keyframe seeing a far wall only (points 4.5-5.5 m
// away in a narrow cone, the near part of the view taken by a mover): a
// sideways slide with a turn reprojects them almost alike, and their depth,
// measured to decimetres at that range, hardly tells the two apart. Local BA
// keeps the newest keyframe where tracking put it rather than letting the
// pixel noise slide it along that freedom.
TEST(LocalBundleAdjustment, KeepsTheNewestKeyFrameWhereFarPointsLeaveItFree) {
  const CameraModel cam = testCamera();
  const LevelInfo levels = testLevels();
  for (int seed = 1; seed <= 8; ++seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> x(-1.2, 1.2), y(-0.8, 0.8), z(4.5, 5.5);
    std::vector<Vec3> wall;
    for (int i = 0; i < 80; ++i) wall.emplace_back(x(rng), y(rng), z(rng));
    std::normal_distribution<double> pixel_noise(0.0, 0.7), depth_noise(0.0, 0.05);
    const auto noise = [&] { return pixel_noise(rng); };
    Map map;
    const SE3 tracked = pose(0.0, 0.01, 0.0, -0.05, 0.0, 0.0);  // 5 cm to the side, turned 0.6 degrees
    KeyFrame* first = addKeyFrameSeeing(&map, 0, cam, levels, SE3::Identity(), wall, noise, wall.size());
    first->origin = true;
    KeyFrame* newest = addKeyFrameSeeing(&map, 1, cam, levels, tracked, wall, noise, wall.size());
    for (std::size_t i = 0; i < wall.size(); ++i) {
      auto p = map.createPoint(wall[i] * (1.0 + depth_noise(rng) / wall[i].z()), first);
      first->addObservation(p, static_cast<int>(i));
      newest->addObservation(p, static_cast<int>(i));
      p->updateFromObservations();
    }
    first->updateConnections();
    newest->updateConnections();
    const Vec3 before = newest->frame.cameraCentre();
    const LocalBaStats stats = localBundleAdjustment(&map, newest, 10, 10);
    EXPECT_EQ(stats.keyframes, 1);
    const double moved = (newest->frame.cameraCentre() - before).norm();
    const double turned = rotationAngle(newest->T_c_w().linear() * tracked.linear().transpose()) * 180.0 / M_PI;
    // Unheld, the noise slides it 13-23 cm with a turn of 1.4-2.6 degrees here.
    EXPECT_LT(moved, 0.04) << "seed " << seed;
    EXPECT_LT(turned, 0.5) << "seed " << seed;
  }
}

// A map built 2 % too small, seen by six keyframes along a 1 m path:
// keypoints good to a pixel, depth to a twentieth of one in disparity (an
// RGB-D sensor). With every keyframe but the first free, only the depth
// tells the scale; the global BA must take it from there.
constexpr double kShrink = 0.98;
SE3 pathPose(int k) { return pose(0.0, 0.02 * k, 0.0, -0.2 * k, 0.01 * k, 0.0); }

struct ShrunkMap {
  Map map;
  std::vector<KeyFrame*> kfs;
  std::vector<Vec3> truth;
};

void buildShrunkMap(const CameraModel& cam, const LevelInfo& levels, std::mt19937* rng, ShrunkMap* out) {
  out->truth = randomPoints(400, rng);
  std::normal_distribution<double> pixel_noise(0.0, 1.0), disparity_noise(0.0, 0.05);
  for (int k = 0; k < 6; ++k) {
    KeyFrame* kf = addKeyFrameSeeing(&out->map, k, cam, levels, pathPose(k), out->truth,
                                     [&] { return pixel_noise(*rng); }, out->truth.size());
    for (int i = 0; i < kf->frame.size(); ++i)
      kf->frame.u_right[i] =
          static_cast<float>(kf->frame.un[i].x - cam.bf() / kf->frame.depth[i] + disparity_noise(*rng));
    SE3 shrunk = pathPose(k);
    shrunk.translation() *= kShrink;
    kf->T_c_w() = shrunk;
    out->kfs.push_back(kf);
  }
  out->kfs[0]->origin = true;
  for (std::size_t i = 0; i < out->truth.size(); ++i) {
    auto p = out->map.createPoint(out->truth[i] * kShrink, out->kfs[0]);
    for (KeyFrame* kf : out->kfs) kf->addObservation(p, static_cast<int>(i));
    p->updateFromObservations();
  }
  for (KeyFrame* kf : out->kfs) kf->updateConnections();
}

class GlobalBundleAdjustment : public ::testing::Test {
 protected:
  void SetUp() override { buildShrunkMap(cam, levels, &rng, &m); }
  std::mt19937 rng{5};
  const CameraModel cam = testCamera();
  const LevelInfo levels = testLevels();
  ShrunkMap m;
};

TEST_F(GlobalBundleAdjustment, TakesTheMapsScaleFromTheDepth) {
  const LocalBaStats stats = globalBundleAdjustment(&m.map, &cam, 0, GlobalBaOptions{});
  EXPECT_EQ(stats.keyframes, 5);
  EXPECT_TRUE(stats.applied);
  EXPECT_FALSE(stats.out_of_time);
  const double scale = m.kfs[5]->frame.cameraCentre().norm() / pathPose(5).inverse().translation().norm();
  std::printf("scale after the global BA: %.5f (from %.2f)\n", scale, kShrink);
  EXPECT_NEAR(scale, 1.0, 0.002);
}

// A keyframe made while the global BA solves (after its snapshot, as local
// mapping goes on under a running system) is not in the solve. It keeps its
// pose relative to its parent, and the point it made follows it; left where
// it was, it would stay in the 2 % small world, 2.4 cm from its place.
TEST_F(GlobalBundleAdjustment, CarriesAlongKeyFramesMadeDuringTheSolve) {
  const Vec3 new_point_true(0.3, -0.2, 3.5);
  KeyFrame* newcomer = nullptr;
  std::shared_ptr<MapPoint> made;
  SE3 newcomer_from_parent = SE3::Identity();
  Vec3 made_in_newcomer = Vec3::Zero();
  GlobalBaOptions options;
  options.after_solve = [&] {
    std::unique_lock lock(m.map.mutex());
    SE3 shrunk = pathPose(6);
    shrunk.translation() *= kShrink;
    std::vector<Vec3> seen = m.truth;
    seen.push_back(new_point_true);
    newcomer = addKeyFrameSeeing(&m.map, 6, cam, levels, shrunk, seen, [] { return 0.0; }, seen.size());
    for (std::size_t i = 0; i < m.truth.size(); ++i) newcomer->addObservation(m.kfs[0]->frame.points[i], static_cast<int>(i));
    // Made from its depth: true in the camera, placed by the pose in the small world.
    made = m.map.createPoint(shrunk.inverse() * (pathPose(6) * new_point_true), newcomer);
    newcomer->addObservation(made, static_cast<int>(m.truth.size()));
    made->updateFromObservations();
    newcomer->updateConnections();
    newcomer->parent = m.kfs[5];  // its reference keyframe, as tracking makes it
    newcomer_from_parent = newcomer->T_c_w() * m.kfs[5]->T_c_w().inverse();
    made_in_newcomer = newcomer->T_c_w() * made->position;
  };
  const LocalBaStats stats = globalBundleAdjustment(&m.map, &cam, 0, options);
  ASSERT_TRUE(stats.applied);
  ASSERT_NE(newcomer, nullptr);
  EXPECT_EQ(stats.keyframes, 5);
  EXPECT_EQ(stats.keyframes_carried, 1);
  EXPECT_EQ(stats.points_carried, 1);
  const SE3 kept = newcomer->T_c_w() * m.kfs[5]->T_c_w().inverse();
  EXPECT_LT((kept.translation() - newcomer_from_parent.translation()).norm(), 1e-9);
  EXPECT_LT((newcomer->T_c_w() * made->position - made_in_newcomer).norm(), 1e-9);
  const double off = (newcomer->frame.cameraCentre() - pathPose(6).inverse().translation()).norm();
  const double point_off = (made->position - new_point_true).norm();
  std::printf("the newcomer %.4f m from its place, its point %.4f m\n", off, point_off);
  EXPECT_LT(off, 0.008);
  EXPECT_LT(point_off, 0.008);
}

// A keyframe that sees only a few map points (a mover filled its view) is
// left out of the solve: free among many, a handful of points lets it slide.
// It keeps its pose relative to its parent instead.
TEST_F(GlobalBundleAdjustment, LeavesOutAKeyFrameItsPointsCannotPlace) {
  SE3 shrunk = pathPose(6);
  shrunk.translation() *= kShrink;
  const std::vector<Vec3> few(m.truth.begin(), m.truth.begin() + 12);
  KeyFrame* weak = addKeyFrameSeeing(&m.map, 6, cam, levels, shrunk, few, [] { return 0.0; }, few.size());
  for (std::size_t i = 0; i < few.size(); ++i) weak->addObservation(m.kfs[0]->frame.points[i], static_cast<int>(i));
  weak->updateConnections();
  weak->parent = m.kfs[5];
  const SE3 from_parent = weak->T_c_w() * m.kfs[5]->T_c_w().inverse();
  const LocalBaStats stats = globalBundleAdjustment(&m.map, &cam, 0, GlobalBaOptions{});
  ASSERT_TRUE(stats.applied);
  EXPECT_EQ(stats.keyframes_held_out, 1);
  EXPECT_EQ(stats.keyframes, 5);
  EXPECT_EQ(stats.keyframes_carried, 1);
  const SE3 kept = weak->T_c_w() * m.kfs[5]->T_c_w().inverse();
  EXPECT_LT((kept.matrix() - from_parent.matrix()).norm(), 1e-9);
  EXPECT_LT((weak->frame.cameraCentre() - pathPose(6).inverse().translation()).norm(), 0.008);
}

// Past its keyframe cap the global BA optimises the loop's part of the map
// (its seed and the keyframes nearest it by covisibility); the others stay
// exactly where they were, holding the part in place.
TEST_F(GlobalBundleAdjustment, PastItsCapOptimisesTheLoopsPartOnly) {
  std::vector<SE3> before;
  for (KeyFrame* kf : m.kfs) before.push_back(kf->T_c_w());
  GlobalBaOptions options;
  options.max_keyframes = 3;
  options.seeds = {5};
  const LocalBaStats stats = globalBundleAdjustment(&m.map, &cam, 0, options);
  ASSERT_TRUE(stats.applied);
  EXPECT_EQ(stats.keyframes + stats.fixed_keyframes, 6);
  int moved = 0;
  for (std::size_t k = 0; k < m.kfs.size(); ++k)
    moved += (m.kfs[k]->T_c_w().matrix() - before[k].matrix()).norm() > 1e-12 ? 1 : 0;
  EXPECT_EQ(moved, stats.keyframes);
  EXPECT_GE(stats.keyframes, 2);
  EXPECT_LE(stats.keyframes, 3);
  EXPECT_NE((m.kfs[5]->T_c_w().matrix() - before[5].matrix()).norm(), 0.0);
}

// Local mapping culls keyframes while the global BA solves, and tracking
// frees them: the write-back finds its keyframes again by id and leaves the
// freed one alone (under the asan preset, touching it fails the test).
TEST_F(GlobalBundleAdjustment, WritesBackAroundAKeyFrameFreedDuringTheSolve) {
  GlobalBaOptions options;
  std::size_t freed = 0;
  options.after_solve = [&] {
    std::unique_lock lock(m.map.mutex());
    m.map.setKeyFrameBad(m.kfs[3]);
    freed = m.map.releaseCulledKeyFrames();
  };
  const LocalBaStats stats = globalBundleAdjustment(&m.map, &cam, 0, options);
  EXPECT_EQ(freed, 1u);
  EXPECT_TRUE(stats.applied);
  EXPECT_EQ(m.map.keyFrame(3), nullptr);
  const double scale = m.kfs[5]->frame.cameraCentre().norm() / pathPose(5).inverse().translation().norm();
  EXPECT_NEAR(scale, 1.0, 0.002);
  // Five keyframes see each point; the chi-square test set some aside.
  std::size_t observations = 0;
  for (KeyFrame* kf : {m.kfs[0], m.kfs[1], m.kfs[2], m.kfs[4], m.kfs[5]})
    for (const auto& p : kf->frame.points) observations += p ? 1 : 0;
  EXPECT_EQ(observations, 5 * m.truth.size() - static_cast<std::size_t>(stats.outliers_removed));
}

// A solve the world moved under (a merge, another loop) is dropped, and
// done again from the moved map when asked.
TEST_F(GlobalBundleAdjustment, SolvesAgainWhenTheWorldMovedDuringTheSolve) {
  GlobalBaOptions options;
  int solves = 0;
  options.after_solve = [&] {
    if (solves++ > 0) return;
    std::unique_lock lock(m.map.mutex());
    m.map.worldMoved();
  };
  const std::uint64_t epoch = m.map.epoch();
  LocalBaStats stats = globalBundleAdjustment(&m.map, &cam, 0, options);
  EXPECT_EQ(solves, 1);
  EXPECT_FALSE(stats.applied);
  EXPECT_TRUE(stats.world_moved);
  EXPECT_EQ(m.map.epoch(), epoch + 1);
  const double before = m.kfs[5]->frame.cameraCentre().norm() / pathPose(5).inverse().translation().norm();
  EXPECT_NEAR(before, kShrink, 1e-9);  // nothing written back

  solves = 0;
  options.retries = 1;
  stats = globalBundleAdjustment(&m.map, &cam, 0, options);
  EXPECT_EQ(solves, 2);
  EXPECT_TRUE(stats.applied);
  EXPECT_EQ(stats.dropped, 1);
  EXPECT_EQ(m.map.epoch(), epoch + 3);  // moved once in the first solve, once by the write-back
  const double scale = m.kfs[5]->frame.cameraCentre().norm() / pathPose(5).inverse().translation().norm();
  EXPECT_NEAR(scale, 1.0, 0.002);
}

// Cut at its time limit, a global BA still writes back the best map it
// found, no worse than the one it read, and says it was cut.
TEST_F(GlobalBundleAdjustment, CutAtItsTimeLimitWritesBackWhatItFound) {
  GlobalBaOptions options;
  options.max_seconds = 1e-6;
  const LocalBaStats stats = globalBundleAdjustment(&m.map, &cam, 0, options);
  EXPECT_TRUE(stats.applied);
  EXPECT_TRUE(stats.out_of_time);
  EXPECT_LE(stats.final_cost, stats.initial_cost);
  const double scale = m.kfs[5]->frame.cameraCentre().norm() / pathPose(5).inverse().translation().norm();
  EXPECT_GE(scale, kShrink - 1e-6);
  EXPECT_LE(scale, 1.002);
}

// Every point comes from a depth measurement; one that keeps only image
// observations (its measured ones set aside) can slide along its ray with
// little parallax. Points BA moves beyond every observer's depth range leave
// the map; points seen without depth but within range stay.
TEST(LocalBundleAdjustment, RemovesPointsItMovesBeyondTheSensorsRange) {
  std::mt19937 rng(5);
  const CameraModel cam = testCamera();
  const LevelInfo levels = testLevels();
  std::vector<Vec3> truth = randomPoints(200, &rng);
  const std::size_t measured = truth.size();
  // Seen without depth: half at 20 m (beyond fr3's 6 m), half at 5 m.
  std::vector<Vec3> start;
  for (int i = 0; i < 20; ++i) {
    const Vec3 ray(-0.3 + 0.03 * i, 0.1 * (i % 3) - 0.1, 1.0);
    const double z = i % 2 ? 20.0 : 5.0;
    truth.push_back(ray * z);
    start.push_back(ray * (0.9 * z));  // a little in front: reprojects within the inlier bound
  }
  std::vector<SE3> poses;
  for (int k = 0; k < 5; ++k) poses.push_back(pose(0.0, 0.01 * k, 0.0, -0.1 * k, 0.0, 0.0));

  Map map;
  std::vector<KeyFrame*> kfs;
  for (int k = 0; k < 5; ++k)
    kfs.push_back(addKeyFrameSeeing(&map, k, cam, levels, poses[k], truth, [] { return 0.0; }, measured));
  std::vector<std::shared_ptr<MapPoint>> points;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    auto p = map.createPoint(i < measured ? truth[i] : start[i - measured], kfs[0]);
    for (KeyFrame* kf : kfs) kf->addObservation(p, static_cast<int>(i));
    p->updateFromObservations();
    points.push_back(p);
  }
  for (KeyFrame* kf : kfs) kf->updateConnections();

  const LocalBaStats stats = localBundleAdjustment(&map, kfs[4], 10, 20);
  for (std::size_t i = 0; i < measured; ++i) EXPECT_FALSE(points[i]->bad) << "measured point " << i;
  for (std::size_t j = 0; j < start.size(); ++j) {
    const auto& p = points[measured + j];
    if (j % 2) {
      EXPECT_TRUE(p->bad) << "point " << j << " at " << p->position.transpose();
    } else {
      ASSERT_FALSE(p->bad) << "point " << j;
      EXPECT_NEAR(p->position.z(), truth[measured + j].z(), 0.2) << "point " << j;
    }
  }
  EXPECT_EQ(stats.out_of_range_removed, 10);
}

// A camera path round a ring: odometry edges carry a small bias (drift),
// one loop edge ties the last pose to the first as the truth has it. The
// graph must spread the correction so the end meets the start again, and
// fixed poses must not move; with measurements that agree, it must find the
// truth from scattered poses.
TEST(PoseGraph, ALoopEdgeRemovesTheDriftOfARing) {
  constexpr int kPoses = 24;
  std::vector<SE3> truth(kPoses);
  for (int k = 0; k < kPoses; ++k) {
    const double a = 2 * M_PI * k / kPoses;
    SE3 T_w_c = SE3::Identity();
    T_w_c.linear() = Eigen::AngleAxisd(a, Vec3::UnitY()).toRotationMatrix();
    T_w_c.translation() = Vec3(2 * std::cos(a), 0, 2 * std::sin(a));
    truth[k] = T_w_c.inverse();
  }
  SE3 bias = SE3::Identity();
  bias.linear() = Eigen::AngleAxisd(0.01, Vec3::UnitX()).toRotationMatrix();
  bias.translation() = Vec3(0.01, -0.005, 0.008);
  std::vector<PoseGraphEdge> edges;
  std::vector<SE3> drifted{truth[0]};
  for (int k = 1; k < kPoses; ++k) {
    const SE3 measured = bias * truth[k] * truth[k - 1].inverse();  // T_k_(k-1), biased
    edges.push_back({static_cast<std::size_t>(k), static_cast<std::size_t>(k - 1), measured});
    drifted.push_back(measured * drifted.back());
  }
  const double drift_m = (drifted.back().inverse().translation() - truth.back().inverse().translation()).norm();
  ASSERT_GT(drift_m, 0.1);
  edges.push_back({kPoses - 1, 0, truth[kPoses - 1] * truth[0].inverse()});
  std::vector<char> fixed(kPoses, 0);
  fixed[0] = 1;
  const std::vector<SE3> out = optimizePoseGraph(drifted, fixed, edges, 50);
  ASSERT_EQ(out.size(), drifted.size());
  EXPECT_LT((out[0].matrix() - truth[0].matrix()).norm(), 1e-9);
  const double end_m = (out.back().inverse().translation() - truth.back().inverse().translation()).norm();
  EXPECT_LT(end_m, 0.1 * drift_m) << "drift " << drift_m << " m, after the graph " << end_m << " m";
  // Measurements that agree with one another (no bias) and poses scattered
  // away from them: the graph finds the truth again.
  edges.clear();
  std::vector<SE3> scattered{truth[0]};
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.05);
  for (int k = 1; k < kPoses; ++k) {
    edges.push_back({static_cast<std::size_t>(k), static_cast<std::size_t>(k - 1), truth[k] * truth[k - 1].inverse()});
    SE3 off = SE3::Identity();
    off.linear() = Eigen::AngleAxisd(noise(rng), Vec3::UnitZ()).toRotationMatrix();
    off.translation() = Vec3(noise(rng), noise(rng), noise(rng));
    scattered.push_back(off * truth[k]);
  }
  edges.push_back({kPoses - 1, 0, truth[kPoses - 1] * truth[0].inverse()});
  const std::vector<SE3> recovered = optimizePoseGraph(scattered, fixed, edges, 50);
  for (int k = 0; k < kPoses; ++k) EXPECT_LT((recovered[k].matrix() - truth[k].matrix()).norm(), 1e-6) << "pose " << k;
}

}  // namespace
}  // namespace stillpoint::slam
