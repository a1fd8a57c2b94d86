// The `bridge` backend over loopback with a test-side sender: loss, reordering, duplication,
// garbage, lateness, a restarted sender and silence are counted and handled (the newest pose is
// used, malformed datagrams never are, silence past the timeout is a fault), commands go back to
// the sender, non-loopback binding needs an explicit option, and read/write allocate nothing.
// No timing thresholds: time is passed to readAt(), and datagrams are awaited, not timed.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <thread>

#include "../../support/alloc_counter.h"
#include "../../support/bridge_sender.h"
#include "tactus/device/bridge_device.h"
#include "tactus/shared/error.h"

namespace tactus::device {
namespace {

using bridge::kStateBytes;

constexpr std::int64_t kT0 = 1'000'000'000'000;   // the sender's clock
constexpr std::int64_t kNow = 5'000'000'000'000;  // the bridge's clock (another machine's)

std::uint64_t handled(const BridgeCounters& c) {
  return c.accepted + c.duplicated + c.reordered + c.malformed + c.foreign + c.out_of_window;
}

class BridgeDeviceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    device_.emplace(DeviceConfig{{"port", "0"}, {"timeout_ms", "50"}, {"late_ms", "10"}});
    device_->open();
    sender_.emplace(device_->port());
  }
  // Reads at `now` until `count` datagrams in all were handled (loopback delivery is
  // asynchronous); returns the status of the read that got there (kOk if any read had a state).
  IoStatus readUntil(std::uint64_t count, std::int64_t now, DeviceState* out) {
    IoStatus any = IoStatus::kNoData;
    for (int i = 0; i < 50'000 && handled(device_->counters()) < count; ++i) {
      if (device_->readAt(now, out) == IoStatus::kOk) any = IoStatus::kOk;
      if (handled(device_->counters()) < count) {
        std::this_thread::sleep_for(std::chrono::microseconds(100));
      }
    }
    EXPECT_EQ(handled(device_->counters()), count) << "datagrams not delivered";
    return any;
  }
  std::optional<BridgeDevice> device_;
  std::optional<test::BridgeSender> sender_;
};

TEST_F(BridgeDeviceTest, NothingYetIsNoDataThenTheNewestStateIsUsed) {
  DeviceState out;
  EXPECT_EQ(device_->readAt(kNow, &out), IoStatus::kNoData);
  for (std::uint64_t seq = 1; seq <= 5; ++seq) {
    sender_->sendState(seq, kT0 + 1'000'000 * static_cast<std::int64_t>(seq), {0.01 * seq, 0, 0});
  }
  EXPECT_EQ(readUntil(5, kNow, &out), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.05);
  EXPECT_EQ(out.quat_wxyz[0], 1.0);
  // t_ns on the bridge's clock: the sender's stamp plus the smallest offset seen
  EXPECT_EQ(out.t_ns, kNow);
  const BridgeCounters& c = device_->counters();
  EXPECT_EQ(c.accepted, 5u);
  EXPECT_EQ(c.lost + c.duplicated + c.reordered + c.malformed + c.late, 0u);
}

TEST_F(BridgeDeviceTest, LossReorderingAndDuplicationAreCountedAndTheNewestPoseKept) {
  DeviceState out;
  auto send = [&](std::uint64_t seq) {
    sender_->sendState(seq, kT0 + static_cast<std::int64_t>(seq), {0.001 * seq, 0, 0});
  };
  for (std::uint64_t seq : {1, 2, 5}) send(seq);     // 3 and 4 lost (for now)
  readUntil(3, kNow, &out);
  EXPECT_EQ(device_->counters().lost, 2u);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.005);
  send(4);                                           // late arrival: reordered, not lost after all
  send(4);                                           // and again: a duplicate
  send(5);                                           // the newest again: a duplicate
  send(3);
  out.pos_m = {9, 9, 9};
  EXPECT_EQ(readUntil(7, kNow, &out), IoStatus::kNoData);   // nothing newer: no new state
  EXPECT_DOUBLE_EQ(out.pos_m[0], 9.0);                      // left unchanged
  const BridgeCounters& c = device_->counters();
  EXPECT_EQ(c.reordered, 2u);
  EXPECT_EQ(c.duplicated, 2u);
  EXPECT_EQ(c.lost, 0u);
  EXPECT_EQ(c.accepted, 3u);
  send(6);
  EXPECT_EQ(readUntil(8, kNow, &out), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.006);
  // a jump beyond the duplicate window counts every missing datagram
  send(200);
  readUntil(9, kNow, &out);
  EXPECT_EQ(c.lost, 193u);
}

TEST_F(BridgeDeviceTest, MalformedDatagramsAreCountedAndDroppedNeverUsed) {
  DeviceState out;
  sender_->sendState(1, kT0, {0.01, 0.02, 0.03});
  readUntil(1, kNow, &out);
  std::vector<std::vector<unsigned char>> bad;
  DeviceState s;
  auto valid = [&] { return test::BridgeSender::encoded(2, kT0 + 10, s); };
  auto patched = [&](std::size_t at, const void* v, std::size_t n) {
    auto b = valid();
    std::memcpy(b.data() + at, v, n);
    bad.push_back(b);
  };
  const std::uint32_t wrong_magic = 0x12345678;
  const std::uint16_t v2 = 2, command = bridge::kTypeCommand;
  const std::uint32_t wrong_payload = 100, one = 1;
  const std::int64_t negative = -5;
  const double nan = std::nan(""), inf = INFINITY, far = 1e3, half = 0.5;
  patched(0, &wrong_magic, 4);
  patched(4, &v2, 2);
  patched(6, &command, 2);
  patched(16, &negative, 8);          // t_ns
  patched(24, &wrong_payload, 4);
  patched(28, &one, 4);               // header reserved
  patched(32, &nan, 8);               // pos x
  patched(32 + 8, &far, 8);           // pos y: 1 km
  patched(32 + 24, &inf, 8);          // quaternion w
  patched(32 + 24, &half, 8);         // quaternion w = 0.5: not unit
  patched(32 + 56, &far, 8);          // velocity 1000 m/s
  patched(32 + 104, &far, 8);         // gripper 1000 rad
  patched(32 + 120 - 4, &one, 4);     // payload reserved
  auto truncated = valid();
  truncated.resize(kStateBytes - 1);
  bad.push_back(truncated);
  auto longer = valid();
  longer.resize(kStateBytes + 8);
  bad.push_back(longer);
  bad.push_back(std::vector<unsigned char>(4000, 0x54));   // larger than the receive buffer
  bad.push_back({});                                       // empty datagram
  std::mt19937 rng(19);
  for (int i = 0; i < 200; ++i) {
    std::vector<unsigned char> junk(rng() % 300);
    for (auto& b : junk) b = static_cast<unsigned char>(rng());
    // every other one starts with a good magic, version and type
    if (i % 2 == 0 && junk.size() >= 8) std::memcpy(junk.data(), valid().data(), 8);
    bad.push_back(junk);
  }
  out.pos_m = {7, 7, 7};
  std::uint64_t sent = 1;
  for (const auto& b : bad) {   // one at a time: a burst could overflow the socket buffer
    bridge::Header h;
    DeviceState decoded;
    EXPECT_NE(bridge::decodeState(b.data(), b.size(), &h, &decoded), bridge::DecodeStatus::kOk)
        << "datagram " << sent - 1 << " decodes";
    sender_->sendBytes(b.data(), b.size());
    EXPECT_EQ(readUntil(++sent, kNow, &out), IoStatus::kNoData) << "datagram " << sent - 2;
  }
  EXPECT_EQ(device_->counters().malformed, bad.size());
  EXPECT_EQ(device_->counters().accepted, 1u);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 7.0);   // nothing used
  // and a good datagram after all that is used
  sender_->sendState(3, kT0 + 20, {0.04, 0, 0});
  EXPECT_EQ(readUntil(2 + bad.size(), kNow, &out), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.04);
}

TEST_F(BridgeDeviceTest, SilencePastTheTimeoutIsAFaultWithThePoseHeldUntilDataReturns) {
  DeviceState out;
  sender_->sendState(1, kT0, {0.01, 0, 0});
  readUntil(1, kNow, &out);
  out.pos_m = {0.01, 0, 0};
  EXPECT_EQ(device_->readAt(kNow + 49'000'000, &out), IoStatus::kNoData);   // quiet: hold
  EXPECT_EQ(device_->readAt(kNow + 51'000'000, &out), IoStatus::kFault);    // past 50 ms
  EXPECT_EQ(device_->readAt(kNow + 90'000'000, &out), IoStatus::kFault);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.01);
  EXPECT_EQ(device_->counters().silences, 1u);   // one silence, however long
  sender_->sendState(2, kT0 + 100'000'000, {0.02, 0, 0});
  EXPECT_EQ(readUntil(2, kNow + 100'000'000, &out), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.02);
}

TEST_F(BridgeDeviceTest, LateStatesAndARestartedSenderAreRecognised) {
  DeviceState out;
  sender_->sendState(1, kT0, {0.01, 0, 0});
  readUntil(1, kNow, &out);                                 // offset kNow - kT0
  sender_->sendState(2, kT0 + 1'000'000, {0.02, 0, 0});     // arrives 5 ms late: fine
  readUntil(2, kNow + 6'000'000, &out);
  sender_->sendState(3, kT0 + 2'000'000, {0.03, 0, 0});     // 30 ms late: counted, still used
  EXPECT_EQ(readUntil(3, kNow + 32'000'000, &out), IoStatus::kOk);
  EXPECT_EQ(device_->counters().late, 1u);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.03);
  EXPECT_EQ(out.t_ns, kNow + 2'000'000);                    // stamped on the bridge's clock
  sender_->sendState(1, kT0 + 500'000'000, {0.05, 0, 0});   // seq 1 again, stamped later
  EXPECT_EQ(readUntil(4, kNow + 500'000'000, &out), IoStatus::kOk);
  EXPECT_EQ(device_->counters().restarts, 1u);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.05);
  EXPECT_EQ(device_->counters().duplicated + device_->counters().reordered, 0u);
}

// One datagram must not take the device from a live client: a state from another sender
// (address and port) is dropped while the session is live, whatever its seq and stamp (seq
// 2^64-1 and t = INT64_MAX used to lock the real client out until a restart and wrap the lost
// counter), and a second sender interleaving with the client is never followed.
TEST_F(BridgeDeviceTest, AnotherSenderNeverTakesOrJoinsALiveSession) {
  DeviceState out;
  test::BridgeSender spoofer(device_->port());
  sender_->sendState(1, kT0, {0.01, 0, 0});
  readUntil(1, kNow, &out);
  spoofer.sendState(~std::uint64_t{0}, std::numeric_limits<std::int64_t>::max(), {0.5, 0, 0});
  EXPECT_NE(readUntil(2, kNow + 1'000'000, &out), IoStatus::kOk);
  EXPECT_EQ(device_->counters().foreign, 1u);
  std::uint64_t handled_so_far = 2;
  for (std::uint64_t seq = 2; seq <= 40; ++seq) {   // interleaved: client, spoofer, client, ...
    const std::int64_t t = 1'000'000 * static_cast<std::int64_t>(seq);
    sender_->sendState(seq, kT0 + t, {0.01, 0, 0});
    spoofer.sendState(seq, kT0 + t, {0.5, 0, 0});
    handled_so_far += 2;
    readUntil(handled_so_far, kNow + t, &out);
    EXPECT_DOUBLE_EQ(out.pos_m[0], 0.01) << "the second sender's pose was used (seq " << seq << ")";
  }
  EXPECT_EQ(device_->counters().accepted, 40u);
  EXPECT_EQ(device_->counters().foreign, 40u);
  EXPECT_EQ(device_->counters().lost, 0u);
  EXPECT_EQ(device_->counters().restarts, 0u);
  // commands keep going to the client
  device_->enableForces(true);
  ASSERT_EQ(device_->write(DeviceCommand{}), IoStatus::kOk);
  DeviceCommand got;
  std::uint64_t state_seq = 0;
  ASSERT_TRUE(sender_->receive(&got, &state_seq));
  EXPECT_EQ(state_seq, 40u);
}

// Within its own session a sender cannot jump out of a sane window either (a seq far ahead, a
// stamp running ahead of the time elapsed here), and no session starts on absurd values.
TEST_F(BridgeDeviceTest, ASeqOrStampOutsideTheSaneWindowIsDropped) {
  DeviceState out;
  sender_->sendState(~std::uint64_t{0}, 5, {0.3, 0, 0});                 // no session on it
  sender_->sendState(1, std::numeric_limits<std::int64_t>::max(), {0.3, 0, 0});
  EXPECT_EQ(readUntil(2, kNow, &out), IoStatus::kNoData);
  EXPECT_EQ(device_->counters().out_of_window, 2u);
  sender_->sendState(1, kT0, {0.01, 0, 0});
  readUntil(3, kNow, &out);
  sender_->sendState(~std::uint64_t{0}, kT0 + 1'000'000, {0.3, 0, 0});    // a seq jump
  sender_->sendState(2, kT0 + 3'600'000'000'000, {0.3, 0, 0});           // an hour ahead
  readUntil(5, kNow + 1'000'000, &out);
  EXPECT_EQ(device_->counters().out_of_window, 4u);
  sender_->sendState(2, kT0 + 1'000'000, {0.02, 0, 0});                   // sane: used
  EXPECT_EQ(readUntil(6, kNow + 1'000'000, &out), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.02);
  EXPECT_EQ(device_->counters().lost, 0u);
}

// A client restarted on a new port takes over once the old session has been silent past the
// timeout (and not before): the documented way to restart the real client.
TEST_F(BridgeDeviceTest, ARestartedClientOnANewPortTakesOverAfterTheTimeout) {
  DeviceState out;
  sender_->sendState(100, kT0, {0.01, 0, 0});
  readUntil(1, kNow, &out);
  test::BridgeSender restarted(device_->port());
  restarted.sendState(1, kT0 + 10'000'000, {0.02, 0, 0});
  EXPECT_NE(readUntil(2, kNow + 10'000'000, &out), IoStatus::kOk);   // within the timeout
  EXPECT_EQ(device_->counters().foreign, 1u);
  EXPECT_EQ(device_->readAt(kNow + 60'000'000, &out), IoStatus::kFault);   // silent: ended
  restarted.sendState(2, kT0 + 61'000'000, {0.03, 0, 0});
  EXPECT_EQ(readUntil(3, kNow + 61'000'000, &out), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(out.pos_m[0], 0.03);
  EXPECT_EQ(device_->counters().restarts, 1u);
  device_->enableForces(true);
  ASSERT_EQ(device_->write(DeviceCommand{}), IoStatus::kOk);
  DeviceCommand got;
  std::uint64_t state_seq = 0;
  ASSERT_TRUE(restarted.receive(&got, &state_seq)) << "commands go to the new session's client";
  EXPECT_EQ(state_seq, 2u);
}

TEST_F(BridgeDeviceTest, CommandsGoBackToTheSenderAndZeroWhileForcesAreDisabled) {
  DeviceState out;
  DeviceCommand cmd;
  cmd.force_n = {1.0, -2.0, 0.5};
  cmd.torque_nm = {0.0, 0.0, 0.1};
  EXPECT_EQ(device_->write(cmd), IoStatus::kOk);   // no sender yet: nothing sent
  EXPECT_EQ(device_->counters().commands_sent, 0u);
  sender_->sendState(7, kT0, {0, 0, 0});
  readUntil(1, kNow, &out);
  device_->enableForces(true);
  ASSERT_EQ(device_->write(cmd), IoStatus::kOk);
  DeviceCommand got;
  std::uint64_t state_seq = 0;
  ASSERT_TRUE(sender_->receive(&got, &state_seq));
  EXPECT_EQ(got.force_n, cmd.force_n);
  EXPECT_EQ(got.torque_nm, cmd.torque_nm);
  EXPECT_EQ(state_seq, 7u);
  device_->enableForces(false);
  ASSERT_EQ(device_->write(cmd), IoStatus::kOk);
  ASSERT_TRUE(sender_->receive(&got, &state_seq));
  EXPECT_EQ(got.force_n, (std::array<double, 3>{}));
  EXPECT_EQ(device_->counters().commands_sent, 2u);
}

// The command's reserved word (once a gripper force that nothing rendered) is sent as 0 and a
// command with anything else there is refused, as the state's reserved word is.
TEST(BridgeProtocol, TheCommandsReservedWordIsZeroAndChecked) {
  DeviceCommand cmd;
  cmd.force_n = {1.0, 2.0, 3.0};
  std::array<unsigned char, bridge::kCommandBytes> buf{};
  ASSERT_EQ(bridge::encodeCommand(3, 1000, cmd, 2, buf.data()), bridge::kCommandBytes);
  double reserved = -1.0;
  std::memcpy(&reserved, buf.data() + bridge::kHeaderBytes + 48, 8);
  EXPECT_EQ(reserved, 0.0);
  bridge::Header h;
  DeviceCommand got;
  std::uint64_t state_seq = 0;
  ASSERT_EQ(bridge::decodeCommand(buf.data(), buf.size(), &h, &got, &state_seq),
            bridge::DecodeStatus::kOk);
  EXPECT_EQ(got.force_n, cmd.force_n);
  EXPECT_EQ(state_seq, 2u);
  for (const double bad : {0.5, std::nan("")}) {
    std::memcpy(buf.data() + bridge::kHeaderBytes + 48, &bad, 8);
    EXPECT_EQ(bridge::decodeCommand(buf.data(), buf.size(), &h, &got, &state_seq),
              bridge::DecodeStatus::kBadReserved);
  }
}

TEST_F(BridgeDeviceTest, ReadAndWriteAllocateNothing) {
  DeviceState out;
  sender_->sendState(1, kT0, {0, 0, 0});
  readUntil(1, kNow, &out);
  for (std::uint64_t seq = 2; seq < 40; ++seq) sender_->sendState(seq, kT0 + 1, {0, 0, 0});
  const unsigned char junk[10] = {1, 2, 3};
  sender_->sendBytes(junk, sizeof junk);
  test::AllocScope scope;
  for (int i = 0; i < 2000 && handled(device_->counters()) < 40; ++i) {
    (void)device_->readAt(kNow, &out);
    (void)device_->write(DeviceCommand{});
  }
  (void)device_->readAt(kNow + 1'000'000'000, &out);   // silence
  EXPECT_EQ(scope.allocations(), 0);
  EXPECT_EQ(scope.cAllocations(), 0);
}

TEST(BridgeDeviceOptions, NonLoopbackNeedsAnExplicitOptionAndBadOptionsAreRefused) {
  EXPECT_THROW(BridgeDevice(DeviceConfig{{"bind", "0.0.0.0"}}), DeviceError);
  EXPECT_THROW(BridgeDevice(DeviceConfig{{"bind", "192.168.1.20"}}), DeviceError);
  EXPECT_NO_THROW(BridgeDevice(DeviceConfig{{"bind", "0.0.0.0"}, {"allow_remote", "1"}}));
  EXPECT_NO_THROW(BridgeDevice(DeviceConfig{{"bind", "127.0.0.2"}}));
  EXPECT_THROW(BridgeDevice(DeviceConfig{{"bind", "localhost:1"}}), DeviceError);
  EXPECT_THROW(BridgeDevice(DeviceConfig{{"port", "70000"}}), DeviceError);
  EXPECT_THROW(BridgeDevice(DeviceConfig{{"port", "1.5"}}), DeviceError);
  EXPECT_THROW(BridgeDevice(DeviceConfig{{"timeout_ms", "0"}}), DeviceError);
  EXPECT_THROW(BridgeDevice(DeviceConfig{{"bogus", "1"}}), DeviceError);
  // the default binds loopback; a second bridge on the same port says the port is taken
  BridgeDevice first(DeviceConfig{{"port", "0"}});
  first.open();
  EXPECT_EQ(first.bindAddress(), "127.0.0.1");
  BridgeDevice second(DeviceConfig{{"port", std::to_string(first.port())}});
  try {
    second.open();
    ADD_FAILURE() << "a second bind on the same port succeeded";
  } catch (const DeviceError& e) {
    EXPECT_NE(std::string(e.what()).find("port"), std::string::npos) << e.what();
  }
  // through the loader, like the other backends
  auto loaded = loadDevice("bridge", {{"port", "0"}, {"max_force", "3"}});
  EXPECT_EQ(loaded->info().max_force_n, 3.0);
}

}  // namespace
}  // namespace tactus::device
