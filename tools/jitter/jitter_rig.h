#pragma once
// What the jitter tool's in-process modes share (synthetic, replay): a private segment, the real
// HapticLoop ticking on a pinned real-time thread, a snapshot publisher thread whose schedule the
// mode supplies, and an in-process device moving on a small circle about a pose that the mode
// selects. The stats ring of that segment is then read exactly as in attach mode.

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "tactus/device/device.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/messages.h"
#include "tactus/shared/segment.h"

namespace tactus::haptic::jitter {

/// An in-process device: a slow small circle (radius_m at freq_hz, pressing in by up to one
/// radius) about the pose of a table that the publisher selects with follow() (a table of one
/// pose: a fixed centre), sampled from the monotonic clock on every read. Real-time safe (the
/// table is fixed before the loop starts).
class CircleDevice : public device::Device {
 public:
  CircleDevice(std::vector<shared::PoseSample> centres, std::string model,
               double radius_m = 2e-4, double freq_hz = 1.0);
  device::DeviceInfo info() const override;
  void open() override {}
  void calibrate() override {}
  void enableForces(bool) override {}
  void close() noexcept override {}
  [[nodiscard]] device::IoStatus read(device::DeviceState* out) noexcept override;
  /// The sample read() gives `t_ns` after the device was made (offline replays).
  device::IoStatus readAt(std::int64_t t_ns, device::DeviceState* out) const noexcept;
  [[nodiscard]] device::IoStatus write(const device::DeviceCommand& cmd) noexcept override;
  /// Selects the centre the device circles about (index into the table; clamped).
  void follow(std::size_t index) noexcept { index_.store(index, std::memory_order_relaxed); }
  /// The centre it circles about now (any thread).
  std::size_t following() const noexcept { return index_.load(std::memory_order_relaxed); }
  /// Commands written so far.
  std::uint64_t writes() const noexcept { return writes_.load(std::memory_order_relaxed); }

 private:
  std::vector<shared::PoseSample> centres_;
  std::string model_;
  double radius_m_;
  double omega_;
  std::int64_t t0_ns_;
  std::atomic<std::size_t> index_{0};
  std::atomic<std::uint64_t> writes_{0};
};

/// How an in-process mode runs the haptic loop (the synthetic and replay modes' options).
struct LoopRunOptions {
  double rate_hz = 1000.0;             ///< haptic loop rate
  int core = -1;                       ///< -1: the last CPU
  int priority = 80;                   ///< SCHED_FIFO priority (0: none)
  int max_sweeps = 50;                 ///< NSGS sweeps per tick
  int anderson_depth = 0;              ///< NSGS Anderson acceleration (HapticSettings)
  double snapshot_blend_ms = 0.0;      ///< HapticSettings::snapshot_blend_ms
  double solve_budget_fraction = 0.4;  ///< the tick's deadline as a fraction of the period
  LocalModelKind local_model = LocalModelKind::kAutomatic;   ///< HapticSettings::local_model
  bool reduced_fallback = true;        ///< HapticSettings::reduced_fallback
  bool active_set_correction = true;   ///< HapticSettings::active_set_correction
};

/// The loop's settings in an in-process mode.
struct RigLoopOptions : LoopRunOptions {
  double watchdog_ms = 50.0;           ///< snapshot age at which the force fades
};

class LoopRig {
 public:
  /// Creates the segment `segment_name` with `capacity` and the loop on `device`. The loop
  /// engages at once (the whole safety chain runs on every tick, as in a session in contact).
  /// Throws tactus::Error subclasses.
  LoopRig(const std::string& segment_name, const shared::SegmentCapacity& capacity,
          std::unique_ptr<CircleDevice> device, const RigLoopOptions& options);
  /// The same with one device per instrument (1 .. shared::kMaxInstruments), all served by the
  /// one loop; the segment gets one device buffer each.
  LoopRig(const std::string& segment_name, shared::SegmentCapacity capacity,
          std::vector<std::unique_ptr<CircleDevice>> devices, const RigLoopOptions& options);
  ~LoopRig();
  LoopRig(const LoopRig&) = delete;
  LoopRig& operator=(const LoopRig&) = delete;

  /// Publishes one snapshot: fill(slot, seq) writes it, then it is published, counted and the
  /// simulation's heartbeat beats.
  void publish(const std::function<void(shared::SnapshotWriter, std::uint64_t)>& fill);
  /// Starts the real-time haptic thread and, once it is set up, a publisher thread running
  /// `publisher` (which must return soon after stopRequested() turns true).
  void start(std::function<void()> publisher);
  /// Stops both threads (idempotent); the device is sent a zero command.
  void stop();
  bool stopRequested() const { return stop_.load(std::memory_order_relaxed); }

  const shared::Segment& segment() const { return segment_; }
  std::int64_t periodNs() const { return settings_.period_ns; }
  int core() const { return core_; }
  /// What the real-time set-up refused (empty: pinned, SCHED_FIFO, memory locked).
  const std::string& rtSummary() const { return rt_summary_; }
  HapticLoop& loop() { return *loop_; }
  CircleDevice& device(std::size_t i = 0) { return *devices_.at(i); }
  std::size_t deviceCount() const { return devices_.size(); }
  std::uint64_t published() const { return published_.load(std::memory_order_relaxed); }

 private:
  RigLoopOptions options_;
  shared::Segment segment_;
  shared::SnapshotPublisher publisher_;
  HapticSettings settings_;
  std::vector<std::unique_ptr<CircleDevice>> devices_;
  std::unique_ptr<HapticLoop> loop_;
  std::unique_ptr<AttachedSegment> link_;
  int core_ = -1;
  std::string rt_summary_;
  std::thread haptic_thread_, publisher_thread_;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> published_{0};
  bool running_ = false;
};

}  // namespace tactus::haptic::jitter
