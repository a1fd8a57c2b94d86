#include "tactus/device/backends.h"
#include "tactus/shared/clock.h"

namespace tactus::device {

NullDevice::NullDevice(const DeviceConfig& config) {
  OptionReader opt("null", config);
  has_pose_ = opt.has("pose");
  pose_ = opt.vec3("pose", {0.0, 0.0, 0.0}, 10.0);   // m, within any workspace
  opt.rejectUnknown();
}

DeviceInfo NullDevice::info() const {
  DeviceInfo i;
  i.model = "tactus null device";
  return i;
}

IoStatus NullDevice::read(DeviceState* out) noexcept {
  if (!has_pose_) return IoStatus::kNoData;
  // a fixed, motionless pose
  *out = DeviceState{};
  out->t_ns = shared::monotonicNs();
  out->pos_m = pose_;
  return IoStatus::kOk;
}

IoStatus NullDevice::write(const DeviceCommand&) noexcept { return IoStatus::kOk; }

}  // namespace tactus::device
