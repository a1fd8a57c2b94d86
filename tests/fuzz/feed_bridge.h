#pragma once
// Fuzz target for the network device bridge decoder (device/bridge_protocol.h), shared by the
// libFuzzer harness (bridge_fuzz.cpp) and the regression test (tests/unit/device).
//
// Contract checked: decodeState/decodeCommand never read past the datagram and accept only
// what the protocol allows: an accepted state has finite fields within the protocol's bounds, a
// unit quaternion and a non-negative time stamp; an accepted command finite bounded values; a
// refused datagram leaves the output untouched. A violation escapes as std::logic_error.

#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "tactus/device/bridge_protocol.h"

namespace tactus::fuzz {

/// Decodes `bytes` as a state and as a command (a copy of exactly that size, so a sanitizer sees
/// any over-read). Returns true when either decoded.
inline bool feedBridge(const std::string& bytes) {
  namespace bridge = device::bridge;
  const std::vector<unsigned char> datagram(bytes.begin(), bytes.end());
  const unsigned char* data = datagram.empty() ? nullptr : datagram.data();
  bridge::Header h;
  device::DeviceState s;
  s.pos_m = {123.0, 0.0, 0.0};
  const bridge::DecodeStatus st = bridge::decodeState(data, datagram.size(), &h, &s);
  if (st == bridge::DecodeStatus::kOk) {
    if (datagram.size() != bridge::kStateBytes) throw std::logic_error("state of wrong size");
    double n2 = 0.0;
    for (double q : s.quat_wxyz) n2 += q * q;
    if (!(std::abs(std::sqrt(n2) - 1.0) < 1e-12)) throw std::logic_error("quaternion not unit");
    for (double p : s.pos_m) {
      if (!(std::abs(p) <= bridge::kMaxPositionM)) throw std::logic_error("position unbounded");
    }
    for (double v : s.vel_mps) {
      if (!(std::abs(v) <= bridge::kMaxSpeedMps)) throw std::logic_error("speed unbounded");
    }
    if (!(std::abs(s.gripper_rad) <= bridge::kMaxGripperRad) || s.t_ns < 0 || h.t_ns < 0) {
      throw std::logic_error("gripper or time stamp out of range");
    }
  } else if (s.pos_m[0] != 123.0) {
    throw std::logic_error("a refused state changed the output");
  }
  device::DeviceCommand c;
  std::uint64_t state_seq = 0;
  const bridge::DecodeStatus ct = bridge::decodeCommand(data, datagram.size(), &h, &c, &state_seq);
  if (ct == bridge::DecodeStatus::kOk) {
    if (datagram.size() != bridge::kCommandBytes) throw std::logic_error("command of wrong size");
    for (double f : c.force_n) {
      if (!(std::abs(f) <= bridge::kMaxCommandComponent)) {
        throw std::logic_error("force unbounded");
      }
    }
  }
  return st == bridge::DecodeStatus::kOk || ct == bridge::DecodeStatus::kOk;
}

}  // namespace tactus::fuzz
