#pragma once
// Messages that cross the process boundary through the shared segment. All are plain data (no
// pointers, no std::vector, no Eigen members): trivially copyable fixed-size structs, or, for the
// contact snapshot, a fixed header followed by arrays placed at offsets computed from the segment
// capacity (so one layout serves every scene without recompiling).
//
// Units are SI and in the names (t_ns, pos_m, force_n). Frames: world frame of the simulation;
// quaternions are unit, scalar first (w, x, y, z). Twists are [vx vy vz wx wy wz].
//
// Every message carries `seq` (incremented per publish, 0 = never written) and `t_ns`
// (CLOCK_MONOTONIC, comparable across the two processes).

#include <array>
#include <cstddef>
#include <cstdint>
#include <type_traits>

#include "tactus/shared/nsgs.h"
#include "tactus/shared/triple_buffer.h"

namespace tactus::shared {

/// Instruments a scene may have, and so devices one haptic_server serves and per-instrument
/// blocks a snapshot carries (docs/design.md, "Several instruments and devices").
inline constexpr int kMaxInstruments = 4;

/// A device / instrument pose: position, orientation and gripper opening.
struct PoseSample {
  std::array<double, 3> pos_m{};
  std::array<double, 4> quat_wxyz{1.0, 0.0, 0.0, 0.0};
  double gripper_rad = 0.0;
};
static_assert(std::is_trivially_copyable_v<PoseSample>);

/// ContactSnapshotHeader::flags bits.
enum SnapshotFlags : std::uint32_t {
  kSnapshotValid = 1u << 0,         ///< a complete problem (rows/contacts may still be 0)
  kSnapshotConverged = 1u << 1,     ///< the simulation's NSGS converged for this problem
  kSnapshotHasJacobian = 1u << 2,   ///< J is filled (else the haptic side must not move delta_free)
  kSnapshotShuttingDown = 1u << 3,  ///< the simulation is stopping: fade out
  /// W is exactly symmetric (W[i][j] == W[j][i] bit for bit, checked by the publisher): the
  /// haptic side may use the cheaper symmetric row-update sweep; without it, the column sweep
  kSnapshotSymmetricW = 1u << 4,
};

/// One instrument's block of the snapshot header: where its device was (J's origin for the rows
/// of its contacts) and where its god object ended the step.
struct SnapshotInstrument {
  std::uint64_t device_seq = 0;      ///< seq of the instrument's DeviceSample the step used
  PoseSample device_pose;            ///< x_h* of the instrument's device
  PoseSample tool_pose;              ///< the god object pose after the step
};
static_assert(std::is_trivially_copyable_v<SnapshotInstrument>);

/// Fixed part of the contact snapshot (the haptic local model of
/// ../../../../docs/design.md#the-haptic-local-model), at offset 0 of its triple-buffer slot.
/// Several instruments (docs/design.md, "Several instruments and devices"): `instruments`
/// blocks are valid, contact c belongs to instrument SnapshotView::contactInstrument()[c] (-1: to
/// none, a static obstacle's contact, whose J and tool rows are zero; kContactUnreachable, -2: to
/// none, and no instrument's contact reaches it through W either: W is zero between it and every
/// contact of an instrument, so no device can change its force and the haptic loop need not
/// re-solve it, docs/design.md "Bodies that do not couple"), and
/// row r of J is d delta_free_r / d x_h of that instrument's device. device_seq, device_pose
/// and tool_pose repeat instrument 0's block for readers of one instrument.
/// contactInstrument() of a contact in a group of bodies without instrument (see below).
inline constexpr std::int32_t kContactUnreachable = -2;

struct ContactSnapshotHeader {
  std::uint64_t seq = 0;             ///< publish counter, 0 = nothing published yet
  std::int64_t t_ns = 0;             ///< monotonic time of publication
  std::uint64_t step = 0;            ///< simulation step index
  double h_s = 0.0;                  ///< simulation time step
  std::int32_t rows = 0;             ///< m = row_offset[contacts]
  std::int32_t contacts = 0;         ///< nc
  std::uint32_t flags = 0;           ///< SnapshotFlags
  std::int32_t solver_sweeps = 0;    ///< sweeps the simulation's NSGS took (0: no solve)
  double solver_error = 0.0;         ///< its natural-map error at exit (0: no solve)
  std::uint64_t device_seq = 0;      ///< seq of the DeviceSample the step used
  PoseSample device_pose;            ///< x_h*: the device pose used for this step (J's origin)
  PoseSample tool_pose;              ///< the instrument (god object) pose after the step
  std::int32_t instruments = 0;      ///< valid blocks in `instrument` (0 .. kMaxInstruments)
  std::int32_t reserved = 0;
  std::array<SnapshotInstrument, kMaxInstruments> instrument{};
};
static_assert(std::is_trivially_copyable_v<ContactSnapshotHeader>);
static_assert(std::is_standard_layout_v<ContactSnapshotHeader>);

/// Byte offsets of the snapshot arrays inside a slot, computed from the capacity. Every array
/// starts on a cache line. W is row-major with leading dimension ld = max_rows.
struct SnapshotLayout {
  std::int32_t max_rows = 0;         ///< cap_r
  std::int32_t max_contacts = 0;     ///< cap_c
  std::size_t row_offset = 0;        ///< int32[cap_c + 1]
  std::size_t contact_id = 0;        ///< uint64[cap_c]   (stable contact identities, warm start)
  std::size_t mu = 0;                ///< double[cap_c]
  std::size_t W = 0;                 ///< double[cap_r * cap_r], row-major, ld = cap_r
  std::size_t delta_free = 0;        ///< double[cap_r]
  std::size_t f = 0;                 ///< double[cap_r]   (the simulation's solution)
  std::size_t J = 0;                 ///< double[cap_r * 6], row-major m x 6: d delta_free / d x_h
  std::size_t contact_point_m = 0;   ///< double[cap_c * 3] world contact points
  std::size_t contact_normal = 0;    ///< double[cap_c * 3] world normals (local frame row n)
  std::size_t contact_tangent = 0;   ///< double[cap_c * 6] world t1 then t2 per contact
  std::size_t contact_instrument = 0;  ///< int32[cap_c] the instrument of each contact (-1: none)
  std::size_t total_bytes = 0;       ///< slot payload size

  /// Rows and contacts beyond these have no layout (W alone would need 8 TiB); the bound keeps
  /// every product below from overflowing.
  static constexpr std::int32_t kMaxRows = std::int32_t{1} << 20;
  static constexpr std::int32_t kMaxContacts = std::int32_t{1} << 20;
  /// total_bytes of a capacity that has no layout (negative or beyond the bounds above): larger
  /// than any segment, so creators and attachers refuse it.
  static constexpr std::size_t kNoLayout = ~std::size_t{0};

  /// Layout for a capacity (0 <= max_rows <= kMaxRows, 0 <= max_contacts <= kMaxContacts;
  /// otherwise total_bytes = kNoLayout and no offsets). Pure function: both processes compute
  /// the same offsets from the capacity stored in the segment header.
  static constexpr SnapshotLayout forCapacity(std::int32_t max_rows,
                                              std::int32_t max_contacts) noexcept {
    SnapshotLayout l;
    l.max_rows = max_rows;
    l.max_contacts = max_contacts;
    if (max_rows < 0 || max_contacts < 0 || max_rows > kMaxRows || max_contacts > kMaxContacts) {
      l.total_bytes = kNoLayout;
      return l;
    }
    const auto r = static_cast<std::size_t>(max_rows);
    const auto c = static_cast<std::size_t>(max_contacts);
    std::size_t at = roundUpToCacheLine(sizeof(ContactSnapshotHeader));
    auto place = [&at](std::size_t bytes) {
      const std::size_t here = at;
      at = roundUpToCacheLine(at + bytes);
      return here;
    };
    l.row_offset = place((c + 1) * sizeof(std::int32_t));
    l.contact_id = place(c * sizeof(std::uint64_t));
    l.mu = place(c * sizeof(double));
    l.W = place(r * r * sizeof(double));
    l.delta_free = place(r * sizeof(double));
    l.f = place(r * sizeof(double));
    l.J = place(r * 6 * sizeof(double));
    l.contact_point_m = place(c * 3 * sizeof(double));
    l.contact_normal = place(c * 3 * sizeof(double));
    l.contact_tangent = place(c * 6 * sizeof(double));
    l.contact_instrument = place(c * sizeof(std::int32_t));
    l.total_bytes = at;
    return l;
  }
};

/// Read access to a snapshot slot (the haptic side). Returns typed pointers into the slot and a
/// ContactProblemView over it: no copy.
class SnapshotView {
 public:
  SnapshotView() = default;
  SnapshotView(const void* slot, const SnapshotLayout& layout) noexcept
      : base_(static_cast<const unsigned char*>(slot)), layout_(layout) {}

  bool valid() const noexcept { return base_ != nullptr; }
  const SnapshotLayout& layout() const noexcept { return layout_; }
  const ContactSnapshotHeader& header() const noexcept {
    return *reinterpret_cast<const ContactSnapshotHeader*>(base_);
  }
  int rows() const noexcept { return header().rows; }
  int contacts() const noexcept { return header().contacts; }
  int ld() const noexcept { return layout_.max_rows; }

  const std::int32_t* rowOffset() const noexcept { return at<std::int32_t>(layout_.row_offset); }
  const std::uint64_t* contactId() const noexcept { return at<std::uint64_t>(layout_.contact_id); }
  const double* mu() const noexcept { return at<double>(layout_.mu); }
  const double* W() const noexcept { return at<double>(layout_.W); }
  const double* deltaFree() const noexcept { return at<double>(layout_.delta_free); }
  const double* f() const noexcept { return at<double>(layout_.f); }
  const double* J() const noexcept { return at<double>(layout_.J); }
  const double* contactPoint() const noexcept { return at<double>(layout_.contact_point_m); }
  const double* contactNormal() const noexcept { return at<double>(layout_.contact_normal); }
  const double* contactTangent() const noexcept { return at<double>(layout_.contact_tangent); }
  const std::int32_t* contactInstrument() const noexcept {
    return at<std::int32_t>(layout_.contact_instrument);
  }

  /// The NSGS sweep this snapshot allows: the row-wise update only when the simulation marked W
  /// exactly symmetric (kSnapshotSymmetricW).
  NsgsCoupling coupling() const noexcept {
    return (header().flags & kSnapshotSymmetricW) != 0 ? NsgsCoupling::kSymmetricRowUpdate
                                                       : NsgsCoupling::kColumnUpdate;
  }

  /// The contact problem delta = W f + delta_free, pointing into the slot. Pass another
  /// delta_free (e.g. moved with the device) to solve the same problem from a local copy.
  ContactProblemView problem(const double* delta_free_override = nullptr) const noexcept {
    return denseProblemView(contacts(), rows(), rowOffset(), W(), ld(),
                            delta_free_override != nullptr ? delta_free_override : deltaFree(),
                            mu());
  }

 private:
  template <class T>
  const T* at(std::size_t offset) const noexcept {
    return reinterpret_cast<const T*>(base_ + offset);
  }
  const unsigned char* base_ = nullptr;
  SnapshotLayout layout_;
};

/// Write access to a snapshot slot (the simulation side), same accessors, mutable.
class SnapshotWriter {
 public:
  SnapshotWriter() = default;
  SnapshotWriter(void* slot, const SnapshotLayout& layout) noexcept
      : base_(static_cast<unsigned char*>(slot)), layout_(layout) {}

  bool valid() const noexcept { return base_ != nullptr; }
  const SnapshotLayout& layout() const noexcept { return layout_; }
  ContactSnapshotHeader& header() noexcept {
    return *reinterpret_cast<ContactSnapshotHeader*>(base_);
  }
  int ld() const noexcept { return layout_.max_rows; }

  /// Sets rows/contacts; returns false (and changes nothing) if they exceed the capacity.
  bool setSize(int rows, int contacts) noexcept {
    if (rows < 0 || contacts < 0 || rows > layout_.max_rows || contacts > layout_.max_contacts) {
      return false;
    }
    header().rows = rows;
    header().contacts = contacts;
    return true;
  }

  std::int32_t* rowOffset() noexcept { return at<std::int32_t>(layout_.row_offset); }
  std::uint64_t* contactId() noexcept { return at<std::uint64_t>(layout_.contact_id); }
  double* mu() noexcept { return at<double>(layout_.mu); }
  double* W() noexcept { return at<double>(layout_.W); }
  double* deltaFree() noexcept { return at<double>(layout_.delta_free); }
  double* f() noexcept { return at<double>(layout_.f); }
  double* J() noexcept { return at<double>(layout_.J); }
  double* contactPoint() noexcept { return at<double>(layout_.contact_point_m); }
  double* contactNormal() noexcept { return at<double>(layout_.contact_normal); }
  double* contactTangent() noexcept { return at<double>(layout_.contact_tangent); }
  std::int32_t* contactInstrument() noexcept {
    return at<std::int32_t>(layout_.contact_instrument);
  }

  /// Read-only view of the same slot.
  SnapshotView view() const noexcept { return SnapshotView(base_, layout_); }
  ContactProblemView problem() const noexcept { return view().problem(); }

 private:
  template <class T>
  T* at(std::size_t offset) noexcept {
    return reinterpret_cast<T*>(base_ + offset);
  }
  unsigned char* base_ = nullptr;
  SnapshotLayout layout_;
};

/// Simulation-side endpoint of the snapshot triple buffer: fill slot(), then publish().
class SnapshotPublisher {
 public:
  SnapshotPublisher() = default;
  SnapshotPublisher(TripleBufferControl* control, const SnapshotLayout& layout) noexcept
      : writer_(control, layout.total_bytes), layout_(layout) {}
  bool attached() const noexcept { return writer_.attached(); }
  const SnapshotLayout& layout() const noexcept { return layout_; }
  /// The slot being filled (the writer's back slot); valid until publish().
  SnapshotWriter slot() noexcept { return SnapshotWriter(writer_.buffer(), layout_); }
  /// Hands the slot to the haptic side; true if it replaced an untaken snapshot.
  bool publish() noexcept { return writer_.publish(); }

 private:
  TripleBufferWriter writer_;
  SnapshotLayout layout_;
};

/// Haptic-side endpoint of the snapshot triple buffer.
class SnapshotSubscriber {
 public:
  SnapshotSubscriber() = default;
  SnapshotSubscriber(TripleBufferControl* control, const SnapshotLayout& layout) noexcept
      : reader_(control, layout.total_bytes), layout_(layout) {}
  bool attached() const noexcept { return reader_.attached(); }
  const SnapshotLayout& layout() const noexcept { return layout_; }
  bool hasNew() const noexcept { return reader_.hasNew(); }
  /// The newest published snapshot (header().seq == 0: nothing published yet). The view stays
  /// valid and unchanged until the next latest().
  SnapshotView latest(bool* fresh = nullptr) noexcept {
    return SnapshotView(reader_.latest(fresh), layout_);
  }
  SnapshotView current() const noexcept { return SnapshotView(reader_.current(), layout_); }

 private:
  TripleBufferReader reader_;
  SnapshotLayout layout_;
};

/// DeviceSample::status bits.
enum DeviceSampleStatus : std::uint32_t {
  kDeviceOk = 1u << 0,              ///< the last read returned data
  kDeviceNoData = 1u << 1,          ///< the last read returned no new data (pose held)
  kDeviceFault = 1u << 2,           ///< the backend reported a fault
  kDeviceForcesEnabled = 1u << 3,   ///< forces engaged (the engage gate has opened)
  kDeviceForceClamped = 1u << 4,    ///< the rendered wrench was clamped to the force limit
  /// the fade gain is below 1: fading out (stale snapshot, device fault) or back in
  kDeviceForceFading = 1u << 5,
  // bit 6 (formerly "shutting down", never raised) is unused
  /// the pose is one the device delivered (not the zero pose before its first sample): only
  /// such a sample may move the instrument
  kDevicePoseValid = 1u << 7,
};

/// The haptic side's device state and rendered wrench, published every tick (haptic -> sim).
struct DeviceSample {
  std::uint64_t seq = 0;
  std::int64_t t_ns = 0;
  std::array<double, 3> pos_m{};
  std::array<double, 4> quat_wxyz{1.0, 0.0, 0.0, 0.0};
  std::array<double, 3> vel_mps{};
  std::array<double, 3> angvel_radps{};
  double gripper_rad = 0.0;
  std::uint32_t buttons = 0;
  std::uint32_t status = 0;          ///< DeviceSampleStatus bits
  std::array<double, 3> force_n{};   ///< wrench rendered on the hand at t_ns
  std::array<double, 3> torque_nm{};
  std::uint64_t snapshot_seq = 0;    ///< seq of the snapshot the wrench was computed from
};
static_assert(std::is_trivially_copyable_v<DeviceSample>);
static_assert(std::is_standard_layout_v<DeviceSample>);

/// StatsRecord::flags bits.
enum StatsFlags : std::uint32_t {
  /// the tick's work finished more than one period after its scheduled start
  /// (finished_ns - scheduled_ns > period): it ate into the next tick
  kStatsOverrun = 1u << 0,
  kStatsSnapshotStale = 1u << 1,
  kStatsNoSnapshot = 1u << 2,
  kStatsSolverNotConverged = 1u << 3,
  kStatsForceClamped = 1u << 4,
  kStatsDeviceNoData = 1u << 5,
  kStatsDeviceFault = 1u << 6,
  /// the linearised local model did not hold at this pose: the tick re-solved the full problem
  kStatsModelFallback = 1u << 7,
  /// the tick's work ended after its deadline (its start plus the solve budget)
  kStatsDeadlineMissed = 1u << 8,
};

/// StatsRecord::model: what the tick's local model solved (haptic::LocalModelUsed's values).
enum StatsModel : std::int64_t {
  kStatsModelNone = 0,        ///< no solve (no snapshot, stale, no pose)
  kStatsModelFull = 1,        ///< full re-solve
  kStatsModelLinearized = 2,  ///< the linearisation held
  kStatsModelFallbackSolve = 3,  ///< the linearisation did not hold: full re-solve
  kStatsModelCorrected = 4,   ///< the linearisation with its active set corrected in a few contacts
};
inline constexpr int kStatsModelCount = 5;

/// StatsRecord::fallback_reason: why the linearisation did not hold at the tick's pose
/// (haptic::FallbackReason's values).
enum StatsFallbackReason : std::int64_t {
  kStatsFallbackNone = 0,
  kStatsFallbackNotLinearized = 1,  ///< the snapshot has no linearisation
  kStatsFallbackOutOfRange = 2,     ///< the device is beyond the linearisation's validity range
  kStatsFallbackContactCloses = 3,  ///< a separated contact would penetrate
  kStatsFallbackContactLifts = 4,   ///< an active contact's normal force would turn negative
  kStatsFallbackLeavesCone = 5,     ///< a sticking contact's force would leave its cone
  kStatsFallbackSlipTurns = 6,      ///< a sliding contact would stop or turn against its force
};
inline constexpr int kStatsFallbackReasonCount = 7;

/// One record per haptic tick, written into the stats ring. Only 8-byte fields (the ring copies
/// records word by word).
struct StatsRecord {
  std::uint64_t tick = 0;            ///< tick index since the loop started
  std::int64_t scheduled_ns = 0;     ///< deadline of the tick
  std::int64_t woken_ns = 0;         ///< when the timer returned
  std::int64_t finished_ns = 0;      ///< end of the tick's work
  std::int64_t solve_ns = 0;         ///< time spent in the NSGS solve
  std::int64_t sweeps = 0;
  double residual = 0.0;             ///< natural-map error at exit
  std::int64_t contacts = 0;
  double force_norm_n = 0.0;         ///< |rendered force| (device 0)
  std::uint64_t snapshot_seq = 0;
  std::uint64_t flags = 0;           ///< StatsFlags (any device's)
  std::int64_t devices = 0;          ///< devices served (entries of device_force_norm_n)
  std::array<double, kMaxInstruments> device_force_norm_n{};   ///< |rendered force| per device
  // the tick's phases [ns]: reading and publishing the devices, taking the prepared snapshot and
  // solving the local model, the safety chain and device writes; and its deadline
  std::int64_t read_ns = 0;
  std::int64_t model_ns = 0;
  std::int64_t output_ns = 0;
  std::int64_t started_ns = 0;       ///< when the tick's work began (its deadline's origin)
  std::int64_t deadline_ns = 0;      ///< the tick's absolute deadline (0: sweeps only)
  std::int64_t model = 0;            ///< StatsModel
  std::int64_t prepare_ns = 0;       ///< off-thread preparation time of the snapshot solved
  /// StatsFallbackReason: why the linearisation did not hold (also on a corrected tick: what the
  /// correction repaired); kStatsFallbackNone when it held or was not used
  std::int64_t fallback_reason = 0;
  /// corrected solves of the active-set correction (on a fallback tick: those it made before it
  /// gave up; 0: none, because it was not tried or it gave up at the prediction's own check,
  /// e.g. more contacts to change than it corrects)
  std::int64_t correction_rounds = 0;
};
static_assert(std::is_trivially_copyable_v<StatsRecord>);
static_assert(sizeof(StatsRecord) % 8 == 0);

}  // namespace tactus::shared
