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

void HapticLoop::disengage(DeviceChannel& ch, int i) noexcept {
  ch.engaged = false;
  counters_.disengaged.fetch_add(1, std::memory_order_relaxed);
  pushEvent(kEventDisengaged, i, wrenchNorm(ch.held_force_n));
}

void HapticLoop::applySafetyChain(DeviceChannel& ch, int i, TickOutput& out,
                                  DeviceTickOutput& dev, std::array<double, 3>& force,
                                  std::array<double, 3>& torque) noexcept {
  // scale, engage gate, fade, clamp, slew
  for (int k = 0; k < 3; ++k) {
    force[k] = settings_.force_scale * dev.force_n[k];
    torque[k] = settings_.render_torque ? settings_.force_scale * dev.torque_nm[k] : 0.0;
  }
  bool usable = dev.model;
  if (!finite(force) || !finite(torque)) {   // never rendered, and no model this tick
    force = {};
    torque = {};
    usable = false;
  }
  dev.unlimited_force_norm_n = wrenchNorm(force);
  // Engage gate: any interruption closes it; it opens again only once the fade-out has ended
  // and the requested force is below the threshold (no kick with the hand inside tissue).
  if (!usable) {
    if (ch.engaged) disengage(ch, i);
  } else if (!ch.engaged && ch.gain_ticks == 0 &&
             dev.unlimited_force_norm_n < settings_.engage_threshold_n) {
    ch.engaged = true;
    pushEvent(kEventEngaged, dev.unlimited_force_norm_n);
  }
  // Fade: engaged, the gain ramps up on the live wrench; otherwise it ramps down on the held
  // one (the last engaged tick's), so a lost model fades what the hand felt, over fade_ms.
  // (counted in whole ticks, so the ramp is exact: k / n of the held wrench)
  if (ch.engaged) {
    ch.held_force_n = force;
    ch.held_torque_nm = torque;
    ch.gain_ticks = std::min(fade_ticks_, ch.gain_ticks + 1);
  } else {
    ch.gain_ticks = std::max(0, ch.gain_ticks - 1);
  }
  ch.gain = static_cast<double>(ch.gain_ticks) / fade_ticks_;
  for (int k = 0; k < 3; ++k) {
    force[k] = ch.held_force_n[k] * ch.gain;
    torque[k] = ch.held_torque_nm[k] * ch.gain;
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
  // per nominal period: a late tick gets no larger step
  slewLimit(force, ch.last_force_n, slew_step_n_);
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
