// Device options per device (device_options.h).
#include "tactus/haptic/device_options.h"

#include <cctype>

#include "tactus/shared/error.h"

namespace tactus::haptic {

std::vector<device::DeviceConfig> splitDeviceOptions(const std::vector<std::string>& options,
                                                     std::size_t devices) {
  std::vector<device::DeviceConfig> configs(devices);
  for (const std::string& option : options) {
    // "I:" prefix: digits then a colon before any '='
    std::size_t digits = 0;
    while (digits < option.size() && std::isdigit(static_cast<unsigned char>(option[digits]))) {
      ++digits;
    }
    std::size_t device = 0;
    std::string_view kv = option;
    if (digits > 0 && digits < option.size() && option[digits] == ':') {
      if (digits > 3) throw Error("device option '" + option + "': no such device");
      device = std::stoul(option.substr(0, digits));
      kv.remove_prefix(digits + 1);
    }
    if (device >= devices) {
      throw Error("device option '" + option + "' is for device " + std::to_string(device) +
                  " but " + std::to_string(devices) + " device(s) are given (--device per device)");
    }
    device::addDeviceOption(configs[device], kv);
  }
  return configs;
}

}  // namespace tactus::haptic
