#include "config.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "bounded_queue.hpp"

namespace stillpoint::daemon {
namespace {

class ConfigTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("sp_daemon_config_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string write(const std::string& text, const std::string& name = "d.yaml") {
    const auto path = dir_ / name;
    std::ofstream(path) << text;
    return path.string();
  }
  // Expects loading to fail with a message containing every piece.
  void expectError(const std::string& text, std::initializer_list<std::string> pieces) {
    auto c = loadDaemonConfig(write(text));
    ASSERT_FALSE(c) << text;
    for (const auto& p : pieces) EXPECT_NE(c.error().find(p), std::string::npos) << c.error() << "\n  missing: " << p;
  }
  std::filesystem::path dir_;
};

TEST_F(ConfigTest, MinimalConfigGetsDefaults) {
  auto c = loadDaemonConfig(write("source: {replay: {path: /data/x}}\n"));
  ASSERT_TRUE(c) << c.error();
  EXPECT_EQ(c->source.type, "replay");
  EXPECT_TRUE(c->source.replay.paced);
  EXPECT_EQ(c->camera.name, cameraPreset("fr3")->name);
  EXPECT_TRUE(c->ipc.shm.enabled);
  EXPECT_EQ(c->slam.geometry.enabled, slam::GeometryOptions{}.enabled);
  EXPECT_TRUE(c->threads.tracking.cores.empty());
}

// The daemon runs for days: per-frame poses are kept only for a trajectory
// file, and then as many as the SLAM options say.
TEST_F(ConfigTest, TrajectoryRecordsOnlyForATrajectoryFile) {
  auto without = loadDaemonConfig(
      write("source: {replay: {path: /d}}\nslam: {options: {tracking: {trajectory_records: 500}}}\n"));
  ASSERT_TRUE(without) << without.error();
  EXPECT_EQ(without->slam.tracking.trajectory_records, 0);
  auto with = loadDaemonConfig(write("source: {replay: {path: /d}}\noutput: {trajectory: /tmp/t.txt}\n"
                                     "slam: {options: {tracking: {trajectory_records: 500}}}\n"));
  ASSERT_TRUE(with) << with.error();
  EXPECT_EQ(with->slam.tracking.trajectory_records, 500);
  auto all = loadDaemonConfig(write("source: {replay: {path: /d}}\noutput: {trajectory: /tmp/t.txt}\n"));
  ASSERT_TRUE(all) << all.error();
  EXPECT_EQ(all->slam.tracking.trajectory_records, -1);
}

TEST_F(ConfigTest, ShippedConfigLoads) {
  // The shipped file names the installed slam.yaml; point it at the source tree's copy.
  std::ifstream in(STILLPOINT_SOURCE_DIR "/config/stillpointd.yaml");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string installed = "/etc/stillpoint/slam.yaml";
  const auto at = text.find(installed);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, installed.size(), STILLPOINT_SOURCE_DIR "/config/slam.yaml");
  auto c = loadDaemonConfig(write(text));
  ASSERT_TRUE(c) << c.error();
  EXPECT_EQ(c->threads.tracking.cores, std::vector<int>{1});
  EXPECT_TRUE(c->lock_memory);  // the robot's setting; the built-in default is off
  auto bare = loadDaemonConfig(write("source: {replay: {path: /d}}\n"));
  ASSERT_TRUE(bare) << bare.error();
  EXPECT_FALSE(bare->lock_memory);
}

TEST_F(ConfigTest, PrintedConfigLoadsToTheSameConfig) {
  auto c = loadDaemonConfig(write(
      "camera: fr1\nsource: {queue_capacity: 3, replay: {path: /d, paced: false, max_frames: 7}}\n"
      "modules: {geometry: true}\nthreads: {tracking: {cores: [1, 3], priority: 20}, publisher: {nice: 3}}\n"
      "slam: {options: {orb: {num_features: 800}, sequential: true}}\n"
      "ipc: {shm: {name: ring_x}}\noutput: {trajectory: /tmp/t.txt}\n"));
  ASSERT_TRUE(c) << c.error();
  EXPECT_EQ(c->slam.orb.num_features, 800);
  EXPECT_TRUE(c->slam.sequential);
  EXPECT_TRUE(c->slam.geometry.enabled);
  const std::string printed = toYaml(*c);
  auto again = loadDaemonConfig(write(printed, "printed.yaml"));
  ASSERT_TRUE(again) << again.error() << "\n" << printed;
  EXPECT_EQ(toYaml(*again), printed);
  EXPECT_EQ(again->threads.tracking.cores, (std::vector<int>{1, 3}));
  EXPECT_EQ(again->threads.tracking.priority, 20);
  EXPECT_EQ(again->threads.publisher.nice, 3);
  EXPECT_EQ(again->threads.mapping.nice, 5);     // the defaults: local mapping and
  EXPECT_EQ(again->threads.semantic.nice, 10);   // segmentation yield to tracking
  EXPECT_EQ(again->threads.tracking.nice, 0);
  EXPECT_EQ(again->source.replay.max_frames, 7u);
  EXPECT_EQ(again->ipc.shm.name, "ring_x");
  EXPECT_EQ(again->slam.orb.num_features, 800);
  EXPECT_EQ(again->camera.name, cameraPreset("fr1")->name);
}

TEST_F(ConfigTest, ErrorsNameTheField) {
  const std::string src = "source: {replay: {path: /d}}\n";
  expectError(src + "bogus: 1\n", {"unknown field 'bogus'", "line 2"});
  expectError("source:\n  replay: {path: /d}\n  typo: 3\n", {"unknown field 'source.typo'", "line 3"});
  expectError(src + "camera: fr1\ncamera: fr3\n", {"duplicate field 'camera'", "line 3"});
  expectError(src + "? [a, b]\n: 1\n", {"plain names", "line 2"});
  expectError("source: {replay: {path: /d, paced: maybe}}\n", {"'source.replay.paced'", "wrong type"});
  expectError("source: {type: kinect, replay: {path: /d}}\n", {"'source.type'", "kinect"});
  expectError("source: {queue_capacity: 0, replay: {path: /d}}\n", {"'source.queue_capacity'"});
  expectError("source: {type: replay}\n", {"'source.replay.path'"});
  expectError(src + "camera: fr9\n", {"'camera'"});
  expectError(src + "threads: {tracking: {cores: 3}}\n", {"'threads.tracking.cores'", "list"});
  expectError(src + "threads: {tracking: {cores: [1, x]}}\n", {"'threads.tracking.cores'"});
  expectError(src + "threads: {mapping: {priority: 120}}\n", {"'threads.mapping.priority'", "1..99"});
  expectError(src + "threads: {gpu: {cores: [1]}}\n", {"unknown field 'threads.gpu'"});
  expectError(src + "threads: {semantic: {nice: 20}}\n", {"'threads.semantic.nice'", "-20..19"});
  expectError(src + "slam: {options: {orb: {num_features: -5}}}\n", {"slam.options", "num_features"});
  expectError(src + "slam: {options: {orb: {bogus: 1}}}\n", {"slam.options", "orb.bogus"});
  expectError(src + "slam: {options_file: /nonexistent/slam.yaml}\n", {"'slam.options_file'", "/nonexistent/slam.yaml"});
  expectError(src + "modules: {semantic: maybe}\n", {"'modules.semantic'", "wrong type"});
  expectError(src + "modules: {semantic: true, semantic_model_dirs: /models}\n", {"'modules.semantic_model_dirs'", "list"});
  expectError(src + "threads: {semantic: {priority: -1}}\n", {"'threads.semantic.priority'"});
  expectError(src + "ipc: {shm: {capacity: 1000}}\n", {"ipc", "capacity"});
  expectError(src + "log_level: loud\n", {"'log_level'", "loud"});
  expectError(src + "shutdown_timeout_s: 0\n", {"'shutdown_timeout_s'"});
  expectError("source: [1, 2]\n", {"'source'", "mapping"});
  expectError("source: {replay: {path: /d}\n", {"line"});  // YAML syntax error
  auto missing = loadDaemonConfig((dir_ / "absent.yaml").string());
  ASSERT_FALSE(missing);
  EXPECT_NE(missing.error().find("absent.yaml"), std::string::npos);
}

TEST_F(ConfigTest, SemanticModuleWithTheInTreeModel) {
  // A relative card name is found in the project's models/ folder.
  auto c = loadDaemonConfig(write(
      "source: {replay: {path: /d}}\nmodules: {semantic: true, semantic_model_card: person_selfie_256.yaml}\n"
      "threads: {semantic: {cores: [1], priority: 0}}\n"));
  ASSERT_TRUE(c) << c.error();
  EXPECT_TRUE(c->slam.semantic.enabled);
  EXPECT_EQ(c->slam.semantic.model_card, "person_selfie_256.yaml");
  EXPECT_NE(c->semantic_model.model_path.find("person_selfie_256.onnx"), std::string::npos);
  EXPECT_TRUE(c->source.replay.colour);  // keyframes are segmented in colour
  EXPECT_TRUE(c->source.openni2.colour);
  EXPECT_EQ(c->threads.semantic.cores, std::vector<int>{1});
  const std::string printed = toYaml(*c);
  auto again = loadDaemonConfig(write(printed, "printed.yaml"));
  ASSERT_TRUE(again) << again.error() << "\n" << printed;
  EXPECT_EQ(toYaml(*again), printed);
  EXPECT_EQ(again->modules.semantic_model_card, "person_selfie_256.yaml");

  // Off: no colour asked of the source.
  auto off = loadDaemonConfig(write("source: {replay: {path: /d}}\n"));
  ASSERT_TRUE(off) << off.error();
  EXPECT_FALSE(off->slam.semantic.enabled);
  EXPECT_FALSE(off->source.replay.colour);
}

TEST_F(ConfigTest, SemanticModelErrorsNameTheField) {
  const std::string src = "source: {replay: {path: /d}}\n";
  const std::string missing_card = (dir_ / "no_such_card.yaml").string();
  expectError(src + "modules: {semantic: true, semantic_model_card: " + missing_card + "}\n",
              {"'modules.semantic_model_card'", "no_such_card.yaml", "cannot be opened"});
  // A card that is not one.
  const std::string bad_card = write("name: x\nmodel: [\n", "bad_card.yaml");
  expectError(src + "modules: {semantic: true, semantic_model_card: " + bad_card + "}\n",
              {"'modules.semantic_model_card'", "bad_card.yaml"});
  // A valid card whose model file is missing.
  std::ifstream in(STILLPOINT_SOURCE_DIR "/models/person_selfie_256.yaml");
  const std::string card_text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string card = write(card_text, "card.yaml");
  expectError(src + "modules: {semantic: true, semantic_model_card: " + card + "}\n",
              {"'modules.semantic_model_card'", "person_selfie_256.onnx", "not found"});
  // The card of the SLAM options, when the modules section names none.
  expectError(src + "modules: {semantic: true}\nslam: {options: {semantic: {model_card: " + missing_card + "}}}\n",
              {"'slam.options.semantic.model_card'", "no_such_card.yaml"});
  // Off: the card is not looked at.
  auto off = loadDaemonConfig(write(src + "modules: {semantic: false, semantic_model_card: " + missing_card + "}\n"));
  EXPECT_TRUE(off) << off.error();
}

TEST_F(ConfigTest, V4l2SourceKeysAndErrors) {
  const std::string v4l2 =
      "source:\n  type: v4l2\n  v4l2: {colour_device: /dev/video4, depth_device: /dev/video0, fps: 15, "
      "depth_scale: 0.0001, pair_tolerance_ms: 10, depth_registered: true}\n";
  auto c = loadDaemonConfig(write(v4l2));
  ASSERT_TRUE(c) << c.error();
  EXPECT_EQ(c->source.v4l2.colour_device, "/dev/video4");
  EXPECT_EQ(c->source.v4l2.depth_device, "/dev/video0");
  EXPECT_EQ(c->source.v4l2.fps, 15);
  EXPECT_DOUBLE_EQ(c->source.v4l2.depth_scale, 0.0001);
  EXPECT_DOUBLE_EQ(c->source.v4l2.pair_tolerance_ms, 10);
  EXPECT_EQ(c->source.v4l2.width, 640);
  const std::string printed = toYaml(*c);
  auto again = loadDaemonConfig(write(printed, "printed.yaml"));
  ASSERT_TRUE(again) << again.error() << "\n" << printed;
  EXPECT_EQ(toYaml(*again), printed);
  EXPECT_EQ(again->source.v4l2.depth_device, "/dev/video0");

  expectError("source: {type: v4l2}\n", {"'source.v4l2.colour_device'", "required"});
  expectError("source: {type: v4l2, v4l2: {colour_device: /dev/video4}}\n", {"'source.v4l2.depth_device'"});
  expectError("source: {type: v4l2, v4l2: {colour_device: /dev/video4, depth_device: /dev/video0}}\n",
              {"'source.v4l2.depth_registered'", "registered to colour"});
  const std::string devices = "colour_device: /dev/video4, depth_device: /dev/video0, depth_registered: true";
  expectError("source: {type: v4l2, v4l2: {" + devices + ", depth_scale: -1}}\n", {"'source.v4l2.depth_scale'"});
  expectError("source: {type: v4l2, v4l2: {" + devices + ", pair_tolerance_ms: 0}}\n",
              {"'source.v4l2.pair_tolerance_ms'"});
  expectError("source: {type: v4l2, v4l2: {" + devices + ", width: 848}}\n",
              {"'source.v4l2.width'", "848x480", "camera"});
  expectError("source: {type: v4l2, v4l2: {" + devices + ", fps: fast}}\n", {"'source.v4l2.fps'", "wrong type"});
  expectError("source: {type: v4l2, v4l2: {" + devices + ", format: Z16}}\n", {"unknown field 'source.v4l2.format'"});
  // Colour for the semantic module.
  auto semantic = loadDaemonConfig(write(v4l2 + "modules: {semantic: true, semantic_model_card: person_selfie_256.yaml}\n"));
  ASSERT_TRUE(semantic) << semantic.error();
  EXPECT_TRUE(semantic->source.v4l2.colour);
}

TEST(BoundedQueueTest, DropOldestKeepsTheNewestAndCounts) {
  BoundedQueue<int> q(2, BoundedQueue<int>::Policy::kDropOldest);
  for (int i = 0; i < 5; ++i) EXPECT_TRUE(q.push(i));
  EXPECT_EQ(q.dropped(), 3u);
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(0)), 3);
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(0)), 4);
  EXPECT_FALSE(q.pop(std::chrono::milliseconds(1)));
}

TEST(BoundedQueueTest, BlockingPushWaitsForRoomAndCloseReleasesIt) {
  BoundedQueue<int> q(1, BoundedQueue<int>::Policy::kBlock);
  ASSERT_TRUE(q.push(1));
  std::atomic<int> result{-1};
  std::thread producer([&] { result = q.push(2) ? 1 : 0; });
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_EQ(result, -1);  // still waiting: nothing is dropped in blocking mode
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(100)), 1);
  producer.join();
  EXPECT_EQ(result, 1);
  EXPECT_EQ(q.dropped(), 0u);
  std::thread blocked([&] { result = q.push(3) ? 1 : 0; });
  q.close(/*drain=*/true);
  blocked.join();
  EXPECT_EQ(result, 0);
  EXPECT_EQ(*q.pop(std::chrono::milliseconds(0)), 2);  // drained after close
  EXPECT_TRUE(q.closedAndEmpty());
}

TEST(BoundedQueueTest, CloseWithoutDrainDiscards) {
  BoundedQueue<int> q(4, BoundedQueue<int>::Policy::kBlock);
  q.push(1);
  q.push(2);
  q.close(/*drain=*/false);
  EXPECT_FALSE(q.pop(std::chrono::milliseconds(0)));
  EXPECT_EQ(q.discarded(), 2u);
  EXPECT_FALSE(q.push(3));
}

}  // namespace
}  // namespace stillpoint::daemon
