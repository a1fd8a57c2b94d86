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

// StatsRecord carries LocalModelUsed and FallbackReason as the shared enums' values
static_assert(shared::kStatsModelNone == static_cast<int>(LocalModelUsed::kNone) &&
              shared::kStatsModelFull == static_cast<int>(LocalModelUsed::kFull) &&
              shared::kStatsModelLinearized == static_cast<int>(LocalModelUsed::kLinearized) &&
              shared::kStatsModelFallbackSolve == static_cast<int>(LocalModelUsed::kFallback) &&
              shared::kStatsModelCorrected == static_cast<int>(LocalModelUsed::kCorrected) &&
              shared::kStatsModelCount == static_cast<int>(LocalModelUsed::kCorrected) + 1);
static_assert(
    shared::kStatsFallbackNone == static_cast<int>(FallbackReason::kNone) &&
    shared::kStatsFallbackNotLinearized == static_cast<int>(FallbackReason::kNotLinearized) &&
    shared::kStatsFallbackOutOfRange == static_cast<int>(FallbackReason::kOutOfRange) &&
    shared::kStatsFallbackContactCloses == static_cast<int>(FallbackReason::kContactCloses) &&
    shared::kStatsFallbackContactLifts == static_cast<int>(FallbackReason::kContactLifts) &&
    shared::kStatsFallbackLeavesCone == static_cast<int>(FallbackReason::kLeavesCone) &&
    shared::kStatsFallbackSlipTurns == static_cast<int>(FallbackReason::kSlipTurns) &&
    shared::kStatsFallbackReasonCount == static_cast<int>(FallbackReason::kSlipTurns) + 1);

using detail::ageNs;
using detail::finite;
using detail::sanitizeLimit;

namespace {

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
  checkSetting("snapshot_blend_ms", snapshot_blend_ms, 0.0, false, L::kMaxSnapshotBlendMs, "ms");
  checkSetting("max_sweeps", max_sweeps, 1.0, false, L::kMaxSweeps, "");
  checkSetting("tolerance", tolerance, 0.0, true, L::kMaxTolerance, "");
  checkSetting("anderson_depth", anderson_depth, 0.0, false, shared::kMaxAndersonDepth, "");
  checkSetting("period_ns", static_cast<double>(period_ns), 0.0, true,
               static_cast<double>(L::kMaxPeriodNs), "ns");
  // the deadline must leave room in the period; no deadline only with few sweeps
  checkSetting("solve_budget_ns", static_cast<double>(solve_budget_ns), 0.0, false,
               std::floor(L::kMaxBudgetFraction * static_cast<double>(period_ns)),
               "ns (at most 90 % of period_ns)");
  if (solve_budget_ns == 0 && max_sweeps > L::kMaxSweepsWithoutBudget) {
    throw Error("haptic settings: solve_budget_ns = 0 (no deadline) with max_sweeps = " +
                std::to_string(max_sweeps) + ": give a budget, or at most " +
                std::to_string(L::kMaxSweepsWithoutBudget) + " sweeps");
  }
  localModel().validate();
}

LocalModelSettings HapticSettings::localModel() const noexcept {
  LocalModelSettings m;
  m.kind = local_model;
  m.tolerance = tolerance;
  m.max_sweeps = max_sweeps;
  m.anderson_depth = anderson_depth;
  m.reduced_fallback = reduced_fallback;
  m.active_set_correction = active_set_correction;
  return m;
}

const char* eventName(std::uint32_t code) noexcept {
  switch (code) {
    case kEventEngaged: return "forces_engaged";
    case kEventDeviceRecovered: return "device_recovered";
    case kEventNonFinite: return "non_finite_device_data";
    case kEventSnapshotTooLarge: return "snapshot_too_large";
    case kEventSimShuttingDown: return "simulation_shutting_down";
    case kEventIllPosedSnapshot: return "ill_posed_snapshot";
    case kEventSnapshotRejected: return "snapshot_rejected";
    case kEventDisengaged: return "forces_disengaged";
    case kEventUnusableOrientation: return "unusable_device_orientation";
    case kEventSnapshotFromTheFuture: return "snapshot_from_the_future";
    default: return shared::eventCodeName(code);
  }
}

AttachedSegment::AttachedSegment(shared::Segment&& s)
    : segment(std::move(s)),
      snapshots(segment.snapshotSubscriber()),
      stats(segment.statsWriter()),
      preparer(snapshots, segment.capacity().max_rows, segment.capacity().max_contacts),
      model(segment.capacity().max_rows, segment.capacity().max_contacts) {
  sample_writers = std::clamp(segment.capacity().devices, 0, shared::kMaxInstruments);
  for (int i = 0; i < sample_writers; ++i) {
    samples[static_cast<std::size_t>(i)] = segment.deviceWriter(i);
  }
}

HapticLoop::HapticLoop(device::Device& device, const HapticSettings& settings)
    : settings_(settings), model_settings_(settings.localModel()) {
  settings_.validate();
  channels_[0].device = &device;
  initLimits(channels_[0]);
}

HapticLoop::HapticLoop(std::span<device::Device* const> devices, const HapticSettings& settings)
    : settings_(settings), model_settings_(settings.localModel()) {
  settings_.validate();
  if (devices.empty() || devices.size() > static_cast<std::size_t>(shared::kMaxInstruments)) {
    throw Error("haptic loop: " + std::to_string(devices.size()) + " devices (1 to " +
                std::to_string(shared::kMaxInstruments) + ")");
  }
  device_count_ = static_cast<int>(devices.size());
  for (std::size_t i = 0; i < devices.size(); ++i) {
    if (devices[i] == nullptr) throw Error("haptic loop: device " + std::to_string(i) + " is null");
    channels_[i].device = devices[i];
    initLimits(channels_[i]);
  }
}

HapticLoop::HapticLoop(device::Device& device, const HapticSettings& settings, Unchecked)
    : settings_(settings), model_settings_(settings.localModel()) {
  channels_[0].device = &device;
  initLimits(channels_[0]);
}

void HapticLoop::initLimits(DeviceChannel& ch) {
  ch.force_limit_n = sanitizeLimit(settings_.max_force_n, HapticSettingsLimits::kMaxForceN);
  ch.torque_limit_nm = sanitizeLimit(settings_.max_torque_nm, HapticSettingsLimits::kMaxTorqueNm);
  const double watchdog_ns = settings_.watchdog_ms * 1e6;
  watchdog_ns_ = std::isfinite(watchdog_ns) && watchdog_ns > 0.0 && watchdog_ns < 1e18
                     ? static_cast<std::int64_t>(watchdog_ns)
                     : 0;
  // whole ticks; unchecked settings (tests) that are not finite or out of range blend nothing
  const double blend_ticks = settings_.snapshot_blend_ms * 1e6 /
                             static_cast<double>(std::max<std::int64_t>(settings_.period_ns, 1));
  blend_ticks_ = std::isfinite(blend_ticks) && blend_ticks >= 0.5 && blend_ticks <= 1e5
                     ? static_cast<int>(std::lround(blend_ticks))
                     : 0;
  // the fade and the slew limit count nominal periods, not elapsed time: a late tick (a stalled
  // device read) gets no larger budget; unchecked settings that are not usable: no ramp, no slew
  const double period_s = 1e-9 * static_cast<double>(settings_.period_ns);
  const double fade_ticks = 1e-3 * settings_.fade_ms / period_s;
  fade_ticks_ = std::isfinite(fade_ticks) && fade_ticks >= 1.0 && fade_ticks <= 1e7
                    ? static_cast<int>(std::lround(fade_ticks))
                    : 1;
  const double slew_step = settings_.slew_n_per_s * period_s;
  slew_step_n_ = std::isfinite(slew_step) && slew_step > 0.0 ? slew_step : 0.0;
  const device::DeviceInfo info = ch.device->info();
  const double device_max = info.max_force_n;
  if (std::isfinite(device_max) && device_max > 0.0) {
    ch.force_limit_n = std::min(ch.force_limit_n, device_max);
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

void HapticLoop::stopped() noexcept {
  link_ = nullptr;
  in_use_.store(nullptr, std::memory_order_seq_cst);
}

HapticLoop::TickProgress HapticLoop::tickProgress(std::int64_t now_ns) const noexcept {
  TickProgress p;
  // relaxed: a diagnostic; a stale value only delays the watchdog by one poll
  const std::int64_t started = tick_started_ns_.load(std::memory_order_relaxed);
  if (started == 0) return p;
  p.running_ns = std::max<std::int64_t>(0, ageNs(now_ns, started));
  p.device = in_device_.load(std::memory_order_relaxed);
  return p;
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
  // another simulation (or none): every device's forces fade out and re-engage only below the
  // engage threshold, whatever the new link's first snapshot says
  for (int i = 0; i < device_count_; ++i) {
    DeviceChannel& ch = channels_[static_cast<std::size_t>(i)];
    if (ch.engaged) disengage(ch, i);
  }
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

device::IoStatus HapticLoop::readDevice(DeviceChannel& ch, int i, std::int64_t now,
                                        TickOutput& out) noexcept {
  // relaxed: for the supervisor's watchdog only
  in_device_.store(i, std::memory_order_relaxed);
  device::IoStatus io = ch.device->read(&ch.raw_state);
  in_device_.store(-1, std::memory_order_relaxed);
  if (io == device::IoStatus::kOk) {
    ch.state = ch.raw_state;
    ch.last_sample_ns = now;
  }
  if (io == device::IoStatus::kOk && ch.state.t_ns > 0 &&
      ageNs(now, ch.state.t_ns) > watchdog_ns_) {
    // a sample stamped long ago: the device stopped updating (disconnected, stuck driver)
    counters_.stale_device_samples.fetch_add(1, std::memory_order_relaxed);
    io = device::IoStatus::kFault;
  }
  if (io == device::IoStatus::kNoData && ch.have_pose &&
      (watchdog_ns_ == 0 || ageNs(now, ch.last_sample_ns) > watchdog_ns_)) {
    // silent for longer than the watchdog: the held pose may be far from the hand by now
    counters_.silent_device_ticks.fetch_add(1, std::memory_order_relaxed);
    io = device::IoStatus::kFault;
  }
  if (io == device::IoStatus::kOk) {
    const auto& q = ch.state.quat_wxyz;
    const bool finite_pose = finite(ch.state.pos_m) && std::isfinite(q[0]) &&
                             std::isfinite(q[1]) && std::isfinite(q[2]) && std::isfinite(q[3]);
    // a device's quaternion is unit up to its rounding; zero or far from unit is no orientation
    // (never replaced by identity: the instrument would turn to the scene's axes)
    const double q_norm2 = finite_pose ? q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
                                       : 0.0;
    const bool unit = q_norm2 > kMinQuaternionNorm2 && q_norm2 < kMaxQuaternionNorm2;
    if (finite_pose && unit) {
      ch.mapping.toScene(ch.state);   // the one place where the device pose becomes the scene's
      const auto& p = ch.state.pos_m;
      const auto& qs = ch.state.quat_wxyz;
      ch.last_pose.pos_m = Eigen::Vector3d(p[0], p[1], p[2]);
      const Eigen::Quaterniond rot(qs[0], qs[1], qs[2], qs[3]);
      ch.last_pose.rot = rot.normalized();
      ch.have_pose = true;
      if (ch.device_fault) pushEvent(kEventDeviceRecovered, i);
      ch.device_fault = false;
    } else {
      if (finite_pose) {
        counters_.unusable_orientation.fetch_add(1, std::memory_order_relaxed);
        if (!ch.device_fault) pushEvent(kEventUnusableOrientation, std::sqrt(q_norm2), i);
      } else {
        counters_.non_finite_input.fetch_add(1, std::memory_order_relaxed);
        if (!ch.device_fault) pushEvent(kEventNonFinite, 0.0, i);
      }
      ch.device_fault = true;
      out.flags |= shared::kStatsDeviceFault;
    }
  } else if (io == device::IoStatus::kNoData) {
    counters_.device_no_data.fetch_add(1, std::memory_order_relaxed);
    out.flags |= shared::kStatsDeviceNoData;
    if (!ch.no_data) pushRateLimited(kNoisyNoData, shared::kEventDeviceNoData, now, i);
  } else {
    counters_.device_faults.fetch_add(1, std::memory_order_relaxed);
    if (!ch.device_fault) pushEvent(shared::kEventDeviceFault, i);
    ch.device_fault = true;
    out.flags |= shared::kStatsDeviceFault;
  }

  ch.no_data = io == device::IoStatus::kNoData;

  return io;
}

// Publishes device i's sample (pose held on no data, fault flagged).
void HapticLoop::publishSample(DeviceChannel& ch, int i, std::int64_t now,
                               device::IoStatus io) noexcept {
  if (link_ == nullptr || i >= link_->sample_writers) return;
  auto& writer = link_->samples[static_cast<std::size_t>(i)];
  shared::DeviceSample& s = writer.buffer();
  s.seq = ++ch.sample_seq;
  s.t_ns = now;
  for (int k = 0; k < 3; ++k) {
    s.pos_m[k] = ch.last_pose.pos_m[k];
    s.vel_mps[k] = std::isfinite(ch.state.vel_mps[k]) ? ch.state.vel_mps[k] : 0.0;
    s.angvel_radps[k] = std::isfinite(ch.state.angvel_radps[k]) ? ch.state.angvel_radps[k] : 0.0;
    s.force_n[k] = ch.last_force_n[k];
    s.torque_nm[k] = ch.last_torque_nm[k];
  }
  const Eigen::Quaterniond& r = ch.last_pose.rot;
  s.quat_wxyz = {r.w(), r.x(), r.y(), r.z()};
  s.gripper_rad = std::isfinite(ch.state.gripper_rad) ? ch.state.gripper_rad : 0.0;
  s.buttons = ch.state.buttons;
  s.status = (ch.device_fault ? shared::kDeviceFault : 0u) |
             (io == device::IoStatus::kOk ? shared::kDeviceOk : 0u) |
             (io == device::IoStatus::kNoData ? shared::kDeviceNoData : 0u) |
             (ch.engaged ? shared::kDeviceForcesEnabled : 0u) |
             (ch.gain > 0.0 && ch.gain < 1.0 ? shared::kDeviceForceFading : 0u) |
             (ch.clamped ? shared::kDeviceForceClamped : 0u) |
             // only a pose the device delivered may move the instrument (none yet: the
             // simulation keeps the scene's own pose)
             (ch.have_pose ? shared::kDevicePoseValid : 0u);
  s.snapshot_seq = snapshot_seq_;
  writer.publish();
}

// The newest prepared snapshot, its age, and the local model.
void HapticLoop::takeSnapshot(std::int64_t now, std::int64_t t_now_ns, std::int64_t deadline_ns,
                              TickOutput& out) noexcept {
  bool stale = true;
  bool switched = false;
  bool solved = false;
  bool usable = false;   // the solve gave a model the hand may feel
  if (link_ != nullptr) {
    // each device at its last pose (held while it faults); solved while some device has a
    // live pose
    std::array<const shared::Pose*, shared::kMaxInstruments> poses{};
    bool live = false;
    for (int i = 0; i < device_count_; ++i) {
      const DeviceChannel& ch = channels_[static_cast<std::size_t>(i)];
      if (ch.have_pose) poses[static_cast<std::size_t>(i)] = &ch.last_pose;
      live = live || (ch.have_pose && !ch.device_fault);
    }
    SnapshotPreparer& preparer = link_->preparer;
    // (read at or after the tick's start, on the real clock)
    preparer.publishPoses(DevicePoses(poses.data(), static_cast<std::size_t>(device_count_)),
                          out.started_ns);
    // without a preparer thread the tick prepares (tests, offline tools: not real-time)
    if (!preparer.threaded()) (void)preparer.prepareNewest(model_settings_);
    bool fresh = false;
    const PreparedSnapshot* snap = preparer.latest(&fresh);
    const shared::ContactSnapshotHeader& hdr = snap->header();
    if (hdr.seq == 0) {
      out.flags |= shared::kStatsNoSnapshot;
    } else {
      // aged at the moment it was taken (a tick preempted since it started may be handed one
      // published meanwhile)
      const std::int64_t age =
          t_now_ns >= 0 ? detail::snapshotAgeNs(now, t_now_ns, shared::monotonicNs(), hdr.t_ns)
                        : ageNs(now, hdr.t_ns);
      const bool shutting = (hdr.flags & shared::kSnapshotShuttingDown) != 0;
      // stamped in the future (both sides share CLOCK_MONOTONIC): corrupt, never fresh
      const bool future = detail::fromTheFuture(age);
      stale = watchdog_ns_ == 0 || age > watchdog_ns_ || future || shutting ||
              (hdr.flags & shared::kSnapshotValid) == 0;
      if (future && hdr.seq != snapshot_seq_) {
        pushEvent(kEventSnapshotFromTheFuture, static_cast<double>(-age));
      }
      if (link_->model.adopted() != snap || snap->generation() != adopted_generation_) {
        // O(rows): the preparation's solution and its W f + delta_free become the warm start
        // (a snapshot prepared again at newer poses too)
        link_->model.adopt(snap);
        adopted_generation_ = snap->generation();
      }
      if (hdr.seq != snapshot_seq_) {
        switched = true;
        snapshot_seq_ = hdr.seq;
        counters_.snapshots_taken.fetch_add(1, std::memory_order_relaxed);
        if (shutting) pushEvent(kEventSimShuttingDown);
        const PrepareStatus ps = snap->status();
        if (ps != PrepareStatus::kReady && ps != PrepareStatus::kEmpty) {
          counters_.rejected_snapshots.fetch_add(1, std::memory_order_relaxed);
          if (ps == PrepareStatus::kIllPosed) {
            pushEvent(kEventIllPosedSnapshot, 0.0, static_cast<double>(hdr.seq));
          } else if (ps == PrepareStatus::kTooLarge) {
            pushEvent(kEventSnapshotTooLarge, hdr.rows);
          } else {
            pushEvent(kEventSnapshotRejected, static_cast<double>(ps),
                      static_cast<double>(hdr.seq));
          }
        }
      }
      (void)fresh;
      out.prepare_ns = snap->prepareNs();
      if (!stale && live) {
        out.contacts = std::max(hdr.contacts, 0);
        const PrepareStatus ps = snap->status();
        if (ps == PrepareStatus::kIllPosed || ps == PrepareStatus::kNonFinite) {
          // a corrupt problem: no force from it (the chain fades the force it held)
          out.flags |= shared::kStatsSolverNotConverged;
          auto& counter = ps == PrepareStatus::kIllPosed ? counters_.ill_posed_solves
                                                          : counters_.non_finite_input;
          counter.fetch_add(1, std::memory_order_relaxed);
        }
        // a model the hand may feel: a problem the preparation accepted (or one without
        // contact) and a solve that gave a usable wrench
        const bool solved_ok = solveLocalModel(*link_, poses, deadline_ns, out);
        usable = ps == PrepareStatus::kEmpty || (ps == PrepareStatus::kReady && solved_ok);
        solved = true;
      }
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
  // a device has a model this tick when the solve was usable and it has a live pose
  for (int i = 0; i < device_count_; ++i) {
    const DeviceChannel& ch = channels_[static_cast<std::size_t>(i)];
    out.device[static_cast<std::size_t>(i)].model =
        usable && !stale && ch.have_pose && !ch.device_fault;
  }
  blendSnapshot(switched, solved, out);
}

bool HapticLoop::solveLocalModel(
    AttachedSegment& link, const std::array<const shared::Pose*, shared::kMaxInstruments>& poses,
    std::int64_t deadline_ns, TickOutput& out) noexcept {
  const LocalModelResult res = link.model.solve(
      DevicePoses(poses.data(), static_cast<std::size_t>(device_count_)), model_settings_,
      deadline_ns);
  if (res.solved()) out.contacts = res.contacts;
  out.sweeps = res.sweeps;
  out.residual = res.error;
  out.solve_ns = res.elapsed_ns;
  out.model_used = res.used;
  out.fallback_reason = res.fallback;
  out.correction_rounds = res.correction_rounds;
  if (!res.solved()) return false;
  if (res.used == LocalModelUsed::kLinearized) {
    counters_.linearized_ticks.fetch_add(1, std::memory_order_relaxed);
  } else if (res.used == LocalModelUsed::kCorrected) {
    // rendered from the linearisation, which no longer holds here: prepare it again
    counters_.corrected_ticks.fetch_add(1, std::memory_order_relaxed);
    link.preparer.requestRelinearization();
  } else if (res.used == LocalModelUsed::kFallback) {
    counters_.model_fallbacks.fetch_add(1, std::memory_order_relaxed);
    out.flags |= shared::kStatsModelFallback;
    link.preparer.requestRelinearization();
  }
  if (res.status == shared::NsgsStatus::kEmpty) return false;
  if (res.status == shared::NsgsStatus::kNonFinite) {   // NSGS has zeroed f
    counters_.non_finite_input.fetch_add(1, std::memory_order_relaxed);
    return false;
  }
  // kIllPosed: W itself is unusable (a contact with a zero, negative or denormal diagonal). The
  // simulation never publishes such a W from a real scene, so the snapshot is corrupt: render no
  // force from it (the safety chain ramps the command down) and report it once per snapshot.
  if (res.status == shared::NsgsStatus::kIllPosed) {
    counters_.ill_posed_solves.fetch_add(1, std::memory_order_relaxed);
    out.flags |= shared::kStatsSolverNotConverged;
    if (link.ill_posed_seq != snapshot_seq_) {
      link.ill_posed_seq = snapshot_seq_;
      pushEvent(kEventIllPosedSnapshot, static_cast<double>(res.ill_posed_contacts),
                static_cast<double>(snapshot_seq_));
    }
    return false;
  }
  const bool not_converged = res.status != shared::NsgsStatus::kConverged;
  if (not_converged) {
    out.flags |= shared::kStatsSolverNotConverged;
    counters_.solver_not_converged.fetch_add(1, std::memory_order_relaxed);
    if (!not_converged_) {
      pushRateLimited(kNoisyNotConverged, shared::kEventSolverNotConverged, last_tick_ns_,
                      res.sweeps, res.error);
    }
  }
  not_converged_ = not_converged;
  const int tools = std::min(res.instruments, device_count_);
  for (int i = 0; i < tools; ++i) {
    const auto k = static_cast<std::size_t>(i);
    out.device[k].force_n = res.force_n[k];
    out.device[k].torque_nm = res.torque_nm[k];
  }
  out.force_n = out.device[0].force_n;
  out.torque_nm = out.device[0].torque_nm;
  return true;
}

void HapticLoop::blendSnapshot(bool switched, bool solved, TickOutput& out) noexcept {
  for (int i = 0; i < device_count_; ++i) {
    DeviceChannel& ch = channels_[static_cast<std::size_t>(i)];
    DeviceTickOutput& dev = out.device[static_cast<std::size_t>(i)];
    if (!solved || !ch.have_pose) {   // nothing rendered from a model: nothing to blend from
      ch.have_model_wrench = false;
      ch.blend_ticks_left = 0;
      continue;
    }
    if (switched && blend_ticks_ > 0 && ch.have_model_wrench) {
      for (int k = 0; k < 3; ++k) {
        ch.blend_force_n[k] = ch.model_force_n[k] - dev.force_n[k];
        ch.blend_torque_nm[k] = ch.model_torque_nm[k] - dev.torque_nm[k];
      }
      const bool usable = finite(ch.blend_force_n) && finite(ch.blend_torque_nm);
      ch.blend_ticks_left = usable ? blend_ticks_ : 0;
    }
    if (ch.blend_ticks_left > 0) {
      --ch.blend_ticks_left;   // the last tick of the blend renders the new model alone
      const double w = static_cast<double>(ch.blend_ticks_left) / blend_ticks_;
      for (int k = 0; k < 3; ++k) {
        dev.force_n[k] += w * ch.blend_force_n[k];
        dev.torque_nm[k] += w * ch.blend_torque_nm[k];
      }
    }
    ch.model_force_n = dev.force_n;
    ch.model_torque_nm = dev.torque_nm;
    ch.have_model_wrench = true;
  }
}

void HapticLoop::writeDevice(DeviceChannel& ch, const std::array<double, 3>& force,
                             const std::array<double, 3>& torque) noexcept {
  device::DeviceCommand cmd;
  cmd.force_n = force;
  cmd.torque_nm = torque;
  // relaxed: for the supervisor's watchdog only
  in_device_.store(static_cast<int>(&ch - channels_.data()), std::memory_order_relaxed);
  const device::IoStatus io = ch.device->write(cmd);
  in_device_.store(-1, std::memory_order_relaxed);
  if (io != device::IoStatus::kOk) {
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
  rec.devices = out.devices;
  for (int i = 0; i < out.devices; ++i) {
    rec.device_force_norm_n[static_cast<std::size_t>(i)] =
        wrenchNorm(out.device[static_cast<std::size_t>(i)].force_n);
  }
  rec.snapshot_seq = snapshot_seq_;
  rec.read_ns = out.read_ns;
  rec.model_ns = out.model_ns;
  rec.output_ns = out.output_ns;
  rec.started_ns = out.started_ns;
  rec.deadline_ns = out.deadline_ns;
  rec.model = static_cast<std::int64_t>(out.model_used);
  rec.prepare_ns = out.prepare_ns;
  rec.fallback_reason = static_cast<std::int64_t>(out.fallback_reason);
  rec.correction_rounds = out.correction_rounds;
  // an overrun: the tick's work ended more than one period after its scheduled start
  const std::int64_t late_ns = rec.finished_ns - scheduled_ns - settings_.period_ns;
  const bool overrun = late_ns > 0;
  const bool missed = out.deadline_ns > 0 && rec.finished_ns > out.deadline_ns;
  if (missed) counters_.deadline_misses.fetch_add(1, std::memory_order_relaxed);
  rec.flags = out.flags | (overrun ? shared::kStatsOverrun : 0u) |
              (missed ? shared::kStatsDeadlineMissed : 0u);
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

// The tick's phases after the model (safety chain, writes, stats) are kept out of the solve's
// share of the deadline by this much [ns].
constexpr std::int64_t kOutputReserveNs = 20'000;

TickOutput HapticLoop::tick(std::int64_t scheduled_ns, std::int64_t woken_ns) noexcept {
  TickOutput out;
  // one deadline for the whole tick, from the start of its work (on the real clock, whatever
  // times the caller passes)
  out.started_ns = shared::monotonicNs();
  out.deadline_ns = settings_.solve_budget_ns > 0 ? out.started_ns + settings_.solve_budget_ns : 0;
  // relaxed: for the supervisor's watchdog only
  tick_started_ns_.store(out.started_ns, std::memory_order_relaxed);
  const std::int64_t now = woken_ns;
  last_tick_ns_ = now;

  adoptOfferedLink();   // never waits
  out.devices = device_count_;
  for (int i = 0; i < device_count_; ++i) {
    DeviceChannel& ch = channels_[static_cast<std::size_t>(i)];
    publishSample(ch, i, now, readDevice(ch, i, now, out));
  }
  const std::int64_t t_read = shared::monotonicNs();
  out.read_ns = t_read - out.started_ns;
  const std::int64_t solve_deadline =
      out.deadline_ns > 0
          ? std::max(out.deadline_ns - std::min(kOutputReserveNs, settings_.solve_budget_ns / 4),
                     out.started_ns + 1)
          : 0;
  // one solve: each instrument's wrench in out.device[i]. On the real clock (a solve budget) the
  // snapshot's age is taken on the tick's clock moved on by the real time since the tick started
  // (a device read may have stalled since the tick woke, the tick may be preempted before it
  // takes the snapshot), so a snapshot published meanwhile is not taken for one from the
  // future. Without a clock (solve_budget_ns = 0: simulated time) on the caller's clock alone.
  takeSnapshot(now, settings_.solve_budget_ns > 0 ? out.started_ns : -1, solve_deadline, out);
  const std::int64_t t_model = shared::monotonicNs();
  out.model_ns = t_model - t_read;
  std::array<double, 3> force0{};
  bool all_zero = true;
  for (int i = 0; i < device_count_; ++i) {
    DeviceChannel& ch = channels_[static_cast<std::size_t>(i)];
    DeviceTickOutput& dev = out.device[static_cast<std::size_t>(i)];
    ch.mapping.wrenchToDevice(dev.force_n, dev.torque_nm);   // the chain clamps in device frame
    std::array<double, 3> force{};
    std::array<double, 3> torque{};
    applySafetyChain(ch, i, out, dev, force, torque);
    writeDevice(ch, force, torque);
    if (i == 0) force0 = force;
    all_zero = all_zero && ch.gain == 0.0 && force == std::array<double, 3>{} &&
               torque == std::array<double, 3>{};
  }
  // relaxed: read by a stopping program's thread, nothing else depends on it
  all_forces_zero_.store(all_zero, std::memory_order_relaxed);
  static_cast<DeviceTickOutput&>(out) = out.device[0];
  out.output_ns = shared::monotonicNs() - t_model;
  recordStats(scheduled_ns, woken_ns, out, force0);
  ++tick_index_;
  counters_.ticks.fetch_add(1, std::memory_order_relaxed);
  tick_started_ns_.store(0, std::memory_order_relaxed);
  return out;
}

}  // namespace tactus::haptic
