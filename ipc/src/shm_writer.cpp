#include "stillpoint/ipc/shm_writer.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>

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

// Generation and owner of the ring currently at `path`, if it is a valid ring.
struct Previous {
  std::uint64_t generation = 0;
  std::uint32_t pid = 0;
  bool running = false;
};

// None when nothing is there; an error when anything but a regular file of ours is.
Result<Previous> inspectPrevious(const std::string& path) {
  Previous prev;
  struct stat st {};
  const int fd = sp_shm_open_file(path.c_str(), O_RDONLY, 0, effectiveUid(), &st);
  if (fd == SP_SHM_ERR_NO_RING) return prev;
  if (fd < 0) return Error{fileError(path, fd, st)};
  if (static_cast<std::size_t>(st.st_size) >= SP_SHM_HEADER_SIZE) {
    void* map = ::mmap(nullptr, static_cast<std::size_t>(st.st_size), PROT_READ, MAP_SHARED, fd, 0);
    if (map != MAP_FAILED) {
      const auto* h = static_cast<const sp_shm_header*>(map);
      if (sp_shm_check_header(h, static_cast<std::size_t>(st.st_size)) == SP_SHM_OK) {
        prev.generation = h->generation;
        prev.pid = h->writer_pid;
        prev.running = __atomic_load_n(&h->writer_state, __ATOMIC_ACQUIRE) == SP_SHM_WRITER_RUNNING;
      }
      ::munmap(map, static_cast<std::size_t>(st.st_size));
    }
  }
  ::close(fd);
  return prev;
}

bool processAlive(std::uint32_t pid) {
  if (pid == 0) return false;
  return ::kill(static_cast<pid_t>(pid), 0) == 0 || errno == EPERM;
}

}  // namespace

Result<std::unique_ptr<ShmPoseWriter>> ShmPoseWriter::create(const std::string& name,
                                                             std::uint32_t capacity) {
  char path[256];
  if (sp_shm_make_path(name.c_str(), path, sizeof(path)) != SP_SHM_OK)
    return Error{"shm: invalid ring name '" + name + "': " + sp_shm_strerror(SP_SHM_ERR_NAME)};
  if (capacity < 2 || capacity > SP_SHM_MAX_CAPACITY || (capacity & (capacity - 1)) != 0)
    return Error{"shm: capacity " + std::to_string(capacity) + " must be a power of two in [2, " +
                 std::to_string(SP_SHM_MAX_CAPACITY) + "]"};

  const auto inspected = inspectPrevious(path);
  if (!inspected) return Error{inspected.error()};
  const Previous& prev = *inspected;
  if (prev.running && prev.pid != static_cast<std::uint32_t>(::getpid()) && processAlive(prev.pid))
    return Error{std::string("shm: ring ") + path + " is owned by running process " +
                 std::to_string(prev.pid) + " (one writer per ring)"};

  std::unique_ptr<ShmPoseWriter> w(new ShmPoseWriter());
  w->path_ = path;
  w->capacity_ = capacity;
  w->generation_ = prev.generation + 1;
  w->size_ = SP_SHM_HEADER_SIZE + static_cast<std::size_t>(capacity) * SP_SHM_SLOT_SIZE;

  // Build the ring under a temporary name, then rename: a reader never sees a
  // half-initialised ring under the public name.
  const std::string tmp = w->path_ + ".tmp." + std::to_string(::getpid());
  ::unlink(tmp.c_str());
  const int fd = ::open(tmp.c_str(), O_RDWR | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
  if (fd < 0) return Error{"shm: cannot create " + tmp + ": " + errnoText()};
  if (::ftruncate(fd, static_cast<off_t>(w->size_)) != 0) {
    const std::string err = errnoText();
    ::close(fd);
    ::unlink(tmp.c_str());
    return Error{"shm: cannot size " + tmp + ": " + err};
  }
  void* map = ::mmap(nullptr, w->size_, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  ::close(fd);
  if (map == MAP_FAILED) {
    const std::string err = errnoText();
    ::unlink(tmp.c_str());
    return Error{"shm: cannot map " + tmp + ": " + err};
  }
  w->base_ = static_cast<unsigned char*>(map);
  std::memset(w->base_, 0, w->size_);  // tmpfs pages are zero already; touch them now, not in write()
  auto* h = reinterpret_cast<sp_shm_header*>(w->base_);
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
  __atomic_store_n(&h->magic, SP_SHM_MAGIC, __ATOMIC_RELEASE);
  if (::rename(tmp.c_str(), path) != 0) {
    const std::string err = errnoText();
    ::munmap(w->base_, w->size_);
    w->base_ = nullptr;
    ::unlink(tmp.c_str());
    return Error{"shm: cannot publish ring as " + std::string(path) + ": " + err};
  }
  return w;
}

ShmPoseWriter::~ShmPoseWriter() {
  if (base_ == nullptr) return;
  auto* h = reinterpret_cast<sp_shm_header*>(base_);
  __atomic_store_n(&h->writer_state, SP_SHM_WRITER_CLOSED, __ATOMIC_RELEASE);
  ::munmap(base_, size_);
}

void ShmPoseWriter::write(const sp_pose_record& record) {
  auto* h = reinterpret_cast<sp_shm_header*>(base_);
  const std::uint64_t n = count_ + 1;
  auto* slot = reinterpret_cast<sp_shm_slot*>(base_ + SP_SHM_HEADER_SIZE +
                                              static_cast<std::size_t>(n & (capacity_ - 1)) * SP_SHM_SLOT_SIZE);
  std::uint64_t words[SP_SHM_POSE_WORDS];
  std::memcpy(words, &record, sizeof(words));
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
  if (::unlink(path) != 0 && errno != ENOENT) return Error{std::string("shm: cannot remove ") + path + ": " + errnoText()};
  return Status::success();
}

}  // namespace stillpoint::ipc
