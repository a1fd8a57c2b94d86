// The haptic tick's safety chain: scale, engage gate, fade, clamp, slew and the final guard
// (finite and within the clamps, whatever the settings). Allocation-free.
#include <algorithm>
#include <cmath>

#include "haptic_loop_internal.h"

namespace tactus::haptic {

using detail::finite;
using detail::sanitizeLimit;

double wrenchNorm(const std::array<double, 3>& v) noexcept {
  if (!finite(v)) return std::abs(v[0]) + std::abs(v[1]) + std::abs(v[2]);  // NaN or +inf
  const double s = std::max({std::abs(v[0]), std::abs(v[1]), std::abs(v[2])});
  if (s == 0.0) return 0.0;
  const double a = v[0] / s, b = v[1] / s, c = v[2] / s;
  return s * std::sqrt(a * a + b * b + c * c);
}

namespace {

// Scales `v` so that wrenchNorm(v) <= limit (a limit below kMinLimit, or NaN, zeroes v), with
// a relative margin of 1e-12 so that any rounding of the norm stays within the limit; a result
// that still is not within it (non-finite input) becomes zero. Returns true when it changed v.
bool clampNorm(std::array<double, 3>& v, double limit) noexcept {
  const double n = wrenchNorm(v);
  if (n <= limit) return false;
  if (!(limit >= HapticSettingsLimits::kMinLimit)) {
    v = {};
    return true;
  }
  const double k = (limit / n) * (1.0 - 1e-12);
  for (double& x : v) x *= k;
  if (!(wrenchNorm(v) <= limit)) v = {};
  return true;
}

// Limits the change from `previous` to `v` to a vector of norm <= max_step.
void slewLimit(std::array<double, 3>& v, const std::array<double, 3>& previous,
               double max_step) noexcept {
  std::array<double, 3> d{v[0] - previous[0], v[1] - previous[1], v[2] - previous[2]};
  if (clampNorm(d, max_step)) {
    for (int i = 0; i < 3; ++i) v[i] = previous[i] + d[i];
  }
}

}  // namespace

bool guardWrench(std::array<double, 3>& force_n, std::array<double, 3>& torque_nm,
                 double max_force_n, double max_torque_nm) noexcept {
  bool changed = false;
  if (!finite(force_n)) {
    force_n = {};
    changed = true;
  }
  if (!finite(torque_nm)) {
    torque_nm = {};
    changed = true;
  }
  changed |= clampNorm(force_n, sanitizeLimit(max_force_n, HapticSettingsLimits::kMaxForceN));
  changed |= clampNorm(torque_nm,
                       sanitizeLimit(max_torque_nm, HapticSettingsLimits::kMaxTorqueNm));
  return changed;
}

void HapticLoop::applySafetyChain(DeviceChannel& ch, double dt, TickOutput& out,
                                  DeviceTickOutput& dev, std::array<double, 3>& force,
                                  std::array<double, 3>& torque) noexcept {
  // scale, engage gate, fade, clamp, slew
  for (int i = 0; i < 3; ++i) {
    force[i] = settings_.force_scale * dev.force_n[i];
    torque[i] = settings_.render_torque ? settings_.force_scale * dev.torque_nm[i] : 0.0;
  }
  if (!finite(force) || !finite(torque)) {
    force = {};
    torque = {};
  }
  dev.unlimited_force_norm_n = wrenchNorm(force);
  const bool usable = !out.stale && ch.have_pose && !ch.device_fault;
  if (!ch.engaged && usable && dev.unlimited_force_norm_n < settings_.engage_threshold_n) {
    ch.engaged = true;
    pushEvent(kEventEngaged, dev.unlimited_force_norm_n);
  }
  const double target_gain = (usable && ch.engaged) ? 1.0 : 0.0;
  const double ramp = settings_.fade_ms > 0.0 ? dt / (1e-3 * settings_.fade_ms) : 1.0;
  ch.gain = target_gain > ch.gain ? std::min(target_gain, ch.gain + ramp)
                              : std::max(target_gain, ch.gain - ramp);
  if (!(ch.gain >= 0.0 && ch.gain <= 1.0)) ch.gain = 0.0;   // NaN ramp (unchecked settings)
  for (int i = 0; i < 3; ++i) {
    force[i] *= ch.gain;
    torque[i] *= ch.gain;
  }
  const double requested_n = wrenchNorm(force);
  const bool clamped = clampNorm(force, ch.force_limit_n);
  if (clamped) {
    out.flags |= shared::kStatsForceClamped;
    counters_.clamped.fetch_add(1, std::memory_order_relaxed);
    if (!ch.clamped) {
      pushRateLimited(kNoisyClamped, shared::kEventForceClamped, last_tick_ns_, requested_n,
                      wrenchNorm(force));
    }
  }
  ch.clamped = clamped;
  clampNorm(torque, ch.torque_limit_nm);
  slewLimit(force, ch.last_force_n, settings_.slew_n_per_s * dt);
  // the slew limiter never lets a faded command exceed the clamp
  clampNorm(force, ch.force_limit_n);

  // last stage, whatever the settings: finite and within the clamps
  if (guardWrench(force, torque, ch.force_limit_n, ch.torque_limit_nm)) {
    counters_.guard_interventions.fetch_add(1, std::memory_order_relaxed);
  }
  dev.force_n = force;
  dev.torque_nm = torque;
  dev.gain = ch.gain;
  ch.last_force_n = force;
  ch.last_torque_nm = torque;
}

}  // namespace tactus::haptic
