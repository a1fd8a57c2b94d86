#pragma once
// The POSIX shared-memory segment between sim_server and haptic_server (Boost.Interprocess
// shared_memory_object + mapped_region, i.e. /dev/shm/<name>).
//
// Layout (fixed POD, offsets only, every part 64-byte aligned):
//
//   [ SegmentHeader | snapshot triple buffer (ContactSnapshot, runtime size)
//                   | device triple buffers (DeviceSample, one per device)
//                   | stats ring (StatsRecord)
//                   | display frame triple buffer | display topology ]   (display.h; the
//                   display part is absent when its capacity is zero)
//
// The creator (the simulation) chooses the capacity (max rows, max contacts) from the scene,
// initialises every part, and writes `magic` last (release), so an attacher that sees the magic
// sees a complete segment. An attacher checks magic, ABI version, header size, total size and
// every offset/size against what this build computes from the stored capacity, and refuses a
// mismatch with a message naming what differs and what to do.
//
// Trust: the segment is owner-only (0600, created exclusively). Every attach (tryOpen/open) and
// create()'s look at an existing object first fstat()s the descriptor it opened, before mapping
// anything (segmentTrustProblem): an object of another user, or one group/others may read or
// write, is refused with a message; create() never replaces an object of another user.
//
// Lifetime. Either daemon may start first (the haptic side polls tryOpen(), which never blocks).
//  * Alive = holds the ownership lock. Right after its exclusive create, the creator takes an
//    open-file-description write lock (fcntl F_OFD_SETLK) on the object's first byte and keeps it for
//    its lifetime; the kernel releases it when the process ends, however it ends (SIGKILL, crash).
//    A stopped (SIGSTOP) or hung creator still holds it, and a recycled pid does not. create()
//    probes the lock (F_OFD_GETLK) of an existing segment: held -> refused, whatever the
//    heartbeat says ("in use by a live simulation", with how long it has been silent); free ->
//    the segment is stale and is replaced, bumping the generation: the replacing creator takes
//    the stale object's lock and removes the name only while it still refers to that object, so
//    two creators replacing it at once cannot remove each other's new segment. A segment of an
//    older ABI (< 3, no lock) counts as alive while its creator pid exists.
//  * Displacement. The name can still be removed by hand (rm /dev/shm/<name>) and re-created
//    while a creator is stopped. stillCurrent() tells any holder, creator included, whether the
//    name still refers to the object it mapped (stat of the name: same device and inode; a
//    re-created object is a new inode even under the same name). The simulation checks it a few
//    times a second off the hot path and stops with a message when it was displaced; the haptic
//    side detaches and re-opens.
//  * One haptic process per segment: claimHaptic() takes a second OFD lock (the object's second
//    byte; the creator's lock covers the first), so of two racing claimants exactly one wins and
//    a dead process's claim is free at once, whatever became of its pid.
//
// Not real-time: create/open/remove/stillCurrent/claimHaptic allocate and make system calls. The accessors
// (header, heartbeats, shutdown flags) and the endpoints they return are real-time safe.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "tactus/shared/clock.h"
#include "tactus/shared/display.h"
#include "tactus/shared/messages.h"
#include "tactus/shared/stats_ring.h"
#include "tactus/shared/triple_buffer.h"

namespace tactus::shared {

inline constexpr std::uint64_t kSegmentMagic = 0x3147'4553'5554'4354ULL;  // "TCTUSEG1" (LE)
/// Bump on any change of SegmentHeader, the messages, the part layout or the ownership protocol
/// (3: the creator holds the ownership lock, see the file comment; 4: several instruments and
/// devices: per-instrument blocks in the snapshot header, each contact's instrument, one device
/// triple buffer per device, per-device forces in the stats record; 5: the stats record's phase
/// times, deadline and local model; 6: a device sample moves the instrument only with
/// kDevicePoseValid, and the haptic claim is a lock on the object's second byte).
inline constexpr std::uint32_t kSegmentAbiVersion = 6;
/// Stats ring capacity: 8192 records (8 s at 1 kHz).
inline constexpr std::uint64_t kStatsRingCapacity = 8192;
/// A creator whose heartbeat (or creation time) is older than this is considered gone.
inline constexpr std::int64_t kDefaultStaleAfterNs = 3 * kNsPerS;

/// Capacity chosen by the creator from the scene.
struct SegmentCapacity {
  std::int32_t max_rows = 0;         ///< rows of W (3 per frictional contact, 1 frictionless)
  std::int32_t max_contacts = 0;
  /// Display part (display.h): surface vertices and triangles a frame can carry; its contacts
  /// are max_contacts. 0 vertices or triangles: no display part.
  std::int32_t display_vertices = kDefaultDisplayVertices;
  std::int32_t display_triangles = kDefaultDisplayTriangles;
  /// Device triple buffers (haptic -> sim), one per instrument: 1 .. kMaxInstruments.
  std::int32_t devices = 1;
  DisplayCapacity display() const noexcept {
    return {display_vertices, display_triangles, max_contacts};
  }
  /// Rows for `contacts` frictional (3 rows) or frictionless (1 row) contacts.
  static constexpr SegmentCapacity forContacts(std::int32_t contacts, bool friction = true) {
    SegmentCapacity c;
    c.max_rows = friction ? 3 * contacts : contacts;
    c.max_contacts = contacts;
    return c;
  }
};

enum class Access : std::uint8_t { kReadWrite, kReadOnly };
enum class Side : std::uint8_t { kSim, kHaptic };

/// Header at offset 0. The first 64 bytes are a stable prefix whose offsets never change across
/// ABI versions, so any build can diagnose (and, if its creator is dead, replace) any segment.
struct SegmentHeader {
  // stable prefix
  std::uint64_t magic = 0;                        ///< kSegmentMagic, written last by the creator
  std::uint32_t abi_version = 0;                  ///< kSegmentAbiVersion of the creator
  std::uint32_t header_bytes = 0;                 ///< sizeof(SegmentHeader) of the creator
  std::uint64_t total_bytes = 0;                  ///< mapped size
  std::int64_t creator_pid = 0;
  std::uint64_t generation = 0;                   ///< 1 + generation of the segment it replaced
  std::int64_t created_ns = 0;                    ///< monotonic creation time
  std::atomic<std::int64_t> sim_heartbeat_ns{0};  ///< monotonic, bumped by the simulation
  std::atomic<std::int64_t> haptic_heartbeat_ns{0};
  // ABI-versioned part
  std::int32_t max_rows = 0;
  std::int32_t max_contacts = 0;
  std::uint64_t snapshot_offset = 0;              ///< TripleBufferControl of the snapshots
  std::uint64_t snapshot_bytes = 0;               ///< whole triple buffer
  std::uint64_t snapshot_slot_bytes = 0;          ///< SnapshotLayout::total_bytes
  std::uint64_t device_offset = 0;                ///< TripleBufferControl of device 0's samples
  std::uint64_t device_bytes = 0;                 ///< all devices' (device_stride_bytes each)
  std::uint64_t device_slot_bytes = 0;            ///< sizeof(DeviceSample)
  std::uint64_t stats_offset = 0;                 ///< SeqRingControl of the stats ring
  std::uint64_t stats_bytes = 0;
  std::uint64_t stats_capacity = 0;
  std::uint64_t stats_record_bytes = 0;           ///< sizeof(StatsRecord)
  std::uint32_t snapshot_header_bytes = 0;        ///< sizeof(ContactSnapshotHeader)
  std::uint32_t devices = 0;                      ///< device triple buffers (since ABI 4)
  std::atomic<std::uint32_t> sim_shutdown{0};     ///< 1: the simulation is asked to stop
  std::atomic<std::uint32_t> haptic_shutdown{0};  ///< 1: the haptic loop is asked to stop
  std::atomic<std::int64_t> haptic_pid{0};        ///< the haptic side's claim (claimHaptic)
  // display part (since ABI 2; all zero when absent)
  std::int32_t display_max_vertices = 0;
  std::int32_t display_max_triangles = 0;
  std::int32_t display_max_contacts = 0;          ///< = max_contacts
  std::uint32_t display_frame_header_bytes = 0;   ///< sizeof(DisplayFrameHeader)
  std::uint64_t display_offset = 0;               ///< TripleBufferControl of the display frames
  std::uint64_t display_bytes = 0;                ///< whole triple buffer
  std::uint64_t display_slot_bytes = 0;           ///< DisplayLayout::frame_bytes
  std::uint64_t topology_offset = 0;              ///< DisplayTopologyHeader
  std::uint64_t topology_bytes = 0;
};
static_assert(std::is_standard_layout_v<SegmentHeader>);
static_assert(offsetof(SegmentHeader, sim_heartbeat_ns) == 48);
static_assert(offsetof(SegmentHeader, max_rows) == 64);
static_assert(std::atomic<std::int64_t>::is_always_lock_free);
static_assert(std::atomic<std::uint32_t>::is_always_lock_free);

/// Where every part goes for a capacity (pure function of the capacity and this build).
struct SegmentLayout {
  SnapshotLayout snapshot;
  std::size_t snapshot_offset = 0, snapshot_bytes = 0;
  std::size_t device_offset = 0, device_bytes = 0;      ///< all devices' triple buffers
  std::size_t device_stride_bytes = 0;                  ///< device i at device_offset + i * this
  std::size_t stats_offset = 0, stats_bytes = 0;
  DisplayLayout display;
  std::size_t display_offset = 0, display_bytes = 0;     ///< 0, 0 when the display is absent
  std::size_t topology_offset = 0, topology_bytes = 0;
  std::size_t total_bytes = 0;
  static SegmentLayout forCapacity(SegmentCapacity capacity) noexcept;
};

struct CreateOptions {
  std::int64_t stale_after_ns = kDefaultStaleAfterNs;
  bool remove_on_destroy = true;     ///< the creator's destructor removes the name (if still ours)
};

enum class OpenStatus : std::uint8_t {
  kOpened,        ///< segment attached
  kAbsent,        ///< no object of that name (the simulation has not started yet)
  kInitializing,  ///< exists but its creator has not finished initialising it
  kMismatch,      ///< not a Tactus segment, or another ABI / layout: message says what to do
  kError,         ///< invalid name, permission denied, mapping failed
};

struct TryOpenResult;

/// An attached (or created) segment. Move-only; unmaps on destruction (and, for the creator with
/// remove_on_destroy, removes the name if it still refers to this segment).
class Segment {
 public:
  /// Creates `name` with `capacity` (sim side). Replaces a stale segment (dead creator or
  /// heartbeat older than options.stale_after_ns) and refuses a live one. Throws SegmentError.
  static Segment create(const std::string& name, SegmentCapacity capacity,
                        const CreateOptions& options = {});

  /// Attaches to an existing segment; throws SegmentError (absent, initialising, mismatch, ...).
  static Segment open(const std::string& name, Access access = Access::kReadWrite);

  /// Non-blocking attach attempt (haptic side waiting for the simulation; never throws).
  static TryOpenResult tryOpen(const std::string& name, Access access = Access::kReadWrite);

  /// Removes the name (the memory stays mapped in processes attached to it). True if removed.
  static bool remove(const std::string& name) noexcept;

  /// Whether an object of that name exists in /dev/shm.
  static bool exists(const std::string& name) noexcept;

  /// [A-Za-z0-9_.-]{1,64}, not "." or "..".
  static bool isValidName(std::string_view name) noexcept;
  /// Throws SegmentError explaining the rule when the name is invalid.
  static void validateName(std::string_view name);
  /// "/dev/shm/<name>": for messages.
  static std::string pathOf(std::string_view name);

  Segment(Segment&& other) noexcept;
  Segment& operator=(Segment&& other) noexcept;
  Segment(const Segment&) = delete;
  Segment& operator=(const Segment&) = delete;
  ~Segment();

  const std::string& name() const noexcept;
  Access access() const noexcept;
  bool isCreator() const noexcept;
  std::size_t sizeBytes() const noexcept;
  const SegmentHeader& header() const noexcept;
  SegmentCapacity capacity() const noexcept;
  std::uint64_t generation() const noexcept;
  const SnapshotLayout& snapshotLayout() const noexcept;
  /// Base address of the mapping (for tests and tools).
  const void* data() const noexcept;
  /// For the creator's log: what create() found and replaced under the name, e.g. "replaced a
  /// stale segment of dead process 1234 (generation 3)"; empty when the name was free.
  const std::string& creationNote() const noexcept;

  // Endpoints. Writers (and the snapshot/device readers, which write the triple-buffer state)
  // need kReadWrite and throw SegmentError on a read-only segment. The stats reader works on
  // both. One writer and one reader per triple buffer at a time.
  SnapshotPublisher snapshotPublisher();             ///< sim
  SnapshotSubscriber snapshotSubscriber();           ///< haptic
  /// Device i's samples (0 <= i < capacity().devices; SegmentError otherwise).
  TripleWriter<DeviceSample> deviceWriter(int i = 0);   ///< haptic
  TripleReader<DeviceSample> deviceReader(int i = 0);   ///< sim
  StatsRingWriter statsWriter();                     ///< haptic
  StatsRingReader statsReader(StatsRingReader::Start start = StatsRingReader::Start::kNewest) const;
  /// Display frames and topology (display.h). The publisher needs kReadWrite; the subscriber
  /// works on a read-only mapping and any number may read. Both are detached (attached() false)
  /// when the segment has no display part.
  DisplayPublisher displayPublisher();               ///< sim
  DisplaySubscriber displaySubscriber() const;       ///< viewers

  // Liveness and shutdown (real-time safe; heartbeat and flag writers need kReadWrite).
  void beat(Side side, std::int64_t now_ns) noexcept;
  void beat(Side side) noexcept { beat(side, monotonicNs()); }
  std::int64_t heartbeatNs(Side side) const noexcept;
  /// Asks `side` to stop (e.g. the simulation asks the haptic loop to fade out and stop).
  void requestShutdown(Side side) noexcept;
  bool shutdownRequested(Side side) const noexcept;
  /// Unconditional store of haptic_pid (tests and tools; a daemon uses claimHaptic).
  void setHapticPid(std::int64_t pid) noexcept;
  /// Claims the haptic side of this segment for `pid`: takes the claim lock (an OFD lock on the
  /// object's second byte, held until this Segment is destroyed; the kernel drops it however the
  /// process ends, so a dead holder's recycled pid never blocks a claim) and stores pid in
  /// haptic_pid. Returns 0 when claimed (or already claimed through this Segment), the holder's
  /// pid when another holds it (-1 when it has not stored its pid yet). Of concurrent claimants
  /// exactly one wins. -1 on a read-only segment or pid <= 0. Not real-time.
  std::int64_t claimHaptic(std::int64_t pid) noexcept;
  /// Whether a live haptic process holds this segment's claim (through another mapping than
  /// this one), whether or not its loop is ticking: the kernel holds the claim for exactly as
  /// long as the process lives. Not real-time (one fcntl).
  bool hapticAttached() const noexcept;

  /// The creator process exists and its heartbeat (or creation time if it never beat) is at most
  /// stale_after_ns old. Not real-time (kill(pid, 0)).
  bool creatorAlive(std::int64_t stale_after_ns = kDefaultStaleAfterNs) const noexcept;
  /// The name still refers to this very segment (not removed, not replaced). Not real-time.
  bool stillCurrent() const noexcept;

 private:
  struct Impl;
  explicit Segment(std::unique_ptr<Impl> impl) noexcept;
  SegmentHeader* mutableHeader() noexcept;
  unsigned char* writableBase(const char* what);
  TripleBufferControl* deviceBuffer(int i, const char* what);
  std::unique_ptr<Impl> impl_;
};

/// Why the object open on `fd` (the segment `name`, for messages) must not be trusted: not a
/// regular file, owned by another user than the effective uid, or readable/writable by group or
/// others. Empty when it is fine. Uses fstat, so it judges exactly the object that was opened.
std::string segmentTrustProblem(int fd, const std::string& name);

/// Result of Segment::tryOpen.
struct TryOpenResult {
  OpenStatus status = OpenStatus::kAbsent;
  std::string message;               ///< why not opened (empty when opened)
  std::optional<Segment> segment;    ///< set when status == kOpened
  bool ok() const noexcept { return status == OpenStatus::kOpened; }
};

}  // namespace tactus::shared
