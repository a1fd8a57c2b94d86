#include <algorithm>
#include <cmath>
#include <numbers>

#include "tactus/device/backends.h"
#include "tactus/shared/clock.h"

namespace tactus::device {

namespace {
constexpr double kSubstepS = 0.25e-3;
constexpr double kMaxStepS = 0.05;
constexpr double kMinMassKg = 1e-3;
constexpr double kMaxMassKg = 100.0;
constexpr double kMaxStiffnessNpm = 1e6;
constexpr double kMaxDampingNspm = 1e4;
constexpr double kMinForceN = 1e-3;
constexpr double kMaxForceN = 100.0;
constexpr double kMaxDistanceM = 10.0;
constexpr double kMinPeriodS = 1e-3;
constexpr double kMaxPeriodS = 1e5;
}  // namespace

SimulatedDevice::SimulatedDevice(const DeviceConfig& config) {
  OptionReader opt("simulated", config);
  // ranges keep the hand's integration stable and its numbers physical (a hand-held device)
  mass_ = opt.number("mass", 0.3, kMinMassKg, kMaxMassKg);
  stiffness_ = opt.number("stiffness", 300.0, 0.0, kMaxStiffnessNpm);
  // default: 0.7 of critical damping
  damping_ = opt.number("damping", 1.4 * std::sqrt(stiffness_ * mass_), 0.0, kMaxDampingNspm);
  max_force_ = opt.number("max_force", 10.0, kMinForceN, kMaxForceN);
  origin_ = opt.vec3("origin", {0.0, 0.0, 0.0}, kMaxDistanceM);
  axis_ = opt.vec3("axis", {0.0, 0.0, -1.0}, kMaxDistanceM);
  amplitude_m_ = opt.number("amplitude", 0.02, -kMaxDistanceM, kMaxDistanceM);
  period_s_ = opt.number("period", 4.0, kMinPeriodS, kMaxPeriodS);
  loop_ = opt.flag("loop", true);
  const std::string file = opt.text("trajectory");
  opt.rejectUnknown();
  // semi-implicit Euler at kSubstepS: stable only while the spring and damper rates are small
  // against the sub-step
  if (stiffness_ / mass_ * kSubstepS * kSubstepS > 1.0 || damping_ / mass_ * kSubstepS > 1.0) {
    throw DeviceError("device 'simulated': stiffness=" + std::to_string(stiffness_) +
                      " N/m and damping=" + std::to_string(damping_) + " N s/m are too stiff for "
                      "mass=" + std::to_string(mass_) + " kg (need stiffness/mass <= " +
                      std::to_string(1.0 / (kSubstepS * kSubstepS)) + " and damping/mass <= " +
                      std::to_string(1.0 / kSubstepS) + "): raise mass or lower them");
  }
  const double n = std::sqrt(axis_[0] * axis_[0] + axis_[1] * axis_[1] + axis_[2] * axis_[2]);
  if (n < 1e-12) throw DeviceError("device 'simulated': option axis must not be zero");
  for (auto& a : axis_) a /= n;
  if (!file.empty()) trajectory_ = Trajectory::loadCsv(file);
}

DeviceInfo SimulatedDevice::info() const {
  DeviceInfo i;
  i.model = "tactus simulated hand";
  i.max_force_n = max_force_;
  i.has_rotation = true;
  i.has_gripper = true;
  return i;
}

void SimulatedDevice::setPoint(double t_s, DeviceState* out) const noexcept {
  if (!trajectory_.empty()) {
    const double d = trajectory_.durationS();
    const double t0 = trajectory_.points().front().t_s;
    double t = t_s;
    if (loop_ && d > 0.0) t = std::fmod(t_s, d);
    trajectory_.sample(t0 + t, out);
    return;
  }
  // press-and-release: 0 -> amplitude -> 0 along the axis over one period
  const double w = 2.0 * std::numbers::pi / period_s_;
  const double depth = amplitude_m_ * 0.5 * (1.0 - std::cos(w * t_s));
  const double speed = amplitude_m_ * 0.5 * w * std::sin(w * t_s);
  for (std::size_t i = 0; i < 3; ++i) {
    out->pos_m[i] = origin_[i] + depth * axis_[i];
    out->vel_mps[i] = speed * axis_[i];
  }
  out->quat_wxyz = {1.0, 0.0, 0.0, 0.0};
  out->angvel_radps = {0.0, 0.0, 0.0};
  out->gripper_rad = 0.0;
}

void SimulatedDevice::open() { openAt(shared::monotonicNs()); }

void SimulatedDevice::openAt(std::int64_t t_ns) {
  DeviceState sp;
  setPoint(0.0, &sp);
  x_ = sp.pos_m;
  v_ = {0.0, 0.0, 0.0};
  t0_ns_ = last_ns_ = t_ns;
  opened_ = true;
}

IoStatus SimulatedDevice::read(DeviceState* out) noexcept {
  return readAt(shared::monotonicNs(), out);
}

IoStatus SimulatedDevice::readAt(std::int64_t t_ns, DeviceState* out) noexcept {
  if (!opened_) return IoStatus::kNoData;
  // elapsed time, capped so a paused caller does not produce a huge step
  const double elapsed = std::clamp(shared::nsToSeconds(t_ns - last_ns_), 0.0, kMaxStepS);
  const int steps = static_cast<int>(std::ceil(elapsed / kSubstepS));
  const double h = steps > 0 ? elapsed / steps : 0.0;
  double t_s = shared::nsToSeconds(last_ns_ - t0_ns_);
  DeviceState sp;
  const std::array<double, 3> f = forces_on_ ? force_ : std::array<double, 3>{0.0, 0.0, 0.0};
  // m a = k (set point - x) - c v + F, semi-implicit Euler
  for (int s = 0; s < steps; ++s) {
    t_s += h;
    setPoint(t_s, &sp);
    for (std::size_t i = 0; i < 3; ++i) {
      const double a = (stiffness_ * (sp.pos_m[i] - x_[i]) + damping_ * (sp.vel_mps[i] - v_[i]) +
                        f[i]) / mass_;
      v_[i] += h * a;
      x_[i] += h * v_[i];
    }
  }
  if (t_ns > last_ns_) last_ns_ = t_ns;
  setPoint(shared::nsToSeconds(last_ns_ - t0_ns_), &sp);
  out->t_ns = t_ns;
  out->pos_m = x_;
  out->vel_mps = v_;
  out->quat_wxyz = sp.quat_wxyz;
  out->angvel_radps = sp.angvel_radps;
  out->gripper_rad = sp.gripper_rad;
  out->buttons = 0;
  return IoStatus::kOk;
}

IoStatus SimulatedDevice::write(const DeviceCommand& cmd) noexcept {
  for (double c : cmd.force_n) {
    if (!std::isfinite(c)) return IoStatus::kFault;  // keep the previous force
  }
  force_ = cmd.force_n;
  return IoStatus::kOk;
}

}  // namespace tactus::device
