// Test fixture: a device plugin that misbehaves on request, for the fault suite of the hand
// (tests/security/hand_fault_test.cpp) and the loader's tests. Its hand follows a scripted path
// and, from fault_at_ms into its path for fault_ms, breaks the device contract in one way:
//
//   path=T:x,y,z;T:x,y,z;...   positions (m) at path times (ms after open() while no gate has
//                              held the hand, below), linear in between, the
//                              last one held (default: the origin)
//   fault=KIND                 none (default), silent (read: no data), fault (read: fault),
//                              stall (one read sleeps stall_ms), block (read blocks until halt),
//                              throw (read throws), throw_write (write throws), zero_quat (a zero
//                              quaternion), nan (a NaN position)
//   fault_at_ms, fault_ms      when and how long (defaults 1000, 200); a halted block faults for
//                              fault_ms after the halt, then the device recovers
//   stall_ms                   the stall (default 45)
//   halt=0|1                   whether halt() unblocks a blocked read (default 1; 0 plays a
//                              driver that cannot be interrupted)
//   create_error=unterminated  create() fails and fills the whole error buffer without a NUL
//   report=FILE                open() writes its time (the path's origin, CLOCK_MONOTONIC ns)
//                              to FILE, one line; each gate passed (below) appends a line with
//                              the path's origin from then on (the moment it passed, minus the
//                              gate's path time)
//   gates=T,T,...              path times (ms, increasing) at which the hand waits, holding
//                              its pose, until gate_file has more lines than the gates passed:
//                              a test lets the hand go on once the state it needs is there (the
//                              press rendered), however slowly a loaded machine got there.
//                              Times above (the path, fault_at_ms) are the path's, which
//                              stands still while the hand waits at a gate
//   gate_file=FILE             the file a test appends a line to for each gate it opens
//
// Everything here is deliberately outside the real-time contract when a fault asks for it.
#include "tactus/device/plugin_abi.h"

#include <time.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <new>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

enum class Fault { kNone, kSilent, kFault, kStall, kBlock, kThrow, kThrowWrite, kZeroQuat, kNan };

struct Key {
  double t_ms;
  double p[3];
};

struct Hand {
  std::vector<Key> path;
  Fault fault = Fault::kNone;
  double fault_at_ms = 1000.0, fault_ms = 200.0, stall_ms = 45.0;
  bool honour_halt = true;
  std::string report;                       ///< where open() writes t0_ns
  std::int64_t t0_ns = 0;
  std::vector<double> gates;                ///< path times (ms) at which the hand waits
  std::string gate_file;                    ///< a line per gate opened
  std::size_t gates_passed = 0;
  double waited_ms = 0.0;                   ///< time spent waiting at gates
  double path_ms = 0.0;                     ///< the path's time at the last read()
  bool stalled = false;                     ///< the one stall happened
  std::atomic<bool> halted{false};
  std::atomic<std::int64_t> halted_ns{0};
};

std::int64_t nowNs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000 + ts.tv_nsec;
}

void setError(char* error, size_t size, const std::string& text) {
  if (error != nullptr && size > 0) std::snprintf(error, size, "%s", text.c_str());
}

bool parsePath(const char* text, std::vector<Key>* out) {
  const char* at = text;
  while (*at != '\0') {
    Key k{};
    int used = 0;
    if (std::sscanf(at, "%lf:%lf,%lf,%lf%n", &k.t_ms, &k.p[0], &k.p[1], &k.p[2], &used) != 4) {
      return false;
    }
    if (!out->empty() && !(k.t_ms > out->back().t_ms)) return false;
    out->push_back(k);
    at += used;
    if (*at == ';') ++at;
  }
  return !out->empty();
}

TactusDeviceHandle faultCreate(const TactusKeyValue* options, size_t count, char* error,
                               size_t error_size) {
  auto* h = new (std::nothrow) Hand;
  if (h == nullptr) return nullptr;
  for (size_t i = 0; i < count; ++i) {
    const std::string key = options[i].key, value = options[i].value;
    bool ok = true;
    if (key == "path") {
      ok = parsePath(value.c_str(), &h->path);
    } else if (key == "fault") {
      const char* names[] = {"none", "silent", "fault", "stall", "block",
                             "throw", "throw_write", "zero_quat", "nan"};
      ok = false;
      for (int f = 0; f < 9; ++f) {
        if (value == names[f]) {
          h->fault = static_cast<Fault>(f);
          ok = true;
        }
      }
    } else if (key == "fault_at_ms") {
      h->fault_at_ms = std::atof(value.c_str());
    } else if (key == "fault_ms") {
      h->fault_ms = std::atof(value.c_str());
    } else if (key == "stall_ms") {
      h->stall_ms = std::atof(value.c_str());
    } else if (key == "halt") {
      h->honour_halt = value != "0";
    } else if (key == "report") {
      h->report = value;
    } else if (key == "gates") {
      const char* at = value.c_str();
      while (ok && *at != '\0') {
        char* end = nullptr;
        const double t = std::strtod(at, &end);
        ok = end != at && (h->gates.empty() || t > h->gates.back());
        if (ok) h->gates.push_back(t);
        at = end != nullptr && *end == ',' ? end + 1 : end;
      }
    } else if (key == "gate_file") {
      h->gate_file = value;
    } else if (key == "create_error" && value == "unterminated") {
      if (error != nullptr) std::memset(error, 'E', error_size);   // no terminating NUL
      delete h;
      return nullptr;
    } else {
      ok = false;
    }
    if (!ok) {
      setError(error, error_size, "fault plugin: bad option '" + key + "=" + value + "'");
      delete h;
      return nullptr;
    }
  }
  if (h->path.empty()) h->path.push_back({0.0, {0.0, 0.0, 0.0}});
  if (!h->gates.empty() && h->gate_file.empty()) {
    setError(error, error_size, "fault plugin: gates need gate_file");
    delete h;
    return nullptr;
  }
  return h;
}

void faultDestroy(TactusDeviceHandle h) { delete static_cast<Hand*>(h); }
int faultOpen(TactusDeviceHandle handle, char* error, size_t error_size) {
  Hand& h = *static_cast<Hand*>(handle);
  h.t0_ns = nowNs();
  if (!h.report.empty()) {
    std::FILE* f = std::fopen(h.report.c_str(), "w");
    if (f == nullptr || std::fprintf(f, "%lld\n", static_cast<long long>(h.t0_ns)) < 0 ||
        std::fclose(f) != 0) {
      setError(error, error_size, "fault plugin: cannot write " + h.report);
      return TACTUS_DEVICE_ERROR;
    }
  }
  return TACTUS_DEVICE_OK;
}
int faultCalibrate(TactusDeviceHandle, char*, size_t) { return TACTUS_DEVICE_OK; }
int faultEnableForces(TactusDeviceHandle, int, char*, size_t) { return TACTUS_DEVICE_OK; }
void faultClose(TactusDeviceHandle) {}

void position(const Hand& h, double t_ms, double* p) {
  const std::vector<Key>& k = h.path;
  if (t_ms <= k.front().t_ms) {
    std::memcpy(p, k.front().p, sizeof(k.front().p));
    return;
  }
  for (std::size_t i = 1; i < k.size(); ++i) {
    if (t_ms <= k[i].t_ms) {
      const double a = (t_ms - k[i - 1].t_ms) / (k[i].t_ms - k[i - 1].t_ms);
      for (int j = 0; j < 3; ++j) p[j] = k[i - 1].p[j] + a * (k[i].p[j] - k[i - 1].p[j]);
      return;
    }
  }
  std::memcpy(p, k.back().p, sizeof(k.back().p));
}

// Lines in the gate file (the gates the test has opened so far).
std::size_t gatesOpened(const Hand& h) {
  std::FILE* f = std::fopen(h.gate_file.c_str(), "r");
  if (f == nullptr) return 0;
  std::size_t lines = 0;
  for (int c = std::fgetc(f); c != EOF; c = std::fgetc(f)) lines += c == '\n' ? 1 : 0;
  std::fclose(f);
  return lines;
}

// The path's time now (ms): the time since open() less the time spent waiting at gates; at a
// closed gate it stays at the gate's time.
double pathMs(Hand& h) {
  const std::int64_t now = nowNs();
  const double since_open_ms = 1e-6 * static_cast<double>(now - h.t0_ns);
  double t = since_open_ms - h.waited_ms;
  if (h.gates_passed < h.gates.size() && t >= h.gates[h.gates_passed]) {
    const double gate = h.gates[h.gates_passed];
    h.waited_ms = since_open_ms - gate;
    t = gate;
    if (gatesOpened(h) > h.gates_passed) {
      ++h.gates_passed;
      if (!h.report.empty()) {   // the path's origin from now on
        if (std::FILE* f = std::fopen(h.report.c_str(), "a"); f != nullptr) {
          std::fprintf(f, "%lld\n",
                       static_cast<long long>(now - static_cast<std::int64_t>(gate * 1e6)));
          std::fclose(f);
        }
      }
    }
  }
  h.path_ms = t;
  return t;
}

void sleepMs(double ms) {
  timespec ts{static_cast<time_t>(ms / 1000.0),
              static_cast<long>(std::fmod(ms, 1000.0) * 1e6)};
  nanosleep(&ts, nullptr);
}

int faultRead(TactusDeviceHandle handle, TactusDeviceState* out) {
  Hand& h = *static_cast<Hand*>(handle);
  const double t_ms = pathMs(h);
  const std::int64_t halted_ns = h.halted_ns.load();
  if (halted_ns != 0) {   // after a halt: faulty for fault_ms, then usable again
    if (1e-6 * static_cast<double>(nowNs() - halted_ns) < h.fault_ms) return TACTUS_IO_FAULT;
  }
  const bool in_fault = t_ms >= h.fault_at_ms && t_ms < h.fault_at_ms + h.fault_ms;
  if (in_fault) {
    switch (h.fault) {
      case Fault::kSilent: return TACTUS_IO_NO_DATA;
      case Fault::kFault: return TACTUS_IO_FAULT;
      case Fault::kThrow: throw std::runtime_error("fault plugin: read() throws on purpose");
      case Fault::kStall:
        if (!h.stalled) {
          h.stalled = true;
          sleepMs(h.stall_ms);
        }
        break;
      case Fault::kBlock:
        if (halted_ns == 0) {
          // blocks (against the contract) until halted, forever when halt is not honoured
          while (!(h.honour_halt && h.halted.load())) sleepMs(1.0);
          return TACTUS_IO_FAULT;
        }
        break;
      default: break;
    }
  }
  std::memset(out, 0, sizeof(*out));
  out->t_ns = nowNs();
  position(h, t_ms, out->pos_m);
  out->quat_wxyz[0] = 1.0;
  if (in_fault && h.fault == Fault::kZeroQuat) out->quat_wxyz[0] = 0.0;
  if (in_fault && h.fault == Fault::kNan) out->pos_m[1] = std::nan("");
  return TACTUS_IO_OK;
}

int faultWrite(TactusDeviceHandle handle, const TactusDeviceCommand*) {
  Hand& h = *static_cast<Hand*>(handle);
  const double t_ms = h.path_ms;   // read()'s, just before this write
  if (h.fault == Fault::kThrowWrite && t_ms >= h.fault_at_ms && t_ms < h.fault_at_ms + h.fault_ms) {
    throw std::runtime_error("fault plugin: write() throws on purpose");
  }
  return TACTUS_IO_OK;
}

int faultInfo(TactusDeviceHandle, TactusDeviceInfo* out) {
  std::memset(out, 0, sizeof(*out));
  std::snprintf(out->model, sizeof(out->model), "fault plugin");
  out->max_force_n = 10.0;
  return TACTUS_DEVICE_OK;
}

void faultHalt(TactusDeviceHandle handle) {
  Hand& h = *static_cast<Hand*>(handle);
  if (!h.honour_halt) return;
  h.halted_ns.store(nowNs());
  h.halted.store(true);
}

const TactusDevicePlugin kPlugin = {
    TACTUS_DEVICE_PLUGIN_ABI_VERSION, sizeof(TactusDevicePlugin), "fault",
    faultCreate, faultDestroy, faultOpen, faultCalibrate, faultEnableForces, faultClose,
    faultRead, faultWrite, faultInfo, faultHalt};

}  // namespace

extern "C" __attribute__((visibility("default"))) const TactusDevicePlugin* tactus_device_plugin(
    void) {
  return &kPlugin;
}
