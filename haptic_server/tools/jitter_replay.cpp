// Replay of recorded contact snapshots through the in-process haptic loop (jitter tool).
#include "jitter_replay.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/rt.h"

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
    // snapshot i of pass k at origin + k * pass + (t_i - t_0); the first was published already
    const std::int64_t t_first = snapshots_.front().t_ns;
    std::int64_t origin = shared::monotonicNs();
    std::size_t i = 1;
    while (!rig_.stopRequested()) {
      if (i == snapshots_.size()) {
        passes_.fetch_add(1, std::memory_order_relaxed);
        if (!options_.loop) break;
        origin += pass_ns_;
        i = 0;
      }
      const std::int64_t due = origin + (snapshots_[i].t_ns - t_first);
      // short sleeps so that stop() is seen within 20 ms even across a long recorded gap
      while (!rig_.stopRequested() && shared::monotonicNs() < due) {
        shared::sleepUntilNs(std::min(due, shared::monotonicNs() + 20'000'000));
      }
      if (rig_.stopRequested()) break;
      publish(i);
      ++i;
    }
  });
}

}  // namespace tactus::haptic::jitter
