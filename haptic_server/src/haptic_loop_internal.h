#pragma once
// Private to the haptic loop: small helpers its source files share.
//   haptic_loop.cpp   settings, construction, links, events and the tick's phases (tick() calls
//                     them in order: adopt link, read device, publish sample, take snapshot,
//                     safety chain, write device, record)
//   local_model.cpp   the local model: delta_free moved with the device, warm NSGS, the wrench
//   safety_chain.cpp  scale, engage gate, fade, clamp, slew and the final guard

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

#include "tactus/haptic/haptic_loop.h"

namespace tactus::haptic {

/// A device quaternion is usable when its squared norm lies in (this, kMaxQuaternionNorm2):
/// unit up to the device's rounding, never zero (the sample is refused otherwise).
inline constexpr double kMinQuaternionNorm2 = 0.25;
inline constexpr double kMaxQuaternionNorm2 = 4.0;
/// A snapshot stamped more than this ahead of the tick's clock is from the future (corrupt) and
/// never fresh. Both daemons stamp with CLOCK_MONOTONIC and the age is taken after the snapshot
/// was read, so a real publisher is never ahead; the slack covers the clock's granularity.
inline constexpr std::int64_t kFutureSnapshotSlackNs = 1'000'000;

}  // namespace tactus::haptic

namespace tactus::haptic::detail {

inline bool finite(const std::array<double, 3>& a) noexcept {
  return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]);
}

// A usable clamp: finite and >= kMinLimit, at most `ceiling`; anything else is 0 (no output).
inline double sanitizeLimit(double limit, double ceiling) noexcept {
  if (!std::isfinite(limit) || !(limit >= HapticSettingsLimits::kMinLimit)) return 0.0;
  return std::min(limit, ceiling);
}

}  // namespace tactus::haptic::detail
