// Replay of recorded contact snapshots through the in-process haptic loop (jitter tool).
#include "jitter_replay.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/percentiles.h"
#include "tactus/shared/rt.h"
#include "tactus/haptic/local_model.h"

namespace tactus::haptic::jitter {
namespace {

std::atomic<int> g_replay_counter{0};

// The first recorded step (t_ns gap), or 10 ms when there is a single snapshot.
std::int64_t firstStepNs(const std::vector<shared::RecordedSnapshot>& s) {
  for (std::size_t i = 1; i < s.size(); ++i) {
    if (s[i].t_ns > s[i - 1].t_ns) return s[i].t_ns - s[i - 1].t_ns;
  }
  return 10'000'000;
}

// One device per instrument of the recording (its largest instrument count), each circling
// about its own instrument's device pose of each snapshot.
std::vector<std::unique_ptr<CircleDevice>> devicesFor(
    const std::vector<shared::RecordedSnapshot>& s) {
  int instruments = 1;
  for (const auto& r : s) instruments = std::max(instruments, r.header.instruments);
  std::vector<std::unique_ptr<CircleDevice>> devices;
  for (int i = 0; i < instruments; ++i) {
    std::vector<shared::PoseSample> poses;
    poses.reserve(s.size());
    for (const auto& r : s) {
      poses.push_back(i == 0 ? r.header.device_pose
                             : r.header.instrument[static_cast<std::size_t>(i)].device_pose);
    }
    const std::string model =
        i == 0 ? std::string("jitter replay device") : "jitter replay device " + std::to_string(i);
    devices.push_back(std::make_unique<CircleDevice>(std::move(poses), model));
  }
  return devices;
}

shared::SegmentCapacity capacityFor(const std::vector<shared::RecordedSnapshot>& s) {
  if (s.empty()) throw Error("replay: the snapshot file holds no snapshot");
  shared::SegmentCapacity c;
  for (const auto& r : s) {
    c.max_rows = std::max(c.max_rows, r.rows());
    c.max_contacts = std::max(c.max_contacts, r.contacts());
  }
  c.max_rows = std::max(c.max_rows, 3);
  c.max_contacts = std::max(c.max_contacts, 1);
  return c;
}

// Three recorded steps without a snapshot fade out, as with the live simulation.
double watchdogMs(const std::vector<shared::RecordedSnapshot>& s) {
  std::int64_t max_gap_ns = firstStepNs(s);
  for (std::size_t i = 1; i < s.size(); ++i) {
    max_gap_ns = std::max(max_gap_ns, s[i].t_ns - s[i - 1].t_ns);
  }
  return std::clamp(3e-6 * static_cast<double>(max_gap_ns), 50.0,
                    HapticSettingsLimits::kMaxWatchdogMs);
}

}  // namespace

ReplayRig::ReplayRig(std::vector<shared::RecordedSnapshot> snapshots, const ReplayOptions& options)
    : snapshots_(std::move(snapshots)),
      options_(options),
      rig_(fmt::format("tactus-jitter-replay-{}-{}", static_cast<long>(::getpid()),
                       g_replay_counter++),
           capacityFor(snapshots_),
           devicesFor(snapshots_),
           RigLoopOptions{options, watchdogMs(snapshots_)}) {
  pass_ns_ = snapshots_.back().t_ns - snapshots_.front().t_ns + firstStepNs(snapshots_);
  publish(0);
}

void ReplayRig::publish(std::size_t index) {
  rig_.publish([&](shared::SnapshotWriter slot, std::uint64_t seq) {
    snapshots_[index].writeTo(slot, seq, shared::monotonicNs());  // fits: capacity is the maximum
    slot.header().flags &= ~static_cast<std::uint32_t>(shared::kSnapshotShuttingDown);
    for (std::size_t i = 0; i < rig_.deviceCount(); ++i) rig_.device(i).follow(index);
  });
}

void ReplayRig::start() {
  rig_.start([this] {
    // each snapshot after its recorded gap from the one before it in play order; at an end of
    // the recording: stop, start over (the first snapshot one recorded step after the last) or
    // turn round. The first snapshot was published already.
    const std::size_t n = snapshots_.size();
    const std::int64_t first_step = firstStepNs(snapshots_);
    std::int64_t due = shared::monotonicNs();
    std::size_t current = 0;
    bool backwards = false;
    while (!rig_.stopRequested()) {
      std::size_t next = 0;
      std::int64_t gap = 0;
      if (!backwards && current + 1 < n) {
        next = current + 1;
        gap = snapshots_[next].t_ns - snapshots_[current].t_ns;
      } else if (backwards && current > 0) {
        next = current - 1;
        gap = snapshots_[current].t_ns - snapshots_[next].t_ns;
      } else {
        passes_.fetch_add(1, std::memory_order_relaxed);
        if (!options_.loop) break;
        if (options_.bounce && n > 1) {
          backwards = !backwards;
          continue;
        }
        next = 0;
        gap = first_step;
      }
      due += std::max<std::int64_t>(gap, 0);
      // short sleeps so that stop() is seen within 20 ms even across a long recorded gap
      while (!rig_.stopRequested() && shared::monotonicNs() < due) {
        shared::sleepUntilNs(std::min(due, shared::monotonicNs() + 20'000'000));
      }
      if (rig_.stopRequested()) break;
      publish(next);
      current = next;
    }
  });
}

OfflineReplayReport replayOffline(const std::vector<shared::RecordedSnapshot>& snapshots,
                                  const OfflineReplayOptions& options) {
  const shared::SegmentCapacity cap = capacityFor(snapshots);
  const shared::SnapshotLayout layout =
      shared::SnapshotLayout::forCapacity(cap.max_rows, cap.max_contacts);
  std::vector<unsigned char> bytes(layout.total_bytes + shared::kCacheLineBytes);
  const auto misalign = reinterpret_cast<std::uintptr_t>(bytes.data()) % shared::kCacheLineBytes;
  unsigned char* base = bytes.data() + (shared::kCacheLineBytes - misalign) % shared::kCacheLineBytes;
  OfflineLocalModel model(cap.max_rows, cap.max_contacts, options.settings);
  LocalModelSettings ref_settings = options.settings;
  ref_settings.kind = LocalModelKind::kFull;
  ref_settings.tolerance = options.reference_tolerance;
  ref_settings.max_sweeps = 100'000;
  OfflineLocalModel full(cap.max_rows, cap.max_contacts, ref_settings);
  // the replay device's path about each snapshot's recorded pose
  std::vector<std::unique_ptr<CircleDevice>> devices = devicesFor(snapshots);
  CircleDevice& device = *devices.front();
  const std::int64_t period = static_cast<std::int64_t>(std::llround(1e9 / options.rate_hz));
  const std::int64_t latency = static_cast<std::int64_t>(std::llround(options.latency_ms * 1e6));
  const std::int64_t t_first = snapshots.front().t_ns;
  const std::int64_t pass = snapshots.back().t_ns - t_first + firstStepNs(snapshots);
  OfflineReplayReport rep;
  std::vector<double> held;
  std::vector<std::array<double, 3>> model_f, full_f;
  std::size_t next = 0;
  bool adopted = false;
  for (int k = 0; k < options.passes; ++k) {
    next = 0;
    for (std::int64_t t = 0; t < pass; t += period) {
      // the device: the circle about the newest snapshot's pose at time t (as CircleDevice)
      while (next < snapshots.size() && snapshots[next].t_ns - t_first + latency <= t) ++next;
      if (next == 0) continue;
      const std::size_t i = next - 1;
      std::size_t shown = i;   // the snapshot whose pose the device follows
      while (options.device_leads && shown + 1 < snapshots.size() &&
             snapshots[shown + 1].t_ns - t_first <= t) {
        ++shown;
      }
      device.follow(shown);
      device::DeviceState st;
      (void)device.readAt(t, &st);
      shared::Pose pose;
      pose.pos_m = Eigen::Vector3d(st.pos_m[0], st.pos_m[1], st.pos_m[2]);
      pose.rot = Eigen::Quaterniond(st.quat_wxyz[0], st.quat_wxyz[1], st.quat_wxyz[2],
                                    st.quat_wxyz[3]).normalized();
      const shared::Pose* poses[] = {&pose};
      if (!adopted || model.prepared().seq() != i + 1) {
        shared::SnapshotWriter slot(base, layout);
        snapshots[i].writeTo(slot, i + 1, t);
        (void)model.adopt(slot.view(), poses);
        (void)full.adopt(slot.view(), poses);
        rep.prepare_ms.push_back(1e-6 * static_cast<double>(model.prepared().prepareNs()));
        adopted = true;
      }
      const LocalModelResult r = model.solve(poses);
      const LocalModelResult ref = full.solve(poses);
      if (!r.solved()) continue;
      ++rep.ticks;
      rep.converged += r.converged() ? 1 : 0;
      rep.linearized += r.used == LocalModelUsed::kLinearized ? 1 : 0;
      rep.corrected += r.used == LocalModelUsed::kCorrected ? 1 : 0;
      rep.fallbacks += r.used == LocalModelUsed::kFallback ? 1 : 0;
      rep.full += r.used == LocalModelUsed::kFull ? 1 : 0;
      ++rep.fallback_reasons[static_cast<std::size_t>(r.fallback)];
      rep.reference_not_converged += ref.converged() ? 0 : 1;
      rep.solve_us.push_back(1e-3 * static_cast<double>(r.elapsed_ns));
      model_f.push_back(r.force_n[0]);
      full_f.push_back(ref.force_n[0]);
      held.push_back(std::hypot(ref.force_n[0][0], ref.force_n[0][1], ref.force_n[0][2]));
    }
  }
  if (held.empty()) return rep;
  rep.held_force_n = shared::percentile(held, 0.5);
  for (std::size_t j = 0; j < model_f.size(); ++j) {
    const double d = std::hypot(model_f[j][0] - full_f[j][0], model_f[j][1] - full_f[j][1],
                                model_f[j][2] - full_f[j][2]);
    rep.force_error.push_back(rep.held_force_n > 0.0 ? d / rep.held_force_n : 0.0);
  }
  return rep;
}

}  // namespace tactus::haptic::jitter
