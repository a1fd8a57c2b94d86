#pragma once
// Simulation side of the shared segment: creates it (capacity from the scene), publishes each
// step's contact problem (the haptic local model) and reads the newest device sample.

#include <cstdint>
#include <string>

#include "tactus/shared/segment.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {

class HapticLink {
 public:
  /// Creates the segment `name` (replacing a stale one). Throws tactus::SegmentError.
  HapticLink(const std::string& name, const SceneSpec& spec);
  ~HapticLink();

  /// Replaces `target` by the newest device sample when one arrived within the watchdog period;
  /// otherwise leaves the scripted target (the simulation holds or follows its script).
  bool deviceTarget(DeviceTarget& target);
  /// Publishes the last step's contact problem and beats the heartbeat.
  void publish(const Simulation& sim);
  /// One log line: haptic heartbeat age, device samples seen, snapshots published.
  void logStatus();

 private:
  shared::Segment segment_;
  shared::SnapshotPublisher publisher_;
  shared::TripleReader<shared::DeviceSample> device_;
  std::int64_t watchdog_ns_ = 50'000'000;
  double max_opening_rad_ = 1.0;                 ///< device gripper angle of a fully open grasper
  std::uint64_t published_ = 0;
  std::uint64_t device_seq_ = 0;
  std::uint64_t samples_used_ = 0;
  std::uint64_t truncated_ = 0;
  bool device_active_ = false;
};

}  // namespace tactus::sim
