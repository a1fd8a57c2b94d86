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

void HapticLoop::applySafetyChain(double dt, TickOutput& out, std::array<double, 3>& force,
                                  std::array<double, 3>& torque) noexcept {
  // scale, engage gate, fade, clamp, slew
  for (int i = 0; i < 3; ++i) {
    force[i] = settings_.force_scale * out.force_n[i];
    torque[i] = settings_.render_torque ? settings_.force_scale * out.torque_nm[i] : 0.0;
  }
  if (!finite(force) || !finite(torque)) {
    force = {};
    torque = {};
  }
  out.unlimited_force_norm_n = wrenchNorm(force);
  const bool usable = !out.stale && have_pose_ && !device_fault_;
  if (!engaged_ && usable && out.unlimited_force_norm_n < settings_.engage_threshold_n) {
    engaged_ = true;
    pushEvent(kEventEngaged, out.unlimited_force_norm_n);
  }
  const double target_gain = (usable && engaged_) ? 1.0 : 0.0;
  const double ramp = settings_.fade_ms > 0.0 ? dt / (1e-3 * settings_.fade_ms) : 1.0;
  gain_ = target_gain > gain_ ? std::min(target_gain, gain_ + ramp)
                              : std::max(target_gain, gain_ - ramp);
  if (!(gain_ >= 0.0 && gain_ <= 1.0)) gain_ = 0.0;   // NaN ramp (unchecked settings)
  for (int i = 0; i < 3; ++i) {
    force[i] *= gain_;
    torque[i] *= gain_;
  }
  const double requested_n = wrenchNorm(force);
  const bool clamped = clampNorm(force, force_limit_n_);
  if (clamped) {
    out.flags |= shared::kStatsForceClamped;
    counters_.clamped.fetch_add(1, std::memory_order_relaxed);
    if (!clamped_) {
      pushRateLimited(kNoisyClamped, shared::kEventForceClamped, last_tick_ns_, requested_n,
                      wrenchNorm(force));
    }
  }
  clamped_ = clamped;
  clampNorm(torque, torque_limit_nm_);
  slewLimit(force, last_force_n_, settings_.slew_n_per_s * dt);
  // the slew limiter never lets a faded command exceed the clamp
  clampNorm(force, force_limit_n_);

  // last stage, whatever the settings: finite and within the clamps
  if (guardWrench(force, torque, force_limit_n_, torque_limit_nm_)) {
    counters_.guard_interventions.fetch_add(1, std::memory_order_relaxed);
  }
  out.force_n = force;
  out.torque_nm = torque;
  out.gain = gain_;
  last_force_n_ = force;
  last_torque_nm_ = torque;
}

}  // namespace tactus::haptic
