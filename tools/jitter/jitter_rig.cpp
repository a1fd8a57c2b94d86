// The jitter tool's in-process rig: segment, real-time haptic thread, publisher thread, device.
#include "jitter_rig.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>

#include "tactus/shared/clock.h"
#include "tactus/shared/rt.h"

namespace tactus::haptic::jitter {

CircleDevice::CircleDevice(std::vector<shared::PoseSample> centres, std::string model,
                           double radius_m, double freq_hz)
    : centres_(std::move(centres)),
      model_(std::move(model)),
      radius_m_(radius_m),
      omega_(2.0 * std::numbers::pi * freq_hz),
      t0_ns_(shared::monotonicNs()) {
  if (centres_.empty()) centres_.emplace_back();
}

device::DeviceInfo CircleDevice::info() const {
  device::DeviceInfo i;
  i.model = model_;
  i.max_force_n = 8.0;
  return i;
}

device::IoStatus CircleDevice::read(device::DeviceState* out) noexcept {
  const std::int64_t now = shared::monotonicNs();
  const device::IoStatus io = readAt(now - t0_ns_, out);
  out->t_ns = now;
  return io;
}

device::IoStatus CircleDevice::readAt(std::int64_t t_ns, device::DeviceState* out) const noexcept {
  const double t = 1e-9 * static_cast<double>(t_ns);
  const double c = std::cos(omega_ * t);
  const double s = std::sin(omega_ * t);
  // relaxed: any recent index will do
  const std::size_t i = std::min(index_.load(std::memory_order_relaxed), centres_.size() - 1);
  const shared::PoseSample& centre = centres_[i];
  // a small circle starting at the centre, pressing in by up to one radius
  out->t_ns = t_ns;
  out->pos_m = {centre.pos_m[0] + radius_m_ * (c - 1.0), centre.pos_m[1] + radius_m_ * s,
                centre.pos_m[2] - 0.5 * radius_m_ * (1.0 - c)};
  out->vel_mps = {-radius_m_ * omega_ * s, radius_m_ * omega_ * c, -0.5 * radius_m_ * omega_ * s};
  out->quat_wxyz = centre.quat_wxyz;
  out->angvel_radps = {0.0, 0.0, 0.0};
  out->gripper_rad = centre.gripper_rad;
  out->buttons = 0;
  return device::IoStatus::kOk;
}

device::IoStatus CircleDevice::write(const device::DeviceCommand&) noexcept {
  // relaxed: a counter read after the threads stop
  writes_.fetch_add(1, std::memory_order_relaxed);
  return device::IoStatus::kOk;
}

namespace {

std::vector<std::unique_ptr<CircleDevice>> one(std::unique_ptr<CircleDevice> device) {
  std::vector<std::unique_ptr<CircleDevice>> v;
  v.push_back(std::move(device));
  return v;
}

shared::SegmentCapacity withDevices(shared::SegmentCapacity c, std::size_t devices) {
  c.devices = static_cast<std::int32_t>(devices);
  return c;
}

}  // namespace

LoopRig::LoopRig(const std::string& segment_name, const shared::SegmentCapacity& capacity,
                 std::unique_ptr<CircleDevice> device, const RigLoopOptions& options)
    : LoopRig(segment_name, capacity, one(std::move(device)), options) {}

LoopRig::LoopRig(const std::string& segment_name, shared::SegmentCapacity capacity,
                 std::vector<std::unique_ptr<CircleDevice>> devices, const RigLoopOptions& options)
    : options_(options),
      segment_(shared::Segment::create(segment_name, withDevices(capacity, devices.size()))),
      publisher_(segment_.snapshotPublisher()),
      devices_(std::move(devices)) {
  settings_.period_ns = static_cast<std::int64_t>(std::llround(1e9 / options.rate_hz));
  settings_.solve_budget_ns = static_cast<std::int64_t>(options.solve_budget_fraction *
                                                        static_cast<double>(settings_.period_ns));
  settings_.max_sweeps = options.max_sweeps;
  settings_.local_model = options.local_model;
  settings_.anderson_depth = options.anderson_depth;
  settings_.reduced_fallback = options.reduced_fallback;
  settings_.active_set_correction = options.active_set_correction;
  settings_.snapshot_blend_ms = options.snapshot_blend_ms;
  settings_.engage_threshold_n = 1e9;
  settings_.watchdog_ms = options.watchdog_ms;
  std::vector<device::Device*> ptrs;
  for (const auto& d : devices_) ptrs.push_back(d.get());
  loop_ = std::make_unique<HapticLoop>(ptrs, settings_);
  link_ = std::make_unique<AttachedSegment>(
      shared::Segment::open(segment_.name(), shared::Access::kReadWrite));
  link_->preparer.start(settings_.localModel());   // as haptic_server: off the real-time thread
  core_ = options.core >= 0 ? options.core : shared::availableCpuCount() - 1;
}

LoopRig::~LoopRig() { stop(); }

void LoopRig::publish(const std::function<void(shared::SnapshotWriter, std::uint64_t)>& fill) {
  fill(publisher_.slot(), published_.load(std::memory_order_relaxed) + 1);
  publisher_.publish();
  // relaxed: an informational counter
  published_.fetch_add(1, std::memory_order_relaxed);
  segment_.beat(shared::Side::kSim);
}

void LoopRig::start(std::function<void()> publisher) {
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
    for (const auto& d : devices_) (void)d->write(device::DeviceCommand{});
  });
  while (!ready.load()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  publisher_thread_ = std::thread(std::move(publisher));
}

void LoopRig::stop() {
  if (!running_) return;
  stop_.store(true);
  if (haptic_thread_.joinable()) haptic_thread_.join();
  if (publisher_thread_.joinable()) publisher_thread_.join();
  running_ = false;
}

}  // namespace tactus::haptic::jitter
