// The haptic tick: device -> local model -> NSGS -> safety chain -> device, allocation-free.
// This file: settings, construction, links, events and the tick's phases; the local model is in
// local_model.cpp, the safety chain in safety_chain.cpp.
#include "tactus/haptic/haptic_loop.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>
#include <string>

#include "haptic_loop_internal.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"

namespace tactus::haptic {

using detail::finite;
using detail::sanitizeLimit;

namespace {

// now - t_ns, saturated instead of overflowing (time stamps from shared memory or a device)
std::int64_t ageNs(std::int64_t now, std::int64_t t_ns) noexcept {
  std::int64_t age = 0;
  if (__builtin_sub_overflow(now, t_ns, &age)) {
    return t_ns < 0 ? std::numeric_limits<std::int64_t>::max()
                    : std::numeric_limits<std::int64_t>::min();
  }
  return age;
}

std::string show(double v) {
  std::ostringstream os;
  os << std::setprecision(17) << v;
  return os.str();
}

// Throws unless lo <(=) v <= hi and v is finite.
void checkSetting(const char* name, double v, double lo, bool lo_open, double hi,
                  const char* unit) {
  const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
  if (ok) return;
  throw Error(std::string("haptic settings: ") + name + " = " + show(v) +
              " must be a finite number in " + (lo_open ? "(" : "[") + show(lo) + ", " + show(hi) +
              "]" + (unit[0] != '\0' ? " " : "") + unit);
}

}  // namespace

void HapticSettings::validate() const {
  using L = HapticSettingsLimits;
  checkSetting("force_scale", force_scale, 0.0, false, L::kMaxForceScale, "");
  checkSetting("max_force_n", max_force_n, 0.0, true, L::kMaxForceN, "N");
  checkSetting("max_torque_nm", max_torque_nm, 0.0, true, L::kMaxTorqueNm, "N m");
  checkSetting("slew_n_per_s", slew_n_per_s, 0.0, true, L::kMaxSlewNPerS, "N/s");
  // any finite threshold is safe (the clamp still applies); tools use a huge one to engage at once
  checkSetting("engage_threshold_n", engage_threshold_n, 0.0, false,
               std::numeric_limits<double>::max(), "N");
  checkSetting("watchdog_ms", watchdog_ms, 0.0, true, L::kMaxWatchdogMs, "ms");
  checkSetting("fade_ms", fade_ms, 0.0, false, L::kMaxFadeMs, "ms");
  checkSetting("max_sweeps", max_sweeps, 1.0, false, L::kMaxSweeps, "");
  checkSetting("tolerance", tolerance, 0.0, true, L::kMaxTolerance, "");
  checkSetting("solve_budget_ns", static_cast<double>(solve_budget_ns), 0.0, false,
               static_cast<double>(L::kMaxPeriodNs), "ns");
  checkSetting("period_ns", static_cast<double>(period_ns), 0.0, true,
               static_cast<double>(L::kMaxPeriodNs), "ns");
}

const char* eventName(std::uint32_t code) noexcept {
  switch (code) {
    case kEventEngaged: return "forces_engaged";
    case kEventDeviceRecovered: return "device_recovered";
    case kEventNonFinite: return "non_finite_device_data";
    case kEventSnapshotTooLarge: return "snapshot_too_large";
    case kEventSimShuttingDown: return "simulation_shutting_down";
    case kEventIllPosedSnapshot: return "ill_posed_snapshot";
    default: return shared::eventCodeName(code);
  }
}

AttachedSegment::AttachedSegment(shared::Segment&& s)
    : segment(std::move(s)),
      snapshots(segment.snapshotSubscriber()),
      samples(segment.deviceWriter()),
      stats(segment.statsWriter()),
      workspace(segment.capacity().max_rows, segment.capacity().max_contacts),
      delta_free(static_cast<std::size_t>(segment.capacity().max_rows), 0.0),
      f(static_cast<std::size_t>(segment.capacity().max_rows), 0.0),
      last_delta_free(static_cast<std::size_t>(segment.capacity().max_rows), 0.0),
      blocks(segment.capacity().max_rows, segment.capacity().max_contacts) {}

HapticLoop::HapticLoop(device::Device& device, const HapticSettings& settings)
    : device_(device), settings_(settings) {
  settings_.validate();
  initLimits();
}

HapticLoop::HapticLoop(device::Device& device, const HapticSettings& settings,
                       UncheckedSettingsForTest)
    : device_(device), settings_(settings) {
  initLimits();
}

void HapticLoop::initLimits() {
  force_limit_n_ = sanitizeLimit(settings_.max_force_n, HapticSettingsLimits::kMaxForceN);
  torque_limit_nm_ = sanitizeLimit(settings_.max_torque_nm, HapticSettingsLimits::kMaxTorqueNm);
  const double watchdog_ns = settings_.watchdog_ms * 1e6;
  watchdog_ns_ = std::isfinite(watchdog_ns) && watchdog_ns > 0.0 && watchdog_ns < 1e18
                     ? static_cast<std::int64_t>(watchdog_ns)
                     : 0;
  const device::DeviceInfo info = device_.info();
  const double device_max = info.max_force_n;
  if (std::isfinite(device_max) && device_max > 0.0) {
    force_limit_n_ = std::min(force_limit_n_, device_max);
  } else if (device_max != 0.0) {
    spdlog::warn("device '{}' reports a maximum force of {} N: ignored (must be finite and > 0)",
                 info.model, device_max);
  }
}

void HapticLoop::offerLink(AttachedSegment* link) noexcept {
  // seq_cst: with the tick's hazard store and re-read (adoptOfferedLink), a withdrawn link is
  // either seen as still in use by linkInUse() or never used by the tick
  offered_.store(link, std::memory_order_seq_cst);
}

AttachedSegment* HapticLoop::linkInUse() const noexcept {
  return in_use_.load(std::memory_order_seq_cst);
}

void HapticLoop::adoptOfferedLink() noexcept {
  AttachedSegment* offered = offered_.load(std::memory_order_seq_cst);
  if (offered == link_) return;
  if (adoption_hook_ != nullptr) adoption_hook_(adoption_context_);
  // hazard pointer: announce the link before touching it, then check it is still offered; if
  // the supervisor withdrew it meanwhile it may already be freed, so hold no link this tick
  in_use_.store(offered, std::memory_order_seq_cst);
  if (offered_.load(std::memory_order_seq_cst) != offered) {
    in_use_.store(nullptr, std::memory_order_seq_cst);
    offered = nullptr;
    if (link_ == nullptr) return;
  }
  link_ = offered;
  snapshot_seq_ = 0;
  stale_ = true;
  pushEvent(link_ != nullptr ? shared::kEventSegmentAttached : shared::kEventSegmentLost,
            link_ != nullptr ? static_cast<double>(link_->segment.generation()) : 0.0);
}

void HapticLoop::pushEvent(std::uint32_t code, double a, double b) noexcept {
  if (!shared::pushEvent(events_, shared::monotonicNs(), code, a, b)) {
    counters_.events_dropped.fetch_add(1, std::memory_order_relaxed);
  }
}

void HapticLoop::pushRateLimited(NoisyEvent which, std::uint32_t code, std::int64_t now_ns,
                                 double a, double b) noexcept {
  const auto i = static_cast<std::size_t>(which);
  if (noisy_pushed_[i] && ageNs(now_ns, noisy_event_ns_[i]) < 1'000'000'000) return;
  noisy_pushed_[i] = true;
  noisy_event_ns_[i] = now_ns;
  pushEvent(code, a, b);
}

device::IoStatus HapticLoop::readDevice(std::int64_t now, TickOutput& out) noexcept {
  device::IoStatus io = device_.read(&raw_state_);
  if (io == device::IoStatus::kOk) state_ = raw_state_;
  if (io == device::IoStatus::kOk && state_.t_ns > 0 &&
      ageNs(now, state_.t_ns) > watchdog_ns_) {
    // a sample stamped long ago: the device stopped updating (disconnected, stuck driver)
    counters_.stale_device_samples.fetch_add(1, std::memory_order_relaxed);
    io = device::IoStatus::kFault;
  }
  if (io == device::IoStatus::kOk) {
    if (finite(state_.pos_m) && std::isfinite(state_.quat_wxyz[0]) &&
        std::isfinite(state_.quat_wxyz[1]) && std::isfinite(state_.quat_wxyz[2]) &&
        std::isfinite(state_.quat_wxyz[3])) {
      mapping_.toScene(state_);   // the one place where the device pose becomes the scene's
      last_pose_.pos_m = Eigen::Vector3d(state_.pos_m[0], state_.pos_m[1], state_.pos_m[2]);
      Eigen::Quaterniond q(state_.quat_wxyz[0], state_.quat_wxyz[1], state_.quat_wxyz[2],
                           state_.quat_wxyz[3]);
      last_pose_.rot = q.norm() > 1e-9 ? q.normalized() : Eigen::Quaterniond::Identity();
      have_pose_ = true;
      if (device_fault_) pushEvent(kEventDeviceRecovered);
      device_fault_ = false;
    } else {
      counters_.non_finite_input.fetch_add(1, std::memory_order_relaxed);
      if (!device_fault_) pushEvent(kEventNonFinite);
      device_fault_ = true;
      out.flags |= shared::kStatsDeviceFault;
    }
  } else if (io == device::IoStatus::kNoData) {
    counters_.device_no_data.fetch_add(1, std::memory_order_relaxed);
    out.flags |= shared::kStatsDeviceNoData;
    if (!no_data_) pushRateLimited(kNoisyNoData, shared::kEventDeviceNoData, now);
  } else {
    counters_.device_faults.fetch_add(1, std::memory_order_relaxed);
    if (!device_fault_) pushEvent(shared::kEventDeviceFault);
    device_fault_ = true;
    out.flags |= shared::kStatsDeviceFault;
  }

  no_data_ = io == device::IoStatus::kNoData;

  return io;
}

// Publishes the device sample (pose held on no data, fault flagged).
void HapticLoop::publishSample(std::int64_t now, device::IoStatus io) noexcept {
  if (link_ != nullptr) {
    shared::DeviceSample& s = link_->samples.buffer();
    s.seq = ++sample_seq_;
    s.t_ns = now;
    for (int i = 0; i < 3; ++i) {
      s.pos_m[i] = last_pose_.pos_m[i];
      s.vel_mps[i] = std::isfinite(state_.vel_mps[i]) ? state_.vel_mps[i] : 0.0;
      s.angvel_radps[i] = std::isfinite(state_.angvel_radps[i]) ? state_.angvel_radps[i] : 0.0;
      s.force_n[i] = last_force_n_[i];
      s.torque_nm[i] = last_torque_nm_[i];
    }
    s.quat_wxyz = {last_pose_.rot.w(), last_pose_.rot.x(), last_pose_.rot.y(), last_pose_.rot.z()};
    s.gripper_rad = std::isfinite(state_.gripper_rad) ? state_.gripper_rad : 0.0;
    s.buttons = state_.buttons;
    s.status = (device_fault_ ? shared::kDeviceFault : 0u) |
               (io == device::IoStatus::kOk ? shared::kDeviceOk : 0u) |
               (io == device::IoStatus::kNoData ? shared::kDeviceNoData : 0u) |
               (engaged_ ? shared::kDeviceForcesEnabled : 0u) |
               (gain_ < 1.0 && engaged_ ? shared::kDeviceForceFading : 0u) |
               (clamped_ ? shared::kDeviceForceClamped : 0u);
    s.snapshot_seq = snapshot_seq_;
    link_->samples.publish();
  }

}

// The newest snapshot, its age, and the local model.
void HapticLoop::takeSnapshot(std::int64_t now, TickOutput& out) noexcept {
  bool stale = true;
  if (link_ != nullptr) {
    bool fresh = false;
    const shared::SnapshotView snap = link_->snapshots.latest(&fresh);
    const auto& hdr = snap.header();
    if (hdr.seq == 0) {
      out.flags |= shared::kStatsNoSnapshot;
    } else {
      const std::int64_t age = ageNs(now, hdr.t_ns);
      const bool shutting = (hdr.flags & shared::kSnapshotShuttingDown) != 0;
      stale = watchdog_ns_ == 0 || age > watchdog_ns_ || shutting ||
              (hdr.flags & shared::kSnapshotValid) == 0;
      if (hdr.seq != snapshot_seq_) {
        // a new problem: warm start from the simulation's own solution
        snapshot_seq_ = hdr.seq;
        counters_.snapshots_taken.fetch_add(1, std::memory_order_relaxed);
        const int m = std::clamp(hdr.rows, 0, static_cast<int>(link_->f.size()));
        std::copy_n(snap.f(), m, link_->f.begin());
        if (shutting) pushEvent(kEventSimShuttingDown);
      }
      if (!stale && have_pose_ && !device_fault_) solveLocalModel(*link_, snap, last_pose_, out);
      if (stale != stale_) {
        pushEvent(stale ? shared::kEventSnapshotStale : shared::kEventSnapshotFresh,
                  stale ? static_cast<double>(age) : static_cast<double>(hdr.seq));
      }
    }
  }
  stale_ = stale;
  if (stale) {
    out.flags |= shared::kStatsSnapshotStale;
    counters_.stale_ticks.fetch_add(1, std::memory_order_relaxed);
  }
  out.stale = stale;
  out.snapshot_seq = snapshot_seq_;

}

void HapticLoop::writeDevice(const std::array<double, 3>& force,
                             const std::array<double, 3>& torque) noexcept {
  device::DeviceCommand cmd;
  cmd.force_n = force;
  cmd.torque_nm = torque;
  if (device_.write(cmd) != device::IoStatus::kOk) {
    counters_.write_faults.fetch_add(1, std::memory_order_relaxed);
  }
}

void HapticLoop::recordStats(std::int64_t scheduled_ns, std::int64_t woken_ns,
                             const TickOutput& out, const std::array<double, 3>& force) noexcept {
  // one stats record per tick, and the heartbeat
  if (link_ == nullptr) return;
  shared::StatsRecord rec;
  rec.tick = tick_index_;
  rec.scheduled_ns = scheduled_ns;
  rec.woken_ns = woken_ns;
  rec.finished_ns = shared::monotonicNs();
  rec.solve_ns = out.solve_ns;
  rec.sweeps = out.sweeps;
  rec.residual = out.residual;
  rec.contacts = out.contacts;
  rec.force_norm_n = wrenchNorm(force);
  rec.snapshot_seq = snapshot_seq_;
  // an overrun: the tick's work ended more than one period after its scheduled start
  const std::int64_t late_ns = rec.finished_ns - scheduled_ns - settings_.period_ns;
  const bool overrun = late_ns > 0;
  rec.flags = out.flags | (overrun ? shared::kStatsOverrun : 0u);
  link_->stats.push(rec);
  link_->segment.beat(shared::Side::kHaptic, woken_ns);
  if (overrun) {
    counters_.overruns.fetch_add(1, std::memory_order_relaxed);
    if (!overrun_) {   // first of a burst
      const double periods_missed =
          settings_.period_ns > 0 ? std::floor(static_cast<double>(late_ns) /
                                               static_cast<double>(settings_.period_ns))
                                  : 0.0;
      pushRateLimited(kNoisyOverrun, shared::kEventOverrun, woken_ns,
                      static_cast<double>(late_ns), periods_missed);
    }
  }
  overrun_ = overrun;
}

TickOutput HapticLoop::tick(std::int64_t scheduled_ns, std::int64_t woken_ns) noexcept {
  TickOutput out;
  const std::int64_t now = woken_ns;
  const double dt =
      last_tick_ns_ > 0 ? std::clamp(1e-9 * static_cast<double>(ageNs(now, last_tick_ns_)), 1e-5,
                                     0.05)
                        : 1e-3;
  last_tick_ns_ = now;

  adoptOfferedLink();   // never waits
  const device::IoStatus io = readDevice(now, out);
  publishSample(now, io);
  takeSnapshot(now, out);
  mapping_.wrenchToDevice(out.force_n, out.torque_nm);   // the chain then clamps in device frame
  std::array<double, 3> force{};
  std::array<double, 3> torque{};
  applySafetyChain(dt, out, force, torque);
  writeDevice(force, torque);
  recordStats(scheduled_ns, woken_ns, out, force);
  ++tick_index_;
  counters_.ticks.fetch_add(1, std::memory_order_relaxed);
  return out;
}

}  // namespace tactus::haptic
