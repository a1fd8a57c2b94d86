// Segment ownership and trust: the creator's lock, owner and mode checks, what create() finds
// under a name (segment_ownership.h).
#include "segment_ownership.h"

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <boost/interprocess/mapped_region.hpp>
#include <boost/interprocess/shared_memory_object.hpp>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <limits>
#include <new>
#include <sstream>
#include <utility>

#include "tactus/shared/error.h"
#include "tactus/shared/clock.h"

namespace tactus::shared {

std::string segmentTrustProblem(int fd, const std::string& name) {
  bool other_user = false;
  return segment_detail::trustProblem(fd, name, &other_user);
}

namespace segment_detail {

namespace bip = boost::interprocess;


// Name of this executable for messages ("haptic_server", "sim_server", a test...).
std::string programName() {
  char buf[64] = {0};
  std::FILE* f = std::fopen("/proc/self/comm", "r");
  if (f != nullptr) {
    if (std::fgets(buf, sizeof(buf), f) == nullptr) buf[0] = 0;
    std::fclose(f);
  }
  std::string s(buf);
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
  return s.empty() ? std::string("this program") : s;
}

bool pidAlive(std::int64_t pid) noexcept {
  // a header value out of pid_t range must not turn into kill(-1) or kill(0)
  if (pid <= 0 || pid > std::numeric_limits<std::int32_t>::max()) return false;
  if (::kill(static_cast<pid_t>(pid), 0) == 0) return true;
  return errno == EPERM;
}

// The creator's ownership lock: an open-file-description write lock over the whole object, taken
// right after the exclusive create and held for the creator's lifetime (the kernel drops it when
// the last descriptor of that open file closes, i.e. when the process exits however it dies).
// OFD locks conflict between open file descriptions even inside one process, and closing some
// other descriptor of the same object does not drop them (unlike classic fcntl locks).
namespace {
// The byte each lock covers: the creator's ownership lock and the haptic claim.
constexpr off_t kOwnerLockByte = 0;
constexpr off_t kHapticLockByte = 1;

// A lock request of `type` on one byte of the object.
struct flock byteLock(short type, off_t at) noexcept {
  struct flock lk {};
  lk.l_type = type;
  lk.l_whence = SEEK_SET;
  lk.l_start = at;
  lk.l_len = 1;
  return lk;
}

}  // namespace

bool takeOwnerLock(int fd) noexcept {
  struct flock lk = byteLock(F_WRLCK, kOwnerLockByte);
  return ::fcntl(fd, F_OFD_SETLK, &lk) == 0;
}

// Whether some other open file description holds the ownership lock (the creator is alive,
// running or stopped). A probe through a read-only descriptor is enough: a read lock conflicts
// with the creator's write lock.
bool ownerLockHeld(int fd) noexcept {
  struct flock lk = byteLock(F_RDLCK, kOwnerLockByte);
  if (::fcntl(fd, F_OFD_GETLK, &lk) != 0) return true;  // cannot tell: assume alive (refuse)
  return lk.l_type != F_UNLCK;
}

bool takeHapticLock(int fd) noexcept {
  struct flock lk = byteLock(F_WRLCK, kHapticLockByte);
  return ::fcntl(fd, F_OFD_SETLK, &lk) == 0;
}

bool hapticLockHeld(int fd) noexcept {
  struct flock lk = byteLock(F_RDLCK, kHapticLockByte);
  if (::fcntl(fd, F_OFD_GETLK, &lk) != 0) return false;
  return lk.l_type != F_UNLCK;
}

// segmentTrustProblem, also telling whether the problem is another user's ownership.
std::string trustProblem(int fd, const std::string& name, bool* other_user) {
  *other_user = false;
  struct stat st {};
  const std::string path = Segment::pathOf(name);
  if (::fstat(fd, &st) != 0) {
    return "cannot check '" + path + "' (fstat: " + std::strerror(errno) + ")";
  }
  if (!S_ISREG(st.st_mode)) {
    return "'" + path + "' is not a shared-memory object (not a regular file): refusing it";
  }
  const uid_t me = ::geteuid();
  if (st.st_uid != me) {
    *other_user = true;
    return "'" + path + "' belongs to uid " + std::to_string(st.st_uid) + ", not to this user (uid " +
           std::to_string(me) + "): refusing a segment another user could have written; run "
           "sim_server and haptic_server as the same user, or choose another --segment name";
  }
  if ((st.st_mode & 0077) != 0) {
    char mode[8];
    std::snprintf(mode, sizeof(mode), "%04o", static_cast<unsigned>(st.st_mode & 07777));
    return "'" + path + "' has mode " + mode + ": other users can read or write it (Tactus creates "
           "segments 0600); refusing it: remove it (rm " + path + ") and restart sim_server";
  }
  return {};
}


std::uint64_t loadMagic(const SegmentHeader* h) noexcept {
  // acquire: pairs with the creator's release store of the magic (initialisation complete)
  return __atomic_load_n(&h->magic, __ATOMIC_ACQUIRE);
}

// Age of an object in /dev/shm by its modification time, in ns (large when unknown).
std::int64_t objectAgeNs(const std::string& name) noexcept {
  struct stat st {};
  if (::stat(Segment::pathOf(name).c_str(), &st) != 0) return 0;
  timespec now{};
  clock_gettime(CLOCK_REALTIME, &now);
  return (static_cast<std::int64_t>(now.tv_sec) - st.st_mtim.tv_sec) * kNsPerS +
         (now.tv_nsec - st.st_mtim.tv_nsec);
}

std::string secondsText(std::int64_t ns) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.1f s", nsToSeconds(ns));
  return buf;
}

Existing inspectExisting(const std::string& name, std::int64_t stale_after_ns) {
  Existing ex;
  const std::string path = Segment::pathOf(name);
  bip::shared_memory_object shm;
  try {
    shm = bip::shared_memory_object(bip::open_only, name.c_str(), bip::read_only);
  } catch (const bip::interprocess_exception& e) {
    if (e.get_error_code() == bip::not_found_error) {
      ex.vanished = true;
      return ex;
    }
    ex.live = true;
    ex.message = "shared memory '" + path + "' exists and cannot be opened (" + e.what() +
                 "): it may belong to another user; choose another --segment name or remove it";
    return ex;
  }
  const int fd = shm.get_mapping_handle().handle;
  // never touch (not even replace) an object another user owns: same check as an attacher's
  bool other_user = false;
  if (const std::string why = trustProblem(fd, name, &other_user); other_user) {
    ex.live = true;
    ex.message = "segment '" + name + "': " + why;
    return ex;
  }
  // a directory (or anything else) under the name is not a segment being created
  struct stat st {};
  const bool have_stat = ::fstat(fd, &st) == 0;
  if (have_stat) {
    ex.dev = st.st_dev;
    ex.ino = st.st_ino;
  }
  if (have_stat && !S_ISREG(st.st_mode)) {
    ex.live = true;
    ex.message = "'" + path + "' exists and is not a shared-memory object (" +
                 (S_ISDIR(st.st_mode) ? "a directory" : "not a regular file") +
                 "): choose another --segment name, or remove it if you know it is unused";
    return ex;
  }
  const bool lock_held = ownerLockHeld(fd);
  bip::offset_t size = 0;
  shm.get_size(size);
  const std::int64_t age_ns = objectAgeNs(name);
  // too small to hold even the stable prefix: being created right now, or a crashed creation
  if (size < static_cast<bip::offset_t>(kStablePrefixBytes)) {
    if (!lock_held && age_ns > stale_after_ns) return ex;
    ex.live = true;
    ex.message = "segment '" + name + "' is being created by another process right now; wait for "
                 "it or choose another --segment name";
    return ex;
  }
  bip::mapped_region region(shm, bip::read_only, 0, kStablePrefixBytes);
  const auto* h = static_cast<const SegmentHeader*>(region.get_address());
  const std::uint64_t magic = loadMagic(h);
  const std::int64_t pid = h->creator_pid;
  if (magic == 0) {
    // initialising (or its creator died while initialising)
    if (!lock_held && ((pid != 0 && !pidAlive(pid)) || age_ns > stale_after_ns)) return ex;
    ex.live = true;
    ex.message = "segment '" + name + "' is being initialised by process " + std::to_string(pid) +
                 "; wait for it or choose another --segment name";
    return ex;
  }
  if (magic != kSegmentMagic) {
    ex.live = true;
    ex.message = "'" + path + "' exists but is not a Tactus segment: choose another --segment "
                 "name, or remove that file if you know it is unused";
    return ex;
  }
  ex.generation = h->generation;
  ex.creator = "dead process " + std::to_string(pid);
  // relaxed: a timestamp, no data depends on it
  const std::int64_t beat = h->sim_heartbeat_ns.load(std::memory_order_relaxed);
  const std::int64_t since = monotonicNs() - std::max(beat, h->created_ns);
  // Since ABI 3 the creator holds the ownership lock: held means alive (running, hung or
  // stopped), whatever its heartbeat says; free means dead. An older creator holds no lock:
  // alive when its pid exists.
  const bool locking_abi = h->abi_version >= 3;
  const bool alive = locking_abi ? lock_held : (lock_held || pidAlive(pid));
  if (!alive) return ex;
  ex.live = true;
  if (locking_abi && !pidAlive(pid)) {
    // its creator is gone but the lock is held: another creator is replacing it right now
    ex.message = "segment '" + name + "' (of dead process " + std::to_string(pid) +
                 ") is being replaced by another process right now: wait for it or choose "
                 "another --segment name";
  } else if (since <= stale_after_ns) {
    ex.message = "segment '" + name + "' is in use by a live simulation (pid " +
                 std::to_string(pid) + ", last heartbeat " + secondsText(since) +
                 " ago): stop that sim_server first or pass another --segment name";
  } else {
    ex.message = "segment '" + name + "' is in use by a live simulation (pid " +
                 std::to_string(pid) + ") that has been silent for " + secondsText(since) +
                 " (stopped or hung): a segment whose owner is alive is never replaced; resume or "
                 "stop it first (kill " + std::to_string(pid) + ") or pass another --segment name";
  }
  if (!locking_abi) {
    ex.message += " (created by a build of segment ABI " + std::to_string(h->abi_version) +
                  "; if pid " + std::to_string(pid) + " is not a sim_server, remove " + path + ")";
  }
  return ex;
}

void describeDiff(std::ostringstream& out, bool& any, const char* field, std::uint64_t found,
                  std::uint64_t expected) {
  if (found == expected) return;
  out << (any ? ", " : "") << field << " " << found << " (expected " << expected << ")";
  any = true;
}


}  // namespace segment_detail
}  // namespace tactus::shared
