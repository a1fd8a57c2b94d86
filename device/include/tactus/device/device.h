#pragma once
// Haptic device backend interface (docs/design.md section 5.1) and the backend loader.
//
// Lifecycle (non-real-time, may allocate, log and throw tactus::DeviceError with a message that
// says what to do): construct (loadDevice) -> open() -> calibrate() -> enableForces(true) ->
// ... ticks ... -> enableForces(false) -> close().
//
// Real-time, once per haptic tick: read() then write(). They are noexcept and never allocate,
// lock, log, block or throw; a problem is an IoStatus. read() returning kNoData leaves `out`
// unchanged (the caller holds the last pose).
//
// Frames and units: SI; device frame x toward the operator, z up; quaternion unit, scalar first;
// t_ns from CLOCK_MONOTONIC (tactus::shared::monotonicNs()).

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "tactus/shared/error.h"

namespace tactus::device {

/// One device sample. Trivially copyable.
struct DeviceState {
  std::int64_t t_ns = 0;                           ///< CLOCK_MONOTONIC time of the sample
  std::array<double, 3> pos_m{};
  std::array<double, 3> vel_mps{};
  std::array<double, 4> quat_wxyz{1.0, 0.0, 0.0, 0.0};
  std::array<double, 3> angvel_radps{};
  double gripper_rad = 0.0;                        ///< jaw opening angle
  std::uint32_t buttons = 0;                       ///< bit i = button i pressed
};

/// The wrench to render on the hand (device frame).
struct DeviceCommand {
  std::array<double, 3> force_n{};
  std::array<double, 3> torque_nm{};
};

/// What the device can do (chai3d's spec struct).
struct DeviceInfo {
  std::string model;
  double max_force_n = 0.0;          ///< continuous force limit; the haptic loop clamps to it
  bool has_rotation = false;
  bool has_gripper = false;
};

enum class IoStatus : std::uint8_t { kOk, kNoData, kFault };

/// Backend options from `--device-option key=value` (repeated).
using DeviceConfig = std::map<std::string, std::string>;

class Device {
 public:
  virtual ~Device() = default;

  // non-RT: may allocate, log, throw DeviceError
  virtual DeviceInfo info() const = 0;
  virtual void open() = 0;
  virtual void calibrate() = 0;
  virtual void enableForces(bool on) = 0;
  virtual void close() noexcept = 0;

  // RT, once per tick: no allocation, locks, logging, blocking system calls, or throw
  [[nodiscard]] virtual IoStatus read(DeviceState* out) noexcept = 0;
  [[nodiscard]] virtual IoStatus write(const DeviceCommand& cmd) noexcept = 0;

  /// Non-real-time, from another thread, possibly while read() or write() runs on the
  /// real-time thread (haptic_server's supervisor calls it when the tick has been stuck in this
  /// device's read or write past its watchdog): stop rendering force and make a blocked read or
  /// write return; later reads report kFault until the device is usable again. Must not block.
  /// Returns false when the backend cannot (the default: its read and write never block).
  virtual bool halt() noexcept { return false; }
  /// Non-real-time: what went wrong inside read()/write() since the last call that the loop's
  /// status codes cannot say (e.g. a plugin's exception caught at the C boundary), for the log;
  /// empty when nothing.
  virtual std::string takeDiagnostics() { return {}; }
};

/// Names of the built-in backends ("bridge", "null", "replay", "simulated").
std::vector<std::string> builtinDeviceNames();

/// The default backend: "simulated".
inline constexpr std::string_view kDefaultDevice = "simulated";

/// Creates a backend (not opened yet):
///   - a built-in name: "simulated" (default), "replay", "null", "bridge" (bridge_device.h);
///   - a path to a plugin .so (contains '/' or ends in ".so");
///   - another name X: libX.so searched in $TACTUS_DEVICE_PATH (':'-separated), then by the
///     dynamic loader's usual search.
/// Option `record=FILE.csv` (any backend) wraps the device in a recorder that writes every sample
/// read, in the replay CSV format, from a non-real-time thread; `record_commands=FILE.csv` makes
/// it write every command the device receives too (RecordingDevice).
/// Throws DeviceError: unknown backend, missing file, missing symbol, wrong ABI, bad options.
std::unique_ptr<Device> loadDevice(std::string_view name_or_path, const DeviceConfig& config = {});

/// Parses "key=value" into config (throws DeviceError on a missing '=' or an empty key).
void addDeviceOption(DeviceConfig& config, std::string_view key_equals_value);

}  // namespace tactus::device
