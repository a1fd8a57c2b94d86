// Segment publishing for the haptic process.
#include "segment_host.h"
#include "obstacle_stage.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>


namespace tactus::sim {

namespace {

// Scales `v` down to at most `max_norm` without overflowing on huge components.
Eigen::Vector3d boundedNorm(Eigen::Vector3d v, double max_norm) {
  if (!v.allFinite()) return Eigen::Vector3d::Zero();
  const double m = v.cwiseAbs().maxCoeff();
  if (m <= max_norm / 2.0) return v;
  const double n = m * (v / m).norm();
  return n <= max_norm ? v : Eigen::Vector3d(v * (max_norm / n));
}

}  // namespace

namespace {

shared::SegmentCapacity capacityFor(const SceneSpec& spec, std::size_t devices) {
  shared::SegmentCapacity c = problemCapacity(spec);   // instruments' and obstacles' contacts
  c.devices = static_cast<std::int32_t>(std::max<std::size_t>(1, devices));
  return c;
}

}  // namespace

SegmentHost::SegmentHost(const std::string& name, const SceneSpec& spec,
                         std::vector<BoxSpec> workspaces)
    : segment_(shared::Segment::create(name, capacityFor(spec, workspaces.size()))),
      publisher_(segment_.snapshotPublisher()),
      watchdog_ns_(static_cast<std::int64_t>(spec.haptics.watchdog_ms * 1e6)) {
  for (std::size_t i = 0; i < workspaces.size(); ++i) {
    DeviceLink& d = devices_.emplace_back();
    d.reader = segment_.deviceReader(static_cast<int>(i));
    const int n = instrumentCount(spec);
    const double full_rad =
        static_cast<int>(i) < n ? instrumentSpec(spec, static_cast<int>(i)).max_opening_rad : 1.0;
    d.max_opening_rad = full_rad > 0.0 ? full_rad : 1.0;
    d.workspace = workspaces[i];
  }
  segment_.beat(shared::Side::kSim);
  if (!segment_.creationNote().empty()) spdlog::info("{}", segment_.creationNote());
  spdlog::info("segment '{}' created ({:.1f} MiB, up to {} contacts / {} rows)", name,
               static_cast<double>(segment_.sizeBytes()) / (1024.0 * 1024.0),
               segment_.capacity().max_contacts, segment_.capacity().max_rows);
}

SegmentHost::~SegmentHost() {
  // tell the haptic side to fade out now rather than after its watchdog: a snapshot like any
  // other (the next seq, stamped now, so readers see it as the newest) flagged shutting down
  if (publisher_.attached()) {
    auto slot = publisher_.slot();
    slot.header().seq = ++published_;
    slot.header().t_ns = shared::monotonicNs();
    slot.header().flags = shared::kSnapshotShuttingDown;
    slot.setSize(0, 0);
    publisher_.publish();
  }
}

bool deviceSampleFresh(const shared::DeviceSample& s, std::int64_t now_ns,
                       std::int64_t watchdog_ns, bool faulted_too) {
  std::int64_t age = 0;
  if (__builtin_sub_overflow(now_ns, s.t_ns, &age)) return false;
  // (a sample from the future is as untrustworthy as an old one)
  return s.seq != 0 && age < watchdog_ns && age > -watchdog_ns &&
         (faulted_too || (s.status & shared::kDeviceFault) == 0) &&
         (s.status & shared::kDevicePoseValid) != 0;
}

bool deviceTargetFromSample(const shared::DeviceSample& s, double max_opening_rad,
                            DeviceTarget& target) {
  const auto finite = [](const auto& a) {
    return std::all_of(a.begin(), a.end(), [](double x) { return std::isfinite(x); });
  };
  if (!finite(s.pos_m) || !finite(s.quat_wxyz)) return false;
  // orientation: scaled before normalising, so that huge components cannot overflow
  Eigen::Vector4d q(s.quat_wxyz[0], s.quat_wxyz[1], s.quat_wxyz[2], s.quat_wxyz[3]);
  const double q_max = q.cwiseAbs().maxCoeff();
  if (!(q_max > 0.0)) return false;
  q /= q_max;
  q.normalize();
  target.pose.pos_m = Eigen::Vector3d(s.pos_m[0], s.pos_m[1], s.pos_m[2]);
  target.pose.rot = Eigen::Quaterniond(q[0], q[1], q[2], q[3]);
  const Eigen::Vector3d v(s.vel_mps[0], s.vel_mps[1], s.vel_mps[2]);
  const Eigen::Vector3d w(s.angvel_radps[0], s.angvel_radps[1], s.angvel_radps[2]);
  target.twist.head<3>() = boundedNorm(v, kMaxDeviceSpeedMps);
  target.twist.tail<3>() = boundedNorm(w, kMaxDeviceAngularSpeedRadps);
  // the device's gripper angle maps onto the jaws' opening range
  const double full_rad = max_opening_rad > 0.0 ? max_opening_rad : 1.0;
  const double opening = std::isfinite(s.gripper_rad) ? s.gripper_rad / full_rad : 1.0;
  target.gripper_opening = std::clamp(opening, 0.0, 1.0);
  return true;
}

bool SegmentHost::deviceTarget(int i, DeviceTarget& target) {
  if (i < 0 || static_cast<std::size_t>(i) >= devices_.size()) return false;
  DeviceLink& d = devices_[static_cast<std::size_t>(i)];
  const shared::DeviceSample& s = d.reader.latest();
  const std::int64_t now = shared::monotonicNs();
  // A device that faults (the haptic side holds its last pose and fades its force) holds the
  // instrument where it was: going back to the script would move the instrument away from where
  // the hand still is, and on recovery the hand would meet tissue the local model did not have.
  if (d.have_good && (s.status & shared::kDeviceFault) != 0 &&
      deviceSampleFresh(s, now, watchdog_ns_, /*faulted_too=*/true)) {
    if (!d.holding_fault) {
      spdlog::info("device {} faults: the instrument holds its last target until it recovers", i);
      d.holding_fault = true;
    }
    target = d.last_good;
    return true;
  }
  d.holding_fault = false;
  const bool fresh = deviceSampleFresh(s, now, watchdog_ns_);
  // samples stopped while haptic_server lives (its device stalled, or a read blocks): the hand is
  // still where it was, so is the instrument
  const bool hold = !fresh && d.have_good && segment_.hapticAttached();
  if (fresh != d.device_active) {
    if (fresh) {
      spdlog::info("device samples arriving: the instrument follows the device (device {})", i);
    } else if (!hold) {
      spdlog::info("no fresh device sample: the instrument follows the scene's script (device {})",
                   i);
    }
    d.device_active = fresh;
  }
  if (!fresh) {
    if (hold) {
      if (!d.holding_stall) {
        spdlog::info("device {}'s samples stopped with haptic_server still attached: the "
                     "instrument holds its last target", i);
        d.holding_stall = true;
      }
      target = d.last_good;
      return true;
    }
    if (d.holding_stall) {
      spdlog::info("haptic_server is gone: the instrument follows the scene's script (device {})",
                   i);
      d.holding_stall = false;
    }
    d.have_good = false;   // the script took over: the next device sample starts afresh
    return false;
  }
  d.holding_stall = false;
  if (!d.have_good) {
    // the device takes over from the script: its first sample is judged against the script
    d.last_good = target;
    d.last_good.twist.setZero();
    d.last_good_ns = now;
    d.have_good = true;
  }
  DeviceTarget candidate = target;
  const bool usable = deviceTargetFromSample(s, d.max_opening_rad, candidate);
  // the raw position is judged (so 1e300 m never passes), the clamped one is used
  const double dt_s = 1e-9 * static_cast<double>(std::max<std::int64_t>(0, now - d.last_good_ns));
  const double allowed_m = kJumpAllowanceM + kMaxDeviceSpeedMps * dt_s;
  const Eigen::Vector3d jump = candidate.pose.pos_m - d.last_good.pose.pos_m;
  const double jump_scale = jump.cwiseAbs().maxCoeff();   // |jump| without overflow
  const double jump_m = jump_scale > 0.0 ? jump_scale * (jump / jump_scale).norm() : 0.0;
  if (!usable || jump_m > allowed_m) {
    // hold the last accepted target, at rest
    if (!d.rejecting) {
      if (usable) {
        spdlog::warn("implausible device sample (a jump of {:.3g} m in {:.3g} ms): rejected, "
                     "holding the last good target until samples are sane",
                     jump_m, 1e3 * dt_s);
      } else {
        spdlog::warn("unusable device sample (non-finite pose or zero orientation): holding the "
                     "last good target until samples are sane");
      }
      d.rejecting = true;
    }
    ++rejected_jumps_;
    target = d.last_good;
    return true;
  }
  if (d.rejecting) {
    spdlog::info("device samples plausible again: the instrument follows the device");
    d.rejecting = false;
  }
  const Eigen::Vector3d raw = candidate.pose.pos_m;
  candidate.pose.pos_m = raw.cwiseMax(d.workspace.min_m).cwiseMin(d.workspace.max_m);
  if (!(candidate.pose.pos_m == raw)) ++clamped_;
  target = candidate;
  d.device_seq = s.seq;
  ++samples_used_;
  d.last_good = target;
  d.last_good.twist.setZero();
  d.last_good_ns = now;
  return true;
}

std::string SegmentHost::displacedReason(std::int64_t now_ns) {
  if (now_ns < next_displacement_check_ns_) return {};
  next_displacement_check_ns_ = now_ns + kDisplacementCheckNs;
  if (segment_.stillCurrent()) return {};
  return "segment '" + segment_.name() + "' (" + shared::Segment::pathOf(segment_.name()) +
         ") no longer refers to the segment this simulation created (generation " +
         std::to_string(segment_.generation()) + "): it was removed or replaced, e.g. while this "
         "process was stopped; the haptic side cannot see this simulation any more, so it stops. "
         "Restart it (or pass another --segment name)";
}

void SegmentHost::publish(const Simulation& sim) {
  auto slot = publisher_.slot();
  if (!writeSnapshot(sim, devices_.empty() ? 1.0 : devices_[0].max_opening_rad, ++published_,
                     shared::monotonicNs(), devices_.empty() ? 0 : devices_[0].device_seq, slot)) {
    ++truncated_;
  }
  auto& hdr = slot.header();
  const auto blocks = static_cast<std::size_t>(std::max(0, hdr.instruments));
  for (std::size_t i = 0; i < devices_.size() && i < blocks; ++i) {
    hdr.instrument[i].device_seq = devices_[i].device_seq;
  }
  publisher_.publish();
  segment_.beat(shared::Side::kSim);
}

void SegmentHost::logStatus() {
  const std::int64_t beat = segment_.heartbeatNs(shared::Side::kHaptic);
  if (beat == 0) {
    spdlog::info("published {} snapshots; no haptic process attached yet", published_);
    return;
  }
  spdlog::info("published {} snapshots; haptic heartbeat {:.1f} ms ago; {} device samples used",
               published_, 1e-6 * static_cast<double>(shared::monotonicNs() - beat), samples_used_);
  if (truncated_ > 0) spdlog::warn("{} snapshots exceeded the segment capacity", truncated_);
  if (rejected_jumps_ > rejected_reported_) {
    spdlog::warn("{} implausible device samples rejected so far (jumps faster than {} m/s or a "
                 "zero orientation); {} clamped into the workspace",
                 rejected_jumps_, kMaxDeviceSpeedMps, clamped_);
    rejected_reported_ = rejected_jumps_;
  }
}

}  // namespace tactus::sim
