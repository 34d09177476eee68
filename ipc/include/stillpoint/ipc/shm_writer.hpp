#pragma once
// Writer side of the shared-memory pose ring (layout and reader: stillpoint_shm.h).
// Single writer: one ShmPoseWriter per ring name; write() is wait-free.
#include <cstdint>
#include <memory>
#include <string>

#include "stillpoint/core/result.hpp"
#include "stillpoint_shm.h"

namespace stillpoint::ipc {

class ShmPoseWriter {
 public:
  // Takes the writers' lock of the ring (/dev/shm/<name>.lock), then builds a new ring
  // file, write-locked for readers' liveness tests, and renames it over /dev/shm/<name>:
  // readers of a previous writer see a restart. Both locks are held until destruction or
  // death. generation = previous ring's + 1 (1 if none).
  // Fails when the name is invalid, capacity is not a power of two in [2, 2^20], another
  // writer holds the lock, or the ring's path or lock file is anything but a regular
  // file of this process's effective user (a FIFO, a symbolic link, another user's file).
  // `magic`: SP_SHM_MAGIC for a pose ring, SP_SHM_OBJECTS_MAGIC for a dynamic-objects
  // ring (write its records with write(const sp_object_record&)).
  static Result<std::unique_ptr<ShmPoseWriter>> create(const std::string& name, std::uint32_t capacity,
                                                       std::uint32_t magic = SP_SHM_MAGIC);
  // Marks the ring closed, then releases the locks; the files stay so late readers still
  // see the last pose.
  ~ShmPoseWriter();
  ShmPoseWriter(const ShmPoseWriter&) = delete;
  ShmPoseWriter& operator=(const ShmPoseWriter&) = delete;

  // Publishes `record` as the next record; its `sequence` field is overwritten.
  void write(const sp_pose_record& record);
  void write(const sp_object_record& record);

  std::uint64_t generation() const { return generation_; }
  std::uint64_t written() const { return count_; }
  const std::string& path() const { return path_; }

  // Removes /dev/shm/<name> and its lock file (tests, uninstall). Missing is fine;
  // refused while a writer holds the lock.
  static Status remove(const std::string& name);

 private:
  ShmPoseWriter() = default;
  std::string path_;
  int lock_fd_ = -1;  // the writers' lock file
  int ring_fd_ = -1;  // the ring file
  unsigned char* base_ = nullptr;
  std::size_t size_ = 0;
  std::uint64_t generation_ = 0;
  std::uint64_t count_ = 0;
  std::uint32_t capacity_ = 0;
  void writeWords(const void* record);
};

}  // namespace stillpoint::ipc
