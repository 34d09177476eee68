// A robot going round the same room for days: the real excerpt replayed in
// laps, each starting over at the first frame (later timestamps), as
// stillpointd's looped replay source does. At every lap start the camera
// "teleports" back to the start pose. Tracking must find the existing map
// there within a few frames and keep it, and the memory the SLAM core holds (keyframes,
// map points, trajectory records) must stop growing once the room is mapped.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <vector>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/slam/system.hpp"

namespace stillpoint {
namespace {

constexpr int kLaps = 5;

TEST(LoopedReplay, MapStopsGrowingAndEachLapRelocalisesAtOnce) {
  const std::string dir = std::string(STILLPOINT_DATA_DIR) + "/tum_fr3_teddy_200";
  if (!std::filesystem::exists(dir + "/rgb.txt")) GTEST_SKIP() << "no sequence at " << dir;
  auto data = dataset::TumDataset::open(dir);
  ASSERT_TRUE(data.ok()) << data.error();
  ASSERT_GT(data->size(), 100u);
  slam::SlamOptions options;
  options.sequential = true;
  options.tracking.trajectory_records = 0;  // as stillpointd without a trajectory file
  auto system = slam::SlamSystem::create(*cameraPreset("fr3"), options);
  ASSERT_TRUE(system.ok()) << system.error();

  const std::int64_t span = data->load(data->size() - 1)->stamp.nanoseconds() - data->load(0)->stamp.nanoseconds();
  std::vector<slam::MapStats> after_lap;
  std::vector<int> lost_in_lap, lost_after_found;
  for (int lap = 0; lap < kLaps; ++lap) {
    const std::int64_t offset = lap * (span + 33'333'333);
    int lost = 0, relost = 0;
    bool found = false;
    for (std::size_t i = 0; i < data->size(); ++i) {
      auto frame = data->load(i);
      ASSERT_TRUE(frame.ok()) << frame.error();
      const Timestamp stamp = Timestamp::fromNanoseconds(frame->stamp.nanoseconds() + offset);
      auto out = (*system)->track({stamp, frame->gray, frame->depth_m});
      ASSERT_TRUE(out.ok()) << out.error();
      const bool is_lost = out->state == slam::TrackingState::kLost;
      lost += is_lost;
      relost += found && is_lost;
      found |= !is_lost;
    }
    lost_in_lap.push_back(lost);
    lost_after_found.push_back(relost);
    after_lap.push_back((*system)->mapStats());
    const slam::MapStats& m = after_lap.back();
    std::printf("lap %d: %d frames lost; map %zu keyframes, %zu points; in memory %zu keyframes, %zu points, "
                "%zu trajectory records\n",
                lap, lost, m.keyframes, m.points, m.keyframes_in_memory, m.points_in_memory, m.trajectory_records);
  }
  (*system)->finish();

  EXPECT_EQ(lost_in_lap[0], 0);
  for (int lap = 1; lap < kLaps; ++lap) {
    EXPECT_LE(lost_in_lap[lap], 3) << "lap " << lap << ": the start of the room is mapped; relocalise there";
    // Once relocalised, tracking holds: the frame after a relocalisation
    // falls back on the last frame's points (it used to be lost every lap).
    EXPECT_EQ(lost_after_found[lap], 0) << "lap " << lap;
  }
  for (const slam::MapStats& m : after_lap) {
    EXPECT_EQ(m.trajectory_records, 0u);
    // Culled keyframes are freed at the next keyframe: only the last few wait.
    EXPECT_LE(m.keyframes_in_memory, m.keyframes + 5);
  }
  // The same room again: the last laps add nothing that stays.
  const slam::MapStats &before = after_lap[kLaps - 2], &last = after_lap[kLaps - 1];
  EXPECT_LE(last.keyframes_in_memory, before.keyframes_in_memory + 1);
  EXPECT_LE(last.points_in_memory, before.points_in_memory + before.points_in_memory / 20);
}

}  // namespace
}  // namespace stillpoint
