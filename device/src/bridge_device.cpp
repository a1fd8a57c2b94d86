// The `bridge` backend: device states over UDP in, force commands out (bridge_device.h).
#include "tactus/device/bridge_device.h"

#include <arpa/inet.h>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <unistd.h>

#include "tactus/device/backends.h"
#include "tactus/shared/clock.h"

namespace tactus::device {
namespace {

constexpr double kMaxTimeoutMs = 10'000.0;
constexpr int kWindowBits = 64;

std::int64_t msToNs(double ms) { return static_cast<std::int64_t>(std::llround(ms * 1e6)); }

}  // namespace

BridgeDevice::BridgeDevice(const DeviceConfig& config) {
  OptionReader opt("bridge", config);
  bind_ = opt.text("bind", "127.0.0.1");
  const double port = opt.number("port", bridge::kDefaultPort, 0.0, 65535.0);
  if (port != std::floor(port)) {
    throw DeviceError("device 'bridge': option port must be an integer in [0, 65535]");
  }
  port_ = static_cast<std::uint16_t>(port);
  allow_remote_ = opt.flag("allow_remote", false);
  timeout_ns_ = msToNs(opt.number("timeout_ms", 50.0, 1e-3, kMaxTimeoutMs));
  late_ns_ = msToNs(opt.number("late_ms", 10.0, 1e-3, kMaxTimeoutMs));
  max_force_n_ = opt.number("max_force", 10.0, 1e-3, 100.0);
  has_rotation_ = opt.flag("rotation", false);
  has_gripper_ = opt.flag("gripper", false);
  opt.rejectUnknown();
  in_addr addr{};
  if (::inet_pton(AF_INET, bind_.c_str(), &addr) != 1) {
    throw DeviceError("device 'bridge': bind=" + bind_ + " is not an IPv4 address");
  }
  const bool loopback = (ntohl(addr.s_addr) >> 24) == 127;
  if (!loopback && !allow_remote_) {
    throw DeviceError("device 'bridge': bind=" + bind_ +
                      " is not a loopback address: anyone who reaches it can move the "
                      "instrument; add --device-option allow_remote=1 to accept that");
  }
}

BridgeDevice::~BridgeDevice() { close(); }

DeviceInfo BridgeDevice::info() const {
  DeviceInfo i;
  i.model = "bridge " + bind_ + ":" + std::to_string(port_);
  i.max_force_n = max_force_n_;
  i.has_rotation = has_rotation_;
  i.has_gripper = has_gripper_;
  return i;
}

void BridgeDevice::open() {
  close();
  fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd_ < 0) throw DeviceError(std::string("device 'bridge': socket: ") + std::strerror(errno));
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(port_);
  ::inet_pton(AF_INET, bind_.c_str(), &a.sin_addr);
  if (::bind(fd_, reinterpret_cast<const sockaddr*>(&a), sizeof a) != 0) {
    const int e = errno;
    close();
    throw DeviceError("device 'bridge': cannot listen on " + bind_ + ":" +
                      std::to_string(port_) + " (" + std::strerror(e) +
                      "); another haptic_server or program may hold it: pick another "
                      "--device-option port=N");
  }
  socklen_t len = sizeof a;
  ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &len);
  port_ = ntohs(a.sin_port);
  have_state_ = fresh_ = silent_ = have_peer_ = had_session_ = false;
  newest_seq_ = 0;
}

void BridgeDevice::close() noexcept {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

IoStatus BridgeDevice::read(DeviceState* out) noexcept {
  return readAt(shared::monotonicNs(), out);
}

namespace {

bool sameSender(const sockaddr_in& a, const sockaddr_in& b) noexcept {
  return a.sin_addr.s_addr == b.sin_addr.s_addr && a.sin_port == b.sin_port;
}

}  // namespace

void BridgeDevice::startSession(const bridge::Header& h, const sockaddr_in& from,
                                std::int64_t now_ns) noexcept {
  if (had_session_) counters_.restarts.fetch_add(1, std::memory_order_relaxed);
  had_session_ = true;
  have_state_ = true;
  window_ = 0;
  first_seq_ = h.seq;
  newest_seq_ = h.seq - 1;             // take() sees the first state as the next in sequence
  newest_sender_ns_ = h.t_ns;
  min_offset_ns_ = now_ns - h.t_ns;    // both >= 0: no overflow
  peer_ = from;
  have_peer_ = true;
}

void BridgeDevice::take(const bridge::Header& h, const DeviceState& s, const sockaddr_in& from,
                        std::int64_t now_ns) noexcept {
  const bool live = have_state_ && now_ns - last_accept_ns_ <= timeout_ns_;
  if (live && !sameSender(from, peer_)) {
    // another sender while the session is live: never followed, never answered
    counters_.foreign.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  // the sender's clock may not run ahead of ours by more than the timeout between two states
  const auto sane_stamp = [&] {
    const std::int64_t elapsed = now_ns - last_accept_ns_;
    return h.t_ns - newest_sender_ns_ <= elapsed + timeout_ns_;   // both terms bounded: no overflow
  };
  if (live && h.seq <= newest_seq_ && h.t_ns > newest_sender_ns_ && sane_stamp() &&
      h.seq < kMaxSaneValue) {
    // the same sender, a lower or equal seq stamped later than the newest: it restarted
    startSession(h, from, now_ns);
  } else if (!live) {
    // no live session (none yet, or silent past the timeout): this sender starts one
    if (h.seq == 0 || h.seq >= kMaxSaneValue ||
        static_cast<std::uint64_t>(h.t_ns) >= kMaxSaneValue) {
      counters_.out_of_window.fetch_add(1, std::memory_order_relaxed);
      return;
    }
    startSession(h, from, now_ns);
  } else if (h.seq > newest_seq_ && (h.seq - newest_seq_ > kMaxSeqStep || !sane_stamp())) {
    counters_.out_of_window.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  const std::int64_t offset = now_ns - h.t_ns;   // both >= 0: no overflow
  if (h.seq == newest_seq_) {
    counters_.duplicated.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  if (h.seq < newest_seq_) {
    const std::uint64_t age = newest_seq_ - h.seq;
    // within the window and this session: a set bit is a duplicate; an unset one (never the
    // session's first seq, whose bit is set when it is superseded) was counted lost at the gap
    if (age <= kWindowBits && h.seq >= first_seq_) {
      const std::uint64_t bit = std::uint64_t{1} << (age - 1);
      if ((window_ & bit) != 0) {
        counters_.duplicated.fetch_add(1, std::memory_order_relaxed);
        return;
      }
      window_ |= bit;
      counters_.lost.fetch_sub(1, std::memory_order_relaxed);
    }
    counters_.reordered.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  const std::uint64_t step = h.seq - newest_seq_;   // 1 .. kMaxSeqStep
  counters_.lost.fetch_add(step - 1, std::memory_order_relaxed);
  window_ = step >= kWindowBits ? 0 : (window_ << step);
  if (h.seq - 1 >= first_seq_ && step <= kWindowBits) {
    window_ |= std::uint64_t{1} << (step - 1);   // the old newest
  }
  if (offset < min_offset_ns_) min_offset_ns_ = offset;
  if (offset - min_offset_ns_ > late_ns_) counters_.late.fetch_add(1, std::memory_order_relaxed);
  newest_seq_ = h.seq;
  newest_sender_ns_ = h.t_ns;
  newest_ = s;
  newest_.t_ns = h.t_ns + min_offset_ns_;   // on this machine's clock
  last_accept_ns_ = now_ns;
  fresh_ = true;
  counters_.accepted.fetch_add(1, std::memory_order_relaxed);
}

IoStatus BridgeDevice::readAt(std::int64_t now_ns, DeviceState* out) noexcept {
  if (fd_ < 0) return IoStatus::kFault;
  for (int i = 0; i < kMaxDatagramsPerRead; ++i) {
    sockaddr_in from{};
    socklen_t from_len = sizeof from;
    const ssize_t n = ::recvfrom(fd_, buf_.data(), buf_.size(), MSG_DONTWAIT | MSG_TRUNC,
                                 reinterpret_cast<sockaddr*>(&from), &from_len);
    if (n < 0) {
      if (errno == EAGAIN || errno == EWOULDBLOCK) break;   // drained
      continue;   // a reported ICMP error (the client went away): the queue may hold more
    }
    bridge::Header h;
    DeviceState s;
    // MSG_TRUNC: n is the datagram's real length, so an oversized one is refused too
    if (static_cast<std::size_t>(n) > buf_.size() || from.sin_family != AF_INET ||
        bridge::decodeState(buf_.data(), static_cast<std::size_t>(n), &h, &s) !=
            bridge::DecodeStatus::kOk) {
      counters_.malformed.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    take(h, s, from, now_ns);
  }
  if (fresh_) {
    fresh_ = false;
    silent_ = false;
    *out = newest_;
    return IoStatus::kOk;
  }
  if (!have_state_) return IoStatus::kNoData;   // no device yet
  if (now_ns - last_accept_ns_ > timeout_ns_) {
    if (!silent_) counters_.silences.fetch_add(1, std::memory_order_relaxed);
    silent_ = true;
    return IoStatus::kFault;
  }
  return IoStatus::kNoData;
}

IoStatus BridgeDevice::write(const DeviceCommand& cmd) noexcept {
  if (fd_ < 0) return IoStatus::kFault;
  if (!have_peer_) return IoStatus::kOk;   // nobody to send to yet
  DeviceCommand c = forces_on_ ? cmd : DeviceCommand{};
  unsigned char msg[bridge::kCommandBytes];
  const std::size_t size =
      bridge::encodeCommand(++command_seq_, shared::monotonicNs(), c, newest_seq_, msg);
  const ssize_t n = ::sendto(fd_, msg, size, MSG_DONTWAIT | MSG_NOSIGNAL,
                             reinterpret_cast<const sockaddr*>(&peer_), sizeof peer_);
  if (n == static_cast<ssize_t>(size)) {
    counters_.commands_sent.fetch_add(1, std::memory_order_relaxed);
  } else {
    counters_.send_failures.fetch_add(1, std::memory_order_relaxed);
  }
  return IoStatus::kOk;
}

std::string BridgeDevice::describeCounters() const {
  auto v = [](const std::atomic<std::uint64_t>& a) { return std::to_string(a.load()); };
  const BridgeCounters& c = counters_;
  return "bridge: " + v(c.accepted) + " states, " + v(c.lost) + " lost, " + v(c.duplicated) +
         " duplicated, " + v(c.reordered) + " reordered, " + v(c.late) + " late, " +
         v(c.malformed) + " malformed, " + v(c.foreign) + " from another sender, " +
         v(c.out_of_window) + " out of window, " + v(c.silences) + " silences, " +
         v(c.restarts) + " new sessions, " + v(c.commands_sent) + " commands sent, " +
         v(c.send_failures) + " not sent";
}

}  // namespace tactus::device
