// Kidnapped camera on real data: after frames 0..kFirstPass-1 the camera
// "jumps" back to the start of the sequence. Tracking must notice (lost), find
// itself again against the map (relocalised) and then report poses that agree
// with the ones it estimated the first time it saw those frames.
#include <gtest/gtest.h>

#include <filesystem>
#include <map>

#include "stillpoint/core/camera.hpp"
#include "stillpoint/dataset/tum_dataset.hpp"
#include "stillpoint/slam/system.hpp"

namespace stillpoint {
namespace {

constexpr std::size_t kFirstPass = 90;
constexpr std::size_t kSecondPass = 40;

TEST(Relocalisation, RecoversAfterTheCameraJumpsBackToTheStart) {
  const std::string dir = std::string(STILLPOINT_DATA_DIR) + "/tum_fr3_teddy_200";
  if (!std::filesystem::exists(dir + "/rgb.txt")) GTEST_SKIP() << "no sequence at " << dir;
  auto data = dataset::TumDataset::open(dir);
  ASSERT_TRUE(data.ok()) << data.error();
  ASSERT_GT(data->size(), kFirstPass);
  const CameraModel camera = *cameraPreset("fr3");
  slam::SlamOptions options;
  options.sequential = true;
  auto system = slam::SlamSystem::create(camera, options);
  ASSERT_TRUE(system.ok()) << system.error();

  std::map<std::size_t, SE3> first_pass;
  std::int64_t last_ns = 0;
  for (std::size_t i = 0; i < kFirstPass; ++i) {
    auto frame = data->load(i);
    ASSERT_TRUE(frame.ok()) << frame.error();
    last_ns = frame->stamp.nanoseconds();
    auto out = (*system)->track({frame->stamp, frame->gray, frame->depth_m});
    ASSERT_TRUE(out.ok()) << out.error();
    ASSERT_NE(out->state, slam::TrackingState::kLost) << "frame " << i;
    first_pass[i] = out->T_w_c;
  }

  // Replay the first frames again with later timestamps: a kidnapped camera.
  bool saw_lost = false, saw_relocalised = false;
  int compared = 0;
  double worst_m = 0;
  for (std::size_t i = 0; i < kSecondPass; ++i) {
    auto frame = data->load(i);
    ASSERT_TRUE(frame.ok()) << frame.error();
    const Timestamp stamp = Timestamp::fromNanoseconds(last_ns + static_cast<std::int64_t>(i + 1) * 33'000'000);
    auto out = (*system)->track({stamp, frame->gray, frame->depth_m});
    ASSERT_TRUE(out.ok()) << out.error();
    saw_lost |= out->state == slam::TrackingState::kLost;
    saw_relocalised |= out->state == slam::TrackingState::kRelocalised;
    if (saw_relocalised && out->state != slam::TrackingState::kLost) {
      const double d = (out->T_w_c.translation() - first_pass[i].translation()).norm();
      worst_m = std::max(worst_m, d);
      ++compared;
    }
  }
  (*system)->finish();
  EXPECT_TRUE(saw_relocalised) << "never relocalised (lost seen: " << saw_lost << ")";
  EXPECT_GT(compared, static_cast<int>(kSecondPass) / 2) << "too few frames tracked after the jump";
  // Same images, same map: the second estimate must land where the first was.
  EXPECT_LT(worst_m, 0.03) << "relocalised poses differ from the first pass by up to " << worst_m << " m";
  std::printf("relocalisation: lost seen %d, %d frames compared after relocalising, worst difference %.4f m\n",
              saw_lost, compared, worst_m);
}

}  // namespace
}  // namespace stillpoint
