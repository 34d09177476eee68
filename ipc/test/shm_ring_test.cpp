// The shared-memory ring in one process: the C++ writer against the header-only reader.
// Cross-process stress (torn reads, restarts, late readers) is in shm_stress_test.sh.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <utility>

#include "stillpoint/ipc/shm_writer.hpp"
#include "stillpoint/ipc/transport.hpp"
#include "stillpoint_shm.h"

namespace stillpoint::ipc {
namespace {

std::string uniqueName(const char* what) { return std::string("sp_ut_") + what + "_" + std::to_string(::getpid()); }

sp_pose_record record(std::uint64_t k) {
  sp_pose_record r{};
  r.frame_counter = k;
  r.sensor_stamp_ns = static_cast<std::int64_t>(k) * 1000;
  r.position[0] = 0.5 * static_cast<double>(k);
  r.orientation[3] = 1.0;
  r.tracking_state = SP_TRACKING_OK;
  r.map_id = 0xABCDEF0123456789ULL;
  return r;
}

class Ring : public testing::Test {
 protected:
  void SetUp() override {
    name_ = uniqueName(testing::UnitTest::GetInstance()->current_test_info()->name());
    (void)ShmPoseWriter::remove(name_);
    sp_shm_reader_init(&reader_);
  }
  void TearDown() override {
    sp_shm_reader_close(&reader_);
    (void)ShmPoseWriter::remove(name_);
    (void)ShmPoseWriter::remove(name_ + "_objects");
  }
  // A writer that published record 1, which the reader read from its start,
  // and then stopped cleanly.
  void readFromAWriterThatStops() {
    auto w = ShmPoseWriter::create(name_, 8);
    ASSERT_TRUE(w.ok());
    ASSERT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_OK);
    (*w)->write(record(1));
    sp_pose_record out;
    ASSERT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_OK);
  }
  std::string name_;
  sp_shm_reader reader_;
};

TEST_F(Ring, RecordsArriveInOrderWithEveryField) {
  auto w = ShmPoseWriter::create(name_, 16);
  ASSERT_TRUE(w.ok()) << w.error();
  ASSERT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_OK);
  sp_pose_record out;
  EXPECT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_EMPTY);
  for (std::uint64_t k = 1; k <= 5; ++k) (*w)->write(record(k));
  for (std::uint64_t k = 1; k <= 5; ++k) {
    ASSERT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_OK);
    sp_pose_record expected = record(k);
    expected.sequence = k;
    EXPECT_EQ(std::memcmp(&expected, &out, sizeof(out)), 0) << "record " << k;
  }
  EXPECT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_EMPTY);
  EXPECT_EQ(reader_.lost, 0u);
  EXPECT_EQ(reader_.generation, 1u);
}

TEST_F(Ring, StartLatestSkipsHistoryStartOldestReplaysIt) {
  auto w = ShmPoseWriter::create(name_, 8);
  ASSERT_TRUE(w.ok());
  for (std::uint64_t k = 1; k <= 3; ++k) (*w)->write(record(k));
  sp_pose_record out;
  ASSERT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_OK);
  EXPECT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_EMPTY);
  ASSERT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_OLDEST), SP_SHM_OK);
  ASSERT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_OK);
  EXPECT_EQ(out.sequence, 1u);
  ASSERT_EQ(sp_shm_reader_latest(&reader_, &out), SP_SHM_OK);
  EXPECT_EQ(out.frame_counter, 3u);
}

TEST_F(Ring, OverrunSkipsToTheOldestSurvivorAndCountsTheLoss) {
  auto w = ShmPoseWriter::create(name_, 8);
  ASSERT_TRUE(w.ok());
  ASSERT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_OLDEST), SP_SHM_OK);
  for (std::uint64_t k = 1; k <= 20; ++k) (*w)->write(record(k));
  sp_pose_record out;
  ASSERT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_OK);
  EXPECT_EQ(out.sequence, 13u);
  EXPECT_EQ(reader_.lost, 12u);
}

TEST_F(Ring, WriterRestartIsDetectedAndTheNewStreamRead) {
  ASSERT_NO_FATAL_FAILURE(readFromAWriterThatStops());
  EXPECT_EQ(sp_shm_reader_writer_closed(&reader_), 1);
  sp_pose_record out;
  auto w2 = ShmPoseWriter::create(name_, 8);
  ASSERT_TRUE(w2.ok()) << w2.error();
  EXPECT_EQ((*w2)->generation(), 2u);
  (*w2)->write(record(100));
  EXPECT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_RESTARTED);
  EXPECT_EQ(reader_.generation, 2u);
  EXPECT_EQ(reader_.restarts, 1u);
  ASSERT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_OK);
  EXPECT_EQ(out.sequence, 1u);
  EXPECT_EQ(out.frame_counter, 100u);
}

// A restarted writer whose ring cannot be attached at first (here another
// file stands at the name for a moment) is still reported as a restart once
// its ring can be read.
TEST_F(Ring, ARestartAttachedLateIsStillARestart) {
  ASSERT_NO_FATAL_FAILURE(readFromAWriterThatStops());
  sp_pose_record out;
  const std::string path = "/dev/shm/" + name_;
  ::unlink(path.c_str());
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL, 0600);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::write(fd, "not a ring", 10), 10);
  ::close(fd);
  EXPECT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_EMPTY);  // the new file is no ring: not attached
  ::unlink(path.c_str());
  auto w2 = ShmPoseWriter::create(name_, 8);
  ASSERT_TRUE(w2.ok()) << w2.error();
  (*w2)->write(record(100));
  EXPECT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_RESTARTED);
  EXPECT_EQ(reader_.restarts, 1u);
  ASSERT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_OK);
  EXPECT_EQ(out.frame_counter, 100u);
}

// A ring file cut short under the reader is let go before a read of the
// missing part would fault (SIGBUS).
TEST_F(Ring, ARingTruncatedUnderTheReaderIsLetGo) {
  auto w = ShmPoseWriter::create(name_, 8);
  ASSERT_TRUE(w.ok());
  ASSERT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_OK);
  ASSERT_EQ(::truncate(("/dev/shm/" + name_).c_str(), SP_SHM_HEADER_SIZE), 0);  // the header alone
  sp_pose_record out;
  int rc = SP_SHM_EMPTY;
  for (int k = 0; k < 100 && rc == SP_SHM_EMPTY; ++k) rc = sp_shm_reader_next(&reader_, &out);
  EXPECT_EQ(rc, SP_SHM_ERR_LAYOUT);
  EXPECT_EQ(reader_.base, nullptr);
}

TEST_F(Ring, ReaderOpenedBeforeTheWriterAttachesLater) {
  sp_pose_record out;
  EXPECT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_OLDEST), SP_SHM_ERR_NO_RING);
  EXPECT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_ERR_NO_RING);
  auto w = ShmPoseWriter::create(name_, 8);
  ASSERT_TRUE(w.ok());
  (*w)->write(record(1));
  EXPECT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_EMPTY);  // attached
  ASSERT_EQ(sp_shm_reader_next(&reader_, &out), SP_SHM_OK);
  EXPECT_EQ(out.sequence, 1u);
}

TEST_F(Ring, BadNamesAndBadFilesGiveClearErrors) {
  EXPECT_EQ(sp_shm_reader_open(&reader_, "", SP_SHM_START_LATEST), SP_SHM_ERR_NAME);
  EXPECT_EQ(sp_shm_reader_open(&reader_, "../etc/passwd", SP_SHM_START_LATEST), SP_SHM_ERR_NAME);
  EXPECT_EQ(sp_shm_reader_open(&reader_, ".hidden", SP_SHM_START_LATEST), SP_SHM_ERR_NAME);
  EXPECT_FALSE(ShmPoseWriter::create("a/b", 8).ok());
  EXPECT_FALSE(ShmPoseWriter::create(name_, 12).ok());  // not a power of two

  const std::string path = "/dev/shm/" + name_;
  auto writeFile = [&](const void* data, std::size_t size) {
    const int fd = ::open(path.c_str(), O_CREAT | O_TRUNC | O_WRONLY, 0644);
    ASSERT_GE(fd, 0);
    ASSERT_EQ(::write(fd, data, size), static_cast<ssize_t>(size));
    ::close(fd);
  };
  writeFile("hello", 5);
  EXPECT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_ERR_NOT_A_RING);

  std::vector<unsigned char> buf(SP_SHM_HEADER_SIZE + 8 * SP_SHM_SLOT_SIZE, 0);
  auto* h = reinterpret_cast<sp_shm_header*>(buf.data());
  h->magic = SP_SHM_MAGIC;
  h->schema_version = 99;
  writeFile(buf.data(), buf.size());
  EXPECT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_ERR_VERSION);

  h->schema_version = SP_SHM_SCHEMA_VERSION;
  h->header_size = SP_SHM_HEADER_SIZE;
  h->record_size = sizeof(sp_pose_record);
  h->slot_size = SP_SHM_SLOT_SIZE;
  h->capacity = 16;  // file only holds 8
  writeFile(buf.data(), buf.size());
  EXPECT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_ERR_LAYOUT);
  h->capacity = 8;
  writeFile(buf.data(), buf.size());
  EXPECT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_OK);

  // The C++ subscriber turns the codes into messages that say what is wrong.
  ShmOptions o;
  o.name = name_ + "_missing";
  auto sub = makeShmSubscriber(o);
  ASSERT_FALSE(sub.ok());
  EXPECT_NE(sub.error().find("is the stillpoint publisher running"), std::string::npos) << sub.error();
}

TEST_F(Ring, ShmTransportAndSubscriberRoundTripAPose) {
  ShmOptions o;
  o.name = name_;
  o.capacity = 8;
  auto t = makeShmTransport(o);
  ASSERT_TRUE(t.ok()) << t.error();
  auto sub = makeShmSubscriber(o);
  ASSERT_TRUE(sub.ok()) << sub.error();
  std::vector<PoseMessage> got;
  (*sub)->onPose([&](const PoseMessage& p) { got.push_back(p); });
  PoseMessage p;
  p.sensor_stamp = Timestamp::fromNanoseconds(123456789);
  p.publish_stamp = Timestamp::fromNanoseconds(987654321);
  p.frame_counter = 42;
  p.position = {1.5, -2.25, 1e-300};
  p.orientation = {0.5, 0.5, 0.5, 0.5};
  p.state = TrackingState::kRelocalised;
  p.tracked_features = 812;
  p.dynamic_rejected_features = 17;
  p.keyframes = 9;
  p.map_id = 0xFFFFFFFFFFFFFFFFULL;
  for (std::size_t i = 0; i < p.covariance.size(); ++i) p.covariance[i] = 1e-6f * static_cast<float>(i + 1);
  ASSERT_TRUE((*t)->publishPose(p).ok());
  auto n = (*sub)->poll(std::chrono::milliseconds(100));
  ASSERT_TRUE(n.ok()) << n.error();
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0], p);
}

// A record that says "pose" without one (NaN position, a quaternion that is
// not a unit one) is refused by the subscriber, as by the LCM and DDS ones:
// nothing a consumer could take for a pose.
TEST_F(Ring, ShmSubscriberRefusesAPoseThatIsNone) {
  ShmOptions o;
  o.name = name_;
  auto t = makeShmTransport(o);
  ASSERT_TRUE(t.ok()) << t.error();
  PoseMessage no_position, long_quaternion;
  no_position.state = long_quaternion.state = TrackingState::kOk;
  no_position.orientation = {0.0, 0.0, 0.0, 1.0};
  long_quaternion.position = {1.0, 2.0, 3.0};
  long_quaternion.orientation = {0.0, 0.0, 0.0, 2.0};
  const std::pair<PoseMessage, const char*> cases[] = {{no_position, "position is not finite"},
                                                       {long_quaternion, "not a unit quaternion"}};
  for (const auto& [pose, why] : cases) {
    auto sub = makeShmSubscriber(o);  // from the newest record on
    ASSERT_TRUE(sub.ok()) << sub.error();
    ASSERT_TRUE((*t)->publishPose(pose).ok());
    auto n = (*sub)->poll(std::chrono::milliseconds(100));
    ASSERT_FALSE(n.ok()) << why;
    EXPECT_NE(n.error().find(why), std::string::npos) << n.error();
  }
}

// Objects travel in their own ring, one record per object: frames with
// none, one and several objects come back whole, and the pose reader refuses
// the objects ring (and the other way round).
TEST_F(Ring, ShmTransportAndSubscriberRoundTripObjects) {
  ShmOptions o;
  o.name = name_;
  o.capacity = 16;  // the objects ring: 64 records
  auto t = makeShmTransport(o);
  ASSERT_TRUE(t.ok()) << t.error();
  ShmSubscriberOptions so;
  so.objects = true;
  auto sub = makeShmSubscriber(o, so);
  ASSERT_TRUE(sub.ok()) << sub.error();
  std::vector<ObjectsMessage> got;
  (*sub)->onObjects([&](const ObjectsMessage& m) { got.push_back(m); });
  std::vector<ObjectsMessage> sent;
  for (std::size_t n : {0u, 1u, 3u, 32u}) {
    ObjectsMessage m;
    m.sensor_stamp = Timestamp::fromNanoseconds(1000 + static_cast<std::int64_t>(n));
    m.publish_stamp = Timestamp::fromNanoseconds(2000 + static_cast<std::int64_t>(n));
    m.frame_counter = 10 + n;
    m.map_id = 0xFFFFFFFFFFFFFFF0ULL;
    for (std::size_t j = 0; j < n; ++j) {
      ObjectMessage x;
      x.id = static_cast<std::uint32_t>(7 * j + 1);
      x.label = j % 2 ? "person" : std::string(ObjectsMessage::kMaxLabelLength, 'z');
      x.sources = static_cast<std::uint8_t>(1 + j % 3);
      x.centroid = {0.25f * static_cast<float>(j), -1.5f, 3.0f};
      x.extent = {0.5f, 1.75f, 0.125f};
      x.velocity = {0.1f, 0.0f, -0.2f};
      x.has_velocity = j % 2 == 0;
      x.samples = static_cast<std::uint32_t>(100 + j);
      m.objects.push_back(x);
    }
    ASSERT_TRUE((*t)->publishObjects(m).ok());
    sent.push_back(m);
  }
  auto n = (*sub)->poll(std::chrono::milliseconds(100));
  ASSERT_TRUE(n.ok()) << n.error();
  ASSERT_EQ(got.size(), sent.size());
  for (std::size_t k = 0; k < sent.size(); ++k) EXPECT_EQ(got[k], sent[k]) << "frame " << k;

  ObjectsMessage too_many = sent.back();
  too_many.objects.push_back(too_many.objects.back());
  EXPECT_FALSE((*t)->publishObjects(too_many).ok());

  sp_pose_record pose;
  sp_object_record object;
  ASSERT_EQ(sp_shm_reader_open(&reader_, (name_ + "_objects").c_str(), SP_SHM_START_OLDEST), SP_SHM_ERR_NOT_A_RING);
  ASSERT_EQ(sp_shm_reader_open_objects(&reader_, name_.c_str(), SP_SHM_START_OLDEST), SP_SHM_ERR_NOT_A_RING);
  ASSERT_EQ(sp_shm_reader_open_objects(&reader_, (name_ + "_objects").c_str(), SP_SHM_START_OLDEST), SP_SHM_OK);
  EXPECT_EQ(sp_shm_reader_next(&reader_, &pose), SP_SHM_ERR_NOT_A_RING);
  EXPECT_EQ(sp_shm_reader_latest(&reader_, &pose), SP_SHM_ERR_NOT_A_RING);
  ASSERT_EQ(sp_shm_reader_next_object(&reader_, &object), SP_SHM_OK);
  // The same reader opened on the pose ring reads poses again.
  ASSERT_EQ(sp_shm_reader_open(&reader_, name_.c_str(), SP_SHM_START_OLDEST), SP_SHM_OK);
  EXPECT_EQ(sp_shm_reader_next_object(&reader_, &object), SP_SHM_ERR_NOT_A_RING);
}

}  // namespace
}  // namespace stillpoint::ipc
