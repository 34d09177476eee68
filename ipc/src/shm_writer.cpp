#include "stillpoint/ipc/shm_writer.hpp"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>

namespace stillpoint::ipc {
namespace {

std::string errnoText() { return std::strerror(errno); }

std::uint32_t effectiveUid() { return static_cast<std::uint32_t>(::geteuid()); }

// Why sp_shm_open_file() refused or failed to open `path`, from its code and what it found.
std::string fileError(const std::string& path, int code, const struct stat& st) {
  const int err = errno;
  if (code == SP_SHM_ERR_NOT_REGULAR)
    return "shm: " + path + " is a " + sp_shm_file_kind(st.st_mode) + ", not a regular file; refusing to use it";
  if (code == SP_SHM_ERR_OWNER)
    return "shm: " + path + " is owned by uid " + std::to_string(st.st_uid) + ", not by uid " +
           std::to_string(effectiveUid()) + " (this process); refusing to use it";
  return "shm: cannot open " + path + ": " + std::strerror(err);
}

// The pid the lock's holder wrote into the lock file, or "unknown".
std::string recordedPid(int fd) {
  char buf[24] = {};
  const ssize_t n = ::pread(fd, buf, sizeof(buf) - 1, 0);
  std::string pid = n > 0 ? std::string(buf, static_cast<std::size_t>(n)) : "";
  while (!pid.empty() && pid.back() == '\n') pid.pop_back();
  if (pid.empty() || pid.find_first_not_of("0123456789") != std::string::npos) return "unknown";
  return pid;
}

// An open-file-description write lock on the whole file, without waiting. The kernel
// drops it when the last descriptor of this open goes, whenever and however the process
// ends. Returns 0 or errno.
int writeLock(int fd) {
  struct flock lock {};
  lock.l_type = F_WRLCK;
  lock.l_whence = SEEK_SET;  // l_start = l_len = 0: the whole file
  return ::fcntl(fd, F_OFD_SETLK, &lock) == 0 ? 0 : errno;
}

// The process's umask, read without changing it: umask() sets it while reading it, for
// every thread of the process.
mode_t currentUmask() {
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);)
    if (line.rfind("Umask:", 0) == 0) return static_cast<mode_t>(std::strtoul(line.c_str() + 6, nullptr, 8) & 0777);
  return 022;
}

// Takes the writers' lock of the ring. Taken before the ring is looked at, so finding no
// owner and replacing the ring are one step. Mode 0600: a user who could open the lock
// file could hold a read lock on it and so keep every writer from starting.
Result<int> lockRing(const std::string& name, const std::string& lock_path) {
  // remove() may unlink the lock file between our open() and our lock, which would then
  // guard nothing: keep the lock only on the file the name still refers to.
  for (int attempt = 0; attempt < 8; ++attempt) {
    struct stat st {};
    const int fd = sp_shm_open_file(lock_path.c_str(), O_RDWR | O_CREAT, 0600, effectiveUid(), &st);
    if (fd < 0) return Error{fileError(lock_path, fd, st)};
    if ((st.st_mode & 077) != 0 && ::fchmod(fd, 0600) != 0) {
      const std::string err = errnoText();
      ::close(fd);
      return Error{"shm: cannot make " + lock_path + " private: " + err};
    }
    if (const int err = writeLock(fd); err != 0) {
      const std::string pid = recordedPid(fd);
      ::close(fd);
      if (err == EAGAIN || err == EACCES)
        return Error{"shm: ring " + name + " is owned by a running writer, pid " + pid + " (" + lock_path +
                     " is locked)"};
      return Error{"shm: cannot lock " + lock_path + ": " + std::strerror(err)};
    }
    struct stat now {};
    if (::lstat(lock_path.c_str(), &now) == 0 && now.st_dev == st.st_dev && now.st_ino == st.st_ino) {
      // For the error message of the next writer that tries; the lock is what counts.
      const std::string pid = std::to_string(::getpid()) + "\n";
      if (::ftruncate(fd, 0) != 0 || ::pwrite(fd, pid.data(), pid.size(), 0) != static_cast<ssize_t>(pid.size())) {
        const std::string err = errnoText();
        ::close(fd);
        return Error{"shm: cannot write " + lock_path + ": " + err};
      }
      return fd;
    }
    ::close(fd);
  }
  return Error{"shm: " + lock_path + " keeps being replaced; cannot lock ring " + name};
}

// Generation of the ring at `path`: 0 when there is none or the file is not a valid ring
// (it is replaced); an error when anything but a regular file of ours is there.
Result<std::uint64_t> previousGeneration(const std::string& path, std::uint32_t magic) {
  struct stat st {};
  const int fd = sp_shm_open_file(path.c_str(), O_RDONLY, 0, effectiveUid(), &st);
  if (fd == SP_SHM_ERR_NO_RING) return std::uint64_t{0};
  if (fd < 0) return Error{fileError(path, fd, st)};
  std::uint64_t generation = 0;
  const auto size = static_cast<std::size_t>(st.st_size);
  if (size >= SP_SHM_HEADER_SIZE) {
    void* map = ::mmap(nullptr, size, PROT_READ, MAP_SHARED, fd, 0);
    if (map != MAP_FAILED) {
      const auto* h = static_cast<const sp_shm_header*>(map);
      if (sp_shm_check_header_of(h, size, magic) == SP_SHM_OK) generation = h->generation;
      ::munmap(map, size);
    }
  }
  ::close(fd);
  return generation;
}

}  // namespace

Result<std::unique_ptr<ShmPoseWriter>> ShmPoseWriter::create(const std::string& name,
                                                             std::uint32_t capacity, std::uint32_t magic) {
  char path[256];
  if (sp_shm_make_path(name.c_str(), path, sizeof(path)) != SP_SHM_OK)
    return Error{"shm: invalid ring name '" + name + "': " + sp_shm_strerror(SP_SHM_ERR_NAME)};
  if (capacity < 2 || capacity > SP_SHM_MAX_CAPACITY || (capacity & (capacity - 1)) != 0)
    return Error{"shm: capacity " + std::to_string(capacity) + " must be a power of two in [2, " +
                 std::to_string(SP_SHM_MAX_CAPACITY) + "]"};

  std::unique_ptr<ShmPoseWriter> w(new ShmPoseWriter());
  w->path_ = path;
  auto lock = lockRing(name, w->path_ + SP_SHM_LOCK_SUFFIX);
  if (!lock) return Error{lock.error()};
  w->lock_fd_ = *lock;  // from here on the destructor releases it on every error path

  if (magic != SP_SHM_MAGIC && magic != SP_SHM_OBJECTS_MAGIC) return Error{"shm: unknown ring kind"};
  const auto previous = previousGeneration(w->path_, magic);
  if (!previous) return Error{previous.error()};
  w->capacity_ = capacity;
  w->generation_ = *previous + 1;
  w->size_ = SP_SHM_HEADER_SIZE + static_cast<std::size_t>(capacity) * SP_SHM_SLOT_SIZE;

  // Build the ring under a temporary name, then rename: a reader never sees a
  // half-initialised ring under the public name. The file is private until it carries
  // the liveness lock, so no other user can get a lock on it first.
  const std::string tmp = w->path_ + ".tmp." + std::to_string(::getpid());
  ::unlink(tmp.c_str());
  const int fd = ::open(tmp.c_str(), O_RDWR | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0600);
  if (fd < 0) return Error{"shm: cannot create " + tmp + ": " + errnoText()};
  w->ring_fd_ = fd;  // kept open: it carries the lock readers test
  auto fail = [&](const std::string& what) -> Error {
    const std::string err = errnoText();
    ::unlink(tmp.c_str());
    return Error{"shm: cannot " + what + " " + tmp + ": " + err};
  };
  if (const int err = writeLock(fd); err != 0) {
    errno = err;
    return fail("lock");
  }
  if (::fchmod(fd, 0644 & ~currentUmask()) != 0) return fail("set the mode of");
  if (::ftruncate(fd, static_cast<off_t>(w->size_)) != 0) return fail("size");
  void* map = ::mmap(nullptr, w->size_, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  if (map == MAP_FAILED) return fail("map");
  unsigned char* base = static_cast<unsigned char*>(map);
  std::memset(base, 0, w->size_);  // tmpfs pages are zero already; touch them now, not in write()
  auto* h = reinterpret_cast<sp_shm_header*>(base);
  h->schema_version = SP_SHM_SCHEMA_VERSION;
  h->header_size = SP_SHM_HEADER_SIZE;
  h->record_size = sizeof(sp_pose_record);
  h->slot_size = SP_SHM_SLOT_SIZE;
  h->capacity = capacity;
  h->writer_pid = static_cast<std::uint32_t>(::getpid());
  h->generation = w->generation_;
  h->created_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                      std::chrono::system_clock::now().time_since_epoch()).count();
  __atomic_store_n(&h->write_count, 0, __ATOMIC_RELAXED);
  __atomic_store_n(&h->writer_state, SP_SHM_WRITER_RUNNING, __ATOMIC_RELAXED);
  __atomic_store_n(&h->magic, magic, __ATOMIC_RELEASE);
  if (::rename(tmp.c_str(), path) != 0) {
    const std::string err = errnoText();
    ::munmap(base, w->size_);
    ::unlink(tmp.c_str());
    return Error{"shm: cannot publish ring as " + std::string(path) + ": " + err};
  }
  w->base_ = base;
  return w;
}

ShmPoseWriter::~ShmPoseWriter() {
  if (base_ != nullptr) {
    auto* h = reinterpret_cast<sp_shm_header*>(base_);
    __atomic_store_n(&h->writer_state, SP_SHM_WRITER_CLOSED, __ATOMIC_RELEASE);
    ::munmap(base_, size_);
  }
  // The locks go after the ring says closed: a reader that finds the ring's lock free
  // and the ring still running knows the writer died.
  if (ring_fd_ >= 0) ::close(ring_fd_);
  if (lock_fd_ >= 0) ::close(lock_fd_);
}

void ShmPoseWriter::write(const sp_pose_record& record) { writeWords(&record); }
void ShmPoseWriter::write(const sp_object_record& record) { writeWords(&record); }

void ShmPoseWriter::writeWords(const void* record) {
  auto* h = reinterpret_cast<sp_shm_header*>(base_);
  const std::uint64_t n = count_ + 1;
  auto* slot = reinterpret_cast<sp_shm_slot*>(base_ + SP_SHM_HEADER_SIZE +
                                              static_cast<std::size_t>(n & (capacity_ - 1)) * SP_SHM_SLOT_SIZE);
  std::uint64_t words[SP_SHM_POSE_WORDS];
  std::memcpy(words, record, sizeof(words));
  words[0] = n;  // sp_pose_record::sequence

  // Seqlock write: mark the slot busy (odd); each payload store is a release, so a reader
  // that loads (acquire) any new word also sees the odd mark and discards its copy. The
  // final release store of 2n publishes the complete record.
  __atomic_store_n(&slot->seq, 2 * n - 1, __ATOMIC_RELAXED);
  for (int i = 0; i < SP_SHM_POSE_WORDS; ++i) __atomic_store_n(&slot->words[i], words[i], __ATOMIC_RELEASE);
  __atomic_store_n(&slot->seq, 2 * n, __ATOMIC_RELEASE);
  __atomic_store_n(&h->write_count, n, __ATOMIC_RELEASE);
  count_ = n;
}

Status ShmPoseWriter::remove(const std::string& name) {
  char path[256];
  if (sp_shm_make_path(name.c_str(), path, sizeof(path)) != SP_SHM_OK)
    return Error{"shm: invalid ring name '" + name + "'"};
  const std::string lock_path = std::string(path) + SP_SHM_LOCK_SUFFIX;
  // Holding the lock while unlinking: a writer that opened the old lock file meanwhile
  // sees it replaced and locks the new one (lockRing).
  struct stat st {};
  const int fd = sp_shm_open_file(lock_path.c_str(), O_RDWR, 0, effectiveUid(), &st);
  if (fd < 0 && fd != SP_SHM_ERR_NO_RING) return Error{fileError(lock_path, fd, st)};
  if (fd >= 0) {
    if (writeLock(fd) != 0) {
      const std::string pid = recordedPid(fd);
      ::close(fd);
      return Error{"shm: ring " + name + " is owned by a running writer, pid " + pid + "; not removed"};
    }
  }
  Status status;
  if (::unlink(path) != 0 && errno != ENOENT)
    status = Error{std::string("shm: cannot remove ") + path + ": " + errnoText()};
  if (fd >= 0) {
    if (status.ok() && ::unlink(lock_path.c_str()) != 0 && errno != ENOENT)
      status = Error{"shm: cannot remove " + lock_path + ": " + errnoText()};
    ::close(fd);
  }
  return status;
}

}  // namespace stillpoint::ipc
