// Test fixture: exports tactus_device_plugin with an ABI version this build does not speak.
#include "tactus/device/plugin_abi.h"

namespace {
const TactusDevicePlugin kPlugin = {7u,
                                    sizeof(TactusDevicePlugin),
                                    "wrong_abi",
                                    nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr,
                                    nullptr, nullptr, nullptr};
}  // namespace

extern "C" const TactusDevicePlugin* tactus_device_plugin(void) { return &kPlugin; }
