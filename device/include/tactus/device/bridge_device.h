#pragma once
// `bridge`: a device driven over the network by another process (a vendor SDK on this or another
// machine; the reference client is tools/bridge_client/). Protocol: tactus/device/bridge_protocol.h,
// documented in device/README.md.
//
// Options (--device-option key=value):
//   bind=ADDR        IPv4 address to listen on (default 127.0.0.1). A non-loopback address is
//                    refused unless allow_remote=1 is given too (the port accepts poses from
//                    anyone who can reach it).
//   port=N           UDP port (default 47000; 0: any free port, see port()).
//   timeout_ms=T     silence longer than this is a fault (default 50, in (0, 10000]): read()
//                    returns kFault and the haptic loop holds the pose and fades the force out.
//   late_ms=T        a state arriving more than this after its time stamp (against the fastest
//                    one seen, so clocks of another machine cancel out) is counted late
//                    (default 10, in (0, 10000]). It is still used if it is the newest.
//   max_force=N      the remote device's force limit, reported by info() (default 10, (0, 100]).
//   rotation=0|1, gripper=0|1   what the remote device has (info(); default 0).
//
// Sessions: the bridge follows one sender (IPv4 address and UDP port) at a time. The first
// valid state starts a session with its sender; while the session is live (a state accepted
// within timeout_ms), states from any other sender are dropped (counted `foreign`), and states
// of the session's sender must stay within a sane window: seq at most kMaxSeqStep ahead of the
// newest, a time stamp that does not run ahead of the time elapsed here by more than timeout_ms
// (a datagram outside it is dropped, `out_of_window`). Once the session has been silent past
// timeout_ms it ends and the next valid state, from any sender, starts a new one: a restarted
// client (a new port) takes over after the old one's timeout; a client restarted on the same
// port (a lower seq, a later sane stamp) at once (`restarts`). A session never starts on a seq or
// time stamp beyond kMaxSaneValue. So one datagram cannot take the device from a live client,
// and a second sender cannot interleave with it.
//
// read() never blocks: it drains up to kMaxDatagramsPerRead datagrams from a non-blocking
// socket into a preallocated buffer, validates each (a malformed one is counted and dropped),
// applies the session rules above, classifies sequence numbers (lost, duplicated, reordered),
// and returns the newest state: kOk if one arrived, kNoData while quiet (the loop holds the last
// pose), kFault once quiet for longer than timeout_ms. The returned t_ns is on this machine's clock (the sender's stamp plus the
// smallest receive-minus-send offset seen). write() sends the command to the address the newest
// state came from, non-blocking; a send that would block or fails is counted, never waited for.
// No allocation, lock or logging in read() and write().

#include <sys/socket.h>
#include <netinet/in.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <string>

#include "tactus/device/bridge_protocol.h"
#include "tactus/device/device.h"

namespace tactus::device {

/// Counters of a bridge (relaxed atomics, read by any thread).
struct BridgeCounters {
  std::atomic<std::uint64_t> accepted{0};      ///< states used (each newer than the last)
  std::atomic<std::uint64_t> lost{0};          ///< sequence gaps not filled by a later arrival
  std::atomic<std::uint64_t> duplicated{0};    ///< a sequence number received twice
  std::atomic<std::uint64_t> reordered{0};     ///< arrived after a newer one (dropped)
  std::atomic<std::uint64_t> late{0};          ///< accepted but late (late_ms)
  std::atomic<std::uint64_t> malformed{0};     ///< refused by the protocol checks (dropped)
  std::atomic<std::uint64_t> silences{0};      ///< times the sender went quiet past timeout_ms
  std::atomic<std::uint64_t> restarts{0};      ///< new sessions after the first one
  /// states from another sender than the live session's (dropped)
  std::atomic<std::uint64_t> foreign{0};
  /// states of the session's sender whose seq or time stamp leaves the sane window (dropped)
  std::atomic<std::uint64_t> out_of_window{0};
  std::atomic<std::uint64_t> commands_sent{0};
  std::atomic<std::uint64_t> send_failures{0}; ///< commands not sent (would block, no route)
};

class BridgeDevice final : public Device {
 public:
  static constexpr int kMaxDatagramsPerRead = 64;
  /// Largest seq step within a session (a live session is at most timeout_ms <= 10 s silent: no
  /// real sender skips a million datagrams in that time).
  static constexpr std::uint64_t kMaxSeqStep = std::uint64_t{1} << 20;
  /// A session never starts on a seq or a time stamp beyond this (2^62: 146 years of ns).
  static constexpr std::uint64_t kMaxSaneValue = std::uint64_t{1} << 62;

  explicit BridgeDevice(const DeviceConfig& config = {});
  ~BridgeDevice() override;
  BridgeDevice(const BridgeDevice&) = delete;
  BridgeDevice& operator=(const BridgeDevice&) = delete;

  DeviceInfo info() const override;
  /// Opens and binds the socket (throws DeviceError saying why, e.g. the port is in use).
  void open() override;
  void calibrate() override {}
  void enableForces(bool on) override { forces_on_ = on; }
  void close() noexcept override;
  IoStatus read(DeviceState* out) noexcept override;
  IoStatus write(const DeviceCommand& cmd) noexcept override;

  /// read() with an explicit local time (tests): silence and lateness are judged at now_ns.
  IoStatus readAt(std::int64_t now_ns, DeviceState* out) noexcept;

  /// The bound UDP port (after open()).
  std::uint16_t port() const noexcept { return port_; }
  const std::string& bindAddress() const noexcept { return bind_; }
  const BridgeCounters& counters() const noexcept { return counters_; }
  /// One line with every counter (non-real-time; for status lines).
  std::string describeCounters() const;

 private:
  void take(const bridge::Header& h, const DeviceState& s, const sockaddr_in& from,
            std::int64_t now_ns) noexcept;
  /// Starts a session with `from` (its first state is taken by take()).
  void startSession(const bridge::Header& h, const sockaddr_in& from, std::int64_t now_ns) noexcept;

  std::string bind_;
  std::uint16_t port_ = 0;
  bool allow_remote_ = false;
  std::int64_t timeout_ns_ = 0;
  std::int64_t late_ns_ = 0;
  double max_force_n_ = 10.0;
  bool has_rotation_ = false;
  bool has_gripper_ = false;
  bool forces_on_ = false;
  int fd_ = -1;

  // real-time state (the haptic thread only)
  std::array<unsigned char, 2048> buf_{};
  DeviceState newest_{};
  bool have_state_ = false;          ///< a state was accepted in this session
  bool had_session_ = false;         ///< a session existed before (the next one is a restart)
  bool fresh_ = false;               ///< accepted since the last read
  bool silent_ = false;              ///< in a silence past the timeout
  std::uint64_t newest_seq_ = 0;
  std::uint64_t first_seq_ = 0;      ///< the session's first accepted seq
  std::int64_t newest_sender_ns_ = 0;
  std::uint64_t window_ = 0;         ///< bit i: newest_seq_ - 1 - i was received
  std::int64_t min_offset_ns_ = 0;   ///< smallest receive - send seen this session
  std::int64_t last_accept_ns_ = 0;  ///< local time of the newest accepted state
  sockaddr_in peer_{};
  bool have_peer_ = false;
  std::uint64_t command_seq_ = 0;
  BridgeCounters counters_;
};

}  // namespace tactus::device
