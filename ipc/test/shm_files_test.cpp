// Files at the ring's path that are not a ring of ours (a FIFO, a symbolic link, a
// directory, another user's file), real ones in /dev/shm: the writer, the C reader and the
// C++ subscriber refuse them at once with an error naming the path.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstring>
#include <string>

#include "shm_processes.hpp"
#include "stillpoint/ipc/shm_writer.hpp"
#include "stillpoint/ipc/transport.hpp"
#include "stillpoint_shm.h"

namespace stillpoint::ipc {
namespace {

using namespace shm_test;

class RingFiles : public RingNameTest {
 protected:
  RingFiles() : RingNameTest("sp_files_") {}
};

TEST_F(RingFiles, FifoAtTheRingPathFailsFastNamingThePath) {
  ASSERT_EQ(::mkfifo(ringPath(name_).c_str(), 0666), 0) << std::strerror(errno);

  const ChildOutcome writer = runInChild([&](std::string& out) { return expectRefused(name_, out); });
  ASSERT_TRUE(writer.finished) << "writer start-up: " << writer.output;
  EXPECT_EQ(writer.exit_code, 0) << writer.output;
  EXPECT_NE(writer.output.find(ringPath(name_)), std::string::npos) << writer.output;
  EXPECT_NE(writer.output.find("FIFO"), std::string::npos) << writer.output;

  const ChildOutcome reader = runInChild([&](std::string& out) {
    sp_shm_reader r;
    sp_shm_reader_init(&r);
    const int rc = sp_shm_reader_open(&r, name_.c_str(), SP_SHM_START_LATEST);
    out = sp_shm_strerror(rc);
    sp_shm_reader_close(&r);
    return rc == SP_SHM_ERR_NOT_REGULAR ? 0 : 1;
  });
  ASSERT_TRUE(reader.finished) << "reader open: " << reader.output;
  EXPECT_EQ(reader.exit_code, 0) << reader.output;

  const ChildOutcome subscriber = runInChild([&](std::string& out) {
    ShmOptions o;
    o.name = name_;
    auto sub = makeShmSubscriber(o);
    out = sub ? "subscribed" : sub.error();
    return sub ? 1 : 0;
  });
  ASSERT_TRUE(subscriber.finished) << "subscriber open: " << subscriber.output;
  EXPECT_EQ(subscriber.exit_code, 0) << subscriber.output;
  EXPECT_NE(subscriber.output.find(ringPath(name_)), std::string::npos) << subscriber.output;
  EXPECT_NE(subscriber.output.find("FIFO"), std::string::npos) << subscriber.output;
}

TEST_F(RingFiles, FifoAtTheLockPathFailsFastNamingThePath) {
  ASSERT_EQ(::mkfifo(lockPath(name_).c_str(), 0666), 0) << std::strerror(errno);
  const ChildOutcome writer = runInChild([&](std::string& out) { return expectRefused(name_, out); });
  ASSERT_TRUE(writer.finished) << "writer start-up: " << writer.output;
  EXPECT_EQ(writer.exit_code, 0) << writer.output;
  EXPECT_NE(writer.output.find(lockPath(name_)), std::string::npos) << writer.output;
  EXPECT_NE(writer.output.find("FIFO"), std::string::npos) << writer.output;
}

TEST_F(RingFiles, SymlinkOrDirectoryAtTheRingPathIsRefused) {
  // A valid ring elsewhere: following the link would have found nothing wrong.
  const std::string target = name_ + "_target";
  {
    auto w = ShmPoseWriter::create(target, 8);
    ASSERT_TRUE(w.ok()) << w.error();
  }
  ASSERT_EQ(::symlink(ringPath(target).c_str(), ringPath(name_).c_str()), 0) << std::strerror(errno);

  const ChildOutcome writer = runInChild([&](std::string& out) { return expectRefused(name_, out); });
  ASSERT_TRUE(writer.finished) << writer.output;
  EXPECT_EQ(writer.exit_code, 0) << writer.output;
  EXPECT_NE(writer.output.find(ringPath(name_)), std::string::npos) << writer.output;
  EXPECT_NE(writer.output.find("symbolic link"), std::string::npos) << writer.output;
  struct stat st {};
  ASSERT_EQ(::lstat(ringPath(name_).c_str(), &st), 0);
  EXPECT_TRUE(S_ISLNK(st.st_mode)) << "the refused writer replaced the link";

  sp_shm_reader r;
  sp_shm_reader_init(&r);
  EXPECT_EQ(sp_shm_reader_open(&r, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_ERR_NOT_REGULAR);
  EXPECT_TRUE(S_ISLNK(r.found_mode));
  sp_shm_reader_close(&r);
  ASSERT_TRUE(ShmPoseWriter::remove(target).ok());

  ASSERT_EQ(::unlink(ringPath(name_).c_str()), 0);
  ASSERT_EQ(::mkdir(ringPath(name_).c_str(), 0755), 0);
  const ChildOutcome on_dir = runInChild([&](std::string& out) { return expectRefused(name_, out); });
  ASSERT_TRUE(on_dir.finished) << on_dir.output;
  EXPECT_EQ(on_dir.exit_code, 0) << on_dir.output;
  EXPECT_NE(on_dir.output.find(ringPath(name_) + " is a directory"), std::string::npos) << on_dir.output;
  EXPECT_EQ(sp_shm_reader_open(&r, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_ERR_NOT_REGULAR);
  sp_shm_reader_close(&r);
}

TEST_F(RingFiles, AnotherUsersFileIsRefusedUnlessTheReaderNamesThatUser) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root to give a file to another user";
  constexpr uid_t kOther = 65534;
  {
    auto w = ShmPoseWriter::create(name_, 8);
    ASSERT_TRUE(w.ok()) << w.error();
  }
  ASSERT_EQ(::chown(ringPath(name_).c_str(), kOther, kOther), 0) << std::strerror(errno);

  const ChildOutcome writer = runInChild([&](std::string& out) { return expectRefused(name_, out); });
  ASSERT_TRUE(writer.finished) << writer.output;
  EXPECT_EQ(writer.exit_code, 0) << writer.output;
  EXPECT_NE(writer.output.find(ringPath(name_) + " is owned by uid 65534"), std::string::npos) << writer.output;

  sp_shm_reader r;
  sp_shm_reader_init(&r);
  EXPECT_EQ(sp_shm_reader_open(&r, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_ERR_OWNER);
  EXPECT_EQ(r.found_uid, kOther);
  r.owner_uid = kOther;  // a reader of a writer that runs as another user says so
  EXPECT_EQ(sp_shm_reader_open(&r, name_.c_str(), SP_SHM_START_LATEST), SP_SHM_OK);
  sp_shm_reader_close(&r);

  ASSERT_EQ(::unlink(ringPath(name_).c_str()), 0);
  ASSERT_EQ(::chown(lockPath(name_).c_str(), kOther, kOther), 0) << std::strerror(errno);
  const ChildOutcome on_lock = runInChild([&](std::string& out) { return expectRefused(name_, out); });
  ASSERT_TRUE(on_lock.finished) << on_lock.output;
  EXPECT_EQ(on_lock.exit_code, 0) << on_lock.output;
  EXPECT_NE(on_lock.output.find(lockPath(name_) + " is owned by uid 65534"), std::string::npos) << on_lock.output;
}

}  // namespace
}  // namespace stillpoint::ipc
