// Overlay and room generation: real pixels untouched outside the masks, masks
// equal to what the movers drew, determinism by seed, sensor model, paths,
// and clear errors on bad input.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>

#include <unistd.h>

#include <opencv2/imgcodecs.hpp>

#include "stillpoint/dataset/testing.hpp"
#include "stillpoint/eval/trajectory.hpp"
#include "stillpoint/synth/generator.hpp"
#include "stillpoint/synth/movers.hpp"
#include "stillpoint/synth/room.hpp"
#include "stillpoint/synth/sensor.hpp"

namespace stillpoint::synth {
namespace {

namespace fs = std::filesystem;

fs::path tempDir(const std::string& name) {
  const fs::path p = fs::temp_directory_path() / ("stillpoint_synth_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  return p;
}

std::string readFile(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::vector<std::string> listFiles(const fs::path& list) {
  std::vector<std::string> out;
  std::ifstream in(list);
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    out.push_back(line.substr(line.find(' ') + 1));
  }
  return out;
}

MoverSpec boxMover(const Vec3& at) {
  MoverSpec m;
  m.name = "cube";
  m.shape = MoverShape::kBox;
  m.texture = "fabric";
  m.size = Vec3(0.5, 0.5, 0.5);
  m.path.type = PathType::kOscillate;
  m.path.start = at;
  m.path.end = at + Vec3(0.3, 0.0, 0.0);
  m.path.period_s = 0.2;
  return m;
}

TEST(Overlay, RealPixelsUntouchedOutsideMask) {
  const fs::path in = tempDir("ov_in"), out = tempDir("ov_out");
  dataset::testing::SyntheticDatasetOptions o;
  o.n_frames = 6;
  o.width = 96;
  o.height = 72;
  Result<dataset::testing::SyntheticDataset> data = dataset::testing::writeSyntheticTumDataset(in.string(), o);
  ASSERT_TRUE(data.ok()) << data.error();
  SynthConfig config;
  // That writer's world has z along the first camera's optical axis, so the
  // stage's "height" is the distance in front of the camera (plane at 1.5 m).
  config.movers = {boxMover(Vec3(0.0, 0.0, 1.0))};
  config.sensor.sigma_at_1m = 0.0;
  GenerateOptions go;
  Result<GenerationReport> r = generateOverlay(in.string(), out.string(), data->camera, config, go);
  ASSERT_TRUE(r.ok()) << r.error();
  EXPECT_EQ(r->frames, 6);
  EXPECT_EQ(r->frames_with_movers, 6);
  EXPECT_GT(r->coverage_mean, 0.05);
  const auto rgb_in = listFiles(in / "rgb.txt"), rgb_out = listFiles(out / "rgb.txt");
  const auto dep_in = listFiles(in / "depth.txt"), dep_out = listFiles(out / "depth.txt");
  const auto masks = listFiles(out / "mask.txt");
  ASSERT_EQ(rgb_out.size(), 6u);
  ASSERT_EQ(masks.size(), 6u);
  for (std::size_t k = 0; k < 6; ++k) {
    const cv::Mat a = cv::imread((in / rgb_in[k]).string(), cv::IMREAD_COLOR);
    const cv::Mat b = cv::imread((out / rgb_out[k]).string(), cv::IMREAD_COLOR);
    const cv::Mat da = cv::imread((in / dep_in[k]).string(), cv::IMREAD_UNCHANGED);
    const cv::Mat db = cv::imread((out / dep_out[k]).string(), cv::IMREAD_UNCHANGED);
    const cv::Mat m = cv::imread((out / masks[k]).string(), cv::IMREAD_UNCHANGED);
    ASSERT_EQ(m.type(), CV_16UC1);
    const cv::Mat outside = m == 0;
    cv::Mat diff;
    cv::absdiff(a, b, diff);
    // Colour and depth are byte-identical wherever the mask is 0.
    cv::Mat colour_changed;
    cv::transform(diff, colour_changed, cv::Matx13f(1, 1, 1));
    EXPECT_EQ(cv::countNonZero(colour_changed & outside), 0) << "frame " << k;
    cv::Mat depth_changed = da != db;
    EXPECT_EQ(cv::countNonZero(depth_changed & outside), 0) << "frame " << k;
    // Where the mover is, the sequence shows it: depth ~1 m (or none at its edges).
    int near = 0, on = 0;
    for (int y = 0; y < m.rows; ++y) {
      for (int x = 0; x < m.cols; ++x) {
        if (!m.at<std::uint16_t>(y, x)) continue;
        EXPECT_EQ(m.at<std::uint16_t>(y, x), 1);
        ++on;
        const double z = db.at<std::uint16_t>(y, x) / 5000.0;
        near += z > 0.7 && z < 1.26;
      }
    }
    EXPECT_GT(on, 200);
    EXPECT_GT(near, on * 8 / 10);
  }
  EXPECT_EQ(readFile(in / "groundtruth.txt"), readFile(out / "groundtruth.txt"));
  EXPECT_TRUE(fs::exists(out / "movers.yaml"));
  // movers.txt: one speed per frame and mover, at the frames' stamps.
  std::ifstream speeds(out / "movers.txt");
  std::string line;
  int rows = 0;
  double t0 = -1;
  while (std::getline(speeds, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ss(line);
    double stamp = 0, speed = -1;
    int id = 0;
    ASSERT_TRUE(ss >> stamp >> id >> speed) << line;
    if (t0 < 0) t0 = stamp;
    EXPECT_EQ(id, 1);
    EXPECT_NEAR(speed, moverSpeed(config.movers[0], stamp - t0), 1e-3) << line;
    ++rows;
  }
  EXPECT_EQ(rows, 6);
  fs::remove_all(in);
  fs::remove_all(out);
}

TEST(Overlay, BadInputGivesClearErrors) {
  const CameraModel cam = roomCamera(64, 48);
  SynthConfig config;
  Result<GenerationReport> r = generateOverlay("/nonexistent/seq", tempDir("x").string(), cam, config, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("/nonexistent/seq"), std::string::npos) << r.error();

  const fs::path in = tempDir("nogt");
  dataset::testing::SyntheticDatasetOptions o;
  o.n_frames = 2;
  o.width = 64;
  o.height = 48;
  o.write_ground_truth = false;
  Result<dataset::testing::SyntheticDataset> data = dataset::testing::writeSyntheticTumDataset(in.string(), o);
  ASSERT_TRUE(data.ok());
  r = generateOverlay(in.string(), tempDir("y").string(), data->camera, config, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("groundtruth"), std::string::npos) << r.error();

  SynthConfig bad_texture;
  bad_texture.movers = {boxMover(Vec3(0, 0, 1))};
  bad_texture.movers[0].texture = "/nonexistent/photo.png";
  const fs::path in2 = tempDir("gt");
  o.write_ground_truth = true;
  ASSERT_TRUE(dataset::testing::writeSyntheticTumDataset(in2.string(), o).ok());
  r = generateOverlay(in2.string(), tempDir("z").string(), data->camera, bad_texture, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("/nonexistent/photo.png"), std::string::npos) << r.error();
  EXPECT_NE(r.error().find("cube"), std::string::npos) << r.error();

  SynthConfig bad_size;
  bad_size.movers = {boxMover(Vec3(0, 0, 1))};
  bad_size.movers[0].size.x() = -1;
  r = generateOverlay(in2.string(), tempDir("z").string(), data->camera, bad_size, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("movers[0].size"), std::string::npos) << r.error();
  fs::remove_all(in);
  fs::remove_all(in2);
}

// A camera path that is not a line (a rigid alignment of its positions is
// then unique), looking along +z and turning a little about y.
eval::Trajectory curvedPath(const std::vector<Timestamp>& stamps) {
  eval::Trajectory path;
  for (std::size_t k = 0; k < stamps.size(); ++k) {
    const double a = 0.15 * static_cast<double>(k);
    SE3 T = SE3::Identity();
    T.linear() = Eigen::AngleAxisd(0.02 * std::sin(a), Vec3::UnitY()).toRotationMatrix();
    T.translation() = Vec3(0.2 * std::sin(a), 0.1 * (1 - std::cos(a)), 0.02 * static_cast<double>(k));
    path.push_back({stamps[k], T});
  }
  return path;
}

std::vector<cv::Mat> readMasks(const fs::path& dir) {
  std::vector<cv::Mat> masks;
  for (const std::string& f : listFiles(dir / "mask.txt")) masks.push_back(cv::imread((dir / f).string(), cv::IMREAD_UNCHANGED));
  return masks;
}

// --render-poses: movers are placed by the given trajectory, aligned onto the
// ground truth: the same path in another world frame renders the same masks,
// and a pose turned in one frame moves the mover in that frame alone.
TEST(Overlay, RenderPosesPlaceTheMoversAndAreAlignedOntoTheGroundTruth) {
  const fs::path in = tempDir("rp_in");
  dataset::testing::SyntheticDatasetOptions o;
  o.n_frames = 12;
  o.width = 96;
  o.height = 72;
  Result<dataset::testing::SyntheticDataset> data = dataset::testing::writeSyntheticTumDataset(in.string(), o);
  ASSERT_TRUE(data.ok()) << data.error();
  const eval::Trajectory gt = curvedPath(data->colour_stamps);
  ASSERT_TRUE(eval::writeTumTrajectory((in / "groundtruth.txt").string(), gt));
  SynthConfig config;
  MoverSpec still = boxMover(Vec3(0.0, 0.0, 1.0));
  still.path.type = PathType::kStatic;
  config.movers = {still};
  config.sensor.sigma_at_1m = 0.0;

  const auto run = [&](const std::string& name, const std::string& poses) -> std::vector<cv::Mat> {
    const fs::path out = tempDir(name);
    GenerateOptions go;
    go.render_poses = poses;
    Result<GenerationReport> r = generateOverlay(in.string(), out.string(), data->camera, config, go);
    EXPECT_TRUE(r.ok()) << r.error();
    if (!r.ok()) return {};
    EXPECT_EQ(readFile(in / "groundtruth.txt"), readFile(out / "groundtruth.txt"));
    std::vector<cv::Mat> masks = readMasks(out);
    fs::remove_all(out);
    return masks;
  };
  const auto differing = [](const cv::Mat& a, const cv::Mat& b) { return cv::countNonZero(a != b); };
  const std::vector<cv::Mat> by_gt = run("rp_gt", "");
  ASSERT_EQ(by_gt.size(), 12u);
  for (const cv::Mat& m : by_gt) ASSERT_GT(cv::countNonZero(m), 500);

  // The same path in a world turned and shifted.
  SE3 X = SE3::Identity();
  X.linear() = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  X.translation() = Vec3(3, -1, 2);
  eval::Trajectory moved = gt;
  for (eval::StampedPose& p : moved) p.T_w_c = X * p.T_w_c;
  const fs::path moved_file = in / "moved.txt";
  ASSERT_TRUE(eval::writeTumTrajectory(moved_file.string(), moved));
  const std::vector<cv::Mat> by_moved = run("rp_moved", moved_file.string());
  ASSERT_EQ(by_moved.size(), 12u);
  for (std::size_t k = 0; k < 12; ++k) EXPECT_LE(differing(by_gt[k], by_moved[k]), 20) << "frame " << k;

  // Frame 6 turned by 2 degrees: its mover shifts by about 3 pixels.
  eval::Trajectory turned = gt;
  turned[6].T_w_c.linear() = turned[6].T_w_c.linear() * Eigen::AngleAxisd(0.035, Vec3::UnitY()).toRotationMatrix();
  const fs::path turned_file = in / "turned.txt";
  ASSERT_TRUE(eval::writeTumTrajectory(turned_file.string(), turned));
  const std::vector<cv::Mat> by_turned = run("rp_turned", turned_file.string());
  ASSERT_EQ(by_turned.size(), 12u);
  for (std::size_t k = 0; k < 12; ++k) {
    if (k == 6) EXPECT_GT(differing(by_gt[k], by_turned[k]), 100);
    else EXPECT_LE(differing(by_gt[k], by_turned[k]), 20) << "frame " << k;
  }

  // Bad trajectories: missing, too short, two maps.
  GenerateOptions go;
  go.render_poses = (in / "missing.txt").string();
  Result<GenerationReport> r = generateOverlay(in.string(), tempDir("rp_bad").string(), data->camera, config, go);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("missing.txt"), std::string::npos) << r.error();
  const fs::path short_file = in / "short.txt";
  ASSERT_TRUE(eval::writeTumTrajectory(short_file.string(), eval::Trajectory(gt.begin(), gt.begin() + 3)));
  go.render_poses = short_file.string();
  r = generateOverlay(in.string(), tempDir("rp_bad").string(), data->camera, config, go);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("at least 10"), std::string::npos) << r.error();
  eval::Trajectory two_maps = gt;
  for (std::size_t k = 6; k < two_maps.size(); ++k) two_maps[k].map_id = 1;
  const fs::path maps_file = in / "maps.txt";
  ASSERT_TRUE(eval::writeTumTrajectory(maps_file.string(), two_maps));
  go.render_poses = maps_file.string();
  r = generateOverlay(in.string(), tempDir("rp_bad").string(), data->camera, config, go);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().find("more than one map"), std::string::npos) << r.error();
  fs::remove_all(tempDir("rp_bad"));
  fs::remove_all(in);
}

SynthConfig smallRoom(std::uint64_t seed) {
  SynthConfig c;
  c.seed = seed;
  c.room.width = 80;
  c.room.height = 60;
  c.room.frames = 3;
  c.room.motion = CameraMotion::kHalfsphere;
  MoverSpec w;
  w.name = "walker";
  w.shape = MoverShape::kWalker;
  w.size = Vec3(0.45, 1.75, 0.25);
  w.path.type = PathType::kWalk;
  w.path.start = Vec3(-0.5, 2.0, 0);
  w.path.end = Vec3(0.5, 2.0, 0);
  c.movers = {w};
  return c;
}

TEST(Movers, FaceCameraPosterTurnsToTheCamera) {
  MoverSpec m;
  m.shape = MoverShape::kPoster;
  m.texture = "paper";
  m.size = Vec3(0.6, 0.9, 0.0);
  m.path.start = m.path.end = Vec3(0.5, 2.0, 1.0);
  Result<MoverTextures> tx = makeMoverTextures(m, "", 1);
  ASSERT_TRUE(tx.ok()) << tx.error();
  // Normal of the drawn poster, horizontal part, against the direction to each camera.
  auto facing = [&](const MoverSpec& spec, const Vec3& camera) {
    Mesh mesh;
    addMover(&mesh, spec, *tx, SE3::Identity(), 0.0, 1, camera);
    const Triangle& t = mesh.triangles.front();
    Vec3 n = (t.p[1] - t.p[0]).cross(t.p[2] - t.p[0]).normalized();
    Vec3 to_camera = camera - m.path.start;
    to_camera.z() = 0;
    return std::abs(n.dot(to_camera.normalized()));
  };
  m.face_camera = true;
  for (const Vec3& camera : {Vec3(0, 0, 1.5), Vec3(3, 2, 1.5), Vec3(-2, 4, 0.5), Vec3(0.5, 5, 1)})
    EXPECT_NEAR(facing(m, camera), 1.0, 1e-9) << camera.transpose();
  m.face_camera = false;  // a plain poster keeps its yaw: edge-on from the side
  EXPECT_NEAR(facing(m, Vec3(3, 2, 1.5)), 0.0, 1e-9);
}

TEST(Movers, CutOutMaskErrorsNameTheFile) {
  MoverSpec m;
  m.name = "person";
  m.cutout = "/nonexistent/mask.png";
  Result<MoverTextures> tx = makeMoverTextures(m, "", 1);
  ASSERT_FALSE(tx.ok());
  EXPECT_NE(tx.error().find("/nonexistent/mask.png"), std::string::npos) << tx.error();
  EXPECT_NE(tx.error().find("person"), std::string::npos) << tx.error();
  const fs::path empty = tempDir("empty_mask.png");
  cv::imwrite(empty.string(), cv::Mat(8, 8, CV_8UC1, cv::Scalar(0)));
  m.cutout = empty.string();
  tx = makeMoverTextures(m, "", 1);
  ASSERT_FALSE(tx.ok());
  EXPECT_NE(tx.error().find("keeps no pixel"), std::string::npos) << tx.error();
  fs::remove(empty);
  SynthConfig config;
  m.shape = MoverShape::kBox;
  m.cutout = "mask.png";
  config.movers = {m};
  const Status s = config.validate();
  ASSERT_FALSE(s);
  EXPECT_NE(s.error().find("cutout"), std::string::npos) << s.error();
}

TEST(Movers, CropShowsOnePersonOfAPhotoOfSeveral) {
  // A 100 x 50 photo: left half red, right half blue; its mask keeps a
  // large blob in the left half, a small one that the crop cuts into, and
  // one outside the crop.
  const fs::path dir = tempDir("crop");
  fs::create_directories(dir);
  cv::Mat photo(50, 100, CV_8UC3, cv::Scalar(0, 0, 255));
  photo.colRange(50, 100).setTo(cv::Scalar(255, 0, 0));
  cv::Mat mask(50, 100, CV_8UC1, cv::Scalar(0));
  mask(cv::Rect(10, 5, 20, 40)).setTo(255);  // the person
  mask(cv::Rect(36, 5, 8, 8)).setTo(255);    // a piece of another, inside the crop
  mask(cv::Rect(70, 5, 20, 40)).setTo(255);  // another, outside it
  ASSERT_TRUE(cv::imwrite((dir / "photo.png").string(), photo));
  ASSERT_TRUE(cv::imwrite((dir / "mask.png").string(), mask));
  MoverSpec m;
  m.name = "person";
  m.texture = "photo.png";
  m.cutout = "mask.png";
  m.crop = {0.0, 0.0, 0.4, 1.0};
  Result<MoverTextures> tx = makeMoverTextures(m, dir.string(), 1);
  ASSERT_TRUE(tx.ok()) << tx.error();
  const Texture& t = *tx->textures.front();
  ASSERT_TRUE(t.cutout());
  EXPECT_EQ(t.level(0).cols, 40);
  EXPECT_EQ(t.level(0).rows, 50);
  const cv::Mat& keep = t.keepLevel(0);
  EXPECT_EQ(keep.at<std::uint8_t>(25, 20), 255);  // the person
  EXPECT_EQ(keep.at<std::uint8_t>(8, 39), 0);     // the other's piece is dropped
  EXPECT_EQ(keep.at<std::uint8_t>(25, 5), 0);
  EXPECT_EQ(t.level(0).at<cv::Vec3b>(25, 20), cv::Vec3b(0, 0, 255));  // the left half's colour
  // A crop holding none of the mask, and crops that are no rectangle.
  m.crop = {0.45, 0.0, 0.65, 1.0};
  tx = makeMoverTextures(m, dir.string(), 1);
  ASSERT_FALSE(tx.ok());
  EXPECT_NE(tx.error().find("nothing kept inside the crop"), std::string::npos) << tx.error();
  SynthConfig config;
  for (const std::array<double, 4> bad :
       {std::array<double, 4>{0.5, 0.0, 0.4, 1.0}, {0.0, -0.1, 1.0, 1.0}, {0.0, 0.0, 1.0, 1.2}}) {
    m.crop = bad;
    config.movers = {m};
    const Status st = config.validate();
    ASSERT_FALSE(st);
    EXPECT_NE(st.error().find("crop"), std::string::npos) << st.error();
  }
  m.crop = {0.0, 0.0, 0.5, 1.0};
  m.shape = MoverShape::kBox;
  m.cutout.clear();
  config.movers = {m};
  EXPECT_FALSE(config.validate());
  fs::remove_all(dir);
}

TEST(Room, DeterministicBySeedWhateverTheThreads) {
  const fs::path a = tempDir("room_a"), b = tempDir("room_b"), c = tempDir("room_c");
  GenerateOptions one;
  one.threads = 1;
  GenerateOptions two;
  two.threads = 2;
  ASSERT_TRUE(generateRoom(a.string(), smallRoom(5), one).ok());
  ASSERT_TRUE(generateRoom(b.string(), smallRoom(5), two).ok());
  ASSERT_TRUE(generateRoom(c.string(), smallRoom(6), two).ok());
  int compared = 0, depth_differs = 0;
  for (const auto& entry : fs::recursive_directory_iterator(a)) {
    if (!entry.is_regular_file()) continue;
    const fs::path rel = fs::relative(entry.path(), a);
    if (rel == "movers.yaml") continue;  // holds the run time
    EXPECT_EQ(readFile(entry.path()), readFile(b / rel)) << rel;
    if (rel.string().rfind("depth/", 0) == 0) depth_differs += readFile(entry.path()) != readFile(c / rel);
    ++compared;
  }
  EXPECT_EQ(compared, 3 * 3 + 5);
  EXPECT_EQ(depth_differs, 3);  // another seed, other noise
  fs::remove_all(a);
  fs::remove_all(b);
  fs::remove_all(c);
}

TEST(Room, MaskEqualsPixelsTheMoversDrew) {
  const SynthConfig config = smallRoom(3);
  Result<Room> room = buildRoom(config.room, "", config.seed);
  ASSERT_TRUE(room.ok());
  const CameraModel cam = roomCamera(80, 60);
  Result<MoverRenderer> movers = MoverRenderer::create(config, stageFromCamera(roomCameraPose(config.room.motion, 0)));
  ASSERT_TRUE(movers.ok()) << movers.error();
  for (double t : {0.0, 0.5, 1.3}) {
    const SE3 T_w_c = roomCameraPose(config.room.motion, t);
    RenderTarget still = RenderTarget::blank(cam.width, cam.height);
    render(room->mesh, T_w_c, cam, &still);
    RenderTarget both{still.colour.clone(), still.depth.clone(), still.id.clone()};
    movers->render(t, T_w_c, cam, &both);
    int on = 0;
    for (int y = 0; y < cam.height; ++y) {
      for (int x = 0; x < cam.width; ++x) {
        if (both.id.at<std::uint16_t>(y, x) == 0) {
          ASSERT_EQ(both.colour.at<cv::Vec3b>(y, x), still.colour.at<cv::Vec3b>(y, x));
          ASSERT_EQ(both.depth.at<float>(y, x), still.depth.at<float>(y, x));
        } else {
          ++on;
          ASSERT_LT(both.depth.at<float>(y, x), still.depth.at<float>(y, x));
        }
      }
    }
    EXPECT_GT(on, 30) << "t " << t;
  }
}

TEST(Sensor, QuantisesDropsOutOfRangeAndEdges) {
  cv::Mat z(20, 20, CV_32FC1, cv::Scalar(1.2345f));
  z(cv::Rect(10, 0, 10, 20)).setTo(2.0f);   // a depth step at x = 10
  z(cv::Rect(0, 0, 3, 3)).setTo(9.0f);      // beyond range
  z.at<float>(19, 0) = std::numeric_limits<float>::infinity();
  DepthSensorOptions o;
  o.sigma_at_1m = 0;
  o.random_dropout = 0;
  o.edge_dropout = 1.0;
  cv::Mat raw;
  applyDepthSensor(z, cv::Mat(), o, 1, &raw);
  EXPECT_EQ(raw.at<std::uint16_t>(10, 5), 6173);  // round(1.2345 * 5000)
  EXPECT_EQ(raw.at<std::uint16_t>(10, 15), 10000);
  EXPECT_EQ(raw.at<std::uint16_t>(1, 1), 0);
  EXPECT_EQ(raw.at<std::uint16_t>(19, 0), 0);
  for (int y = 4; y < 20; ++y) {
    EXPECT_EQ(raw.at<std::uint16_t>(y, 9), 0);   // both sides of the step
    EXPECT_EQ(raw.at<std::uint16_t>(y, 10), 0);
    EXPECT_NE(raw.at<std::uint16_t>(y, 8), 0);
  }
  // Noise grows with range: spread at 3 m is ~9x the spread at 1 m.
  cv::Mat z1(100, 100, CV_32FC1, cv::Scalar(1.0f)), z3(100, 100, CV_32FC1, cv::Scalar(3.0f));
  DepthSensorOptions n;
  n.random_dropout = 0;
  cv::Mat r1, r3;
  applyDepthSensor(z1, cv::Mat(), n, 2, &r1);
  applyDepthSensor(z3, cv::Mat(), n, 2, &r3);
  cv::Scalar m1, s1, m3, s3;
  cv::meanStdDev(r1, m1, s1);
  cv::meanStdDev(r3, m3, s3);
  EXPECT_NEAR(s1[0] / 5000, n.sigma_at_1m, 0.3 * n.sigma_at_1m);
  EXPECT_NEAR(s3[0] / s1[0], 9.0, 1.5);
  // Only selected pixels are written.
  cv::Mat select(20, 20, CV_8UC1, cv::Scalar(0));
  select(cv::Rect(0, 0, 5, 20)).setTo(1);
  cv::Mat keep(20, 20, CV_16UC1, cv::Scalar(42));
  applyDepthSensor(z, select, o, 1, &keep);
  EXPECT_EQ(keep.at<std::uint16_t>(10, 15), 42);
  EXPECT_EQ(keep.at<std::uint16_t>(10, 4), 6173);
}

TEST(Paths, FollowTheirDefinitions) {
  PathSpec p;
  p.start = Vec3(0, 1, 0);
  p.end = Vec3(2, 1, 0);
  p.type = PathType::kOscillate;
  p.period_s = 4;
  EXPECT_TRUE(evaluatePath(p, 0).position.isApprox(p.start));
  EXPECT_TRUE(evaluatePath(p, 2).position.isApprox(p.end));
  p.type = PathType::kWalk;
  p.speed_m_s = 0.5;  // 4 s per leg
  EXPECT_TRUE(evaluatePath(p, 4).position.isApprox(p.end));
  EXPECT_TRUE(evaluatePath(p, 8).position.isApprox(p.start));
  EXPECT_NEAR(evaluatePath(p, 2).position.x(), 1.0, 1e-9);
  EXPECT_GT(evaluatePath(p, 2).velocity.x(), 0);
  EXPECT_LT(evaluatePath(p, 6).velocity.x(), 0);
  EXPECT_NEAR(evaluatePath(p, 6).travelled_m, 3.0, 0.01);
  // Speeds: the path's, nought at the ends of a walk leg, plus a spin.
  MoverSpec m;
  m.path = p;
  EXPECT_NEAR(moverSpeed(m, 0.0), 0.0, 1e-3);
  EXPECT_NEAR(moverSpeed(m, 2.0), evaluatePath(p, 2).velocity.norm(), 1e-9);
  EXPECT_GT(moverSpeed(m, 2.0), 0.5);  // eased: faster than the mean mid-leg
  m.size = Vec3(0.6, 1.0, 0.05);
  m.yaw_rate_deg_s = 90;
  EXPECT_NEAR(moverSpeed(m, 0.0), 0.3 * std::numbers::pi / 2, 1e-3);
  m.shape = MoverShape::kWalker;  // walkers face where they walk: no spin
  EXPECT_NEAR(moverSpeed(m, 0.0), 0.0, 1e-3);
  p.type = PathType::kStopAndGo;
  p.go_s = 1;
  p.stop_s = 1;
  EXPECT_NEAR(evaluatePath(p, 1.5).position.x(), 0.5, 1e-9);  // stopped after 0.5 m
  EXPECT_NEAR(evaluatePath(p, 1.9).position.x(), 0.5, 1e-9);
  EXPECT_NEAR(evaluatePath(p, 3.0).position.x(), 1.0, 1e-9);
  p.type = PathType::kStaticThenMove;
  p.hold_s = 3;
  EXPECT_TRUE(evaluatePath(p, 2.9).position.isApprox(p.start));
  EXPECT_GT(evaluatePath(p, 4).position.x(), 0.1);
  p.type = PathType::kStatic;
  EXPECT_TRUE(evaluatePath(p, 7).position.isApprox(p.start));
}

}  // namespace
}  // namespace stillpoint::synth
