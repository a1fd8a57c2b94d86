// Test fixture: a plugin built against version 1 of the plugin ABI (its table ends after `info`,
// before the `halt` entry version 2 added): it must keep loading. A null device that reports a
// fixed pose.
#include <stddef.h>
#include <stdint.h>

#include <cstring>

#include "tactus/device/plugin_abi.h"

namespace {

// The version 1 table, as a plugin compiled against the old header declares it.
struct PluginTableV1 {
  uint32_t abi_version;
  uint32_t struct_size;
  const char* name;
  TactusDeviceHandle (*create)(const TactusKeyValue*, size_t, char*, size_t);
  void (*destroy)(TactusDeviceHandle);
  int (*open)(TactusDeviceHandle, char*, size_t);
  int (*calibrate)(TactusDeviceHandle, char*, size_t);
  int (*enable_forces)(TactusDeviceHandle, int, char*, size_t);
  void (*close)(TactusDeviceHandle);
  int (*read)(TactusDeviceHandle, TactusDeviceState*);
  int (*write)(TactusDeviceHandle, const TactusDeviceCommand*);
  int (*info)(TactusDeviceHandle, TactusDeviceInfo*);
};
static_assert(sizeof(PluginTableV1) == TACTUS_DEVICE_PLUGIN_V1_SIZE);

int g_instance = 0;

TactusDeviceHandle v1Create(const TactusKeyValue*, size_t, char*, size_t) { return &g_instance; }
void v1Destroy(TactusDeviceHandle) {}
int v1Ok(TactusDeviceHandle, char*, size_t) { return TACTUS_DEVICE_OK; }
int v1Enable(TactusDeviceHandle, int, char*, size_t) { return TACTUS_DEVICE_OK; }
void v1Close(TactusDeviceHandle) {}
int v1Read(TactusDeviceHandle, TactusDeviceState* out) {
  std::memset(out, 0, sizeof(*out));
  out->pos_m[2] = 0.25;
  out->quat_wxyz[0] = 1.0;
  return TACTUS_IO_OK;
}
int v1Write(TactusDeviceHandle, const TactusDeviceCommand*) { return TACTUS_IO_OK; }
int v1Info(TactusDeviceHandle, TactusDeviceInfo* out) {
  std::memset(out, 0, sizeof(*out));
  std::strcpy(out->model, "abi v1 plugin");
  return TACTUS_DEVICE_OK;
}

const PluginTableV1 kPlugin = {1u,      sizeof(PluginTableV1), "abi_v1", v1Create, v1Destroy,
                               v1Ok,    v1Ok,                  v1Enable, v1Close,  v1Read,
                               v1Write, v1Info};

}  // namespace

extern "C" const TactusDevicePlugin* tactus_device_plugin(void) {
  return reinterpret_cast<const TactusDevicePlugin*>(&kPlugin);
}
