// The haptic tick: device -> local model -> NSGS -> safety chain -> device, allocation-free.
#include "tactus/haptic/haptic_loop.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>
#include <string>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"

namespace tactus::haptic {
namespace {

bool finite(const std::array<double, 3>& a) noexcept {
  return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]);
}

}  // namespace

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

// now - t_ns, saturated instead of overflowing (time stamps from shared memory or a device)
std::int64_t ageNs(std::int64_t now, std::int64_t t_ns) noexcept {
  std::int64_t age = 0;
  if (__builtin_sub_overflow(now, t_ns, &age)) {
    return t_ns < 0 ? std::numeric_limits<std::int64_t>::max()
                    : std::numeric_limits<std::int64_t>::min();
  }
  return age;
}

// A usable clamp: finite and >= kMinLimit, at most `ceiling`; anything else is 0 (no output).
double sanitizeLimit(double limit, double ceiling) noexcept {
  if (!std::isfinite(limit) || !(limit >= HapticSettingsLimits::kMinLimit)) return 0.0;
  return std::min(limit, ceiling);
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

shared::Pose toPose(const shared::PoseSample& s) noexcept {
  shared::Pose p;
  p.pos_m = Eigen::Vector3d(s.pos_m[0], s.pos_m[1], s.pos_m[2]);
  p.rot = Eigen::Quaterniond(s.quat_wxyz[0], s.quat_wxyz[1], s.quat_wxyz[2], s.quat_wxyz[3]);
  const double n = p.rot.norm();
  if (n > 1e-12 && std::isfinite(n)) {
    p.rot.coeffs() /= n;
  } else {
    p.rot = Eigen::Quaterniond::Identity();
  }
  return p;
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

void HapticLoop::solveLocalModel(AttachedSegment& link, const shared::SnapshotView& snap,
                                 const shared::Pose& device_pose, TickOutput& out) noexcept {
  shared::NsgsWorkspace& workspace = link.workspace;
  std::vector<double>& delta_free = link.delta_free;
  std::vector<double>& f = link.f;
  const auto& hdr = snap.header();
  const int m = hdr.rows;
  const int nc = hdr.contacts;
  out.contacts = nc;
  if (m <= 0 || nc <= 0) return;
  if (m > workspace.maxRows() || nc > workspace.maxContacts()) {
    pushEvent(kEventSnapshotTooLarge, m);
    return;
  }
  // delta_free(t) = delta_free* + J (x_h [-] x_h*)
  const shared::Pose x_star = toPose(hdr.device_pose);
  const shared::Vector6d dx = shared::poseDifference(device_pose, x_star);
  const double* df = snap.deltaFree();
  const double* J = snap.J();
  const bool move = (hdr.flags & shared::kSnapshotHasJacobian) != 0;
  for (int r = 0; r < m; ++r) {
    double d = df[r];
    if (move) {
      const double* jr = J + 6 * r;
      for (int k = 0; k < 6; ++k) d += jr[k] * dx[k];
    }
    delta_free[r] = d;
  }
  shared::NsgsSettings ns;
  ns.tolerance = settings_.tolerance;
  ns.max_sweeps = settings_.max_sweeps;
  ns.time_budget_ns = settings_.solve_budget_ns;
  // the row-update sweep needs an exactly symmetric W: only when the snapshot says so
  ns.coupling = (hdr.flags & shared::kSnapshotSymmetricW) != 0
                    ? shared::NsgsCoupling::kSymmetricRowUpdate
                    : shared::NsgsCoupling::kColumnUpdate;
  // same snapshot as the last solve: W and f are unchanged, so W f + delta_free only shifts by
  // the change of delta_free (saves a pass over W)
  if (link.delta_seq == hdr.seq) {
    double* delta = workspace.delta.data();
    for (int r = 0; r < m; ++r) delta[r] += delta_free[r] - link.last_delta_free[r];
    ns.delta_is_current = true;
  }
  // W's storage, chosen once per snapshot: dense (one tissue) or blocks (several bodies)
  shared::ContactProblemView problem = snap.problem(delta_free.data());
  if (link.blocks_seq != hdr.seq) {
    link.use_blocks = shared::chooseStorage(problem, link.blocks).blocks != nullptr;
    link.blocks_seq = hdr.seq;
  }
  if (link.use_blocks) problem.blocks = &link.blocks;
  const shared::NsgsResult res = shared::solveNsgs(problem, ns, workspace, f.data());
  link.delta_seq = res.status == shared::NsgsStatus::kEmpty ? 0 : hdr.seq;
  std::copy_n(delta_free.begin(), m, link.last_delta_free.begin());
  out.sweeps = res.sweeps;
  out.residual = res.error;
  out.solve_ns = res.elapsed_ns;
  // kEmpty: the view is inconsistent (row offsets, sizes): its offsets must not be used
  if (res.status == shared::NsgsStatus::kEmpty) return;
  if (res.status == shared::NsgsStatus::kNonFinite) {   // NSGS has zeroed f
    counters_.non_finite_input.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  // kIllPosed: W itself is unusable (a contact with a zero, negative or denormal diagonal). The
  // simulation never publishes such a W from a real scene, so the snapshot is corrupt: render no
  // force from it (the safety chain ramps the command down) and report it once per snapshot.
  if (res.status == shared::NsgsStatus::kIllPosed) {
    counters_.ill_posed_solves.fetch_add(1, std::memory_order_relaxed);
    out.flags |= shared::kStatsSolverNotConverged;
    if (link.ill_posed_seq != hdr.seq) {
      link.ill_posed_seq = hdr.seq;
      pushEvent(kEventIllPosedSnapshot, static_cast<double>(res.ill_posed_contacts),
                static_cast<double>(hdr.seq));
    }
    return;
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
  // wrench on the instrument from the contact forces (frame rows n, t1, t2)
  const std::int32_t* ro = snap.rowOffset();
  const double* pt = snap.contactPoint();
  const double* nn = snap.contactNormal();
  const double* tt = snap.contactTangent();
  const Eigen::Vector3d origin = toPose(hdr.tool_pose).pos_m + dx.head<3>();
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  Eigen::Vector3d torque = Eigen::Vector3d::Zero();
  for (int c = 0; c < nc; ++c) {
    const int r0 = ro[c];
    const int rows = ro[c + 1] - r0;
    Eigen::Vector3d fc = f[r0] * Eigen::Vector3d(nn[3 * c], nn[3 * c + 1], nn[3 * c + 2]);
    if (rows == 3) {
      fc += f[r0 + 1] * Eigen::Vector3d(tt[6 * c], tt[6 * c + 1], tt[6 * c + 2]);
      fc += f[r0 + 2] * Eigen::Vector3d(tt[6 * c + 3], tt[6 * c + 4], tt[6 * c + 5]);
    }
    force += fc;
    torque += (Eigen::Vector3d(pt[3 * c], pt[3 * c + 1], pt[3 * c + 2]) - origin).cross(fc);
  }
  for (int i = 0; i < 3; ++i) {
    out.force_n[i] = force[i];
    out.torque_nm[i] = torque[i];
  }
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
