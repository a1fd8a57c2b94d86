#pragma once
// Replay mode of the jitter tool: the contact snapshots a run recorded (shared/snapshot_file.h,
// tactus-bench --record-snapshots FILE) are published into a private segment at their recorded
// times (optionally looping), and the real HapticLoop re-solves them every period on a pinned
// real-time thread, as in synthetic mode. The in-process device follows the recorded device pose
// of the snapshot being replayed plus a small circle (so the local model moves delta_free by J
// times a small displacement, as with a hand on the device). The kSnapshotShuttingDown flag of a
// recorded snapshot is dropped (a replayed run never shuts the loop down).

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
  /// Snapshots published so far (the first one included) and whole passes completed.
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

}  // namespace tactus::haptic::jitter
