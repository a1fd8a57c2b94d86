// The haptic tick's phases one at a time (HapticLoop::tick calls them in this order): adopt the
// offered link, read the device, publish the sample, take the snapshot (and solve the local
// model), the safety chain, write the device, record the stats. Each is checked on its own
// against a real shared segment; haptic_loop_test.cpp checks them together through tick().
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "../../support/haptic_loop_access.h"
#include "../../support/haptic_segment_test.h"
#include "../../support/scripted_device.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/clock.h"

namespace tactus::haptic {
namespace {

using P = HapticLoopTestAccess;
using test::ScriptedDevice;

// A device whose writes fail.
class RefusingDevice : public ScriptedDevice {
 public:
  device::IoStatus write(const device::DeviceCommand&) noexcept override {
    return device::IoStatus::kFault;
  }
};

class HapticPhasesTest : public test::HapticSegmentTest {
 protected:
  // Adopts the link and reads one valid device sample at the origin (the loop has a pose).
  void readValidPose() {
    P::adoptOfferedLink(*loop_);
    device_.state.pos_m = {0.0, 0.0, 0.0};
    device_.state.t_ns = t_;
    TickOutput out;
    ASSERT_EQ(P::readDevice(*loop_, t_, out), device::IoStatus::kOk);
  }
};

TEST_F(HapticPhasesTest, AdoptTakesTheOfferedLinkAndANullOfferDetaches) {
  EXPECT_EQ(loop_->linkInUse(), nullptr) << "an offer is taken only by the tick";
  P::adoptOfferedLink(*loop_);
  EXPECT_EQ(loop_->linkInUse(), link_.get());
  loop_->offerLink(nullptr);
  EXPECT_EQ(loop_->linkInUse(), link_.get()) << "the old link stays in use until the next tick";
  P::adoptOfferedLink(*loop_);
  EXPECT_EQ(loop_->linkInUse(), nullptr);
}

TEST_F(HapticPhasesTest, ReadDeviceSortsFreshStaleNonFiniteAndMissingSamples) {
  TickOutput out;
  device_.state.pos_m = {0.01, 0.02, 0.03};
  device_.state.t_ns = t_;
  EXPECT_EQ(P::readDevice(*loop_, t_, out), device::IoStatus::kOk);
  EXPECT_EQ(out.flags, 0u);

  // a sample stamped a second ago while the watchdog is 50 ms: the device stopped updating
  out = {};
  device_.state.t_ns = t_ - 1'000'000'000;
  EXPECT_EQ(P::readDevice(*loop_, t_, out), device::IoStatus::kFault);
  EXPECT_NE(out.flags & shared::kStatsDeviceFault, 0u);
  EXPECT_EQ(loop_->counters().stale_device_samples.load(), 1u);
  EXPECT_EQ(loop_->counters().device_faults.load(), 1u);

  // a fresh sample with a NaN coordinate is read but not trusted
  out = {};
  device_.state.t_ns = t_;
  device_.state.pos_m = {std::nan(""), 0.0, 0.0};
  EXPECT_EQ(P::readDevice(*loop_, t_, out), device::IoStatus::kOk);
  EXPECT_NE(out.flags & shared::kStatsDeviceFault, 0u);
  EXPECT_EQ(loop_->counters().non_finite_input.load(), 1u);

  out = {};
  device_.no_data = true;
  EXPECT_EQ(P::readDevice(*loop_, t_, out), device::IoStatus::kNoData);
  EXPECT_NE(out.flags & shared::kStatsDeviceNoData, 0u);
  EXPECT_EQ(loop_->counters().device_no_data.load(), 1u);
}

TEST_F(HapticPhasesTest, PublishSampleGivesTheSimulationThePoseHeldAndTheDeviceStatus) {
  auto samples = sim_->deviceReader();
  P::adoptOfferedLink(*loop_);
  TickOutput out;
  // before the device's first sample the pose is not one it delivered: never to be followed
  P::publishSample(*loop_, t_, device::IoStatus::kNoData);
  EXPECT_EQ(samples.latest().status & shared::kDevicePoseValid, 0u);
  device_.state.pos_m = {0.01, 0.02, 0.03};
  device_.state.t_ns = t_;
  device_.state.gripper_rad = 0.25;
  device::IoStatus io = P::readDevice(*loop_, t_, out);
  P::publishSample(*loop_, t_, io);
  shared::DeviceSample s = samples.latest();
  EXPECT_EQ(s.seq, 2u);
  EXPECT_NE(s.status & shared::kDevicePoseValid, 0u);
  EXPECT_EQ(s.t_ns, t_);
  EXPECT_DOUBLE_EQ(s.pos_m[0], 0.01);
  EXPECT_DOUBLE_EQ(s.pos_m[2], 0.03);
  EXPECT_DOUBLE_EQ(s.gripper_rad, 0.25);
  EXPECT_NE(s.status & shared::kDeviceOk, 0u);
  EXPECT_EQ(s.status & shared::kDeviceFault, 0u);

  // a non-finite sample: the last good pose is held and the fault is flagged
  device_.state.pos_m = {std::nan(""), 1.0, 1.0};
  io = P::readDevice(*loop_, t_ + 1'000'000, out);
  P::publishSample(*loop_, t_ + 1'000'000, io);
  s = samples.latest();
  EXPECT_EQ(s.seq, 3u);
  EXPECT_DOUBLE_EQ(s.pos_m[0], 0.01);
  EXPECT_DOUBLE_EQ(s.pos_m[1], 0.02);
  EXPECT_NE(s.status & shared::kDeviceFault, 0u);
}

TEST_F(HapticPhasesTest, TakeSnapshotFlagsAMissingOrOldSnapshotAndSolvesAFreshOne) {
  readValidPose();
  TickOutput out;
  P::takeSnapshot(*loop_, t_, out);
  EXPECT_TRUE(out.stale);
  EXPECT_NE(out.flags & shared::kStatsNoSnapshot, 0u);

  publish(-0.002, 1e-3, 0.0, t_ - 1'000'000'000);   // a second old: beyond the 50 ms watchdog
  out = {};
  P::takeSnapshot(*loop_, t_, out);
  EXPECT_TRUE(out.stale);
  EXPECT_NE(out.flags & shared::kStatsSnapshotStale, 0u);
  EXPECT_EQ(out.snapshot_seq, 1u) << "an old snapshot is adopted (warm start), not solved";
  EXPECT_EQ(out.contacts, 0);

  publish(-0.002, 1e-3, 0.0, t_);                    // 2 mm penetration, W = 1 mm/N: 2 N
  out = {};
  P::takeSnapshot(*loop_, t_, out);
  EXPECT_FALSE(out.stale);
  EXPECT_EQ(out.snapshot_seq, 2u);
  EXPECT_EQ(out.contacts, 1);
  EXPECT_NEAR(out.force_n[2], 2.0, 1e-9);
  EXPECT_EQ(loop_->counters().snapshots_taken.load(), 2u);
}

// A tick preempted between its device read and taking the snapshot may be handed one that the
// simulation published meanwhile, stamped after the read: it is aged when taken, so it is fresh,
// never "from the future" (aged at the read, it was 19 ms ahead and faded a correct force).
// One stamped after the moment it was taken still is from the future.
TEST_F(HapticPhasesTest, ASnapshotPublishedWhileTheTickWasPreemptedIsFresh) {
  settings_.watchdog_ms = 1000.0;   // the test's own stalls never make it stale
  loop_.emplace(device_, settings_);
  loop_->offerLink(link_.get());
  readValidPose();
  constexpr std::int64_t kPreemptedNs = 20'000'000;
  // the read 20 ms ago on the real clock, at t_ on the tick's; the snapshot published 19 ms later
  const std::int64_t t_read = shared::monotonicNs() - kPreemptedNs;
  publish(-0.002, 1e-3, 0.0, t_ + kPreemptedNs - 1'000'000);
  TickOutput out;
  P::takeSnapshot(*loop_, t_, out, t_read);
  EXPECT_FALSE(out.stale);
  EXPECT_EQ(out.flags & shared::kStatsSnapshotStale, 0u);
  EXPECT_EQ(out.contacts, 1);
  EXPECT_NEAR(out.force_n[2], 2.0, 1e-9);
  shared::RtEvent e;
  while (loop_->events().tryPop(&e)) EXPECT_NE(e.code, kEventSnapshotFromTheFuture);

  // stamped a minute after it was taken: from the future, not solved, one event
  publish(-0.002, 1e-3, 0.0, shared::monotonicNs() - t_read + t_ + 60'000'000'000);
  out = {};
  P::takeSnapshot(*loop_, t_, out, t_read);
  EXPECT_TRUE(out.stale);
  EXPECT_EQ(out.contacts, 0);
  int future_events = 0;
  while (loop_->events().tryPop(&e)) future_events += e.code == kEventSnapshotFromTheFuture;
  EXPECT_EQ(future_events, 1);
}

TEST_F(HapticPhasesTest, LocalModelMovesDeltaFreeWithTheDevice) {
  publish(-0.002, 1e-3, 0.0, t_);
  ASSERT_EQ(P::prepareNewest(*loop_, *link_), 1u);
  for (const double dz : {-0.001, 0.0, 0.0015, 0.003}) {
    shared::Pose device_pose;
    device_pose.pos_m = Eigen::Vector3d(0.0, 0.0, dz);
    TickOutput out;
    P::solveLocalModel(*loop_, *link_, device_pose, out);
    // delta_free = -2 mm + dz; the contact pushes with f = max(0, -delta_free / w)
    EXPECT_NEAR(out.force_n[2], std::max(0.0, (0.002 - dz) / 1e-3), 1e-9) << "dz " << dz;
    EXPECT_EQ(out.contacts, 1);
  }
}

// A static obstacle's contact (instrument -1, no J row) is in the problem the local model solves
// but pushes no hand: with one instrument only the instrument's contact is rendered.
TEST_F(HapticPhasesTest, AnObstaclesContactPushesNoHand) {
  auto slot = publisher_.slot();
  auto& h = slot.header();
  ASSERT_TRUE(slot.setSize(2, 2));
  h.seq = ++seq_;
  h.t_ns = t_;
  h.flags = shared::kSnapshotValid | shared::kSnapshotHasJacobian;
  const int row_offset[3] = {0, 1, 2};
  std::copy_n(row_offset, 3, slot.rowOffset());
  slot.contactId()[0] = 7;
  slot.contactId()[1] = 8;
  slot.contactInstrument()[0] = 0;    // the instrument's contact: 2 mm deep, W = 1 mm/N
  slot.contactInstrument()[1] = -1;   // an obstacle's: 3 mm deep under the same tissue
  const int ld = slot.ld();   // W is row-major with the segment's leading dimension
  slot.W()[0] = 1e-3;
  slot.W()[1] = 0.0;
  slot.W()[ld] = 0.0;
  slot.W()[ld + 1] = 1e-3;
  slot.deltaFree()[0] = -0.002;
  slot.deltaFree()[1] = -0.003;
  for (int k = 0; k < 2; ++k) {
    slot.mu()[k] = 0.0;
    slot.f()[k] = 0.0;
  }
  for (int k = 0; k < 12; ++k) slot.J()[k] = k == 2 ? 1.0 : 0.0;   // the obstacle's row: 0
  for (int k = 0; k < 6; ++k) {
    slot.contactPoint()[k] = 0.0;
    slot.contactNormal()[k] = k % 3 == 2 ? 1.0 : 0.0;
  }
  publisher_.publish();
  ASSERT_EQ(P::prepareNewest(*loop_, *link_), 1u);
  for (const double dz : {0.0, 0.001}) {
    shared::Pose device_pose;
    device_pose.pos_m = Eigen::Vector3d(0.0, 0.0, dz);
    TickOutput out;
    P::solveLocalModel(*loop_, *link_, device_pose, out);
    EXPECT_EQ(out.contacts, 2);
    EXPECT_NEAR(link_->model.forces()[1], 3.0, 1e-9) << "the obstacle's contact is solved";
    // the instrument's contact follows the device (2 N, then 1 N); the obstacle's 3 N is not felt
    EXPECT_NEAR(out.force_n[2], (0.002 - dz) / 1e-3, 1e-9) << "dz " << dz;
  }
}

TEST_F(HapticPhasesTest, SafetyChainEngagesFadesInClampsAndZeroesNonFiniteWrenches) {
  readValidPose();
  std::array<double, 3> force{}, torque{};
  TickOutput out;
  // one tick's chain on the local model's wrench `command` (the chain overwrites out.force_n);
  // model: the tick solved a usable model for the device
  auto chain = [&](const std::array<double, 3>& command, bool model = true) {
    out = {};
    out.stale = !model;
    out.model = model;
    out.force_n = command;
    P::applySafetyChain(*loop_, out, force, torque);
  };
  chain({0.0, 0.0, 2.0});                   // above the 0.5 N engage threshold: held at zero
  EXPECT_DOUBLE_EQ(out.gain, 0.0);
  EXPECT_DOUBLE_EQ(force[2], 0.0);
  chain({0.0, 0.0, 0.4});                   // below it: engages and fades in (10 ms ramp)
  EXPECT_NEAR(out.gain, 0.1, 1e-12);
  EXPECT_NEAR(force[2], 0.1 * 0.4, 1e-12);
  for (int i = 0; i < 20; ++i) chain({0.0, 0.0, 0.4});
  EXPECT_DOUBLE_EQ(out.gain, 1.0);
  EXPECT_NEAR(force[2], 0.4, 1e-12);

  chain({0.0, 30.0, 40.0});                 // 50 N against the 5 N clamp
  EXPECT_NEAR(std::hypot(force[1], force[2]), 5.0, 1e-9);
  EXPECT_LE(std::hypot(force[1], force[2]), 5.0);
  EXPECT_NE(out.flags & shared::kStatsForceClamped, 0u);
  EXPECT_NEAR(force[2] / force[1], 40.0 / 30.0, 1e-9) << "the clamp keeps the direction";

  chain({0.0, 0.0, 1.0});
  chain({std::nan(""), 0.0, 1.0});          // never rendered: the 1 N held and faded (10 ticks)
  EXPECT_TRUE(std::isfinite(force[0]));
  EXPECT_NEAR(force[2], 0.9, 1e-12);
  for (int i = 0; i < 4; ++i) chain({0.0, 0.0, 0.4}, /*model=*/false);   // no fresh snapshot
  EXPECT_NEAR(force[2], 0.5, 1e-12) << "the held 1 N keeps fading";
  for (int i = 0; i < 20; ++i) chain({0.0, 0.0, 0.4}, /*model=*/false);
  EXPECT_DOUBLE_EQ(out.gain, 0.0);
  EXPECT_DOUBLE_EQ(force[2], 0.0);
  chain({0.0, 0.0, 0.6});                   // back, above the threshold: the gate stays closed
  EXPECT_DOUBLE_EQ(force[2], 0.0);
  chain({0.0, 0.0, 0.3});                   // below it: engaged again
  EXPECT_NEAR(force[2], 0.03, 1e-12);
}

TEST_F(HapticPhasesTest, WriteDeviceSendsTheCommandAndCountsRefusedWrites) {
  P::writeDevice(*loop_, {1.0, 2.0, 3.0}, {0.1, 0.2, 0.3});
  EXPECT_DOUBLE_EQ(device_.last.force_n[1], 2.0);
  EXPECT_DOUBLE_EQ(device_.last.torque_nm[2], 0.3);
  EXPECT_EQ(loop_->counters().write_faults.load(), 0u);

  RefusingDevice refusing;
  HapticLoop other(refusing, settings_);
  P::writeDevice(other, {1.0, 2.0, 3.0}, {0.0, 0.0, 0.0});
  EXPECT_EQ(other.counters().write_faults.load(), 1u);
}

TEST_F(HapticPhasesTest, RecordStatsWritesOneRecordBeatsAndFlagsAnOverrun) {
  auto stats = sim_->statsReader(shared::StatsRingReader::Start::kOldest);
  P::adoptOfferedLink(*loop_);
  TickOutput out;
  out.contacts = 3;
  out.sweeps = 7;
  out.flags = shared::kStatsForceClamped;
  // scheduled in the future: cannot have overrun
  const std::int64_t scheduled = shared::monotonicNs() + 1'000'000'000;
  P::recordStats(*loop_, scheduled, scheduled, out, {3.0, 4.0, 0.0});
  std::vector<shared::StatsRecord> recs(8);
  ASSERT_EQ(stats.poll(recs.data(), recs.size()), 1u);
  EXPECT_EQ(recs[0].contacts, 3);
  EXPECT_EQ(recs[0].sweeps, 7);
  EXPECT_DOUBLE_EQ(recs[0].force_norm_n, 5.0);
  EXPECT_EQ(recs[0].scheduled_ns, scheduled);
  EXPECT_NE(recs[0].flags & shared::kStatsForceClamped, 0u);
  EXPECT_EQ(recs[0].flags & shared::kStatsOverrun, 0u);
  EXPECT_EQ(sim_->heartbeatNs(shared::Side::kHaptic), scheduled);
  EXPECT_EQ(loop_->counters().overruns.load(), 0u);

  // scheduled ten periods ago: the work ended more than a period late
  const std::int64_t late = shared::monotonicNs() - 10 * settings_.period_ns;
  P::recordStats(*loop_, late, late, out, {0.0, 0.0, 0.0});
  ASSERT_EQ(stats.poll(recs.data(), recs.size()), 1u);
  EXPECT_NE(recs[0].flags & shared::kStatsOverrun, 0u);
  EXPECT_EQ(loop_->counters().overruns.load(), 1u);
}

}  // namespace
}  // namespace tactus::haptic
