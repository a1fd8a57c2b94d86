// The haptic tick: device -> local model -> NSGS -> safety chain -> device, allocation-free.
#include "tactus/haptic/haptic_loop.h"

#include <algorithm>
#include <cmath>

#include "tactus/shared/clock.h"

namespace tactus::haptic {
namespace {

bool finite(const std::array<double, 3>& a) noexcept {
  return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]);
}

double norm3(const std::array<double, 3>& a) noexcept {
  return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
}

// Scales `v` so that |v| <= limit; returns true when it did.
bool clampNorm(std::array<double, 3>& v, double limit) noexcept {
  const double n = norm3(v);
  if (n <= limit || n == 0.0) return false;
  const double k = limit / n;
  for (double& x : v) x *= k;
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

const char* eventName(std::uint32_t code) noexcept {
  switch (code) {
    case kEventEngaged: return "forces_engaged";
    case kEventDeviceRecovered: return "device_recovered";
    case kEventNonFinite: return "non_finite_device_data";
    case kEventSnapshotTooLarge: return "snapshot_too_large";
    case kEventSimShuttingDown: return "simulation_shutting_down";
    default: return shared::eventCodeName(code);
  }
}

HapticLink::HapticLink(shared::Segment&& s)
    : segment(std::move(s)),
      snapshots(segment.snapshotSubscriber()),
      samples(segment.deviceWriter()),
      stats(segment.statsWriter()),
      workspace(segment.capacity().max_rows, segment.capacity().max_contacts),
      delta_free(static_cast<std::size_t>(segment.capacity().max_rows), 0.0),
      f(static_cast<std::size_t>(segment.capacity().max_rows), 0.0),
      last_delta_free(static_cast<std::size_t>(segment.capacity().max_rows), 0.0) {}

HapticLoop::HapticLoop(device::Device& device, const HapticSettings& settings)
    : device_(device), settings_(settings) {}

void HapticLoop::offerLink(HapticLink* link) noexcept {
  // release: the tick that acquires the pointer sees the fully constructed link
  offered_.store(link, std::memory_order_release);
}

HapticLink* HapticLoop::linkInUse() const noexcept {
  // acquire: pairs with the tick's release store, so the supervisor frees only what is unused
  return in_use_.load(std::memory_order_acquire);
}

void HapticLoop::pushEvent(std::uint32_t code, double a, double b) noexcept {
  if (!shared::pushEvent(events_, shared::monotonicNs(), code, a, b)) {
    counters_.events_dropped.fetch_add(1, std::memory_order_relaxed);
  }
}

void HapticLoop::solveLocalModel(HapticLink& link, const shared::SnapshotView& snap,
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
  // the simulation publishes an exactly symmetric W (see pipeline.cpp)
  ns.coupling = shared::NsgsCoupling::kSymmetricRowUpdate;
  // same snapshot as the last solve: W and f are unchanged, so W f + delta_free only shifts by
  // the change of delta_free (saves a pass over W)
  if (link.delta_seq == hdr.seq) {
    double* delta = workspace.delta.data();
    for (int r = 0; r < m; ++r) delta[r] += delta_free[r] - link.last_delta_free[r];
    ns.delta_is_current = true;
  }
  const shared::NsgsResult res =
      shared::solveNsgs(snap.problem(delta_free.data()), ns, workspace, f.data());
  link.delta_seq = res.status == shared::NsgsStatus::kEmpty ? 0 : hdr.seq;
  std::copy_n(delta_free.begin(), m, link.last_delta_free.begin());
  out.sweeps = res.sweeps;
  out.residual = res.error;
  out.solve_ns = res.elapsed_ns;
  if (res.status == shared::NsgsStatus::kNonFinite) {   // NSGS has zeroed f
    counters_.non_finite_input.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  if (res.status != shared::NsgsStatus::kConverged) {
    out.flags |= shared::kStatsSolverNotConverged;
    counters_.solver_not_converged.fetch_add(1, std::memory_order_relaxed);
  }
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

TickOutput HapticLoop::tick(std::int64_t scheduled_ns, std::int64_t woken_ns) noexcept {
  TickOutput out;
  const std::int64_t now = woken_ns;
  const double dt =
      last_tick_ns_ > 0 ? std::clamp(1e-9 * static_cast<double>(now - last_tick_ns_), 1e-5, 0.05)
                        : 1e-3;
  last_tick_ns_ = now;

  // adopt a link offered by the supervisor (never waits)
  HapticLink* offered = offered_.load(std::memory_order_acquire);
  if (offered != link_) {
    link_ = offered;
    snapshot_seq_ = 0;
    stale_ = true;
    // release: the supervisor may now destroy the previous link
    in_use_.store(link_, std::memory_order_release);
    pushEvent(link_ != nullptr ? shared::kEventSegmentAttached : shared::kEventSegmentLost,
              link_ != nullptr ? static_cast<double>(link_->segment.generation()) : 0.0);
  }

  // device
  device::IoStatus io = device_.read(&state_);
  if (io == device::IoStatus::kOk && state_.t_ns > 0 &&
      now - state_.t_ns > static_cast<std::int64_t>(settings_.watchdog_ms * 1e6)) {
    // a sample stamped long ago: the device stopped updating (disconnected, stuck driver)
    counters_.stale_device_samples.fetch_add(1, std::memory_order_relaxed);
    io = device::IoStatus::kFault;
  }
  if (io == device::IoStatus::kOk) {
    if (finite(state_.pos_m) && std::isfinite(state_.quat_wxyz[0]) &&
        std::isfinite(state_.quat_wxyz[1]) && std::isfinite(state_.quat_wxyz[2]) &&
        std::isfinite(state_.quat_wxyz[3])) {
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
  } else {
    counters_.device_faults.fetch_add(1, std::memory_order_relaxed);
    if (!device_fault_) pushEvent(shared::kEventDeviceFault);
    device_fault_ = true;
    out.flags |= shared::kStatsDeviceFault;
  }

  // publish the device sample (pose held on no data, fault flagged)
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
               (gain_ < 1.0 && engaged_ ? shared::kDeviceForceFading : 0u);
    s.snapshot_seq = snapshot_seq_;
    link_->samples.publish();
  }

  // the newest snapshot, its age, and the local model
  bool stale = true;
  if (link_ != nullptr) {
    bool fresh = false;
    const shared::SnapshotView snap = link_->snapshots.latest(&fresh);
    const auto& hdr = snap.header();
    if (hdr.seq == 0) {
      out.flags |= shared::kStatsNoSnapshot;
    } else {
      const std::int64_t age = now - hdr.t_ns;
      const bool shutting = (hdr.flags & shared::kSnapshotShuttingDown) != 0;
      stale = age > static_cast<std::int64_t>(settings_.watchdog_ms * 1e6) || shutting ||
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

  // safety chain: scale, engage gate, fade, clamp, slew
  std::array<double, 3> force{};
  std::array<double, 3> torque{};
  for (int i = 0; i < 3; ++i) {
    force[i] = settings_.force_scale * out.force_n[i];
    torque[i] = settings_.render_torque ? settings_.force_scale * out.torque_nm[i] : 0.0;
  }
  if (!finite(force) || !finite(torque)) {
    force = {};
    torque = {};
  }
  out.unlimited_force_norm_n = norm3(force);
  const bool usable = !stale && have_pose_ && !device_fault_;
  if (!engaged_ && usable && out.unlimited_force_norm_n < settings_.engage_threshold_n) {
    engaged_ = true;
    pushEvent(kEventEngaged, out.unlimited_force_norm_n);
  }
  const double target_gain = (usable && engaged_) ? 1.0 : 0.0;
  const double ramp = settings_.fade_ms > 0.0 ? dt / (1e-3 * settings_.fade_ms) : 1.0;
  gain_ = target_gain > gain_ ? std::min(target_gain, gain_ + ramp)
                              : std::max(target_gain, gain_ - ramp);
  for (int i = 0; i < 3; ++i) {
    force[i] *= gain_;
    torque[i] *= gain_;
  }
  if (clampNorm(force, settings_.max_force_n)) {
    out.flags |= shared::kStatsForceClamped;
    counters_.clamped.fetch_add(1, std::memory_order_relaxed);
  }
  clampNorm(torque, settings_.max_torque_nm);
  slewLimit(force, last_force_n_, settings_.slew_n_per_s * dt);
  // the slew limiter never lets a faded command exceed the clamp
  clampNorm(force, settings_.max_force_n);
  out.force_n = force;
  out.torque_nm = torque;
  out.gain = gain_;
  last_force_n_ = force;
  last_torque_nm_ = torque;

  device::DeviceCommand cmd;
  cmd.force_n = force;
  cmd.torque_nm = torque;
  if (device_.write(cmd) != device::IoStatus::kOk) {
    counters_.write_faults.fetch_add(1, std::memory_order_relaxed);
  }

  // one stats record per tick
  if (link_ != nullptr) {
    shared::StatsRecord rec;
    rec.tick = tick_index_;
    rec.scheduled_ns = scheduled_ns;
    rec.woken_ns = woken_ns;
    rec.finished_ns = shared::monotonicNs();
    rec.solve_ns = out.solve_ns;
    rec.sweeps = out.sweeps;
    rec.residual = out.residual;
    rec.contacts = out.contacts;
    rec.force_norm_n = norm3(force);
    rec.snapshot_seq = snapshot_seq_;
    const bool overrun = rec.finished_ns - scheduled_ns > settings_.period_ns;
    rec.flags = out.flags | (overrun ? shared::kStatsOverrun : 0u);
    link_->stats.push(rec);
    link_->segment.beat(shared::Side::kHaptic, now);
  }
  ++tick_index_;
  counters_.ticks.fetch_add(1, std::memory_order_relaxed);
  return out;
}

}  // namespace tactus::haptic
