// Example Tactus device plugin: a handle held by a virtual spring.
//
// The handle rests at `rest=x,y,z` (m) and is held there by a spring of `stiffness` (N/m): the
// force rendered through write() displaces it quasi-statically by F / stiffness. Enough to show
// every entry of the C ABI; a real driver would talk to its hardware in read()/write().
//
// Rules the example follows: no allocation, locking or I/O in read()/write(); errors as return
// codes plus a message; only tactus_device_plugin is exported.

#include <tactus/device/plugin_abi.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <new>

namespace {

struct Spring {
  double stiffness_npm = 500.0;
  double rest_m[3] = {0.0, 0.0, 0.0};
  double force_n[3] = {0.0, 0.0, 0.0};
  bool open = false;
  bool forces = false;
};

int64_t nowNs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1000000000 + ts.tv_nsec;
}

void setError(char* error, size_t size, const char* text) {
  if (error != nullptr && size > 0) std::snprintf(error, size, "%s", text);
}

bool parseNumber(const char* text, double* out) {
  char* end = nullptr;
  *out = std::strtod(text, &end);
  return end != text && *end == '\0' && std::isfinite(*out);
}

TactusDeviceHandle springCreate(const TactusKeyValue* options, size_t count, char* error,
                          size_t error_size) {
  Spring s;
  for (size_t i = 0; i < count; ++i) {
    const char* key = options[i].key;
    const char* value = options[i].value;
    if (std::strcmp(key, "stiffness") == 0) {
      if (!parseNumber(value, &s.stiffness_npm) || s.stiffness_npm <= 0.0) {
        setError(error, error_size, "option stiffness must be a number > 0 (N/m)");
        return nullptr;
      }
    } else if (std::strcmp(key, "rest") == 0) {
      if (std::sscanf(value, "%lf,%lf,%lf", &s.rest_m[0], &s.rest_m[1], &s.rest_m[2]) != 3) {
        setError(error, error_size, "option rest must be x,y,z in metres");
        return nullptr;
      }
    } else {
      char msg[160];
      std::snprintf(msg, sizeof(msg), "unknown option '%s' (known: stiffness, rest)", key);
      setError(error, error_size, msg);
      return nullptr;
    }
  }
  return new (std::nothrow) Spring(s);
}

void springDestroy(TactusDeviceHandle h) { delete static_cast<Spring*>(h); }

int springOpen(TactusDeviceHandle h, char*, size_t) {
  static_cast<Spring*>(h)->open = true;
  return TACTUS_DEVICE_OK;
}

int springCalibrate(TactusDeviceHandle h, char* error, size_t error_size) {
  if (!static_cast<Spring*>(h)->open) {
    setError(error, error_size, "calibrate before open");
    return TACTUS_DEVICE_ERROR;
  }
  return TACTUS_DEVICE_OK;
}

int springEnableForces(TactusDeviceHandle h, int on, char*, size_t) {
  static_cast<Spring*>(h)->forces = on != 0;
  return TACTUS_DEVICE_OK;
}

void springClose(TactusDeviceHandle h) { static_cast<Spring*>(h)->open = false; }

int springRead(TactusDeviceHandle h, TactusDeviceState* out) {
  const Spring* s = static_cast<const Spring*>(h);
  if (!s->open) return TACTUS_IO_NO_DATA;
  std::memset(out, 0, sizeof(*out));
  out->t_ns = nowNs();
  for (int i = 0; i < 3; ++i) {
    const double f = s->forces ? s->force_n[i] : 0.0;
    out->pos_m[i] = s->rest_m[i] + f / s->stiffness_npm;
  }
  out->quat_wxyz[0] = 1.0;
  return TACTUS_IO_OK;
}

int springWrite(TactusDeviceHandle h, const TactusDeviceCommand* cmd) {
  Spring* s = static_cast<Spring*>(h);
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(cmd->force_n[i])) return TACTUS_IO_FAULT;
  }
  for (int i = 0; i < 3; ++i) s->force_n[i] = cmd->force_n[i];
  return TACTUS_IO_OK;
}

int springInfo(TactusDeviceHandle h, TactusDeviceInfo* out) {
  const Spring* s = static_cast<const Spring*>(h);
  std::memset(out, 0, sizeof(*out));
  std::snprintf(out->model, sizeof(out->model), "example spring (k=%.0f N/m)", s->stiffness_npm);
  out->max_force_n = 5.0;
  return TACTUS_DEVICE_OK;
}

// halt (the last entry) is NULL: read and write never block, so the loop is never stuck in them.
const TactusDevicePlugin kPlugin = {
    TACTUS_DEVICE_PLUGIN_ABI_VERSION, sizeof(TactusDevicePlugin), "spring",
    springCreate, springDestroy, springOpen, springCalibrate, springEnableForces, springClose,
    springRead, springWrite, springInfo, nullptr};

}  // namespace

extern "C" __attribute__((visibility("default"))) const TactusDevicePlugin* tactus_device_plugin(
    void) {
  return &kPlugin;
}
