#include <cmath>

#include "tactus/device/backends.h"
#include "tactus/shared/clock.h"

namespace tactus::device {

ReplayDevice::ReplayDevice(const DeviceConfig& config) {
  OptionReader opt("replay", config);
  const std::string file = opt.text("file");
  loop_ = opt.flag("loop", false);
  speed_ = opt.number("speed", 1.0, 1e-3, 1e3);
  opt.rejectUnknown();
  if (file.empty()) {
    throw DeviceError("device 'replay' needs a trajectory: --device-option file=PATH.csv (format "
                      "t_s,x,y,z,qw,qx,qy,qz,gripper; record one with --device-option "
                      "record=PATH.csv)");
  }
  trajectory_ = Trajectory::loadCsv(file);
}

DeviceInfo ReplayDevice::info() const {
  DeviceInfo i;
  i.model = "tactus trajectory replay";
  i.has_rotation = true;
  i.has_gripper = true;
  return i;
}

void ReplayDevice::open() { openAt(shared::monotonicNs()); }

void ReplayDevice::openAt(std::int64_t t_ns) {
  t0_ns_ = t_ns;
  opened_ = true;
}

IoStatus ReplayDevice::read(DeviceState* out) noexcept {
  return readAt(shared::monotonicNs(), out);
}

IoStatus ReplayDevice::readAt(std::int64_t t_ns, DeviceState* out) noexcept {
  if (!opened_) return IoStatus::kNoData;
  double t = shared::nsToSeconds(t_ns - t0_ns_) * speed_;
  const double d = trajectory_.durationS();
  if (loop_ && d > 0.0) t = std::fmod(t, d);
  trajectory_.sample(trajectory_.points().front().t_s + t, out);
  if (!loop_ && t > d) {
    out->vel_mps = {0.0, 0.0, 0.0};
    out->angvel_radps = {0.0, 0.0, 0.0};
  }
  for (auto& v : out->vel_mps) v *= speed_;
  for (auto& w : out->angvel_radps) w *= speed_;
  out->t_ns = t_ns;
  out->buttons = 0;
  return IoStatus::kOk;
}

IoStatus ReplayDevice::write(const DeviceCommand&) noexcept { return IoStatus::kOk; }

}  // namespace tactus::device
