#pragma once
// The device side of the network bridge for tests: a UDP socket on loopback that sends state
// datagrams (well-formed or not) to a bridge backend and receives its commands.

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <cstdint>
#include <vector>

#include "tactus/device/bridge_protocol.h"

namespace tactus::test {

class BridgeSender {
 public:
  explicit BridgeSender(std::uint16_t port) {
    fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    to_.sin_family = AF_INET;
    to_.sin_port = htons(port);
    ::inet_pton(AF_INET, "127.0.0.1", &to_.sin_addr);
    timeval tv{5, 0};   // receive() gives up after 5 s (a missing command fails the test)
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  }
  ~BridgeSender() { ::close(fd_); }
  BridgeSender(const BridgeSender&) = delete;
  BridgeSender& operator=(const BridgeSender&) = delete;

  void sendBytes(const void* data, std::size_t size) {
    ASSERT_EQ(::sendto(fd_, data, size, 0, reinterpret_cast<const sockaddr*>(&to_), sizeof to_),
              static_cast<ssize_t>(size));
  }
  /// A valid state with the given seq, stamp and position.
  void sendState(std::uint64_t seq, std::int64_t t_ns, std::array<double, 3> pos_m,
                 std::uint32_t buttons = 0) {
    device::DeviceState s;
    s.pos_m = pos_m;
    s.buttons = buttons;
    sendBytes(encoded(seq, t_ns, s).data(), device::bridge::kStateBytes);
  }
  static std::vector<unsigned char> encoded(std::uint64_t seq, std::int64_t t_ns,
                                            const device::DeviceState& s) {
    std::vector<unsigned char> b(device::bridge::kStateBytes);
    device::bridge::encodeState(seq, t_ns, s, b.data());
    return b;
  }
  /// Waits for one command datagram (up to 5 s); false if none arrived or it did not decode.
  bool receive(device::DeviceCommand* cmd, std::uint64_t* state_seq, int flags = 0) {
    unsigned char buf[256];
    const ssize_t n = ::recv(fd_, buf, sizeof buf, flags);
    if (n <= 0) return false;
    device::bridge::Header h;
    return device::bridge::decodeCommand(buf, static_cast<std::size_t>(n), &h, cmd, state_seq) ==
           device::bridge::DecodeStatus::kOk;
  }
  /// Waits for a command, then takes every queued one: the newest (false if none decoded).
  bool receiveNewest(device::DeviceCommand* cmd, std::uint64_t* state_seq) {
    if (!receive(cmd, state_seq)) return false;
    while (receive(cmd, state_seq, MSG_DONTWAIT)) {
    }
    return true;
  }

 private:
  int fd_ = -1;
  sockaddr_in to_{};
};

}  // namespace tactus::test
