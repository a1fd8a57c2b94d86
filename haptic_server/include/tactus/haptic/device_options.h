#pragma once
// haptic_server's device options for several devices: `--device-option I:key=value` addresses
// device I (0-based), a plain `key=value` device 0 (so a one-device command line reads as
// before). Not real-time (runs once at start).

#include <cstddef>
#include <string>
#include <vector>

#include "tactus/device/device.h"

namespace tactus::haptic {

/// One DeviceConfig per device from the options in the order given. Throws tactus::Error when an
/// option names a device beyond `devices`, and device::DeviceError on a malformed key=value.
std::vector<device::DeviceConfig> splitDeviceOptions(const std::vector<std::string>& options,
                                                     std::size_t devices);

}  // namespace tactus::haptic
