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
#include <limits>

#include "tactus/haptic/haptic_loop.h"

namespace tactus::haptic {

/// A device quaternion is usable when its squared norm lies in (this, kMaxQuaternionNorm2):
/// unit up to the device's rounding, never zero (the sample is refused otherwise).
inline constexpr double kMinQuaternionNorm2 = 0.25;
inline constexpr double kMaxQuaternionNorm2 = 4.0;
/// A snapshot stamped more than this ahead of the tick's clock is from the future (corrupt) and
/// never fresh. Both daemons stamp with CLOCK_MONOTONIC and the age is taken once the snapshot
/// was taken (snapshotAgeNs), so a real publisher is never ahead; the slack covers the clock's
/// granularity.
inline constexpr std::int64_t kFutureSnapshotSlackNs = 1'000'000;

}  // namespace tactus::haptic

namespace tactus::haptic::detail {

// now - t_ns, saturated instead of overflowing (time stamps from shared memory or a device)
inline std::int64_t ageNs(std::int64_t now, std::int64_t t_ns) noexcept {
  std::int64_t age = 0;
  if (__builtin_sub_overflow(now, t_ns, &age)) {
    return t_ns < 0 ? std::numeric_limits<std::int64_t>::max()
                    : std::numeric_limits<std::int64_t>::min();
  }
  return age;
}

/// The age [ns] of a snapshot stamped `stamp_ns`, at the moment the tick took it: `now_ns` is
/// the tick's clock at some moment of the tick (its start), `t_now_ns` and `t_taken_ns` the real
/// clock (CLOCK_MONOTONIC) then and once the snapshot was taken. The real time between the two
/// counts: a device read may stall, and a tick preempted after it may be handed a snapshot
/// published meanwhile, which is fresh, not from the future. A backward step of the real clock
/// counts as none; the sums saturate instead of overflowing (stamps come from shared memory).
inline std::int64_t snapshotAgeNs(std::int64_t now_ns, std::int64_t t_now_ns,
                                  std::int64_t t_taken_ns, std::int64_t stamp_ns) noexcept {
  constexpr std::int64_t kMax = std::numeric_limits<std::int64_t>::max();
  std::int64_t since = 0;
  if (__builtin_sub_overflow(t_taken_ns, t_now_ns, &since)) {
    since = t_taken_ns > t_now_ns ? kMax : 0;
  }
  since = std::max<std::int64_t>(since, 0);
  std::int64_t now_at_take = 0;
  if (__builtin_add_overflow(now_ns, since, &now_at_take)) now_at_take = kMax;
  return ageNs(now_at_take, stamp_ns);
}

/// A snapshot of this age was stamped in the future: corrupt, never fresh.
inline bool fromTheFuture(std::int64_t age_ns) noexcept {
  return age_ns < -kFutureSnapshotSlackNs;
}

inline bool finite(const std::array<double, 3>& a) noexcept {
  return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]);
}

// A usable clamp: finite and >= kMinLimit, at most `ceiling`; anything else is 0 (no output).
inline double sanitizeLimit(double limit, double ceiling) noexcept {
  if (!std::isfinite(limit) || !(limit >= HapticSettingsLimits::kMinLimit)) return 0.0;
  return std::min(limit, ceiling);
}

}  // namespace tactus::haptic::detail
