#pragma once
// The device-sample half of sim_server's haptic link (an application part, tactus::sim_app;
// sim_server/src/app/segment_host.h has the rest).

#include <cstdint>

#include "tactus/shared/messages.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {

/// The device-sample half of sim_server's haptic link (also used by tests that run the haptic
/// loop beside an in-process simulation): a sample is fresh when it was published (seq != 0),
/// is younger than watchdog_ns at now_ns, carries no device fault and carries a pose the device
/// delivered (shared::kDevicePoseValid: before its first real sample the haptic side publishes
/// a zero pose that must never move the instrument).
/// With `faulted_too` a sample flagged kDeviceFault counts too (its held pose is still the
/// device's last real one).
bool deviceSampleFresh(const shared::DeviceSample& s, std::int64_t now_ns,
                       std::int64_t watchdog_ns, bool faulted_too = false);
/// Fills `target` from a sample (pose, twist, gripper opening = gripper_rad / max_opening_rad
/// clamped to [0, 1]; max_opening_rad <= 0 counts as 1 rad); false, leaving `target` unchanged,
/// when the pose is not finite or the orientation is zero. The quaternion is normalised without
/// overflow and the twist bounded (segment_host.h); jumps and the workspace are the link's.
bool deviceTargetFromSample(const shared::DeviceSample& s, double max_opening_rad,
                            DeviceTarget& target);

}  // namespace tactus::sim
