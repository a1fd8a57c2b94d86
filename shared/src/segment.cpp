// The shared-memory segment: create, open (with the ownership and trust checks of
// segment_ownership.cpp), the typed endpoints, heartbeats and the shutdown handshake; where each
// part lies is in segment_layout.cpp.
#include "tactus/shared/segment.h"

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
#include <optional>
#include <sstream>
#include <utility>

#include "tactus/shared/error.h"
#include "segment_ownership.h"

namespace tactus::shared {

namespace bip = boost::interprocess;
using namespace segment_detail;

// ---------------------------------------------------------------------------------------------

struct Segment::Impl {
  std::string name;
  Access access = Access::kReadWrite;
  bool creator = false;
  bool remove_on_destroy = false;
  bip::shared_memory_object shm;
  bip::mapped_region region;
  SegmentHeader* header = nullptr;
  SnapshotLayout snapshot_layout;
  DisplayLayout display_layout;
  dev_t dev = 0;
  ino_t ino = 0;
  std::string note;

  unsigned char* base() const { return static_cast<unsigned char*>(region.get_address()); }
  void recordIdentity() {
    struct stat st {};
    if (::fstat(shm.get_mapping_handle().handle, &st) == 0) {
      dev = st.st_dev;
      ino = st.st_ino;
    }
  }
};

Segment::Segment(std::unique_ptr<Impl> impl) noexcept : impl_(std::move(impl)) {}
Segment::Segment(Segment&& other) noexcept = default;
Segment& Segment::operator=(Segment&& other) noexcept = default;

Segment::~Segment() {
  if (impl_ && impl_->creator && impl_->remove_on_destroy && stillCurrent()) remove(impl_->name);
}

bool Segment::isValidName(std::string_view name) noexcept {
  if (name.empty() || name.size() > 64 || name == "." || name == "..") return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
           c == '_' || c == '.' || c == '-';
  });
}

void Segment::validateName(std::string_view name) {
  if (isValidName(name)) return;
  throw SegmentError("invalid segment name '" + std::string(name) +
                     "': use 1 to 64 characters from [A-Za-z0-9_.-] (no slash), e.g. "
                     "--segment tactus");
}

std::string Segment::pathOf(std::string_view name) { return "/dev/shm/" + std::string(name); }

bool Segment::exists(const std::string& name) noexcept {
  if (!isValidName(name)) return false;
  struct stat st {};
  return ::stat(pathOf(name).c_str(), &st) == 0;
}

bool Segment::remove(const std::string& name) noexcept {
  if (!isValidName(name)) return false;
  return bip::shared_memory_object::remove(name.c_str());
}

namespace {

// The stale object `inspected` judged stale, opened and with its ownership lock taken, while the
// name still refers to it; nullopt when it vanished, was replaced (by a new object another
// creator has not locked yet, say), or another process holds its lock (it is replacing it now).
std::optional<bip::shared_memory_object> claimStale(const std::string& name,
                                                    const Existing& inspected) {
  std::optional<bip::shared_memory_object> shm;
  try {
    shm.emplace(bip::open_only, name.c_str(), bip::read_write);
  } catch (const bip::interprocess_exception&) {
    return std::nullopt;
  }
  const int fd = shm->get_mapping_handle().handle;
  if (!takeOwnerLock(fd)) return std::nullopt;
  struct stat held {}, named {};
  if (::fstat(fd, &held) != 0 || held.st_dev != inspected.dev || held.st_ino != inspected.ino ||
      ::stat(Segment::pathOf(name).c_str(), &named) != 0 || held.st_dev != named.st_dev ||
      held.st_ino != named.st_ino) {
    return std::nullopt;
  }
  return shm;
}

}  // namespace

Segment Segment::create(const std::string& name, SegmentCapacity capacity,
                        const CreateOptions& options) {
  validateName(name);
  if (capacity.max_rows < 0 || capacity.max_contacts < 0 || capacity.display_vertices < 0 ||
      capacity.display_triangles < 0) {
    throw SegmentError("segment '" + name + "': negative capacity (max_rows " +
                       std::to_string(capacity.max_rows) + ", max_contacts " +
                       std::to_string(capacity.max_contacts) + ", display_vertices " +
                       std::to_string(capacity.display_vertices) + ", display_triangles " +
                       std::to_string(capacity.display_triangles) + ")");
  }
  if (capacity.devices < 1 || capacity.devices > kMaxInstruments) {
    throw SegmentError("segment '" + name + "': " + std::to_string(capacity.devices) +
                       " devices (1 to " + std::to_string(kMaxInstruments) + " allowed)");
  }
  const SegmentLayout layout = SegmentLayout::forCapacity(capacity);
  if (layout.total_bytes > kMaxSegmentBytes) {
    throw SegmentError("segment '" + name + "': capacity " + std::to_string(capacity.max_rows) +
                       " rows needs " + std::to_string(layout.total_bytes >> 20) +
                       " MiB (W is rows x rows doubles); lower max_contacts in the scene");
  }

  auto impl = std::make_unique<Impl>();
  impl->name = name;
  impl->access = Access::kReadWrite;
  impl->creator = true;
  impl->remove_on_destroy = options.remove_on_destroy;
  std::uint64_t generation = 1;
  bip::permissions owner_only(0600);
  // the stale object being replaced, its ownership lock held until our own create succeeded
  std::optional<bip::shared_memory_object> stale_claim;
  // exclusive create; on a name clash inspect the owner and replace it only if stale
  for (int attempt = 0;; ++attempt) {
    try {
      impl->shm = bip::shared_memory_object(bip::create_only, name.c_str(), bip::read_write,
                                            owner_only);
      if (!takeOwnerLock(impl->shm.get_mapping_handle().handle)) {
        const int err = errno;
        remove(name);
        throw SegmentError("cannot lock new shared memory '" + pathOf(name) + "' (" +
                           std::strerror(err) + ")");
      }
      break;
    } catch (const bip::interprocess_exception& e) {
      if (e.get_error_code() != bip::already_exists_error || attempt >= 3) {
        throw SegmentError("cannot create shared memory '" + pathOf(name) + "': " + e.what());
      }
    }
    const Existing ex = inspectExisting(name, options.stale_after_ns);
    if (ex.live) throw SegmentError(ex.message);
    if (!ex.vanished) {
      // Claim the object judged stale (take its ownership lock, free since its creator is gone)
      // and remove the name only while it still refers to that object: of two creators
      // replacing it at once one claims it, and neither can remove the other's new segment,
      // not even in the moment before the other locks it.
      std::optional<bip::shared_memory_object> stale = claimStale(name, ex);
      if (!stale) continue;   // gone, replaced or being replaced: look again
      generation = ex.generation + 1;
      impl->note = "replaced a stale segment '" + name + "' (generation " +
                   std::to_string(ex.generation) + ", creator " + ex.creator + ")";
      remove(name);
      stale_claim = std::move(stale);
    }
  }
  stale_claim.reset();

  // size, map, and initialise every part; the magic goes last
  try {
    impl->shm.truncate(static_cast<bip::offset_t>(layout.total_bytes));
    impl->region = bip::mapped_region(impl->shm, bip::read_write);
  } catch (const bip::interprocess_exception& e) {
    remove(name);
    throw SegmentError("cannot size/map segment '" + name + "' (" +
                       std::to_string(layout.total_bytes) + " bytes): " + e.what() +
                       "; check free space in /dev/shm (df -h /dev/shm)");
  }
  impl->recordIdentity();
  unsigned char* base = impl->base();
  auto* h = new (base) SegmentHeader();
  h->creator_pid = ::getpid();
  h->created_ns = monotonicNs();
  h->abi_version = kSegmentAbiVersion;
  h->header_bytes = sizeof(SegmentHeader);
  h->total_bytes = layout.total_bytes;
  h->generation = generation;
  h->max_rows = capacity.max_rows;
  h->max_contacts = capacity.max_contacts;
  h->snapshot_offset = layout.snapshot_offset;
  h->snapshot_bytes = layout.snapshot_bytes;
  h->snapshot_slot_bytes = layout.snapshot.total_bytes;
  h->device_offset = layout.device_offset;
  h->device_bytes = layout.device_bytes;
  h->device_slot_bytes = sizeof(DeviceSample);
  h->stats_offset = layout.stats_offset;
  h->stats_bytes = layout.stats_bytes;
  h->stats_capacity = kStatsRingCapacity;
  h->stats_record_bytes = sizeof(StatsRecord);
  h->snapshot_header_bytes = sizeof(ContactSnapshotHeader);
  h->devices = static_cast<std::uint32_t>(capacity.devices);
  h->display_max_vertices = layout.display.capacity.max_vertices;
  h->display_max_triangles = layout.display.capacity.max_triangles;
  h->display_max_contacts = layout.display.capacity.max_contacts;
  h->display_frame_header_bytes = sizeof(DisplayFrameHeader);
  h->display_offset = layout.display_offset;
  h->display_bytes = layout.display_bytes;
  h->display_slot_bytes = layout.display.frame_bytes;
  h->topology_offset = layout.topology_offset;
  h->topology_bytes = layout.topology_bytes;
  if (layout.display_bytes > 0) {
    initTripleBuffer(base + layout.display_offset, layout.display.frame_bytes);
    std::memset(base + layout.topology_offset, 0, layout.topology_bytes);
  }
  initTripleBuffer(base + layout.snapshot_offset, layout.snapshot.total_bytes);
  for (std::int32_t i = 0; i < capacity.devices; ++i) {
    const std::size_t at =
        layout.device_offset + static_cast<std::size_t>(i) * layout.device_stride_bytes;
    initTripleBuffer(base + at, sizeof(DeviceSample));
  }
  initSeqRing<StatsRecord>(base + layout.stats_offset, kStatsRingCapacity);
  // release: everything above is visible to an attacher that acquires the magic
  __atomic_store_n(&h->magic, kSegmentMagic, __ATOMIC_RELEASE);
  impl->header = h;
  impl->snapshot_layout = layout.snapshot;
  impl->display_layout = layout.display;
  return Segment(std::move(impl));
}

TryOpenResult Segment::tryOpen(const std::string& name, Access access) {
  TryOpenResult r;
  const std::string path = pathOf(name);
  if (!isValidName(name)) {
    r.status = OpenStatus::kError;
    r.message = "invalid segment name '" + name + "': use 1 to 64 characters from [A-Za-z0-9_.-]";
    return r;
  }
  auto impl = std::make_unique<Impl>();
  impl->name = name;
  impl->access = access;
  const bip::mode_t mode = access == Access::kReadOnly ? bip::read_only : bip::read_write;
  try {
    impl->shm = bip::shared_memory_object(bip::open_only, name.c_str(), mode);
  } catch (const bip::interprocess_exception& e) {
    if (e.get_error_code() == bip::not_found_error) {
      r.status = OpenStatus::kAbsent;
      r.message = "segment '" + name + "' does not exist yet: start sim_server --segment " + name;
    } else {
      r.status = OpenStatus::kError;
      r.message = "cannot open '" + path + "': " + e.what() +
                  " (segments are owner-only: run both daemons as the same user)";
    }
    return r;
  }
  // trust: only this user's owner-only objects are attached (before anything is mapped)
  if (std::string why = segmentTrustProblem(impl->shm.get_mapping_handle().handle, name);
      !why.empty()) {
    r.status = OpenStatus::kError;
    r.message = std::move(why);
    return r;
  }
  bip::offset_t size = 0;
  impl->shm.get_size(size);
  if (size < static_cast<bip::offset_t>(kStablePrefixBytes)) {
    r.status = OpenStatus::kInitializing;
    r.message = "segment '" + name + "' is still being created";
    return r;
  }
  try {
    impl->region = bip::mapped_region(impl->shm, mode);
  } catch (const bip::interprocess_exception& e) {
    r.status = OpenStatus::kError;
    r.message = "cannot map '" + path + "': " + e.what();
    return r;
  }
  const auto* h = static_cast<const SegmentHeader*>(impl->region.get_address());
  const std::uint64_t magic = loadMagic(h);
  const std::string fix = "rebuild both daemons from the same checkout or remove " + path;
  r.status = OpenStatus::kMismatch;
  if (magic == 0) {
    r.status = OpenStatus::kInitializing;
    r.message = "segment '" + name + "' is still being initialised";
    return r;
  }
  if (magic != kSegmentMagic) {
    r.message = "'" + path + "' is not a Tactus segment (bad magic): choose another --segment "
                "name or remove it if you know it is unused";
    return r;
  }
  if (h->abi_version != kSegmentAbiVersion) {
    r.message = "segment '" + name + "' has ABI version " + std::to_string(h->abi_version) +
                ", this " + programName() + " expects " + std::to_string(kSegmentAbiVersion) +
                ": " + fix;
    return r;
  }
  if (h->header_bytes != sizeof(SegmentHeader)) {
    r.message = "segment '" + name + "' has a " + std::to_string(h->header_bytes) +
                "-byte header, this " + programName() + " expects " +
                std::to_string(sizeof(SegmentHeader)) + ": " + fix;
    return r;
  }
  if (h->total_bytes != static_cast<std::uint64_t>(size) ||
      static_cast<std::size_t>(size) < sizeof(SegmentHeader)) {
    r.message = "segment '" + name + "' says it is " + std::to_string(h->total_bytes) +
                " bytes but the object is " + std::to_string(size) +
                " bytes: it is corrupt or being re-created; restart sim_server, or remove " + path;
    return r;
  }
  if (h->max_rows < 0 || h->max_contacts < 0 || h->display_max_vertices < 0 ||
      h->display_max_triangles < 0) {
    r.message = "segment '" + name + "' has a negative capacity: " + fix;
    return r;
  }
  if (h->devices < 1 || h->devices > static_cast<std::uint32_t>(kMaxInstruments)) {
    r.message = "segment '" + name + "' says it has " + std::to_string(h->devices) +
                " devices (1 to " + std::to_string(kMaxInstruments) + " allowed): " + fix;
    return r;
  }
  // every part must sit where this build would put it for the stored capacity
  SegmentCapacity stored;
  stored.max_rows = h->max_rows;
  stored.max_contacts = h->max_contacts;
  stored.display_vertices = h->display_max_vertices;
  stored.display_triangles = h->display_max_triangles;
  stored.devices = static_cast<std::int32_t>(h->devices);
  const SegmentLayout l = SegmentLayout::forCapacity(stored);
  // the capacity sizes what the attacher allocates (the haptic side's solver memory): never
  // beyond what a simulation may create
  if (l.total_bytes > kMaxSegmentBytes) {
    r.message = "segment '" + name + "' claims a capacity of " + std::to_string(h->max_rows) +
                " rows / " + std::to_string(h->max_contacts) + " contacts, " +
                (l.total_bytes == SnapshotLayout::kNoLayout
                     ? std::string("which has no layout")
                     : "which needs " + std::to_string(l.total_bytes >> 20) + " MiB") +
                ", more than any simulation creates (" + std::to_string(kMaxSegmentBytes >> 20) +
                " MiB): refusing it; " + fix;
    return r;
  }
  std::ostringstream diff;
  bool any = false;
  describeDiff(diff, any, "total_bytes", h->total_bytes, l.total_bytes);
  describeDiff(diff, any, "snapshot_offset", h->snapshot_offset, l.snapshot_offset);
  describeDiff(diff, any, "snapshot_bytes", h->snapshot_bytes, l.snapshot_bytes);
  describeDiff(diff, any, "snapshot_slot_bytes", h->snapshot_slot_bytes, l.snapshot.total_bytes);
  describeDiff(diff, any, "snapshot_header_bytes", h->snapshot_header_bytes,
               sizeof(ContactSnapshotHeader));
  describeDiff(diff, any, "device_offset", h->device_offset, l.device_offset);
  describeDiff(diff, any, "device_bytes", h->device_bytes, l.device_bytes);
  describeDiff(diff, any, "device_slot_bytes", h->device_slot_bytes, sizeof(DeviceSample));
  describeDiff(diff, any, "stats_offset", h->stats_offset, l.stats_offset);
  describeDiff(diff, any, "stats_bytes", h->stats_bytes, l.stats_bytes);
  describeDiff(diff, any, "stats_capacity", h->stats_capacity, kStatsRingCapacity);
  describeDiff(diff, any, "stats_record_bytes", h->stats_record_bytes, sizeof(StatsRecord));
  describeDiff(diff, any, "display_max_contacts", static_cast<std::uint64_t>(h->display_max_contacts),
               static_cast<std::uint64_t>(l.display.capacity.max_contacts));
  describeDiff(diff, any, "display_frame_header_bytes", h->display_frame_header_bytes,
               sizeof(DisplayFrameHeader));
  describeDiff(diff, any, "display_offset", h->display_offset, l.display_offset);
  describeDiff(diff, any, "display_bytes", h->display_bytes, l.display_bytes);
  describeDiff(diff, any, "display_slot_bytes", h->display_slot_bytes, l.display.frame_bytes);
  describeDiff(diff, any, "topology_offset", h->topology_offset, l.topology_offset);
  describeDiff(diff, any, "topology_bytes", h->topology_bytes, l.topology_bytes);
  if (any) {
    r.message = "segment '" + name + "' layout differs from this " + programName() + "'s (" +
                diff.str() + "): " + fix;
    return r;
  }
  // every triple buffer's control block: a valid state and the slot sizes of this layout (its
  // endpoints then never read the sizes from shared memory again)
  const auto* base = static_cast<const unsigned char*>(impl->region.get_address());
  auto control = [base](std::size_t offset) {
    return reinterpret_cast<const TripleBufferControl*>(base + offset);
  };
  std::string corrupt;
  if (!tripleBufferMatches(control(l.snapshot_offset), l.snapshot.total_bytes)) {
    corrupt = "snapshot";
  }
  for (std::uint32_t i = 0; i < h->devices && corrupt.empty(); ++i) {
    if (!tripleBufferMatches(control(l.device_offset + i * l.device_stride_bytes),
                             sizeof(DeviceSample))) {
      corrupt = "device " + std::to_string(i) + " sample";
    }
  }
  if (corrupt.empty() && l.display_bytes > 0 &&
      !tripleBufferMatches(control(l.display_offset), l.display.frame_bytes)) {
    corrupt = "display frame";
  }
  if (!corrupt.empty()) {
    r.message = "segment '" + name + "': its " + corrupt + " triple buffer is corrupt (an invalid "
                "slot state or slot size): refusing it; restart sim_server, or remove " + path;
    return r;
  }
  impl->recordIdentity();
  impl->header = const_cast<SegmentHeader*>(h);
  impl->snapshot_layout = l.snapshot;
  impl->display_layout = l.display;
  r.status = OpenStatus::kOpened;
  r.segment.emplace(Segment(std::move(impl)));
  return r;
}

Segment Segment::open(const std::string& name, Access access) {
  TryOpenResult r = tryOpen(name, access);
  if (!r.ok()) throw SegmentError(r.message);
  return std::move(*r.segment);
}

const std::string& Segment::name() const noexcept { return impl_->name; }
Access Segment::access() const noexcept { return impl_->access; }
bool Segment::isCreator() const noexcept { return impl_->creator; }
std::size_t Segment::sizeBytes() const noexcept { return impl_->region.get_size(); }
const SegmentHeader& Segment::header() const noexcept { return *impl_->header; }
SegmentCapacity Segment::capacity() const noexcept {
  SegmentCapacity c;
  c.max_rows = impl_->header->max_rows;
  c.max_contacts = impl_->header->max_contacts;
  c.display_vertices = impl_->header->display_max_vertices;
  c.display_triangles = impl_->header->display_max_triangles;
  c.devices = static_cast<std::int32_t>(impl_->header->devices);
  return c;
}
std::uint64_t Segment::generation() const noexcept { return impl_->header->generation; }
const SnapshotLayout& Segment::snapshotLayout() const noexcept { return impl_->snapshot_layout; }
const void* Segment::data() const noexcept { return impl_->region.get_address(); }
const std::string& Segment::creationNote() const noexcept { return impl_->note; }
SegmentHeader* Segment::mutableHeader() noexcept { return impl_->header; }

unsigned char* Segment::writableBase(const char* what) {
  if (impl_->access == Access::kReadOnly) {
    throw SegmentError("segment '" + impl_->name + "' is attached read-only: " + what +
                       " needs Access::kReadWrite");
  }
  return impl_->base();
}

SnapshotPublisher Segment::snapshotPublisher() {
  unsigned char* b = writableBase("the snapshot publisher");
  return SnapshotPublisher(
      reinterpret_cast<TripleBufferControl*>(b + impl_->header->snapshot_offset),
      impl_->snapshot_layout);
}

SnapshotSubscriber Segment::snapshotSubscriber() {
  unsigned char* b = writableBase("the snapshot subscriber (it swaps triple-buffer slots)");
  return SnapshotSubscriber(
      reinterpret_cast<TripleBufferControl*>(b + impl_->header->snapshot_offset),
      impl_->snapshot_layout);
}

// Device i's triple buffer (checked against the stored device count).
TripleBufferControl* Segment::deviceBuffer(int i, const char* what) {
  unsigned char* b = writableBase(what);
  const auto devices = static_cast<int>(impl_->header->devices);
  if (i < 0 || i >= devices) {
    throw SegmentError("segment '" + impl_->name + "' has " + std::to_string(devices) +
                       " device(s): no device " + std::to_string(i) + " (" + what + ")");
  }
  const SegmentLayout l = SegmentLayout::forCapacity(capacity());
  return reinterpret_cast<TripleBufferControl*>(
      b + impl_->header->device_offset + static_cast<std::size_t>(i) * l.device_stride_bytes);
}

TripleWriter<DeviceSample> Segment::deviceWriter(int i) {
  return TripleWriter<DeviceSample>(deviceBuffer(i, "the device-sample writer"));
}

TripleReader<DeviceSample> Segment::deviceReader(int i) {
  return TripleReader<DeviceSample>(
      deviceBuffer(i, "the device-sample reader (it swaps triple-buffer slots)"));
}

StatsRingWriter Segment::statsWriter() {
  unsigned char* b = writableBase("the stats writer");
  return StatsRingWriter(reinterpret_cast<SeqRingControl*>(b + impl_->header->stats_offset));
}

StatsRingReader Segment::statsReader(StatsRingReader::Start start) const {
  const unsigned char* b = static_cast<const unsigned char*>(impl_->region.get_address());
  return StatsRingReader(reinterpret_cast<const SeqRingControl*>(b + impl_->header->stats_offset),
                         start);
}

DisplayPublisher Segment::displayPublisher() {
  unsigned char* b = writableBase("the display publisher");
  if (impl_->header->display_bytes == 0) return {};
  return DisplayPublisher(
      reinterpret_cast<TripleBufferControl*>(b + impl_->header->display_offset),
      b + impl_->header->topology_offset, impl_->display_layout);
}

DisplaySubscriber Segment::displaySubscriber() const {
  const unsigned char* b = static_cast<const unsigned char*>(impl_->region.get_address());
  if (impl_->header->display_bytes == 0) return {};
  return DisplaySubscriber(
      reinterpret_cast<const TripleBufferControl*>(b + impl_->header->display_offset),
      b + impl_->header->topology_offset, impl_->display_layout);
}

void Segment::beat(Side side, std::int64_t now_ns) noexcept {
  if (impl_->access == Access::kReadOnly) return;
  // relaxed: a timestamp; nothing else is published through it
  (side == Side::kSim ? impl_->header->sim_heartbeat_ns : impl_->header->haptic_heartbeat_ns)
      .store(now_ns, std::memory_order_relaxed);
}

std::int64_t Segment::heartbeatNs(Side side) const noexcept {
  // relaxed: a timestamp
  return (side == Side::kSim ? impl_->header->sim_heartbeat_ns
                             : impl_->header->haptic_heartbeat_ns)
      .load(std::memory_order_relaxed);
}

void Segment::requestShutdown(Side side) noexcept {
  if (impl_->access == Access::kReadOnly) return;
  // release: whatever the requester wrote before asking is visible to the side that stops
  (side == Side::kSim ? impl_->header->sim_shutdown : impl_->header->haptic_shutdown)
      .store(1, std::memory_order_release);
}

bool Segment::shutdownRequested(Side side) const noexcept {
  // acquire: pairs with requestShutdown's release
  return (side == Side::kSim ? impl_->header->sim_shutdown : impl_->header->haptic_shutdown)
             .load(std::memory_order_acquire) != 0;
}

void Segment::setHapticPid(std::int64_t pid) noexcept {
  if (impl_->access == Access::kReadOnly) return;
  // relaxed: informational
  impl_->header->haptic_pid.store(pid, std::memory_order_relaxed);
}

std::int64_t Segment::claimHaptic(std::int64_t pid) noexcept {
  if (impl_->access == Access::kReadOnly || pid <= 0) return -1;
  std::atomic<std::int64_t>& claim = impl_->header->haptic_pid;
  // The claim is a lock the kernel drops when the holder's process ends, however it ends: a
  // recycled pid (a dead holder's pid reused by another program) can never hold it. One
  // attempt, no waiting: of racing claimants exactly one gets it.
  if (!takeHapticLock(impl_->shm.get_mapping_handle().handle)) {
    // acquire: the holder stored its pid after taking the lock (0 while it is about to)
    const std::int64_t holder = claim.load(std::memory_order_acquire);
    return holder > 0 ? holder : -1;
  }
  // release: a claimant that loses reads this pid (informational: the lock decides)
  claim.store(pid, std::memory_order_release);
  return 0;
}

bool Segment::hapticAttached() const noexcept {
  return hapticLockHeld(impl_->shm.get_mapping_handle().handle);
}

bool Segment::creatorAlive(std::int64_t stale_after_ns) const noexcept {
  const SegmentHeader& h = *impl_->header;
  if (!pidAlive(h.creator_pid)) return false;
  // relaxed: a timestamp
  const std::int64_t last = std::max(h.sim_heartbeat_ns.load(std::memory_order_relaxed),
                                     h.created_ns);
  return monotonicNs() - last <= stale_after_ns;
}

bool Segment::stillCurrent() const noexcept {
  struct stat st {};
  if (::stat(pathOf(impl_->name).c_str(), &st) != 0) return false;
  return st.st_dev == impl_->dev && st.st_ino == impl_->ino;
}

}  // namespace tactus::shared
