#pragma once
// The haptic loop (docs/design.md, "The haptic local model" and section 4): every period it reads the
// device, publishes the sample to the simulation, takes the newest contact snapshot, moves its
// delta_free with the device (delta_free = delta_free* + J (x_h [-] x_h*)), re-solves the
// frictional contact problem with warm-started NSGS under a sweep and time budget, turns the
// forces into the wrench on the instrument, applies the safety chain (scale, clamp, slew limit,
// engage gate, stale-data fade) and writes the device, then writes one stats record.
//
// Real-time rules: tick() allocates nothing, takes no lock, logs nothing and never throws. Faults
// go to counters and to an SPSC event ring that a non-real-time thread drains into spdlog. The
// link to the simulation (the shared segment) is swapped by the non-real-time supervisor through
// an atomic pointer with a hazard-pointer acknowledgement, so the tick never waits for it.
//
// Several devices (docs/design.md, "Several instruments and devices"): one loop serves up to
// shared::kMaxInstruments devices, device i driving instrument i. Each tick reads every device,
// moves delta_free with each device's displacement through the rows of its own instrument,
// solves the one contact problem once, and renders to each device the wrench on its own
// instrument through its own safety chain (mapping, engage gate, fade, clamp, slew, guard): a
// device that faults or goes silent fades its own force only.
//
// Safety: HapticSettings::validate() (called by the HapticLoop constructor) rejects settings that
// are not finite or out of range; whatever the settings, the tick's last stage (guardWrench)
// writes only finite forces and torques within the effective clamps (the smaller of the
// settings' and the device's limit, never above HapticSettingsLimits::kMaxForceN /
// kMaxTorqueNm), and counts every intervention in HapticCounters::guard_interventions.

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "tactus/device/device.h"
#include "tactus/haptic/local_model.h"
#include "tactus/haptic/snapshot_preparer.h"
#include "tactus/haptic/workspace_mapping.h"
#include "tactus/shared/event_ring.h"
#include "tactus/shared/haptic_limits.h"
#include "tactus/shared/stats_ring.h"
#include "tactus/shared/messages.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/pose.h"
#include "tactus/shared/segment.h"

namespace tactus::haptic {

/// Accepted ranges of HapticSettings (validate() and haptic_server's options use the same
/// bounds). The force and torque ceilings also bound the tick's final guard.
struct HapticSettingsLimits {
  /// force_scale in [0, this]
  static constexpr double kMaxForceScale = shared::HapticLimits::kMaxForceScale;
  /// max_force_n in (0, this] N
  static constexpr double kMaxForceN = shared::HapticLimits::kMaxForceN;
  static constexpr double kMaxTorqueNm = 5.0;             ///< max_torque_nm in (0, this] N m
  static constexpr double kMaxSlewNPerS = 1e6;            ///< slew_n_per_s in (0, this] N/s
  /// watchdog_ms in (0, this] ms
  static constexpr double kMaxWatchdogMs = shared::HapticLimits::kMaxWatchdogMs;
  static constexpr double kMaxFadeMs = 10'000.0;          ///< fade_ms in [0, this] ms
  /// snapshot_blend_ms in [0, this] ms
  static constexpr double kMaxSnapshotBlendMs = shared::HapticLimits::kMaxSnapshotBlendMs;
  /// max_sweeps in [1, this]
  static constexpr int kMaxSweeps = shared::HapticLimits::kMaxSweeps;
  /// tolerance in (0, this]
  static constexpr double kMaxTolerance = shared::HapticLimits::kMaxTolerance;
  /// period_ns in (0, this] ns
  static constexpr std::int64_t kMaxPeriodNs = 1'000'000'000;
  /// solve_budget_ns in (0, this x period_ns]: the rest of the period is the timer's wake-up
  /// margin and the tick's phases after the deadline (safety chain, writes, stats)
  static constexpr double kMaxBudgetFraction = 0.9;
  /// solve_budget_ns = 0 (no clock, sweeps only: deterministic tests and offline tools) only with
  /// max_sweeps at most this
  static constexpr int kMaxSweepsWithoutBudget = 200;
  /// Limits below this are treated as zero by the guard (no force rather than denormal maths).
  static constexpr double kMinLimit = 1e-9;
};

/// Safety and solver settings of the loop.
struct HapticSettings {
  double force_scale = 1.0;             ///< rendered = scale * contact wrench
  double max_force_n = 8.0;             ///< clamp on |force| (the device's own limit also applies)
  double max_torque_nm = 0.5;           ///< clamp on |torque|
  /// max change of the force per second, applied per nominal period: no two consecutive
  /// commands differ by more than slew_n_per_s * period, however long the tick between them
  double slew_n_per_s = 2000.0;
  /// Forces engage (at start, and again after every interruption: a link change, a device
  /// fault, a stale snapshot, an unusable model) only once the requested command is below this.
  double engage_threshold_n = 0.5;
  double watchdog_ms = 50.0;            ///< snapshot older than this: fade out
  /// Fade-out and fade-in ramp, counted in nominal periods (fade_ms / period ticks): the gain
  /// moves by period / fade_ms per tick, however late the tick
  double fade_ms = 100.0;
  /// Blends each new snapshot in over this time (0: off). The wrench the new local model gives
  /// differs from the last one rendered by the step between the simulation's two solutions; the
  /// loop renders the new model plus that step, shrunk linearly to zero over the blend, so the
  /// hand feels a ramp instead of a 50-100 Hz staircase. One simulation period is the natural
  /// value (docs/design.md, "Snapshot blending").
  double snapshot_blend_ms = 0.0;
  int max_sweeps = 50;                  ///< NSGS sweep budget per tick
  double tolerance = 1e-6;              ///< NSGS tolerance
  /// The local model the tick solves (local_model.h; scene haptics.local_model, haptic_server
  /// --local-model): the full re-solve, the linearisation with the re-solve as fallback, or
  /// chosen per snapshot by its size.
  LocalModelKind local_model = LocalModelKind::kAutomatic;
  /// Anderson acceleration of the tick's NSGS over this many past sweeps (0: off; at most
  /// shared::kMaxAndersonDepth; shared/nsgs.h). Mostly helps the first ticks on a new snapshot
  /// (docs/measurements.md, "Anderson acceleration")
  int anderson_depth = 0;
  /// The linearisation's fallback re-solves only the contacts that can carry force
  /// (LocalModelSettings::reduced_fallback; tactus-jitter --full-fallback turns it off)
  bool reduced_fallback = true;
  /// Before the fallback, correct the linearisation's active set in a few contacts
  /// (LocalModelSettings::active_set_correction; tactus-jitter --no-correction turns it off)
  bool active_set_correction = true;
  /// The tick's deadline, from the start of its work: the local model's re-solve stops at it
  /// (checked within sweeps). In (0, kMaxBudgetFraction x period_ns]; 0 (no clock) only with
  /// max_sweeps <= kMaxSweepsWithoutBudget.
  std::int64_t solve_budget_ns = 400'000;
  std::int64_t period_ns = 1'000'000;   ///< tick period (a tick ending later is an overrun)
  bool render_torque = false;           ///< devices without rotational feedback: false

  /// Throws tactus::Error naming the first setting that is not finite or outside its range
  /// (HapticSettingsLimits; engage_threshold_n: finite and >= 0), or a budget that leaves no
  /// room in the period.
  void validate() const;
  /// The local model's settings these give (kind, tolerance, sweeps, Anderson depth).
  LocalModelSettings localModel() const noexcept;
};

/// The tick's last stage, a pure function: replaces a non-finite force or torque by zero and
/// scales each so that its norm is at most its limit (a limit that is not finite, or below
/// HapticSettingsLimits::kMinLimit, counts as zero; limits are capped at kMaxForceN /
/// kMaxTorqueNm). Returns true when it changed anything. Real-time safe.
bool guardWrench(std::array<double, 3>& force_n, std::array<double, 3>& torque_nm,
                 double max_force_n, double max_torque_nm) noexcept;

/// Euclidean norm without overflow or underflow in the squares (real-time safe).
double wrenchNorm(const std::array<double, 3>& v) noexcept;

/// Fault and event counters (read by the supervisor; relaxed atomics).
struct HapticCounters {
  std::atomic<std::uint64_t> ticks{0};
  std::atomic<std::uint64_t> device_no_data{0};
  std::atomic<std::uint64_t> device_faults{0};
  std::atomic<std::uint64_t> write_faults{0};
  std::atomic<std::uint64_t> stale_device_samples{0};  ///< samples older than the watchdog
  /// ticks on which a device that had delivered a pose had returned no data for longer than
  /// the watchdog (a silent device counts as faulty: its force fades)
  std::atomic<std::uint64_t> silent_device_ticks{0};
  std::atomic<std::uint64_t> stale_ticks{0};
  std::atomic<std::uint64_t> snapshots_taken{0};
  std::atomic<std::uint64_t> solver_not_converged{0};
  std::atomic<std::uint64_t> clamped{0};
  std::atomic<std::uint64_t> non_finite_input{0};
  /// device samples whose orientation is not a usable quaternion (zero, or far from unit): the
  /// sample is refused like a non-finite one
  std::atomic<std::uint64_t> unusable_orientation{0};
  /// times a device's forces disengaged (an interruption: they fade out and re-engage only
  /// below HapticSettings::engage_threshold_n)
  std::atomic<std::uint64_t> disengaged{0};
  /// solves that found a contact NSGS cannot solve (zero, negative or denormal W diagonal):
  /// the snapshot is corrupt, so the tick renders no force from it (shared::NsgsStatus::kIllPosed)
  std::atomic<std::uint64_t> ill_posed_solves{0};
  std::atomic<std::uint64_t> events_dropped{0};
  std::atomic<std::uint64_t> overruns{0};            ///< ticks flagged shared::kStatsOverrun
  /// ticks where the final guard had to change the command (never with valid settings)
  std::atomic<std::uint64_t> guard_interventions{0};
  /// ticks the linearised local model held, ticks it held with its active set corrected, and
  /// ticks it did not (re-solve instead)
  std::atomic<std::uint64_t> linearized_ticks{0};
  std::atomic<std::uint64_t> corrected_ticks{0};
  std::atomic<std::uint64_t> model_fallbacks{0};
  /// snapshots the preparation refused (too large, inconsistent, non-finite, ill-posed)
  std::atomic<std::uint64_t> rejected_snapshots{0};
  /// ticks whose work ended after their deadline (StatsFlags kStatsDeadlineMissed)
  std::atomic<std::uint64_t> deadline_misses{0};
};

/// Event codes of the haptic loop beyond shared::EventCode (drained into spdlog outside the
/// tick; see eventName()).
enum HapticEvent : std::uint32_t {
  kEventEngaged = shared::kEventUser + 1,         ///< forces engaged (arg0 = |F| N)
  kEventDeviceRecovered = shared::kEventUser + 2, ///< arg0 = device
  /// NaN/Inf from the device (arg1 = device). shared::kEventDeviceFault and kEventDeviceNoData
  /// carry the device in arg0.
  kEventNonFinite = shared::kEventUser + 3,
  kEventSnapshotTooLarge = shared::kEventUser + 4,  ///< arg0 = rows
  kEventSimShuttingDown = shared::kEventUser + 5,
  /// the snapshot's W has a diagonal NSGS cannot use (arg0 = ill-posed contacts, arg1 = snapshot
  /// sequence); raised once per snapshot, no force is rendered from it
  kEventIllPosedSnapshot = shared::kEventUser + 6,
  /// the preparation refused a snapshot: inconsistent counts or offsets, or non-finite numbers
  /// (arg0 = haptic::PrepareStatus, arg1 = snapshot sequence); no force is rendered from it
  kEventSnapshotRejected = shared::kEventUser + 7,
  /// a device's forces disengaged (arg0 = device, arg1 = the held |F| N that fades out): they
  /// re-engage only once the requested force is below the engage threshold
  kEventDisengaged = shared::kEventUser + 8,
  /// a device sample's orientation is zero or far from a unit quaternion (arg1 = device)
  kEventUnusableOrientation = shared::kEventUser + 9,
  /// the snapshot's time stamp lies in the future (arg0 = ns ahead): treated as stale
  kEventSnapshotFromTheFuture = shared::kEventUser + 10,
};

/// Name of a shared::EventCode or HapticEvent code.
const char* eventName(std::uint32_t code) noexcept;

/// What the tick uses of an attached segment, with the local model sized for the segment's
/// capacity (built and destroyed by the non-real-time supervisor).
struct AttachedSegment {
  shared::Segment segment;
  /// Read by `preparer` only (its thread once started, else the tick through it).
  shared::SnapshotSubscriber snapshots;
  /// Device i's samples (one per device the loop serves, up to the segment's device count).
  std::array<shared::TripleWriter<shared::DeviceSample>, shared::kMaxInstruments> samples;
  int sample_writers = 0;               ///< entries of `samples` attached
  shared::StatsRingWriter stats;
  /// Prepares each new snapshot off the tick (snapshot_preparer.h): call
  /// preparer.start(settings.localModel()) before offering the link to run it on its own
  /// thread; otherwise the tick prepares inline (tests, offline tools).
  SnapshotPreparer preparer;
  LocalModel model;                     ///< the tick's solver state (local_model.h)
  std::uint64_t ill_posed_seq = 0;      ///< last snapshot reported unusable (one event each)
  explicit AttachedSegment(shared::Segment&& s);
  ~AttachedSegment() { preparer.stop(); }
};

/// What one tick renders to one device.
struct DeviceTickOutput {
  std::array<double, 3> force_n{};      ///< contact wrench on its instrument, then the command
  std::array<double, 3> torque_nm{};
  double unlimited_force_norm_n = 0.0;  ///< before clamp/slew/fade
  double gain = 0.0;                    ///< fade/engage gain in [0, 1]
  /// this tick solved a usable local model for the device (false: stale or missing snapshot,
  /// an unusable or refused problem, no device pose): the chain then fades the held wrench
  bool model = false;
};

/// Output of one tick (for tests and tools). The DeviceTickOutput part is device 0's (a copy of
/// device[0]).
struct TickOutput : DeviceTickOutput {
  int devices = 0;                      ///< entries of `device`
  std::array<DeviceTickOutput, shared::kMaxInstruments> device{};
  int contacts = 0;
  int sweeps = 0;
  double residual = 0.0;
  std::int64_t solve_ns = 0;            ///< time in the local model's solve
  LocalModelUsed model_used = LocalModelUsed::kNone;
  FallbackReason fallback_reason = FallbackReason::kNone;   ///< LocalModelResult::fallback
  int correction_rounds = 0;            ///< LocalModelResult::correction_rounds
  // the tick's phases [ns] (StatsRecord) and its absolute deadline (0: none)
  std::int64_t read_ns = 0, model_ns = 0, output_ns = 0;
  std::int64_t started_ns = 0, deadline_ns = 0;
  std::int64_t prepare_ns = 0;          ///< preparation time of the snapshot solved
  bool stale = true;
  std::uint64_t snapshot_seq = 0;
  std::uint64_t flags = 0;              ///< shared::StatsFlags
};

/// One device the loop serves: its backend, workspace mapping, and the state of its safety chain.
struct DeviceChannel {
  device::Device* device = nullptr;
  WorkspaceMapping mapping;
  double force_limit_n = 0.0;      ///< min(settings, device), what the chain and guard clamp to
  double torque_limit_nm = 0.0;
  std::uint64_t sample_seq = 0;
  std::int64_t last_sample_ns = 0; ///< tick time of the device's last sample (kOk)
  device::DeviceState raw_state{}; ///< the device's last sample, device frame
  device::DeviceState state{};     ///< the same mapped to the scene frame
  shared::Pose last_pose;
  bool have_pose = false;
  /// the engage gate is open: closed at start and by every interruption (link change, device
  /// fault, stale snapshot, unusable model), opened again only once the fade-out has ended and
  /// the requested force is below the threshold
  bool engaged = false;
  bool device_fault = false;
  bool no_data = false;            ///< the last read returned kNoData (event on the transition)
  bool clamped = false;            ///< the last command was clamped (sample flag, event)
  double gain = 0.0;                ///< gain_ticks / the fade's ticks
  int gain_ticks = 0;               ///< the fade gain in ticks (exact: 0 and 1 are reached)
  /// the wrench (device frame, scaled, before the gain) of the last engaged tick with a usable
  /// model: what a fade-out scales down
  std::array<double, 3> held_force_n{};
  std::array<double, 3> held_torque_nm{};
  std::array<double, 3> last_force_n{};
  std::array<double, 3> last_torque_nm{};
  // snapshot blending (HapticSettings::snapshot_blend_ms), in the scene frame
  bool have_model_wrench = false;            ///< the last tick solved this device's model
  std::array<double, 3> model_force_n{};     ///< the last tick's blended model wrench
  std::array<double, 3> model_torque_nm{};
  std::array<double, 3> blend_force_n{};     ///< old minus new wrench at the last switch
  std::array<double, 3> blend_torque_nm{};
  int blend_ticks_left = 0;
};

class HapticLoop {
 public:
  /// `device` must be opened by the caller. Validates `settings` (throws tactus::Error) and
  /// reads device.info(): a max_force_n that is finite and > 0 lowers the force clamp; any other
  /// non-zero value is ignored with a warning.
  HapticLoop(device::Device& device, const HapticSettings& settings);
  /// Several devices (1 .. shared::kMaxInstruments, each opened by the caller): device i drives
  /// instrument i. Each gets its own clamp from its own info(). Throws tactus::Error on a bad
  /// count or null device.
  HapticLoop(std::span<device::Device* const> devices, const HapticSettings& settings);

  /// One tick at time now_ns (scheduled_ns/woken_ns from the timer, for the stats record).
  /// Real-time: no allocation, lock, logging, exception.
  TickOutput tick(std::int64_t scheduled_ns, std::int64_t woken_ns) noexcept;

  /// Offers a new link (or nullptr to detach). The tick switches to it at its next start.
  /// Hazard-pointer handshake: the tick publishes the link it is about to use in linkInUse()
  /// before touching it and then re-reads the offer, using the link only if it is still offered.
  /// So once the supervisor has withdrawn a link (offerLink of another one), a later
  /// linkInUse() != old proves that the tick does not hold it and never will again: only then
  /// may the old link be destroyed. Withdrawn links must never be offered again.
  void offerLink(AttachedSegment* link) noexcept;
  AttachedSegment* linkInUse() const noexcept;
  /// Call once the thread that runs tick() has ended (joined): the loop lets go of its link, so
  /// linkInUse() is nullptr and the supervisor may free it. A later tick adopts the offer again.
  void stopped() noexcept;

  /// Where the tick now running is, for the supervisor's watchdog (any thread; relaxed reads):
  /// running_ns is how long it has been running by the monotonic clock at now_ns (0: no tick
  /// runs), device the device whose read or write it is inside (-1: none).
  struct TickProgress {
    std::int64_t running_ns = 0;
    int device = -1;
  };
  TickProgress tickProgress(std::int64_t now_ns) const noexcept;
  /// True when the last tick wrote a zero command to every device with every fade gain at zero
  /// (any thread). A stopping program withdraws the link (the forces fade out) and waits for
  /// this before it stops ticking, so the hand never feels a step at shutdown.
  bool allForcesZero() const noexcept { return all_forces_zero_.load(std::memory_order_relaxed); }
  /// Device i (the supervisor halts it and logs its diagnostics; Device::halt and
  /// Device::takeDiagnostics may be called from another thread while the tick runs).
  device::Device& device(int i = 0) noexcept { return *channel(i).device; }

  /// The force and torque clamps in use (settings and device combined, see the constructor), of
  /// device 0 or of device i.
  double forceLimitN(int i = 0) const noexcept { return channel(i).force_limit_n; }
  double torqueLimitNm(int i = 0) const noexcept { return channel(i).torque_limit_nm; }
  int deviceCount() const noexcept { return device_count_; }

  /// Device i's workspace mapping (identity by default): configure() it before the first
  /// tick; setClutchRequest() from any thread.
  WorkspaceMapping& workspaceMapping(int i = 0) noexcept { return channel(i).mapping; }

  HapticCounters& counters() noexcept { return counters_; }
  shared::EventRing& events() noexcept { return events_; }
  const HapticSettings& settings() const noexcept { return settings_; }

  /// The tests' access to the tick's phases, an unvalidated construction and the adoption hook
  /// (tests/support/haptic_loop_access.h); nothing else uses them.
  friend struct HapticLoopTestAccess;

 private:
  struct Unchecked {};
  /// No validation, so the final guard can be exercised with nonsense settings (tests).
  HapticLoop(device::Device& device, const HapticSettings& settings, Unchecked);
  /// The local model on the adopted snapshot with device i at *poses[i] (nullptr: no pose, the
  /// device stays at x_h*): one solve under `deadline_ns`, the wrench on instrument i into
  /// out.device[i] (and device 0's into out). False when it gave no usable wrench (not solved,
  /// non-finite, ill-posed): the devices then fade their held wrench.
  bool solveLocalModel(AttachedSegment& link,
                       const std::array<const shared::Pose*, shared::kMaxInstruments>& poses,
                       std::int64_t deadline_ns, TickOutput& out) noexcept;
  DeviceChannel& channel(int i) noexcept { return channels_[static_cast<std::size_t>(i)]; }
  const DeviceChannel& channel(int i) const noexcept {
    return channels_[static_cast<std::size_t>(i)];
  }
  void pushEvent(std::uint32_t code, double a = 0.0, double b = 0.0) noexcept;
  /// Episode events that can recur every few ticks (no data, clamped, not converged, overrun):
  /// pushed at most once per second each, so the ring and the log are not flooded.
  enum NoisyEvent : int {
    kNoisyNoData,
    kNoisyClamped,
    kNoisyNotConverged,
    kNoisyOverrun,
    kNoisyCount
  };
  void pushRateLimited(NoisyEvent which, std::uint32_t code, std::int64_t now_ns, double a = 0.0,
                       double b = 0.0) noexcept;
  // the tick's phases, in order (per device where they take a channel)
  void adoptOfferedLink() noexcept;
  device::IoStatus readDevice(DeviceChannel& ch, int i, std::int64_t now,
                              TickOutput& out) noexcept;
  void publishSample(DeviceChannel& ch, int i, std::int64_t now, device::IoStatus io) noexcept;
  /// The newest prepared snapshot, its age, and the local model under `deadline_ns`. `now`: the
  /// tick's clock, `t_now_ns` the real clock at that moment (the snapshot is aged at `now` plus
  /// the real time since, once taken), or negative without a clock (aged at `now`).
  void takeSnapshot(std::int64_t now, std::int64_t t_now_ns, std::int64_t deadline_ns,
                    TickOutput& out) noexcept;
  /// After takeSnapshot: blends a new snapshot's wrench in (HapticSettings::snapshot_blend_ms).
  void blendSnapshot(bool switched, bool solved, TickOutput& out) noexcept;
  void writeDevice(DeviceChannel& ch, const std::array<double, 3>& force,
                   const std::array<double, 3>& torque) noexcept;
  void recordStats(std::int64_t scheduled_ns, std::int64_t woken_ns, const TickOutput& out,
                   const std::array<double, 3>& force) noexcept;
  /// `dev` holds the contact wrench on the channel's instrument (mapped to the device frame) on
  /// entry and the command on exit; flags go to `out`.
  void applySafetyChain(DeviceChannel& ch, int i, TickOutput& out, DeviceTickOutput& dev,
                        std::array<double, 3>& force, std::array<double, 3>& torque) noexcept;
  void initLimits(DeviceChannel& ch);
  /// Closes device i's engage gate (an interruption): its held wrench fades out.
  void disengage(DeviceChannel& ch, int i) noexcept;

  std::array<DeviceChannel, shared::kMaxInstruments> channels_{};
  int device_count_ = 1;
  HapticSettings settings_;
  LocalModelSettings model_settings_;   ///< settings_.localModel()
  HapticCounters counters_;
  shared::EventRing events_;
  std::atomic<std::int64_t> tick_started_ns_{0};   ///< monotonic start of the running tick (0: none)
  std::atomic<int> in_device_{-1};                ///< device whose read/write the tick is in
  std::atomic<bool> all_forces_zero_{true};       ///< see allForcesZero()
  std::atomic<AttachedSegment*> offered_{nullptr};
  std::atomic<AttachedSegment*> in_use_{nullptr};
  AttachedSegment* link_ = nullptr;
  /// called by the tick between its first read of the offered link and publishing it as in use
  /// (tests replay a supervisor acting while the real-time thread is stalled there)
  void (*adoption_hook_)(void*) = nullptr;
  void* adoption_context_ = nullptr;
  std::int64_t watchdog_ns_ = 0;   ///< settings' watchdog (0 when not usable: always stale)
  int blend_ticks_ = 0;            ///< snapshot_blend_ms in ticks (0: no blending)
  int fade_ticks_ = 1;             ///< the fade in ticks: fade_ms / period (1: no ramp)
  double slew_step_n_ = 0.0;       ///< largest force change per tick: slew * nominal period

  std::uint64_t snapshot_seq_ = 0;
  std::uint64_t adopted_generation_ = 0;   ///< PreparedSnapshot::generation() adopted
  std::uint64_t tick_index_ = 0;
  bool stale_ = true;
  bool not_converged_ = false;     ///< the last solve did not converge (event on the transition)
  bool overrun_ = false;           ///< the last tick overran (event at the start of a burst)
  std::array<std::int64_t, kNoisyCount> noisy_event_ns_{};   ///< last push per NoisyEvent
  std::array<bool, kNoisyCount> noisy_pushed_{};             ///< pushed at least once
  std::int64_t last_tick_ns_ = 0;
};

}  // namespace tactus::haptic
