/* Tactus haptic device plugin C ABI.
 *
 * An out-of-tree backend is a shared library that exports one C function:
 *
 *   extern "C" const TactusDevicePlugin* tactus_device_plugin(void);
 *
 * returning a pointer to a static table (below) that stays valid while the library is loaded.
 * haptic_server loads it with `--device /path/to/libmydevice.so` (or `--device mydevice` with
 * libmydevice.so on TACTUS_DEVICE_PATH) and passes `--device-option key=value` pairs to create().
 *
 * This header is plain C (C99) and self-contained: a plugin needs nothing else from Tactus, and
 * no C++ types cross the boundary. Errors are return codes plus a message written into a
 * caller-provided buffer (NUL-terminated, at most error_size bytes).
 *
 * Threading and real-time contract:
 *   - create, destroy, open, calibrate, enable_forces, close, info: called from a normal thread;
 *     they may block, allocate and take their time.
 *   - read and write: called once per haptic tick (1 kHz or more) from the real-time thread.
 *     They must not allocate, lock a mutex another thread may hold long, log, or block; return
 *     TACTUS_IO_NO_DATA when no new sample is available.
 *
 * Frames and units: SI units; device frame x toward the operator, z up; quaternion scalar first
 * (w, x, y, z); t_ns from CLOCK_MONOTONIC.
 *
 * Versioning: abi_version is TACTUS_DEVICE_PLUGIN_ABI_VERSION of the header the plugin was built
 * against and struct_size its sizeof(TactusDevicePlugin). This program loads version 2 (the
 * table below) and version 1 (the same table without `halt`, struct_size
 * TACTUS_DEVICE_PLUGIN_V1_SIZE): a plugin built for version 1 loads unchanged. Any other version
 * or size is refused. The `reserved` fields of TactusDeviceCommand and TactusDeviceInfo held a
 * gripper force, a stiffness and a workspace radius that nothing rendered or read; they keep
 * their place, so plugins built against either version keep loading.
 *
 * Exceptions: the entries are C functions. A C++ plugin must not let an exception escape them;
 * if one does anyway, the loader catches it at this boundary (read/write then report a fault
 * and the haptic loop fades the force out; the other entries fail with a message), so it never
 * reaches the real-time loop.
 */
#ifndef TACTUS_DEVICE_PLUGIN_ABI_H_
#define TACTUS_DEVICE_PLUGIN_ABI_H_

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define TACTUS_DEVICE_PLUGIN_ABI_VERSION 2u
#define TACTUS_DEVICE_PLUGIN_SYMBOL "tactus_device_plugin"

/* Return codes of open/calibrate/enable_forces/info. */
#define TACTUS_DEVICE_OK 0
#define TACTUS_DEVICE_ERROR 1

/* Return codes of read/write (same meaning as tactus::device::IoStatus). */
#define TACTUS_IO_OK 0
#define TACTUS_IO_NO_DATA 1
#define TACTUS_IO_FAULT 2

typedef struct TactusDeviceState {
  int64_t t_ns;              /* CLOCK_MONOTONIC time of the sample */
  double pos_m[3];
  double vel_mps[3];
  double quat_wxyz[4];
  double angvel_radps[3];
  double gripper_rad;
  uint32_t buttons;          /* bit i = button i pressed */
  uint32_t reserved;
} TactusDeviceState;

typedef struct TactusDeviceCommand {
  double force_n[3];
  double torque_nm[3];
  double reserved;           /* always 0 (the layout of ABI versions 1 and 2 kept) */
} TactusDeviceCommand;

typedef struct TactusDeviceInfo {
  char model[64];            /* NUL-terminated */
  double max_force_n;        /* continuous force limit; the haptic loop clamps to it */
  double reserved[2];        /* ignored (the layout of ABI versions 1 and 2 kept) */
  int32_t has_rotation;      /* 0 or 1 */
  int32_t has_gripper;       /* 0 or 1 */
} TactusDeviceInfo;

typedef struct TactusKeyValue {
  const char* key;
  const char* value;
} TactusKeyValue;

/* Opaque per-instance state owned by the plugin. */
typedef void* TactusDeviceHandle;

typedef struct TactusDevicePlugin {
  uint32_t abi_version;      /* TACTUS_DEVICE_PLUGIN_ABI_VERSION */
  uint32_t struct_size;      /* sizeof(TactusDevicePlugin) */
  const char* name;          /* short backend name, e.g. "spring" */

  /* Creates an instance from option pairs (options may be NULL when count is 0). Returns NULL
   * on failure with a message in error (e.g. an unknown option and the list of known ones). */
  TactusDeviceHandle (*create)(const TactusKeyValue* options, size_t count, char* error,
                               size_t error_size);
  void (*destroy)(TactusDeviceHandle handle);

  int (*open)(TactusDeviceHandle handle, char* error, size_t error_size);
  int (*calibrate)(TactusDeviceHandle handle, char* error, size_t error_size);
  int (*enable_forces)(TactusDeviceHandle handle, int on, char* error, size_t error_size);
  void (*close)(TactusDeviceHandle handle);

  /* Real-time: see the contract above. */
  int (*read)(TactusDeviceHandle handle, TactusDeviceState* out);
  int (*write)(TactusDeviceHandle handle, const TactusDeviceCommand* command);

  int (*info)(TactusDeviceHandle handle, TactusDeviceInfo* out);

  /* Since ABI version 2; may be NULL. Called from another (non-real-time) thread, possibly while
   * read or write is running, when haptic_server sees the real-time thread stuck in this
   * device's read or write for longer than its watchdog (a plugin that blocks, against the
   * contract above). It must be safe to call concurrently with read/write and must not block.
   * The plugin then stops rendering force (brings it to zero in the device's own safe way) and
   * makes the blocked read/write return (TACTUS_IO_FAULT), and later reads report
   * TACTUS_IO_FAULT until the device is usable again; the loop then fades the force out and
   * holds the pose. */
  void (*halt)(TactusDeviceHandle handle);
} TactusDevicePlugin;

/* The size of a version 1 table (everything before `halt`). */
#define TACTUS_DEVICE_PLUGIN_V1_SIZE offsetof(TactusDevicePlugin, halt)

/* The one symbol a plugin exports. */
typedef const TactusDevicePlugin* (*TactusDevicePluginEntry)(void);

#ifdef __cplusplus
}
#endif

#endif /* TACTUS_DEVICE_PLUGIN_ABI_H_ */
