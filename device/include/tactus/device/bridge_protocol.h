#pragma once
// The network device bridge protocol, version 1 (device/README.md, "Network device bridge"):
// UDP datagrams between a device process (a vendor SDK, the reference client tools/bridge_client/)
// and haptic_server's `bridge` backend. One message per datagram, little-endian, no padding:
//
//   header, 32 bytes
//     u32 magic          'T' 'C' 'T' 'B' (0x42544354 read as little-endian u32)
//     u16 version        1
//     u16 type           1 = state (device -> server), 2 = command (server -> device)
//     u64 seq            per sender, +1 for every message it sends (starts at 1)
//     i64 t_ns           the sender's CLOCK_MONOTONIC time of the message
//     u32 payload_bytes  120 for a state, 64 for a command
//     u32 reserved       0
//   state payload, 120 bytes (device frame, SI, see device.h)
//     f64 pos_m[3], f64 quat_wxyz[4] (unit within 1e-3), f64 vel_mps[3], f64 angvel_radps[3],
//     f64 gripper_rad, u32 buttons, u32 reserved (0)
//   command payload, 64 bytes
//     f64 force_n[3], f64 torque_nm[3], f64 reserved (0),
//     u64 state_seq      the newest state the server had accepted when it computed the force
//
// decode*() validate everything (sizes, magic, version, type, reserved fields, finite numbers,
// a unit quaternion, magnitudes within kMaxPositionM etc.) and never read past `size`; they are
// allocation-free and real-time safe.

#include <cstddef>
#include <cstdint>

#include "tactus/device/device.h"

namespace tactus::device::bridge {

inline constexpr std::uint32_t kMagic = 0x42544354u;   // "TCTB" in memory
inline constexpr std::uint16_t kVersion = 1;
inline constexpr std::uint16_t kTypeState = 1;
inline constexpr std::uint16_t kTypeCommand = 2;
inline constexpr std::size_t kHeaderBytes = 32;
inline constexpr std::size_t kStatePayloadBytes = 120;
inline constexpr std::size_t kCommandPayloadBytes = 64;
inline constexpr std::size_t kStateBytes = kHeaderBytes + kStatePayloadBytes;
inline constexpr std::size_t kCommandBytes = kHeaderBytes + kCommandPayloadBytes;
inline constexpr std::uint16_t kDefaultPort = 47000;

// plausibility bounds of a state (a larger value is a malformed packet)
inline constexpr double kMaxPositionM = 10.0;
inline constexpr double kMaxSpeedMps = 100.0;
inline constexpr double kMaxAngularSpeedRadps = 1e3;
inline constexpr double kMaxGripperRad = 10.0;
inline constexpr double kUnitTolerance = 1e-3;
// bound of a command's force and torque components (a device's clamp is far lower)
inline constexpr double kMaxCommandComponent = 1e3;

struct Header {
  std::uint16_t type = 0;
  std::uint64_t seq = 0;
  std::int64_t t_ns = 0;
};

/// Why a datagram was refused (kOk: accepted).
enum class DecodeStatus : std::uint8_t {
  kOk,
  kTooShort,
  kBadMagic,
  kBadVersion,
  kBadType,
  kBadSize,
  kBadReserved,
  kNonFinite,
  kOutOfRange,
  kNotUnitQuaternion,
};
const char* decodeStatusName(DecodeStatus s) noexcept;

/// Writes a state message into buf (at least kStateBytes); returns kStateBytes.
std::size_t encodeState(std::uint64_t seq, std::int64_t t_ns, const DeviceState& s,
                        unsigned char* buf) noexcept;
/// Writes a command message into buf (at least kCommandBytes); returns kCommandBytes.
std::size_t encodeCommand(std::uint64_t seq, std::int64_t t_ns, const DeviceCommand& c,
                          std::uint64_t state_seq, unsigned char* buf) noexcept;

/// Decodes a state datagram. On kOk fills header and state (quaternion normalised, t_ns = the
/// sender's stamp); otherwise leaves `state` unchanged.
DecodeStatus decodeState(const unsigned char* buf, std::size_t size, Header* header,
                         DeviceState* state) noexcept;
/// Decodes a command datagram (the client side).
DecodeStatus decodeCommand(const unsigned char* buf, std::size_t size, Header* header,
                           DeviceCommand* command, std::uint64_t* state_seq) noexcept;

}  // namespace tactus::device::bridge
