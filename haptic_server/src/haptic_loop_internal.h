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

#include "tactus/haptic/haptic_loop.h"

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
