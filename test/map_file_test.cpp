// Map files on real data: a map made from the excerpt is saved, loaded into a
// new system and tracked against in localisation mode (every frame finds its
// place, the map does not grow, poses agree with the mapping run); a saved
// and reloaded map saves to the same bytes; truncated, corrupt, wrong-version
// and wrong-camera files are errors naming the file, never a crash.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <string>

#include <opencv2/imgproc.hpp>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/core/checksum.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/semantic/segmenter.hpp"
#include "stillpoint/slam/system.hpp"

namespace stillpoint {
namespace {

namespace fs = std::filesystem;

// The first 4.3 s of the excerpt: a map of about 60 keyframes.
constexpr std::size_t kFrames = 130;

std::string readBytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void writeBytes(const fs::path& p, const std::string& bytes) {
  std::ofstream(p, std::ios::binary | std::ios::trunc) << bytes;
}

constexpr std::uint32_t kVersion = 4;  // the format this build writes

// A map file's bytes with another payload: format version, payload size and
// checksum in the 40-byte header made to match.
std::string resealed(const std::string& file, const std::string& payload, std::uint32_t version) {
  std::string out = file.substr(0, 40) + payload;
  const std::uint64_t size = payload.size(), sum = fnv1a64(payload.data(), payload.size());
  std::memcpy(&out[8], &version, 4);
  std::memcpy(&out[16], &size, 8);
  std::memcpy(&out[24], &sum, 8);
  return out;
}

class MapFile : public ::testing::Test {
 protected:
  // One map of the whole excerpt for the suite (mapping takes most of its time).
  static void SetUpTestSuite() {
    const std::string dir = std::string(STILLPOINT_DATA_DIR) + "/tum_fr3_teddy_200";
    if (!fs::exists(dir + "/rgb.txt")) return;
    auto data = dataset::TumDataset::open(dir);
    if (!data) return;
    data_ = new dataset::TumDataset(std::move(*data));
    scratch_ = new fs::path(fs::temp_directory_path() / ("stillpoint_map_file_" + std::to_string(::getpid())));
    fs::create_directories(*scratch_);
    mapped_ = new std::map<std::size_t, SE3>;
    auto system = makeSystem(false);
    std::size_t with_pose = 0;
    *mapped_ = run(system.get(), &with_pose);
    system->finish();
    map_path_ = new fs::path(*scratch_ / "teddy.map");
    map_saved_ = system->saveMap(map_path_->string()).ok();
    map_points_ = system->mapStats().points;
  }
  static void TearDownTestSuite() {
    if (scratch_) fs::remove_all(*scratch_);
    delete data_;
    delete scratch_;
    delete mapped_;
    delete map_path_;
  }
  void SetUp() override {
    if (!data_) GTEST_SKIP() << "no sequence in " << STILLPOINT_DATA_DIR;
    ASSERT_TRUE(map_saved_);
  }
  static std::unique_ptr<slam::SlamSystem> makeSystem(bool localisation, const char* camera = "fr3") {
    slam::SlamOptions options;
    options.sequential = true;
    options.localisation = localisation;
    auto system = slam::SlamSystem::create(*cameraPreset(camera), options);
    EXPECT_TRUE(system.ok()) << system.error();
    return system.ok() ? std::move(*system) : nullptr;
  }
  // Tracks the first `frames` frames (each passed through `edit` first, when
  // given); the poses by frame index.
  static std::map<std::size_t, SE3> run(slam::SlamSystem* system, std::size_t* with_pose,
                                        const std::function<void(std::size_t, dataset::RgbdFrame*)>& edit = {},
                                        std::size_t frames = kFrames) {
    std::map<std::size_t, SE3> poses;
    *with_pose = 0;
    for (std::size_t i = 0; i < std::min(frames, data_->size()); ++i) {
      auto frame = data_->load(i);
      EXPECT_TRUE(frame.ok()) << frame.error();
      if (!frame) continue;
      if (edit) edit(i, &*frame);
      auto out = system->track({frame->stamp, frame->gray, frame->depth_m, frame->bgr});
      EXPECT_TRUE(out.ok()) << out.error();
      if (!out || !slam::hasPose(out->state)) continue;
      ++*with_pose;
      poses[i] = out->T_w_c;
    }
    return poses;
  }
  // The largest distance between a frame's position and the mapping run's.
  static double largestDifference(const std::map<std::size_t, SE3>& poses) {
    double worst = 0;
    for (const auto& [i, T] : poses)
      if (mapped_->count(i)) worst = std::max(worst, (T.translation() - mapped_->at(i).translation()).norm());
    return worst;
  }
  // Mapping (not localisation) over the frames on the map file `path`:
  // every frame must have a pose, within a few centimetres of the mapping
  // run that made the suite's map.
  struct MappingOnFile {
    slam::MapStats before, after;
    std::size_t with_pose = 0, frames = 0;
    double worst = 0;
    std::string summary() const {
      char line[160];
      std::snprintf(line, sizeof(line),
                    "%zu of %zu frames with a pose, largest difference to the mapping run %.4f m, %zu keyframes added",
                    with_pose, frames, worst, after.keyframes - before.keyframes);
      return line;
    }
  };
  static MappingOnFile mapOnFile(const fs::path& path,
                                 const std::function<void(std::size_t, dataset::RgbdFrame*)>& edit = {}) {
    MappingOnFile r;
    auto system = makeSystem(false);
    EXPECT_TRUE(system);
    if (!system) return r;
    EXPECT_TRUE(system->loadMap(path.string()).ok());
    r.before = system->mapStats();
    const auto mapped = run(system.get(), &r.with_pose, edit);
    system->finish();
    r.after = system->mapStats();
    r.frames = std::min(kFrames, data_->size());
    EXPECT_GE(r.with_pose * 100, r.frames * 95) << r.with_pose << " of " << r.frames;
    r.worst = largestDifference(mapped);
    EXPECT_LT(r.worst, 0.03);
    return r;
  }
  static inline dataset::TumDataset* data_ = nullptr;
  static inline fs::path* scratch_ = nullptr;
  static inline fs::path* map_path_ = nullptr;
  static inline std::map<std::size_t, SE3>* mapped_ = nullptr;
  static inline bool map_saved_ = false;
  static inline std::size_t map_points_ = 0;
};

TEST_F(MapFile, LocalisationFindsEveryFrameAndTheMapDoesNotGrow) {
  const fs::path path = *map_path_;
  auto system = makeSystem(true);
  ASSERT_TRUE(system);
  ASSERT_TRUE(system->loadMap(path.string()).ok());
  const slam::MapStats before = system->mapStats();
  EXPECT_GT(before.keyframes, 10u);
  std::size_t with_pose = 0;
  const auto localised = run(system.get(), &with_pose);
  system->finish();
  const slam::MapStats after = system->mapStats();
  EXPECT_EQ(after.keyframes, before.keyframes);
  EXPECT_EQ(after.points, before.points);
  EXPECT_EQ(after.maps, before.maps);
  const std::size_t frames = std::min(kFrames, data_->size());
  EXPECT_GE(with_pose * 100, frames * 95) << with_pose << " of " << frames;
  // In the mapping run's frame: the same place, within a few centimetres.
  const double worst = largestDifference(localised);
  EXPECT_LT(worst, 0.03);
  std::printf("localisation: %zu of %zu frames with a pose, largest difference to the mapping run %.4f m\n",
              with_pose, frames, worst);
}

// A textured board 0.8 m from the camera, over a quarter of the view from
// the first frame, sliding to and fro across it (a poster carried past): a
// rigid near surface moving on its own, nearer than anything in the room, so
// it lends the last frame's depth points first.
void slideBoard(std::size_t i, dataset::RgbdFrame* frame) {
  constexpr int kWidth = 320, kHeight = 240;
  static const cv::Mat texture = [] {
    cv::Mat t(kHeight / 10, kWidth / 10, CV_8UC1);
    cv::RNG rng(7);
    rng.fill(t, cv::RNG::UNIFORM, cv::Scalar(20), cv::Scalar(236));
    cv::resize(t, t, cv::Size(kWidth, kHeight), 0, 0, cv::INTER_NEAREST);
    cv::GaussianBlur(t, t, cv::Size(5, 5), 1.2);
    return t;
  }();
  // 3 px a frame, turning at the image's edges.
  const int travel = frame->gray.cols - kWidth, step = static_cast<int>(i) * 3 % (2 * travel);
  const cv::Rect where(step < travel ? step : 2 * travel - step, 90, kWidth, kHeight);
  texture.copyTo(frame->gray(where));
  frame->depth_m(where).setTo(0.8f);
  if (!frame->bgr.empty()) cv::cvtColor(texture, frame->bgr(where), cv::COLOR_GRAY2BGR);
}

// A segmenter that finds slideBoard's board, and only it, as a person: the
// board is the one large region of grey pixels (B = G = R) in the colour
// images of the excerpt.
class BoardSegmenter : public semantic::Segmenter {
 public:
  BoardSegmenter() {
    card_.name = "board";
    card_.classes = {"person"};
    card_.movable = {"person"};
  }
  Result<semantic::Segmentation> segment(const cv::Mat& bgr) override {
    if (bgr.empty() || bgr.type() != CV_8UC3) return Error{"not a BGR image"};
    ++*calls;
    std::vector<cv::Mat> c;
    cv::split(bgr, c);
    cv::Mat grey = (c[0] == c[1]) & (c[1] == c[2]);
    cv::morphologyEx(grey, grey, cv::MORPH_OPEN, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(31, 31)));
    semantic::Segmentation seg;
    seg.labels = cv::Mat(bgr.size(), CV_8U, cv::Scalar(semantic::kNoLabel));
    seg.movable_mask = cv::Mat::zeros(bgr.size(), CV_8U);
    const cv::Rect box = cv::boundingRect(grey);
    if (box.area() == 0) return seg;
    seg.labels(box).setTo(0, grey(box));
    seg.movable_mask(box).setTo(255, grey(box));
    semantic::Instance person;
    person.class_id = 0;
    person.class_name = "person";
    person.score = 0.9f;
    person.box = box;
    person.mask = grey(box).clone();
    person.area = cv::countNonZero(person.mask);
    person.movable = true;
    seg.movable_pixels = person.area;
    seg.instances.push_back(std::move(person));
    return seg;
  }
  const semantic::ModelCard& card() const override { return card_; }
  const std::vector<int>& movableClassIds() const override { return ids_; }
  std::shared_ptr<int> calls = std::make_shared<int>(0);  // outlives the segmenter (owned by the system)

 private:
  semantic::ModelCard card_;
  std::vector<int> ids_{0};
};

// Tracking against the saved map stays on the room the map holds.
TEST_F(MapFile, LocalisationStaysOnTheMapWhileABoardSlidesAcrossTheView) {
  auto system = makeSystem(true);
  ASSERT_TRUE(system);
  ASSERT_TRUE(system->loadMap(map_path_->string()).ok());
  std::size_t with_pose = 0;
  const auto localised = run(system.get(), &with_pose, slideBoard);
  system->finish();
  const std::size_t frames = std::min(kFrames, data_->size());
  EXPECT_GE(with_pose * 100, frames * 95) << with_pose << " of " << frames;
  const double worst = largestDifference(localised);
  EXPECT_LT(worst, 0.03);
  std::printf("localisation, a board across the view: %zu of %zu frames with a pose, largest difference to the "
              "mapping run %.4f m\n",
              with_pose, frames, worst);
}

// Mapping on the saved map, the same board: the room is a place the map
// holds, so the pose stays on it and the board is not mapped (no keyframe
// is needed there).
TEST_F(MapFile, MappingOnTheMapKeepsTheBoardOutOfIt) {
  const MappingOnFile r = mapOnFile(*map_path_, slideBoard);
  EXPECT_EQ(r.after.maps, r.before.maps);
  EXPECT_LE(r.after.keyframes, r.before.keyframes + 5);
  std::printf("mapping on the map, a board across the view: %s\n", r.summary().c_str());
}

// A map of the first half of the way only: mapping on it goes on mapping
// the ground the file does not hold.
TEST_F(MapFile, MappingOnAPartialMapMapsTheNewGround) {
  auto first = makeSystem(false);
  ASSERT_TRUE(first);
  std::size_t with_pose = 0;
  run(first.get(), &with_pose, {}, kFrames / 2);
  first->finish();
  const fs::path half = *scratch_ / "half.map";
  ASSERT_TRUE(first->saveMap(half.string()).ok());
  const MappingOnFile r = mapOnFile(half);
  EXPECT_GE(r.after.keyframes, r.before.keyframes + 5);  // none where the whole way is in the file (above)
  std::printf("mapping on a map of %zu frames: %s\n", kFrames / 2, r.summary().c_str());
}

// The board of slideBoard held at the left of the view: a person walking
// along with the camera, in front of the room the map holds.
void carriedBoard(std::size_t, dataset::RgbdFrame* frame) { slideBoard(0, frame); }

// Where the map holds the place, no keyframe is made and none brings the
// semantic module's masks (localisation, and mapping on the whole way): the
// frames themselves are segmented whenever the segmenter is free (here every
// 4 frames, the modelled delay), and their masks follow the person into the
// frames after them.
TEST_F(MapFile, FramesAreSegmentedWhereTheMapHoldsThePlace) {
  for (const bool localisation : {true, false}) {
    SCOPED_TRACE(localisation ? "localisation" : "mapping on the map");
    slam::SlamOptions options;
    options.sequential = true;
    options.localisation = localisation;
    options.report_fates = true;
    options.geometry.enabled = false;  // the marks counted are the masks' alone
    options.semantic.enabled = true;
    options.semantic.sequential_latency_frames = 4;
    auto segmenter = std::make_unique<BoardSegmenter>();
    const std::shared_ptr<int> calls = segmenter->calls;
    auto created = slam::SlamSystem::create(*cameraPreset("fr3"), options, std::move(segmenter));
    ASSERT_TRUE(created.ok()) << created.error();
    slam::SlamSystem& system = **created;
    ASSERT_TRUE(system.loadMap(map_path_->string()).ok());
    const slam::MapStats before = system.mapStats();
    std::map<std::size_t, SE3> poses;
    int after_first = 0, marked_frames = 0, on_board = 0, off_board = 0;
    for (std::size_t i = 0; i < std::min(kFrames, data_->size()); ++i) {
      auto frame = data_->load(i);
      ASSERT_TRUE(frame.ok()) << frame.error();
      carriedBoard(i, &*frame);
      const cv::Mat board = frame->depth_m == 0.8f;
      auto out = system.track({frame->stamp, frame->gray, frame->depth_m, frame->bgr});
      ASSERT_TRUE(out.ok()) << out.error();
      if (!slam::hasPose(out->state)) continue;
      poses[i] = out->T_w_c;
      int marked = 0;
      for (const slam::FeatureView& f : out->fates) {
        if (f.fate != slam::FeatureFate::kSemanticDynamic) continue;
        ++marked;
        (board.at<std::uint8_t>(cvRound(f.v), cvRound(f.u)) ? on_board : off_board)++;
      }
      if (system.mapStats().semantic_frames_segmented == 0) continue;
      ++after_first;
      marked_frames += marked > 0;
    }
    system.finish();
    const slam::MapStats after = system.mapStats();
    EXPECT_GE(after.semantic_frames_segmented, static_cast<int>(kFrames) / 8);
    EXPECT_EQ(after.semantic_keyframes_segmented, 0);
    EXPECT_EQ(*calls, after.semantic_frames_segmented);
    EXPECT_EQ(after.keyframes, before.keyframes);
    ASSERT_GT(after_first, static_cast<int>(kFrames) / 2);
    EXPECT_GE(marked_frames * 10, after_first * 9) << marked_frames << " of " << after_first;
    EXPECT_GT(on_board, 50 * marked_frames) << "features followed per frame on the board";
    EXPECT_LT(off_board * 10, on_board) << off_board << " marked off the board, " << on_board << " on it";
    EXPECT_GE(poses.size() * 100, kFrames * 95);
    EXPECT_LT(largestDifference(poses), 0.03);
    std::printf("%s: %d frames segmented, %d of %d frames after the first with the board marked, %.1f features "
                "on it and %.1f off it per such frame, largest difference to the mapping run %.4f m\n",
                localisation ? "localisation" : "mapping on the map", after.semantic_frames_segmented, marked_frames,
                after_first, double(on_board) / std::max(marked_frames, 1), double(off_board) / std::max(marked_frames, 1),
                largestDifference(poses));
  }
}

TEST_F(MapFile, SavedAgainAfterLoadingIsTheSameFile) {
  const fs::path path = *map_path_;
  auto system = makeSystem(false);
  ASSERT_TRUE(system->loadMap(path.string()).ok());
  const fs::path again = *scratch_ / "again.map";
  ASSERT_TRUE(system->saveMap(again.string()).ok());
  EXPECT_EQ(readBytes(path), readBytes(again));
  // A map is loaded before the first frame only.
  auto used = makeSystem(false);
  auto frame = data_->load(0);
  ASSERT_TRUE(frame.ok());
  ASSERT_TRUE(used->track({frame->stamp, frame->gray, frame->depth_m, frame->bgr}).ok());
  const Status late = used->loadMap(path.string());
  ASSERT_FALSE(late.ok());
  EXPECT_NE(late.error().find("before the first frame"), std::string::npos) << late.error();
}

// Version 1 files, from before the map kept its sightings, are read too.
TEST_F(MapFile, AVersionOneFileIsReadWithoutSightings) {
  const std::string good = readBytes(*map_path_);
  ASSERT_GT(good.size(), 1000u);
  const fs::path old = *scratch_ / "version1.map";
  // Without the camera's baseline and distortion (48 bytes after the 52 of
  // size, intrinsics and pyramid) and the sightings' count.
  const std::string payload = good.substr(40);
  writeBytes(old, resealed(good, payload.substr(0, 52) + payload.substr(100, payload.size() - 100 - 8), 1));
  auto system = makeSystem(false);
  const Status s = system->loadMap(old.string());
  ASSERT_TRUE(s.ok()) << s.error();
  EXPECT_EQ(system->mapStats().points, map_points_);
  // Saved again, it is this build's file.
  const fs::path again = *scratch_ / "version1-again.map";
  ASSERT_TRUE(system->saveMap(again.string()).ok());
  EXPECT_EQ(readBytes(again), good);
}

// Version 3 files named a sighting's map and cell by one key (the map id
// from bit 54, 18 bits per coordinate); read, they keep both, and saved
// again they are this build's file.
TEST_F(MapFile, AVersionThreeFilesSightingsKeepTheirMapAndCell) {
  const std::string good = readBytes(*map_path_);
  ASSERT_GT(good.size(), 1000u);
  const std::string payload = good.substr(40);
  ASSERT_EQ(payload.substr(payload.size() - 8), std::string(8, '\0'));  // the suite's map has no sightings
  const auto bits = [](int v) { return static_cast<std::uint64_t>(v) & 0x3ffff; };
  const std::uint64_t one = 1, key = (bits(3) << 36) | (bits(-2) << 18) | bits(7);
  const std::int32_t on_static = 3, in_movable = 1;
  const std::int64_t first_ns = 1'000'000'000, last_ns = 4'000'000'000;
  const auto put = [](std::string* out, const auto& v) {
    out->append(reinterpret_cast<const char*>(&v), sizeof(v));
  };
  std::string v3 = payload.substr(0, payload.size() - 8);
  put(&v3, one);
  put(&v3, key);
  put(&v3, on_static);
  put(&v3, in_movable);
  put(&v3, first_ns);
  put(&v3, last_ns);
  const fs::path old = *scratch_ / "version3.map";
  writeBytes(old, resealed(good, v3, 3));
  auto system = makeSystem(false);
  const Status s = system->loadMap(old.string());
  ASSERT_TRUE(s.ok()) << s.error();
  EXPECT_EQ(system->mapStats().semantic_sighting_cells, 1u);
  const fs::path again = *scratch_ / "version3-again.map";
  ASSERT_TRUE(system->saveMap(again.string()).ok());
  std::string v4 = payload.substr(0, payload.size() - 8);
  put(&v4, one);
  put(&v4, std::uint32_t{0});
  for (std::int32_t c : {3, -2, 7}) put(&v4, c);
  put(&v4, on_static);
  put(&v4, in_movable);
  put(&v4, first_ns);
  put(&v4, last_ns);
  EXPECT_EQ(readBytes(again), resealed(good, v4, kVersion));
}

TEST_F(MapFile, BadFilesAreErrorsNamingTheFile) {
  const fs::path path = *map_path_;
  const std::string good = readBytes(path);
  ASSERT_GT(good.size(), 1000u);
  struct Case {
    const char* name;
    std::string bytes;
    const char* why;
  };
  std::string corrupt = good, version = good, empty;
  corrupt[good.size() / 2] ^= 0x5a;
  version[8] = 9;
  const Case cases[] = {
      {"truncated.map", good.substr(0, good.size() / 2), "truncated"},
      {"header.map", good.substr(0, 20), "truncated"},
      {"corrupt.map", corrupt, "checksum"},
      {"version.map", version, "format version 9"},
      {"empty.map", empty, "truncated"},
      {"text.map", std::string(100, 'x'), "not a stillpoint map"},
  };
  for (const Case& c : cases) {
    const fs::path bad = *scratch_ / c.name;
    writeBytes(bad, c.bytes);
    auto system = makeSystem(false);
    const Status s = system->loadMap(bad.string());
    ASSERT_FALSE(s.ok()) << c.name;
    EXPECT_NE(s.error().find(bad.string()), std::string::npos) << s.error();
    EXPECT_NE(s.error().find(c.why), std::string::npos) << c.name << ": " << s.error();
    // The system is unchanged: it starts its own map.
    auto frame = data_->load(0);
    auto out = system->track({frame->stamp, frame->gray, frame->depth_m, frame->bgr});
    ASSERT_TRUE(out.ok());
    EXPECT_EQ(out->state, slam::TrackingState::kOk) << c.name;
  }
  // A sighting of a map the file does not have (the suite's map has none:
  // the file ends with their count, 0).
  const std::string payload = good.substr(40);
  ASSERT_EQ(payload.substr(payload.size() - 8), std::string(8, '\0'));
  std::string sighting(8 + 40, '\0');
  const std::uint64_t one = 1;
  const std::uint32_t map_200 = 200;
  const std::int32_t seen = 3;
  std::memcpy(&sighting[0], &one, 8);
  std::memcpy(&sighting[8], &map_200, 4);
  std::memcpy(&sighting[24], &seen, 4);
  const fs::path foreign = *scratch_ / "sighting.map";
  writeBytes(foreign, resealed(good, payload.substr(0, payload.size() - 8) + sighting, kVersion));
  const Status s = makeSystem(false)->loadMap(foreign.string());
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().find("bad sighting 0"), std::string::npos) << s.error();
  // Another camera's map.
  auto fr1 = makeSystem(false, "fr1");
  const Status other = fr1->loadMap(path.string());
  ASSERT_FALSE(other.ok());
  EXPECT_NE(other.error().find("another camera"), std::string::npos) << other.error();
  // The same intrinsics, another virtual baseline: the features' right
  // coordinates would be misread.
  std::string baseline = payload;
  const double wider = 0.1;
  std::memcpy(&baseline[52], &wider, 8);
  const fs::path wide = *scratch_ / "baseline.map";
  writeBytes(wide, resealed(good, baseline, kVersion));
  const Status misread = makeSystem(false)->loadMap(wide.string());
  ASSERT_FALSE(misread.ok());
  EXPECT_NE(misread.error().find("baseline 0.1000"), std::string::npos) << misread.error();
  // Missing file; localisation without a map.
  EXPECT_FALSE(makeSystem(false)->loadMap((*scratch_ / "none.map").string()).ok());
  auto lonely = makeSystem(true);
  auto frame = data_->load(0);
  const auto out = lonely->track({frame->stamp, frame->gray, frame->depth_m, frame->bgr});
  ASSERT_FALSE(out.ok());
  EXPECT_NE(out.error().find("loaded map"), std::string::npos) << out.error();
}

TEST_F(MapFile, ExportsTheMapPointsAsAColouredCloud) {
  // From the loaded map: the colours travel in the map file.
  auto system = makeSystem(false);
  ASSERT_TRUE(system->loadMap(map_path_->string()).ok());
  EXPECT_EQ(system->mapStats().points, map_points_);
  const fs::path ply = *scratch_ / "map.ply";
  ASSERT_TRUE(system->exportCloud(ply.string()).ok());
  const std::string bytes = readBytes(ply);
  const std::size_t end = bytes.find("end_header\n");
  ASSERT_NE(end, std::string::npos);
  const std::size_t count_at = bytes.find("element vertex ");
  ASSERT_NE(count_at, std::string::npos);
  const std::size_t vertices = std::stoul(bytes.substr(count_at + 15));
  EXPECT_EQ(vertices, system->mapStats().points);
  EXPECT_EQ(bytes.size() - end - 11, vertices * 15);
  // Colours are the images' (the excerpt is not grey).
  bool coloured = false;
  for (std::size_t v = 0; v < vertices && !coloured; ++v) {
    const unsigned char* c = reinterpret_cast<const unsigned char*>(bytes.data() + end + 11 + v * 15 + 12);
    coloured = c[0] != c[1] || c[1] != c[2];
  }
  EXPECT_TRUE(coloured);
  EXPECT_FALSE(system->exportCloud((*scratch_ / "no" / "dir" / "map.ply").string()).ok());
}

}  // namespace
}  // namespace stillpoint
