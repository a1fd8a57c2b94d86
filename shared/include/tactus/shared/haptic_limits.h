#pragma once
// The hard ranges of the haptic loop's settings, shared by haptic_server (its options and
// HapticSettings::validate) and sim_server's scene parser (a scene's haptics section, which
// scripts/start.sh passes to haptic_server through sim_server --print-haptic-options): a value
// the scene accepts is one haptic_server accepts.

namespace tactus::shared {

struct HapticLimits {
  static constexpr double kMinRateHz = 50.0;        ///< loop rate in [this, kMaxRateHz] Hz
  static constexpr double kMaxRateHz = 4000.0;
  static constexpr double kMaxForceScale = 10.0;    ///< force_scale in [0, this]
  static constexpr double kMaxForceN = 50.0;        ///< max_force in (0, this] N
  static constexpr double kMaxWatchdogMs = 10'000.0;  ///< watchdog in (0, this] ms
  static constexpr int kMaxSweeps = 100'000;        ///< NSGS sweeps per tick in [1, this]
  static constexpr double kMaxTolerance = 1.0;      ///< NSGS tolerance in (0, this]
  static constexpr double kMaxSnapshotBlendMs = 100.0;  ///< snapshot blend in [0, this] ms
};

}  // namespace tactus::shared
