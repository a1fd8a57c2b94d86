// The haptic loop driven by the `bridge` backend over loopback: the remote hand's pose reaches
// the local model and the simulation, the force goes back to the sender, and when the sender
// falls silent past the bridge's timeout the loop holds the last pose and fades the force out
// (the existing device-fault path), then recovers when states come back. Waits for datagrams
// and sleeps past the timeout; asserts no durations.
#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include "../../support/bridge_sender.h"
#include "../../support/one_contact_rig.h"
#include "tactus/device/bridge_device.h"
#include "tactus/shared/clock.h"

namespace tactus::haptic {
namespace {

class BridgeLoopTest : public ::testing::Test {
 protected:
  void SetUp() override {
    device_.open();
    sender_.emplace(device_.port());
    settings_.max_force_n = 5.0;
    settings_.slew_n_per_s = 1e6;
    settings_.fade_ms = 1.0;
    settings_.watchdog_ms = 5000.0;   // the snapshot never goes stale here: only the device can
    rig_.emplace(device_, settings_, "bridge_loop_test");
  }
  // Sends one state and ticks once it has arrived (real clock: the bridge judges silence on it).
  TickOutput sendAndTick(double z) {
    const std::uint64_t before = device_.counters().accepted;
    sender_->sendState(++seq_, shared::monotonicNs(), {0.0, 0.0, z});
    TickOutput out;
    for (int i = 0; i < 50'000 && device_.counters().accepted == before; ++i) {
      out = tick();
      if (device_.counters().accepted == before) {
        std::this_thread::sleep_for(std::chrono::microseconds(100));
      }
    }
    EXPECT_GT(device_.counters().accepted, before) << "state not delivered";
    return out;
  }
  TickOutput tick() {
    const std::int64_t now = shared::monotonicNs();
    return rig_->loop().tick(now, now);
  }

  device::BridgeDevice device_{device::DeviceConfig{{"port", "0"}, {"timeout_ms", "250"}}};
  std::optional<test::BridgeSender> sender_;
  HapticSettings settings_;
  std::optional<test::OneContactRig> rig_;
  std::uint64_t seq_ = 0;
};

TEST_F(BridgeLoopTest, SilenceHoldsThePoseAndFadesTheForceThenStatesBringItBack) {
  device_.enableForces(true);
  rig_->publish(0.0, 1e-3, 0.0, shared::monotonicNs());   // touching at z = 0
  for (int i = 0; i < 200; ++i) sendAndTick(0.0);          // engaged, faded in
  TickOutput out;
  for (int i = 0; i < 200; ++i) out = sendAndTick(-0.002);   // 2 mm in: 2 N up
  EXPECT_NEAR(out.force_n[2], 2.0, 1e-9);
  {
    auto& c = rig_->loop().counters();
    std::printf("DBG ticks %lu nodata %lu faults %lu stale %lu snaps %lu gain %g unl %g flags %lx contacts %d silent %lu\n",
      (unsigned long)c.ticks.load(), (unsigned long)c.device_no_data.load(), (unsigned long)c.device_faults.load(),
      (unsigned long)c.stale_ticks.load(), (unsigned long)c.snapshots_taken.load(), out.gain, out.unlimited_force_norm_n,
      (unsigned long)out.flags, out.contacts, (unsigned long)c.silent_device_ticks.load());
  }
  EXPECT_DOUBLE_EQ(rig_->sample().pos_m[2], -0.002);
  // the remote side receives that force (its queue emptied first: it overflowed long ago)
  device::DeviceCommand cmd;
  std::uint64_t state_seq = 0;
  while (sender_->receive(&cmd, &state_seq, MSG_DONTWAIT)) {
  }
  sendAndTick(-0.002);
  ASSERT_TRUE(sender_->receiveNewest(&cmd, &state_seq));
  EXPECT_NEAR(cmd.force_n[2], 2.0, 1e-9);
  EXPECT_EQ(state_seq, seq_);

  // silence: well past the 250 ms timeout (long enough that a stalled test never looks silent
  // before), then tick
  std::this_thread::sleep_for(std::chrono::milliseconds(750));
  for (int i = 0; i < 300; ++i) out = tick();
  EXPECT_EQ(out.force_n[2], 0.0);                    // faded out
  EXPECT_TRUE(out.flags & shared::kStatsDeviceFault);
  EXPECT_EQ(device_.counters().silences, 1u);
  EXPECT_GT(rig_->loop().counters().device_faults.load(), 0u);
  const shared::DeviceSample held = rig_->sample();
  EXPECT_DOUBLE_EQ(held.pos_m[2], -0.002);           // the last pose, held
  EXPECT_TRUE(held.status & shared::kDeviceFault);

  // the hand is back, still 2 mm deep: the engage gate stays closed (no kick in the tissue)
  for (int i = 0; i < 100; ++i) out = sendAndTick(-0.002);
  EXPECT_EQ(out.force_n[2], 0.0);
  EXPECT_FALSE(out.flags & shared::kStatsDeviceFault);
  for (int i = 0; i < 20; ++i) sendAndTick(0.001);            // out of the tissue: engages
  for (int i = 0; i < 200; ++i) out = sendAndTick(-0.002);   // and presses again
  EXPECT_NEAR(out.force_n[2], 2.0, 1e-9);
}

}  // namespace
}  // namespace tactus::haptic
