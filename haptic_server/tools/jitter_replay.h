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

#include "tactus/device/device.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/segment.h"
#include "tactus/shared/snapshot_file.h"

namespace tactus::haptic::jitter {

/// A device following a pose table: the pose at the index set by the publisher plus a small
/// circle (radius_m at freq_hz). Real-time safe (the table is fixed before the loop starts).
class ReplayDevice : public device::Device {
 public:
  ReplayDevice(std::vector<shared::PoseSample> poses, double radius_m = 2e-4,
               double freq_hz = 1.0);
  device::DeviceInfo info() const override;
  void open() override {}
  void calibrate() override {}
  void enableForces(bool) override {}
  void close() noexcept override {}
  [[nodiscard]] device::IoStatus read(device::DeviceState* out) noexcept override;
  [[nodiscard]] device::IoStatus write(const device::DeviceCommand& cmd) noexcept override;
  /// Selects the pose the device follows (index into the table; clamped).
  void follow(std::size_t index) noexcept { index_.store(index, std::memory_order_relaxed); }

 private:
  std::vector<shared::PoseSample> poses_;
  double radius_m_;
  double omega_;
  std::int64_t t0_ns_;
  std::atomic<std::size_t> index_{0};
};

struct ReplayOptions {
  bool loop = false;                   ///< start over after the last snapshot
  double rate_hz = 1000.0;             ///< haptic loop rate
  int core = -1;                       ///< -1: the last CPU
  int priority = 80;                   ///< SCHED_FIFO priority (0: none)
  int max_sweeps = 50;                 ///< NSGS sweeps per tick
  double solve_budget_fraction = 0.4;  ///< NSGS time budget as a fraction of the period
};

/// The replay set-up: private segment sized for the largest recorded problem, publisher thread
/// at the recorded times, haptic loop thread.
class ReplayRig {
 public:
  /// Takes the recorded snapshots (at least one; throws tactus::Error otherwise), creates the
  /// segment "tactus-jitter-replay-<pid>-<n>" and publishes the first snapshot.
  ReplayRig(std::vector<shared::RecordedSnapshot> snapshots, const ReplayOptions& options);
  ~ReplayRig();
  ReplayRig(const ReplayRig&) = delete;
  ReplayRig& operator=(const ReplayRig&) = delete;

  /// Starts the publisher and the real-time haptic thread; returns once the latter is set up.
  void start();
  /// Stops both threads (idempotent).
  void stop();

  const shared::Segment& segment() const { return segment_; }
  std::int64_t periodNs() const { return settings_.period_ns; }
  /// Length of one pass through the recording [ns] (last - first t_ns plus one recorded step).
  std::int64_t passNs() const { return pass_ns_; }
  std::size_t snapshotCount() const { return snapshots_.size(); }
  int maxRows() const { return max_rows_; }
  int maxContacts() const { return max_contacts_; }
  /// What the real-time set-up refused (empty: pinned, SCHED_FIFO, memory locked).
  const std::string& rtSummary() const { return rt_summary_; }
  HapticLoop& loop() { return *loop_; }
  /// Snapshots published so far (the first one included) and whole passes completed.
  std::uint64_t published() const { return published_.load(std::memory_order_relaxed); }
  std::uint64_t passes() const { return passes_.load(std::memory_order_relaxed); }

 private:
  void publish(std::size_t index);

  std::vector<shared::RecordedSnapshot> snapshots_;
  ReplayOptions options_;
  int max_rows_ = 0, max_contacts_ = 0;
  std::int64_t pass_ns_ = 0;
  shared::Segment segment_;
  shared::SnapshotPublisher publisher_;
  HapticSettings settings_;
  std::unique_ptr<ReplayDevice> device_;
  std::unique_ptr<HapticLoop> loop_;
  std::unique_ptr<HapticLink> link_;
  int core_ = -1;
  std::string rt_summary_;
  std::thread haptic_thread_, publisher_thread_;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> published_{0};
  std::atomic<std::uint64_t> passes_{0};
  bool running_ = false;
};

}  // namespace tactus::haptic::jitter
