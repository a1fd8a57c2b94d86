#pragma once
// The haptic loop (DESIGN sections 3 "haptic local model" and 6): every period it reads the
// device, publishes the sample to the simulation, takes the newest contact snapshot, moves its
// delta_free with the device (delta_free = delta_free* + J (x_h [-] x_h*)), re-solves the
// frictional contact problem with warm-started NSGS under a sweep and time budget, turns the
// forces into the wrench on the instrument, applies the safety chain (scale, clamp, slew limit,
// engage gate, stale-data fade) and writes the device, then writes one stats record.
//
// Real-time rules: tick() allocates nothing, takes no lock, logs nothing and never throws. Faults
// go to counters and to an SPSC event ring that a non-real-time thread drains into spdlog. The
// link to the simulation (the shared segment) is swapped by the non-real-time supervisor through
// an atomic pointer with an acknowledgement, so the tick never waits for it.

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "tactus/device/device.h"
#include "tactus/shared/event_ring.h"
#include "tactus/shared/stats_ring.h"
#include "tactus/shared/messages.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/pose.h"
#include "tactus/shared/segment.h"

namespace tactus::haptic {

/// Safety and solver settings of the loop.
struct HapticSettings {
  double force_scale = 1.0;             ///< rendered = scale * contact wrench
  double max_force_n = 8.0;             ///< clamp on |force| (the device's own limit also applies)
  double max_torque_nm = 0.5;           ///< clamp on |torque|
  double slew_n_per_s = 2000.0;         ///< max change of |force| per second
  double engage_threshold_n = 0.5;      ///< forces engage only once the command is below this
  double watchdog_ms = 50.0;            ///< snapshot older than this: fade out
  double fade_ms = 100.0;               ///< fade-out and fade-in ramp
  int max_sweeps = 50;                  ///< NSGS sweep budget per tick
  double tolerance = 1e-6;              ///< NSGS tolerance
  std::int64_t solve_budget_ns = 400'000;  ///< NSGS time budget per tick
  std::int64_t period_ns = 1'000'000;   ///< tick period (a tick ending later is an overrun)
  bool render_torque = false;           ///< devices without rotational feedback: false
};

/// Fault and event counters (read by the supervisor; relaxed atomics).
struct HapticCounters {
  std::atomic<std::uint64_t> ticks{0};
  std::atomic<std::uint64_t> device_no_data{0};
  std::atomic<std::uint64_t> device_faults{0};
  std::atomic<std::uint64_t> write_faults{0};
  std::atomic<std::uint64_t> stale_device_samples{0};  ///< samples older than the watchdog
  std::atomic<std::uint64_t> stale_ticks{0};
  std::atomic<std::uint64_t> snapshots_taken{0};
  std::atomic<std::uint64_t> solver_not_converged{0};
  std::atomic<std::uint64_t> clamped{0};
  std::atomic<std::uint64_t> non_finite_input{0};
  std::atomic<std::uint64_t> events_dropped{0};
};

/// Event codes of the haptic loop beyond shared::EventCode (drained into spdlog outside the
/// tick; see eventName()).
enum HapticEvent : std::uint32_t {
  kEventEngaged = shared::kEventUser + 1,         ///< forces engaged (arg0 = |F| N)
  kEventDeviceRecovered = shared::kEventUser + 2,
  kEventNonFinite = shared::kEventUser + 3,       ///< NaN/Inf from the device (arg0 = which)
  kEventSnapshotTooLarge = shared::kEventUser + 4,  ///< arg0 = rows
  kEventSimShuttingDown = shared::kEventUser + 5,
};

/// Name of a shared::EventCode or HapticEvent code.
const char* eventName(std::uint32_t code) noexcept;

/// What the tick uses of an attached segment, with the solver memory sized for the segment's
/// capacity (built and destroyed by the non-real-time supervisor).
struct HapticLink {
  shared::Segment segment;
  shared::SnapshotSubscriber snapshots;
  shared::TripleWriter<shared::DeviceSample> samples;
  shared::StatsRingWriter stats;
  shared::NsgsWorkspace workspace;
  std::vector<double> delta_free;       ///< moved delta_free (capacity rows)
  std::vector<double> f;                ///< forces, warm start across ticks
  std::vector<double> last_delta_free;  ///< delta_free of the last solve (capacity rows)
  std::uint64_t delta_seq = 0;          ///< snapshot whose W f + delta_free workspace.delta holds
  explicit HapticLink(shared::Segment&& s);
};

/// Output of one tick (for tests and tools).
struct TickOutput {
  std::array<double, 3> force_n{};
  std::array<double, 3> torque_nm{};
  double unlimited_force_norm_n = 0.0;  ///< before clamp/slew/fade
  int contacts = 0;
  int sweeps = 0;
  double residual = 0.0;
  std::int64_t solve_ns = 0;            ///< time in NSGS
  double gain = 0.0;                    ///< fade/engage gain in [0, 1]
  bool stale = true;
  std::uint64_t snapshot_seq = 0;
  std::uint64_t flags = 0;              ///< shared::StatsFlags
};

class HapticLoop {
 public:
  /// `device` must be opened by the caller.
  HapticLoop(device::Device& device, const HapticSettings& settings);

  /// One tick at time now_ns (scheduled_ns/woken_ns from the timer, for the stats record).
  /// Real-time: no allocation, lock, logging, exception.
  TickOutput tick(std::int64_t scheduled_ns, std::int64_t woken_ns) noexcept;

  /// Offers a new link (or nullptr to detach). The tick switches to it at its next start and
  /// acknowledges; the old link may be destroyed once linkInUse() != old.
  void offerLink(HapticLink* link) noexcept;
  HapticLink* linkInUse() const noexcept;

  HapticCounters& counters() noexcept { return counters_; }
  shared::EventRing& events() noexcept { return events_; }
  const HapticSettings& settings() const noexcept { return settings_; }

 private:
  void solveLocalModel(HapticLink& link, const shared::SnapshotView& snap,
                       const shared::Pose& device_pose, TickOutput& out) noexcept;
  void pushEvent(std::uint32_t code, double a = 0.0, double b = 0.0) noexcept;

  device::Device& device_;
  HapticSettings settings_;
  HapticCounters counters_;
  shared::EventRing events_;
  std::atomic<HapticLink*> offered_{nullptr};
  std::atomic<HapticLink*> in_use_{nullptr};
  HapticLink* link_ = nullptr;

  std::uint64_t snapshot_seq_ = 0;
  std::uint64_t tick_index_ = 0;
  std::uint64_t sample_seq_ = 0;
  device::DeviceState state_{};
  shared::Pose last_pose_;
  bool have_pose_ = false;
  bool engaged_ = false;
  bool stale_ = true;
  bool device_fault_ = false;
  double gain_ = 0.0;
  double last_force_norm_n_ = 0.0;
  std::array<double, 3> last_force_n_{};
  std::array<double, 3> last_torque_nm_{};
  std::int64_t last_tick_ns_ = 0;
};

}  // namespace tactus::haptic
