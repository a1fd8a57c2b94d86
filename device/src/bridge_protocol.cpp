// Encoding and validation of the bridge protocol (tactus/device/bridge_protocol.h).
#include "tactus/device/bridge_protocol.h"

#include <bit>
#include <cmath>
#include <cstring>

namespace tactus::device::bridge {
namespace {

// the layouts of bridge_protocol.h: 14 doubles + buttons + reserved; 7 doubles + state_seq;
static_assert(kStatePayloadBytes == 14 * sizeof(double) + 2 * sizeof(std::uint32_t));
static_assert(kCommandPayloadBytes == 7 * sizeof(double) + sizeof(std::uint64_t));
static_assert(kHeaderBytes == 4 + 2 + 2 + 8 + 8 + 4 + 4);   // magic .. reserved
static_assert(std::endian::native == std::endian::little,
              "the bridge protocol is little-endian; add byte swapping for this host");

class Writer {
 public:
  explicit Writer(unsigned char* p) : p_(p) {}
  template <class T>
  void put(T v) noexcept {
    std::memcpy(p_ + at_, &v, sizeof v);
    at_ += sizeof v;
  }
  template <class T, std::size_t N>
  void put(const std::array<T, N>& a) noexcept {
    for (const T& v : a) put(v);
  }
  std::size_t size() const noexcept { return at_; }

 private:
  unsigned char* p_;
  std::size_t at_ = 0;
};

class Reader {
 public:
  explicit Reader(const unsigned char* p) : p_(p) {}
  template <class T>
  T get() noexcept {
    T v;
    std::memcpy(&v, p_ + at_, sizeof v);
    at_ += sizeof v;
    return v;
  }
  template <std::size_t N>
  void get(std::array<double, N>& a) noexcept {
    for (double& v : a) v = get<double>();
  }

 private:
  const unsigned char* p_;
  std::size_t at_ = 0;
};

void putHeader(Writer& w, std::uint16_t type, std::uint64_t seq, std::int64_t t_ns,
               std::uint32_t payload) noexcept {
  w.put(kMagic);
  w.put(kVersion);
  w.put(type);
  w.put(seq);
  w.put(t_ns);
  w.put(payload);
  w.put(std::uint32_t{0});
}

DecodeStatus getHeader(std::size_t size, std::uint16_t want_type,
                       std::size_t want_payload, Header* h, Reader& r) noexcept {
  if (size < kHeaderBytes) return DecodeStatus::kTooShort;
  if (r.get<std::uint32_t>() != kMagic) return DecodeStatus::kBadMagic;
  if (r.get<std::uint16_t>() != kVersion) return DecodeStatus::kBadVersion;
  h->type = r.get<std::uint16_t>();
  if (h->type != want_type) return DecodeStatus::kBadType;
  h->seq = r.get<std::uint64_t>();
  h->t_ns = r.get<std::int64_t>();
  if (h->t_ns < 0) return DecodeStatus::kOutOfRange;   // CLOCK_MONOTONIC is never negative
  const auto payload = r.get<std::uint32_t>();
  if (payload != want_payload || size != kHeaderBytes + want_payload) {
    return DecodeStatus::kBadSize;
  }
  if (r.get<std::uint32_t>() != 0) return DecodeStatus::kBadReserved;
  return DecodeStatus::kOk;
}

template <std::size_t N>
bool finiteWithin(const std::array<double, N>& a, double bound) noexcept {
  for (double v : a) {
    if (!(std::abs(v) <= bound)) return false;
  }
  return true;
}

template <std::size_t N>
bool allFinite(const std::array<double, N>& a) noexcept {
  for (double v : a) {
    if (!std::isfinite(v)) return false;
  }
  return true;
}

}  // namespace

const char* decodeStatusName(DecodeStatus s) noexcept {
  switch (s) {
    case DecodeStatus::kOk: return "ok";
    case DecodeStatus::kTooShort: return "too short";
    case DecodeStatus::kBadMagic: return "bad magic";
    case DecodeStatus::kBadVersion: return "unsupported version";
    case DecodeStatus::kBadType: return "unexpected message type";
    case DecodeStatus::kBadSize: return "wrong size";
    case DecodeStatus::kBadReserved: return "reserved field not zero";
    case DecodeStatus::kNonFinite: return "non-finite number";
    case DecodeStatus::kOutOfRange: return "value out of range";
    case DecodeStatus::kNotUnitQuaternion: return "quaternion not unit";
  }
  return "?";
}

std::size_t encodeState(std::uint64_t seq, std::int64_t t_ns, const DeviceState& s,
                        unsigned char* buf) noexcept {
  Writer w(buf);
  putHeader(w, kTypeState, seq, t_ns, kStatePayloadBytes);
  w.put(s.pos_m);
  w.put(s.quat_wxyz);
  w.put(s.vel_mps);
  w.put(s.angvel_radps);
  w.put(s.gripper_rad);
  w.put(s.buttons);
  w.put(std::uint32_t{0});
  return w.size();   // == kStateBytes (checked by the tests)
}

std::size_t encodeCommand(std::uint64_t seq, std::int64_t t_ns, const DeviceCommand& c,
                          std::uint64_t state_seq, unsigned char* buf) noexcept {
  Writer w(buf);
  putHeader(w, kTypeCommand, seq, t_ns, kCommandPayloadBytes);
  w.put(c.force_n);
  w.put(c.torque_nm);
  w.put(0.0);  // reserved
  w.put(state_seq);
  return w.size();
}

DecodeStatus decodeState(const unsigned char* buf, std::size_t size, Header* header,
                         DeviceState* state) noexcept {
  Reader r(buf);
  Header h;
  const DecodeStatus hs = getHeader(size, kTypeState, kStatePayloadBytes, &h, r);
  if (hs != DecodeStatus::kOk) return hs;
  DeviceState s;
  r.get(s.pos_m);
  r.get(s.quat_wxyz);
  r.get(s.vel_mps);
  r.get(s.angvel_radps);
  s.gripper_rad = r.get<double>();
  s.buttons = r.get<std::uint32_t>();
  if (r.get<std::uint32_t>() != 0) return DecodeStatus::kBadReserved;
  if (!allFinite(s.pos_m) || !allFinite(s.quat_wxyz) || !allFinite(s.vel_mps) ||
      !allFinite(s.angvel_radps) || !std::isfinite(s.gripper_rad)) {
    return DecodeStatus::kNonFinite;
  }
  if (!finiteWithin(s.pos_m, kMaxPositionM) || !finiteWithin(s.vel_mps, kMaxSpeedMps) ||
      !finiteWithin(s.angvel_radps, kMaxAngularSpeedRadps) ||
      !(std::abs(s.gripper_rad) <= kMaxGripperRad)) {
    return DecodeStatus::kOutOfRange;
  }
  double n2 = 0.0;
  for (double q : s.quat_wxyz) n2 += q * q;
  const double n = std::sqrt(n2);
  if (!(std::abs(n - 1.0) <= kUnitTolerance)) return DecodeStatus::kNotUnitQuaternion;
  for (double& q : s.quat_wxyz) q /= n;
  s.t_ns = h.t_ns;
  *header = h;
  *state = s;
  return DecodeStatus::kOk;
}

DecodeStatus decodeCommand(const unsigned char* buf, std::size_t size, Header* header,
                           DeviceCommand* command, std::uint64_t* state_seq) noexcept {
  Reader r(buf);
  Header h;
  const DecodeStatus hs = getHeader(size, kTypeCommand, kCommandPayloadBytes, &h, r);
  if (hs != DecodeStatus::kOk) return hs;
  DeviceCommand c;
  r.get(c.force_n);
  r.get(c.torque_nm);
  const auto reserved = r.get<double>();
  const auto seq = r.get<std::uint64_t>();
  if (reserved != 0.0) return DecodeStatus::kBadReserved;  // a NaN is not 0 either
  if (!allFinite(c.force_n) || !allFinite(c.torque_nm)) return DecodeStatus::kNonFinite;
  if (!finiteWithin(c.force_n, kMaxCommandComponent) ||
      !finiteWithin(c.torque_nm, kMaxCommandComponent)) {
    return DecodeStatus::kOutOfRange;
  }
  *header = h;
  *command = c;
  *state_seq = seq;
  return DecodeStatus::kOk;
}

}  // namespace tactus::device::bridge
