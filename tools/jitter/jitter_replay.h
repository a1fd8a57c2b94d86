#pragma once
// Replay mode of the jitter tool: the contact snapshots a run recorded (shared/snapshot_file.h,
// sim_server --record-snapshots FILE) are published into a private segment at their recorded
// times (optionally looping), and the real HapticLoop re-solves them every period on a pinned
// real-time thread, as in synthetic mode. The in-process device follows the recorded device pose
// of the snapshot being replayed plus a small circle (so the local model moves delta_free by J
// times a small displacement, as with a hand on the device). The kSnapshotShuttingDown flag of a
// recorded snapshot is dropped (a replayed run never shuts the loop down). Looping starts over at
// the first snapshot (the device jumps back to its pose) or, bouncing, plays the recording
// backwards and forwards (the device only ever moves by a recorded step).

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "jitter_rig.h"
#include "tactus/device/device.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/segment.h"
#include "tactus/shared/snapshot_file.h"

namespace tactus::haptic::jitter {

struct ReplayOptions : LoopRunOptions {
  bool loop = false;                   ///< start over after the last snapshot
  /// With loop: play the recording backwards from its end, then forwards again, and so on, each
  /// step after its recorded gap, instead of jumping from the last snapshot back to the first
  /// (whose device pose a hand cannot reach in one step: liver_grasp_23k's hold jumps 6.7 mm).
  bool bounce = false;
};

/// The replay set-up: private segment sized for the largest recorded problem, publisher thread
/// at the recorded times, haptic loop thread (jitter_rig.h), the device circling about the
/// recorded device pose of the snapshot being replayed.
class ReplayRig {
 public:
  /// Takes the recorded snapshots (at least one; throws tactus::Error otherwise), creates the
  /// segment "tactus-jitter-replay-<pid>-<n>" and publishes the first snapshot.
  ReplayRig(std::vector<shared::RecordedSnapshot> snapshots, const ReplayOptions& options);
  ReplayRig(const ReplayRig&) = delete;
  ReplayRig& operator=(const ReplayRig&) = delete;

  /// Starts the publisher and the real-time haptic thread; returns once the latter is set up.
  void start();
  /// Stops both threads (idempotent).
  void stop() { rig_.stop(); }

  const shared::Segment& segment() const { return rig_.segment(); }
  std::int64_t periodNs() const { return rig_.periodNs(); }
  /// Length of one pass through the recording [ns] (last - first t_ns plus one recorded step).
  std::int64_t passNs() const { return pass_ns_; }
  std::size_t snapshotCount() const { return snapshots_.size(); }
  int maxRows() const { return rig_.segment().capacity().max_rows; }
  int maxContacts() const { return rig_.segment().capacity().max_contacts; }
  /// Devices the loop serves: one per instrument of the recording.
  int devices() const { return rig_.segment().capacity().devices; }
  /// What the real-time set-up refused (empty: pinned, SCHED_FIFO, memory locked).
  const std::string& rtSummary() const { return rig_.rtSummary(); }
  HapticLoop& loop() { return rig_.loop(); }
  /// The device of instrument i (it follows the snapshot last published).
  CircleDevice& device(std::size_t i = 0) { return rig_.device(i); }
  /// Snapshots published so far (the first one included) and whole passes completed (bouncing:
  /// each way counts as one).
  std::uint64_t published() const { return rig_.published(); }
  std::uint64_t passes() const { return passes_.load(std::memory_order_relaxed); }

 private:
  void publish(std::size_t index);

  std::vector<shared::RecordedSnapshot> snapshots_;
  ReplayOptions options_;
  std::int64_t pass_ns_ = 0;
  std::atomic<std::uint64_t> passes_{0};
  LoopRig rig_;
};

/// The replay without the real-time loop, for accuracy: the recording's timeline ticked at
/// `rate_hz`, each snapshot adopted `latency_ms` after its time and prepared at the device's pose
/// of that moment, the device on the replay's circle (CircleDevice's path about the recorded
/// device pose). Every tick solves the local model as the loop would (settings.kind) and the full
/// problem to `reference_tolerance` (warm-started from the previous tick), and compares the
/// wrenches on instrument 0.
struct OfflineReplayOptions {
  double rate_hz = 1000.0;
  double latency_ms = 10.0;            ///< from a snapshot's time to the tick adopting it
  LocalModelSettings settings;         ///< the model the loop renders
  double reference_tolerance = 1e-9;   ///< the full problem's
  /// The device follows the newest published snapshot's pose (as in the loop, where it moves on
  /// while the new snapshot is prepared) instead of the adopted one's.
  bool device_leads = false;
  int passes = 1;
};
struct OfflineReplayReport {
  std::uint64_t ticks = 0, linearized = 0, corrected = 0, fallbacks = 0, full = 0, converged = 0;
  std::uint64_t reference_not_converged = 0;
  /// |F_model - F_full| / held force (the median |F_full| over the ticks), per tick
  std::vector<double> force_error;
  std::vector<double> solve_us;           ///< the model's solve (offline wall time)
  std::vector<double> prepare_ms;         ///< each preparation's time
  double held_force_n = 0.0;
  std::array<std::uint64_t, 8> fallback_reasons{};   ///< by FallbackReason
};
OfflineReplayReport replayOffline(const std::vector<shared::RecordedSnapshot>& snapshots,
                                  const OfflineReplayOptions& options);

}  // namespace tactus::haptic::jitter
