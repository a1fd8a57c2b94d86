#pragma once
// Private to segment.cpp and segment_ownership.cpp: who owns a segment object and whether it can
// be trusted (docs/design.md section 3, "Ownership and trust": ownership lock, owner and mode checks, stale or live
// creators).

#include <sys/types.h>

#include <cstdint>
#include <sstream>
#include <string>

#include "tactus/shared/segment.h"

namespace tactus::shared::segment_detail {

inline constexpr std::size_t kStablePrefixBytes = 64;
inline constexpr std::size_t kMaxSegmentBytes = std::size_t{2} << 30;  // 2 GiB

/// Name of this executable for messages ("haptic_server", "sim_server", a test...).
std::string programName();
/// True when process `pid` exists (also when it belongs to another user).
bool pidAlive(std::int64_t pid) noexcept;
/// The creator's ownership lock (an OFD write lock on the object's first byte, held for the
/// creator's life; creators of ABI 3 and 4 locked the whole object, which covers it): take it
/// on `fd`; true on success.
bool takeOwnerLock(int fd) noexcept;
/// True when some open file description holds the ownership lock of the object behind `fd`.
bool ownerLockHeld(int fd) noexcept;
/// The haptic claim (an OFD write lock on the object's second byte, held while the claimant's
/// segment is open): take it on `fd`; true on success, false when another holds it.
bool takeHapticLock(int fd) noexcept;
/// True when some other open file description holds the haptic claim of the object behind `fd`
/// (a live haptic process serves the segment, ticking or not).
bool hapticLockHeld(int fd) noexcept;
/// Empty when the object behind `fd` may be trusted (owned by this user, mode 0600), else why
/// not; *other_user tells whether another user owns it.
std::string trustProblem(int fd, const std::string& name, bool* other_user);
/// The header's magic, read with acquire ordering (pairs with the creator's release store).
std::uint64_t loadMagic(const SegmentHeader* h) noexcept;
/// Age of an object in /dev/shm by its modification time, in ns (0 when unknown).
std::int64_t objectAgeNs(const std::string& name) noexcept;
/// "1.5 s".
std::string secondsText(std::int64_t ns);

/// What create() found under the name it wanted.
struct Existing {
  bool live = false;           ///< refuse
  bool vanished = false;       ///< gone meanwhile: just retry
  std::string message;         ///< why it is refused (live) or what was replaced (stale)
  std::uint64_t generation = 0;
  std::string creator = "unknown";   ///< "dead process N", "process N, silent for X s", ...
  dev_t dev = 0;   ///< the inspected object's identity: only that object may be claimed as stale
  ino_t ino = 0;
};
/// Inspects the object `name` (a creator that stopped beating for stale_after_ns is stale
/// unless it still holds the ownership lock).
Existing inspectExisting(const std::string& name, std::int64_t stale_after_ns);

/// Appends "field found (expected e)" to `out` when they differ (comma-separated; `any` tracks
/// whether something was written).
void describeDiff(std::ostringstream& out, bool& any, const char* field, std::uint64_t found,
                  std::uint64_t expected);

}  // namespace tactus::shared::segment_detail
