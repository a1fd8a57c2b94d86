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

constexpr double kPi = 3.14159265358979323846;
std::atomic<int> g_replay_counter{0};

// The first recorded step (t_ns gap), or 10 ms when there is a single snapshot.
std::int64_t firstStepNs(const std::vector<shared::RecordedSnapshot>& s) {
  for (std::size_t i = 1; i < s.size(); ++i) {
    if (s[i].t_ns > s[i - 1].t_ns) return s[i].t_ns - s[i - 1].t_ns;
  }
  return 10'000'000;
}

std::vector<shared::PoseSample> devicePoses(const std::vector<shared::RecordedSnapshot>& s) {
  std::vector<shared::PoseSample> poses;
  poses.reserve(s.size());
  for (const auto& r : s) poses.push_back(r.header.device_pose);
  return poses;
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

}  // namespace

ReplayDevice::ReplayDevice(std::vector<shared::PoseSample> poses, double radius_m,
                           double freq_hz)
    : poses_(std::move(poses)),
      radius_m_(radius_m),
      omega_(2.0 * kPi * freq_hz),
      t0_ns_(shared::monotonicNs()) {
  if (poses_.empty()) poses_.emplace_back();
}

device::DeviceInfo ReplayDevice::info() const {
  device::DeviceInfo i;
  i.model = "jitter replay device";
  i.max_force_n = 8.0;
  i.max_stiffness_npm = 2000.0;
  i.workspace_radius_m = 0.1;
  return i;
}

device::IoStatus ReplayDevice::read(device::DeviceState* out) noexcept {
  const std::int64_t now = shared::monotonicNs();
  const double t = 1e-9 * static_cast<double>(now - t0_ns_);
  const double c = std::cos(omega_ * t);
  const double s = std::sin(omega_ * t);
  // relaxed: any recent index will do
  const std::size_t i = std::min(index_.load(std::memory_order_relaxed), poses_.size() - 1);
  const shared::PoseSample& centre = poses_[i];
  out->t_ns = now;
  out->pos_m = {centre.pos_m[0] + radius_m_ * (c - 1.0), centre.pos_m[1] + radius_m_ * s,
                centre.pos_m[2] - 0.5 * radius_m_ * (1.0 - c)};
  out->vel_mps = {-radius_m_ * omega_ * s, radius_m_ * omega_ * c, -0.5 * radius_m_ * omega_ * s};
  out->quat_wxyz = centre.quat_wxyz;
  out->angvel_radps = {0.0, 0.0, 0.0};
  out->gripper_rad = centre.gripper_rad;
  out->buttons = 0;
  return device::IoStatus::kOk;
}

device::IoStatus ReplayDevice::write(const device::DeviceCommand&) noexcept {
  return device::IoStatus::kOk;
}

ReplayRig::ReplayRig(std::vector<shared::RecordedSnapshot> snapshots, const ReplayOptions& options)
    : snapshots_(std::move(snapshots)),
      options_(options),
      segment_(shared::Segment::create(
          fmt::format("tactus-jitter-replay-{}-{}", static_cast<long>(::getpid()),
                      g_replay_counter++),
          capacityFor(snapshots_))),
      publisher_(segment_.snapshotPublisher()) {
  max_rows_ = segment_.capacity().max_rows;
  max_contacts_ = segment_.capacity().max_contacts;
  const std::int64_t step_ns = firstStepNs(snapshots_);
  pass_ns_ = snapshots_.back().t_ns - snapshots_.front().t_ns + step_ns;
  std::int64_t max_gap_ns = step_ns;
  for (std::size_t i = 1; i < snapshots_.size(); ++i) {
    max_gap_ns = std::max(max_gap_ns, snapshots_[i].t_ns - snapshots_[i - 1].t_ns);
  }
  settings_.period_ns = static_cast<std::int64_t>(std::llround(1e9 / options.rate_hz));
  settings_.solve_budget_ns = static_cast<std::int64_t>(options.solve_budget_fraction *
                                                        static_cast<double>(settings_.period_ns));
  settings_.max_sweeps = options.max_sweeps;
  // engage at once: the whole safety chain runs on every tick, as in a session in contact
  settings_.engage_threshold_n = 1e9;
  // three recorded steps without a snapshot fade out, as with the live simulation
  settings_.watchdog_ms = std::clamp(3e-6 * static_cast<double>(max_gap_ns), 50.0,
                                     HapticSettingsLimits::kMaxWatchdogMs);
  device_ = std::make_unique<ReplayDevice>(devicePoses(snapshots_));
  loop_ = std::make_unique<HapticLoop>(*device_, settings_);
  link_ = std::make_unique<HapticLink>(
      shared::Segment::open(segment_.name(), shared::Access::kReadWrite));
  core_ = options.core >= 0 ? options.core : shared::availableCpuCount() - 1;
  publish(0);
}

ReplayRig::~ReplayRig() { stop(); }

void ReplayRig::publish(std::size_t index) {
  shared::SnapshotWriter slot = publisher_.slot();
  const std::uint64_t seq = published_.load(std::memory_order_relaxed) + 1;
  snapshots_[index].writeTo(slot, seq, shared::monotonicNs());  // fits: capacity is the maximum
  slot.header().flags &= ~static_cast<std::uint32_t>(shared::kSnapshotShuttingDown);
  device_->follow(index);
  publisher_.publish();
  // relaxed: an informational counter
  published_.fetch_add(1, std::memory_order_relaxed);
  segment_.beat(shared::Side::kSim);
}

void ReplayRig::start() {
  if (running_) return;
  running_ = true;
  stop_.store(false);
  loop_->offerLink(link_.get());
  std::atomic<bool> ready{false};
  haptic_thread_ = std::thread([this, &ready] {
    rt_summary_ =
        shared::setupRealtimeThread(core_, options_.priority, shared::RealtimeConfig::kIgnore);
    ready.store(true);
    shared::PeriodicTimer timer(settings_.period_ns);
    // relaxed: the stop request only needs to be seen eventually
    while (!stop_.load(std::memory_order_relaxed)) {
      const shared::TimerTick t = timer.wait();
      loop_->tick(t.scheduled_ns, t.woken_ns);
    }
    (void)device_->write(device::DeviceCommand{});
  });
  while (!ready.load()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  publisher_thread_ = std::thread([this] {
    // snapshot i of pass k at origin + k * pass + (t_i - t_0); the first was published already
    const std::int64_t t_first = snapshots_.front().t_ns;
    std::int64_t origin = shared::monotonicNs();
    std::size_t i = 1;
    while (!stop_.load(std::memory_order_relaxed)) {
      if (i == snapshots_.size()) {
        passes_.fetch_add(1, std::memory_order_relaxed);
        if (!options_.loop) break;
        origin += pass_ns_;
        i = 0;
      }
      const std::int64_t due = origin + (snapshots_[i].t_ns - t_first);
      // short sleeps so that stop() is seen within 20 ms even across a long recorded gap
      while (!stop_.load(std::memory_order_relaxed) && shared::monotonicNs() < due) {
        shared::sleepUntilNs(std::min(due, shared::monotonicNs() + 20'000'000));
      }
      if (stop_.load(std::memory_order_relaxed)) break;
      publish(i);
      ++i;
    }
  });
}

void ReplayRig::stop() {
  if (!running_) return;
  stop_.store(true);
  if (haptic_thread_.joinable()) haptic_thread_.join();
  if (publisher_thread_.joinable()) publisher_thread_.join();
  running_ = false;
}

}  // namespace tactus::haptic::jitter
