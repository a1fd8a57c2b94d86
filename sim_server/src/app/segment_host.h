#pragma once
// Simulation side of the shared segment: creates it (capacity from the scene), publishes each
// step's contact problem (the haptic local model) and reads the newest device sample.
//
// Device samples are untrusted input. A fresh sample drives the instrument only after:
//  * per sample (deviceTargetFromSample, pipeline.h): a non-finite pose or a zero orientation
//    makes it unusable; any other finite quaternion is normalised (scaled first, so huge
//    components do not overflow); the twist is bounded to kMaxDeviceSpeedMps /
//    kMaxDeviceAngularSpeedRadps (non-finite parts zeroed);
//  * jumps: a device cannot move faster than kMaxDeviceSpeedMps. A raw position further than
//    kJumpAllowanceM + kMaxDeviceSpeedMps * (time since the last accepted sample) from the last
//    accepted one, or an unusable sample, is rejected (counted in rejectedJumps(), logged once
//    per episode) and the last accepted target is held at rest. The first sample after the
//    script drove is judged against the scripted target. The allowance grows with time, so a
//    device that really is elsewhere (e.g. re-homed) is followed again after
//    (distance / kMaxDeviceSpeedMps) s, a sane sample near the last good one at once, and
//    1e300 m never;
//  * position: clamped into the instrument's workspace (counted in clampedSamples()).
//
// Displacement: displacedReason() tells, at most every kDisplacementCheckNs (one stat() call, off
// the hot path), whether the segment's name no longer refers to this simulation's object
// (removed, or re-created while this process was stopped): the simulation must then stop.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "tactus/shared/segment.h"
#include "tactus/sim/haptic_link.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {

/// Fastest plausible device (hand) motion [m/s] and rotation [rad/s].
inline constexpr double kMaxDeviceSpeedMps = 10.0;
inline constexpr double kMaxDeviceAngularSpeedRadps = 100.0;
/// Jump allowed between two samples regardless of their time difference [m].
inline constexpr double kJumpAllowanceM = 0.02;
/// Period of the displacement check [ns].
inline constexpr std::int64_t kDisplacementCheckNs = 200'000'000;

/// The simulation's end of the shared segment: it creates and owns the segment, publishes the
/// contact snapshots and reads the device samples (see the header comment).
class SegmentHost {
 public:
  /// Creates the segment `name` (replacing a stale one) with one device buffer per instrument.
  /// Device i's positions are bounded to workspaces[i] (instrument i's, see
  /// instrumentWorkspace); one workspace: one device. Throws tactus::SegmentError.
  SegmentHost(const std::string& name, const SceneSpec& spec, std::vector<BoxSpec> workspaces);
  SegmentHost(const std::string& name, const SceneSpec& spec, const BoxSpec& workspace)
      : SegmentHost(name, spec, std::vector<BoxSpec>{workspace}) {}
  ~SegmentHost();

  /// Replaces `target` by the newest sample of device `i` (instrument i's; 0 when not given)
  /// when one arrived within the watchdog period (bounded as described above; a rejected jump
  /// holds the last accepted target); otherwise leaves the scripted target (the simulation
  /// holds or follows its script). A device that reports a fault after it drove the instrument,
  /// or whose samples stop while haptic_server is still attached (Segment::hapticAttached: a
  /// stalled or blocked device), holds the last accepted target (at rest) until it recovers. True when the device drives
  /// (or holds) the target. Each device is judged on its own: one device silent or faulty leaves
  /// the others driving.
  bool deviceTarget(DeviceTarget& target) { return deviceTarget(0, target); }
  bool deviceTarget(int i, DeviceTarget& target);
  /// Publishes the last step's contact problem and beats the heartbeat.
  void publish(const Simulation& sim);
  /// One log line: haptic heartbeat age, device samples seen, snapshots published.
  void logStatus();
  /// Non-empty (why) when the segment's name no longer refers to the segment this simulation
  /// created; checked at most every kDisplacementCheckNs of `now_ns` (empty in between).
  std::string displacedReason(std::int64_t now_ns);

  std::uint64_t rejectedJumps() const { return rejected_jumps_; }
  std::uint64_t clampedSamples() const { return clamped_; }
  const shared::Segment& segment() const { return segment_; }

 private:
  /// One device's end: its samples and what the jump filter remembers.
  struct DeviceLink {
    shared::TripleReader<shared::DeviceSample> reader;
    double max_opening_rad = 1.0;                ///< device gripper angle of a fully open grasper
    BoxSpec workspace;
    std::uint64_t device_seq = 0;
    bool device_active = false;
    bool have_good = false;                      ///< an accepted sample exists
    bool rejecting = false;                      ///< in an episode of rejected samples
    bool holding_fault = false;                  ///< holding the target while the device faults
    bool holding_stall = false;                  ///< ... or while its samples stopped
    DeviceTarget last_good;                      ///< the last accepted target (held on a jump)
    std::int64_t last_good_ns = 0;               ///< when it was accepted (this clock)
  };
  shared::Segment segment_;
  shared::SnapshotPublisher publisher_;
  std::vector<DeviceLink> devices_;
  std::int64_t watchdog_ns_ = 50'000'000;
  std::uint64_t published_ = 0;
  std::uint64_t samples_used_ = 0;
  std::uint64_t truncated_ = 0;
  std::uint64_t rejected_jumps_ = 0;
  std::uint64_t clamped_ = 0;
  std::uint64_t rejected_reported_ = 0;          ///< rejected_jumps_ at the last status line
  std::int64_t next_displacement_check_ns_ = 0;
};

}  // namespace tactus::sim
