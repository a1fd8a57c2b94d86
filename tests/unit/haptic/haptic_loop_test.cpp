// The haptic tick on a real shared segment with synthetic contact snapshots: the local model
// moves delta_free with the device, forces rise with penetration, the safety chain (engage gate,
// clamp, watchdog fade) holds, bad device data is survived, and a tick allocates nothing.
#include <gtest/gtest.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <thread>
#include <limits>
#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include "../../support/alloc_counter.h"
#include "../../support/haptic_loop_access.h"
#include "../../support/haptic_segment_test.h"
#include "../../support/scripted_device.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/haptic/supervisor.h"
#include "tactus/shared/clock.h"

namespace tactus::haptic {
namespace {

using test::ScriptedDevice;

class HapticLoopTest : public test::HapticSegmentTest {
 protected:
  // Publishes a general frictionless-or-frictional problem (normals per contact, tangents x/y),
  // with zero J (the device does not move delta_free) and the given flags.
  void publishProblem(const std::vector<int>& row_offset, const std::vector<double>& W,
                      const std::vector<double>& delta_free, const std::vector<double>& f,
                      const std::vector<std::array<double, 3>>& normals, std::uint32_t flags,
                      double jz = 0.0) {
    auto slot = publisher_.slot();
    const int contacts = static_cast<int>(normals.size());
    const int rows = static_cast<int>(delta_free.size());
    ASSERT_TRUE(slot.setSize(rows, contacts));
    auto& h = slot.header();
    h.seq = ++seq_;
    h.t_ns = t_;
    h.flags = flags;
    h.device_pose.pos_m = {0.0, 0.0, 0.0};
    h.tool_pose.pos_m = {0.0, 0.0, 0.0};
    for (int c = 0; c <= contacts; ++c) slot.rowOffset()[c] = row_offset[c];
    for (int c = 0; c < contacts; ++c) {
      slot.contactId()[c] = static_cast<std::uint64_t>(c + 1);
      slot.mu()[c] = 0.0;
      for (int k = 0; k < 3; ++k) {
        slot.contactPoint()[3 * c + k] = 0.0;
        slot.contactNormal()[3 * c + k] = normals[c][k];
        slot.contactTangent()[6 * c + k] = k == 0 ? 1.0 : 0.0;
        slot.contactTangent()[6 * c + 3 + k] = k == 1 ? 1.0 : 0.0;
      }
    }
    for (int i = 0; i < rows; ++i) {
      for (int j = 0; j < rows; ++j) slot.W()[i * slot.ld() + j] = W[i * rows + j];
      slot.deltaFree()[i] = delta_free[i];
      slot.f()[i] = f[i];
      for (int k = 0; k < 6; ++k) slot.J()[6 * i + k] = k == 2 ? jz : 0.0;
    }
    publisher_.publish();
  }

  // A new loop with settings_ on the same segment (the old one lets go of the link first).
  void restartLoop() {
    loop_->offerLink(nullptr);
    t_ += 1'000'000;
    loop_->tick(t_, t_);
    loop_.emplace(device_, settings_);
    loop_->offerLink(link_.get());
  }

  TickOutput tickFor(int n) {
    TickOutput out;
    for (int i = 0; i < n; ++i) {
      t_ += 1'000'000;
      out = loop_->tick(t_, t_);
    }
    return out;
  }
};

TEST_F(HapticLoopTest, ForceRisesWithPenetrationThroughTheLocalModel) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.001, 1e-3, 0.0);           // 1 mm gap at the snapshot pose: no force
  TickOutput out = tickFor(20);
  EXPECT_EQ(out.contacts, 1);
  EXPECT_NEAR(out.force_n[2], 0.0, 1e-12);
  EXPECT_DOUBLE_EQ(out.gain, 1.0);
  double previous = 0.0;
  for (double z : {-0.0015, -0.002, -0.003, -0.004}) {   // press down: the gap closes, then -
    device_.state.pos_m = {0.0, 0.0, z};
    out = tickFor(3);
    const double expected = std::max(0.0, -(0.001 + z) / 1e-3);   // f = -delta_free / W
    EXPECT_NEAR(out.force_n[2], std::min(expected, settings_.max_force_n), 1e-6) << "z = " << z;
    EXPECT_GT(out.force_n[2], previous);
    previous = out.force_n[2];
    // the force pushes the hand out of the tissue (+n), never sideways
    EXPECT_NEAR(out.force_n[0], 0.0, 1e-12);
    EXPECT_NEAR(out.force_n[1], 0.0, 1e-12);
  }
}

TEST_F(HapticLoopTest, AtTheSnapshotPoseTheHapticSolutionEqualsTheSimulations) {
  device_.state.pos_m = {0.0, 0.0, 0.01};
  publish(0.0, 1e-3, 0.01);            // touching: engages at zero force
  tickFor(5);
  publish(-0.002, 1e-3, 0.01);         // the simulation's own solution: f = 2 N
  const TickOutput out = tickFor(30);
  EXPECT_NEAR(out.force_n[2], 2.0, 1e-9);
}

TEST_F(HapticLoopTest, ForcesEngageOnlyOnceTheCommandIsSmall) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(-0.003, 1e-3, 0.0);          // starts deep inside: 3 N would kick the hand
  TickOutput out = tickFor(20);
  EXPECT_DOUBLE_EQ(out.force_n[2], 0.0);
  EXPECT_GT(out.unlimited_force_norm_n, 2.9);
  device_.state.pos_m = {0.0, 0.0, 0.004};   // the hand leaves the tissue
  tickFor(5);
  device_.state.pos_m = {0.0, 0.0, 0.0};     // and comes back: now the force is rendered
  publish(-0.003, 1e-3, 0.0);
  out = tickFor(30);
  EXPECT_NEAR(out.force_n[2], 3.0, 1e-6);
}

TEST_F(HapticLoopTest, ForceNeverExceedsTheClamp) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.0, 1e-3, 0.0);
  tickFor(5);
  for (double z = 0.0; z > -0.05; z -= 0.001) {
    device_.state.pos_m = {0.0, 0.0, z};
    const TickOutput out = tickFor(1);
    const double norm = std::sqrt(out.force_n[0] * out.force_n[0] +
                                  out.force_n[1] * out.force_n[1] + out.force_n[2] * out.force_n[2]);
    EXPECT_LE(norm, settings_.max_force_n + 1e-12);
  }
}

// A lost model (here a stale snapshot) fades what the hand felt: the last rendered wrench is held
// and scaled down linearly over fade_ms (20 ticks here), checked at 25, 50 and 75 % of the ramp,
// with no slew limit to shape it; zero after. Fresh data with the hand still in the tissue does
// not bring the force back (the gate stays closed above the engage threshold); once the hand has
// left the tissue, the force re-engages and a new press is rendered.
TEST_F(HapticLoopTest, StaleSnapshotFadesTheHeldForceOverTheFadeTimeAndReengagesOnlyOutside) {
  settings_.fade_ms = 20.0;
  restartLoop();
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.0, 1e-3, 0.0);
  tickFor(30);                         // engaged, fade-in ramp complete
  publish(-0.002, 1e-3, 0.0, t_);
  TickOutput out = tickFor(1);
  ASSERT_NEAR(out.force_n[2], 2.0, 1e-9);
  // the force is held while the snapshot is younger than the watchdog; the first stale tick
  // starts the fade
  int fresh_ticks = 0;
  for (out = tickFor(1); !out.stale && fresh_ticks < 100; out = tickFor(1)) {
    ASSERT_NEAR(out.force_n[2], 2.0, 1e-9);
    ++fresh_ticks;
  }
  EXPECT_GE(fresh_ticks, static_cast<int>(settings_.watchdog_ms) - 2);
  std::vector<double> ramp = {out.force_n[2]};
  for (int k = 2; k <= 20; ++k) {
    out = tickFor(1);
    ASSERT_TRUE(out.stale) << k;
    ramp.push_back(out.force_n[2]);
  }
  EXPECT_NEAR(ramp[4], 2.0 * 0.75, 1e-9) << "25 % of the ramp";
  EXPECT_NEAR(ramp[9], 2.0 * 0.50, 1e-9) << "50 % of the ramp";
  EXPECT_NEAR(ramp[14], 2.0 * 0.25, 1e-9) << "75 % of the ramp";
  EXPECT_DOUBLE_EQ(ramp[19], 0.0) << "zero at the end of the fade";
  out = tickFor(10);
  EXPECT_DOUBLE_EQ(out.force_n[2], 0.0);
  EXPECT_GT(loop_->counters().stale_ticks.load(), 0u);
  EXPECT_EQ(loop_->counters().disengaged.load(), 1u);
  // fresh again, the hand still 2 mm deep: no force fades back in
  publish(-0.002, 1e-3, 0.0, t_ + 1'000'000);
  out = tickFor(40);
  EXPECT_FALSE(out.stale);
  EXPECT_DOUBLE_EQ(out.force_n[2], 0.0);
  EXPECT_GT(out.unlimited_force_norm_n, 1.9);
  // the hand leaves the tissue: the gate opens; pressing again renders the force
  device_.state.pos_m = {0.0, 0.0, 0.003};
  tickFor(5);
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(-0.002, 1e-3, 0.0);
  out = tickFor(30);
  EXPECT_NEAR(out.force_n[2], 2.0, 1e-9);
}

// The other losses of the model fade the held wrench the same way: a device fault, a corrupt
// snapshot (an ill-posed W) and a snapshot larger than the segment's capacity.
TEST_F(HapticLoopTest, EveryLossOfTheModelFadesTheHeldWrenchLinearly) {
  settings_.fade_ms = 20.0;
  restartLoop();
  enum Loss { kDeviceFault, kIllPosed, kTooLarge };
  for (Loss loss : {kDeviceFault, kIllPosed, kTooLarge}) {
    SCOPED_TRACE(loss);
    device_.fault = false;
    device_.state.pos_m = {0.0, 0.0, 0.003};   // out of the tissue: the gate opens
    publish(0.0, 1e-3, 0.003);
    tickFor(30);
    device_.state.pos_m = {0.0, 0.0, 0.0};     // 3 mm in: 3 N
    publish(0.0, 1e-3, 0.003);                 // (a fresh snapshot)
    ASSERT_NEAR(tickFor(30).force_n[2], 3.0, 1e-9);
    if (loss == kDeviceFault) device_.fault = true;
    if (loss == kIllPosed) {
      publishProblem({0, 1}, {-1e-3}, {-0.003}, {3.0}, {{0.0, 0.0, 1.0}},
                     shared::kSnapshotValid | shared::kSnapshotSymmetricW);
    }
    if (loss == kTooLarge) {
      // rows and contacts beyond the segment's capacity (50 contacts, 150 rows)
      auto slot = publisher_.slot();
      auto& h = slot.header();
      h.seq = ++seq_;
      h.t_ns = t_;
      h.flags = shared::kSnapshotValid | shared::kSnapshotHasJacobian;
      h.rows = 151;
      h.contacts = 51;
      publisher_.publish();
    }
    std::vector<double> ramp;
    for (int k = 1; k <= 20; ++k) ramp.push_back(tickFor(1).force_n[2]);
    EXPECT_NEAR(ramp[4], 3.0 * 0.75, 1e-9);
    EXPECT_NEAR(ramp[9], 3.0 * 0.50, 1e-9);
    EXPECT_NEAR(ramp[14], 3.0 * 0.25, 1e-9);
    EXPECT_DOUBLE_EQ(ramp[19], 0.0);
    EXPECT_DOUBLE_EQ(tickFor(5).force_n[2], 0.0);
  }
}

// The engage gate closes at every interruption, not only at start: after a device fault, a
// stale period or a link change the force returns only once the requested force is below the
// threshold, never with the hand deep in tissue.
TEST_F(HapticLoopTest, TheGateReengagesOnlyBelowTheThresholdAfterEveryInterruption) {
  enum Interruption { kDeviceFault, kStale, kLinkChange };
  for (Interruption what : {kDeviceFault, kStale, kLinkChange}) {
    SCOPED_TRACE(what);
    device_.state.pos_m = {0.0, 0.0, 0.003};
    publish(0.0, 1e-3, 0.003);
    tickFor(30);
    device_.state.pos_m = {0.0, 0.0, 0.0};
    publish(0.0, 1e-3, 0.003);
    ASSERT_NEAR(tickFor(30).force_n[2], 3.0, 1e-9);
    if (what == kDeviceFault) {
      device_.fault = true;
      tickFor(3);
      device_.fault = false;
    } else if (what == kStale) {
      tickFor(static_cast<int>(settings_.watchdog_ms) + 3);
    } else {
      loop_->offerLink(nullptr);
      tickFor(2);
      loop_->offerLink(nullptr);
      link_ = std::make_unique<AttachedSegment>(shared::Segment::open(name_));
      loop_->offerLink(link_.get());
    }
    publish(-0.003, 1e-3, 0.0);                 // a fresh model, the hand 3 mm deep
    TickOutput out;
    for (int k = 0; k < 40; ++k) {   // (within the snapshot's watchdog)
      out = tickFor(1);
      ASSERT_LE(out.force_n[2], std::max(0.0, 3.0 * (1.0 - (k + 1) / 10.0)) + 1e-9)
          << "tick " << k;
    }
    EXPECT_DOUBLE_EQ(out.force_n[2], 0.0);
    EXPECT_FALSE(out.stale);
  }
}

// The slew limit is a budget per nominal period: a tick that comes 50 ms after the previous one
// (a stalled device read) may change the force by no more than any other tick.
TEST_F(HapticLoopTest, TheSlewBudgetIsPerNominalPeriodWhateverTheTimeSinceTheLastTick) {
  settings_.slew_n_per_s = 100.0;   // 0.1 N per 1 ms period
  restartLoop();
  device_.state.pos_m = {0.0, 0.0, 0.003};
  publish(0.0, 1e-3, 0.003);
  tickFor(30);
  device_.state.pos_m = {0.0, 0.0, 0.0};
  double last = tickFor(1).force_n[2];
  EXPECT_NEAR(last, 0.1, 1e-12);
  for (int k = 0; k < 5; ++k) {
    t_ += 50'000'000;                // 50 ms late
    publish(-0.003, 1e-3, 0.0, t_);  // (keep the snapshot fresh)
    const double f = loop_->tick(t_, t_).force_n[2];
    EXPECT_NEAR(f - last, 0.1, 1e-12) << k;
    last = f;
  }
}

// A snapshot stamped in the future is never fresh (its negative age used to pass the watchdog).
TEST_F(HapticLoopTest, ASnapshotStampedInTheFutureIsStale) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.0, 1e-3, 0.0, t_ + 3'600'000'000'000);   // an hour ahead
  TickOutput out = tickFor(5);
  EXPECT_TRUE(out.stale);
  EXPECT_EQ(out.contacts, 0) << "no model solved from it";
  publish(0.0, 1e-3, 0.0, std::numeric_limits<std::int64_t>::max());
  EXPECT_TRUE(tickFor(5).stale);
  publish(0.0, 1e-3, 0.0);
  EXPECT_FALSE(tickFor(1).stale);
}

// A device whose reads take `read_delay` of real time.
class SlowReadingDevice : public ScriptedDevice {
 public:
  device::IoStatus read(device::DeviceState* out) noexcept override {
    std::this_thread::sleep_for(read_delay);
    return ScriptedDevice::read(out);
  }
  std::chrono::milliseconds read_delay{0};
};

// Without a clock (solve_budget_ns = 0: simulated time, in tests and offline tools) a snapshot
// is aged on the caller's clock alone, however long the tick takes in real time: after a 30 ms
// device read, a snapshot 40 ms old on that clock is fresh under the 50 ms watchdog. On the real
// clock (a solve budget) the read's 30 ms count: 70 ms, stale.
TEST_F(HapticLoopTest, WithoutAClockTheSnapshotIsAgedOnTheCallersClockAlone) {
  loop_->offerLink(nullptr);   // the fixture's loop lets go of the segment
  tickFor(1);
  SlowReadingDevice slow;
  slow.state.pos_m = {0.0, 0.0, 0.0};
  for (const bool clocked : {false, true}) {
    SCOPED_TRACE(clocked ? "real clock" : "no clock");
    HapticSettings s = settings_;
    s.solve_budget_ns = clocked ? 400'000 : 0;
    s.max_sweeps = std::min(s.max_sweeps, HapticSettingsLimits::kMaxSweepsWithoutBudget);
    HapticLoop loop(slow, s);
    loop.offerLink(link_.get());
    slow.read_delay = std::chrono::milliseconds(0);
    t_ += 1'000'000;
    (void)loop.tick(t_, t_);   // takes the link
    t_ += 1'000'000;
    publish(-0.002, 1e-3, 0.0, t_ - 40'000'000);
    slow.read_delay = std::chrono::milliseconds(30);
    EXPECT_EQ(loop.tick(t_, t_).stale, clocked);
    loop.offerLink(nullptr);
    slow.read_delay = std::chrono::milliseconds(0);
    t_ += 1'000'000;
    (void)loop.tick(t_, t_);
  }
}

// A zero (or far from unit) quaternion from a device is not an orientation: the sample is
// refused like a non-finite one (the pose held, the force faded), never taken as identity.
TEST_F(HapticLoopTest, AZeroQuaternionFromTheDeviceIsAFaultNotIdentity) {
  auto samples = sim_->deviceReader();
  device_.state.pos_m = {0.0, 0.0, 0.0};
  device_.state.quat_wxyz = {0.0, 0.7071067811865476, 0.0, 0.7071067811865476};
  publish(0.001, 1e-3, 0.0);
  tickFor(5);
  EXPECT_NEAR(samples.latest().quat_wxyz[1], 0.7071067811865476, 1e-15);
  for (const auto& q : {std::array<double, 4>{0.0, 0.0, 0.0, 0.0},
                        std::array<double, 4>{1e-10, 0.0, 0.0, 0.0},
                        std::array<double, 4>{3.0, 0.0, 0.0, 0.0}}) {
    device_.state.quat_wxyz = q;
    const TickOutput out = tickFor(2);
    EXPECT_NE(out.flags & shared::kStatsDeviceFault, 0u);
    const shared::DeviceSample& s = samples.latest();
    EXPECT_NE(s.status & shared::kDeviceFault, 0u);
    EXPECT_NEAR(s.quat_wxyz[1], 0.7071067811865476, 1e-15) << "the last orientation is held";
  }
  EXPECT_EQ(loop_->counters().unusable_orientation.load(), 6u);
  device_.state.quat_wxyz = {1.0, 0.0, 0.0, 1e-4};   // unit up to rounding: accepted
  EXPECT_EQ(tickFor(1).flags & shared::kStatsDeviceFault, 0u);
}

TEST_F(HapticLoopTest, DeviceFaultAndNonFiniteDataFadeWithoutPropagatingNaN) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.0, 1e-3, 0.0);
  tickFor(5);
  publish(-0.002, 1e-3, 0.0);
  tickFor(5);
  device_.state.pos_m = {std::nan(""), 0.0, INFINITY};
  TickOutput out = tickFor(40);
  EXPECT_TRUE(std::isfinite(out.force_n[0]) && std::isfinite(out.force_n[2]));
  EXPECT_DOUBLE_EQ(out.force_n[2], 0.0);
  EXPECT_GT(loop_->counters().non_finite_input.load(), 0u);
  device_.state.pos_m = {0.0, 0.0, 0.0};
  device_.fault = true;
  out = tickFor(5);
  EXPECT_DOUBLE_EQ(out.force_n[2], 0.0);
  EXPECT_GT(loop_->counters().device_faults.load(), 0u);
  device_.fault = false;
  device_.state.pos_m = {0.0, 0.0, 0.003};    // out of the tissue: the gate reopens
  publish(-0.002, 1e-3, 0.0);
  tickFor(20);
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(-0.002, 1e-3, 0.0);
  out = tickFor(40);
  EXPECT_NEAR(out.force_n[2], 2.0, 1e-9);
}

TEST_F(HapticLoopTest, StaleDeviceTimestampsFadeTheForceLikeAFault) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.0, 1e-3, 0.0);
  tickFor(20);
  publish(-0.002, 1e-3, 0.0);
  device_.state.t_ns = t_;                      // fresh samples: force rendered
  TickOutput out = tickFor(1);
  EXPECT_NEAR(out.force_n[2], 2.0, 1e-9);
  publish(-0.002, 1e-3, 0.0);
  device_.state.t_ns = t_ - 1'000'000'000;      // the driver keeps returning a 1 s old sample
  out = tickFor(static_cast<int>(settings_.fade_ms) + 2);
  EXPECT_DOUBLE_EQ(out.force_n[2], 0.0);
  EXPECT_GT(loop_->counters().stale_device_samples.load(), 0u);
}

TEST_F(HapticLoopTest, ASecondHapticProcessOnTheSameSegmentIsRefused) {
  // the fixture's link holds the haptic claim (as a live haptic_server would)
  ASSERT_EQ(link_->segment.claimHaptic(static_cast<std::int64_t>(::getpid())), 0);
  ScriptedDevice other_device;
  HapticLoop other(other_device, settings_);
  Supervisor supervisor(other, name_);
  try {
    supervisor.poll();
    FAIL() << "a second haptic process was accepted";
  } catch (const SegmentError& e) {
    EXPECT_NE(std::string(e.what()).find("already served by haptic_server pid"), std::string::npos)
        << e.what();
  }
}

// ~Supervisor must never free a link the tick may still hold: here the real-time thread has
// adopted the link and then stalls (it never ticks again), and the supervisor is destroyed. The
// link's mapping must still be there afterwards (it used to be unmapped at once).
TEST_F(HapticLoopTest, TheSupervisorNeverFreesALinkTheTickMayStillHold) {
  ScriptedDevice other_device;
  HapticLoop other(other_device, settings_);
  const void* mapped = nullptr;
  AttachedSegment* held = nullptr;
  {
    Supervisor supervisor(other, name_);
    supervisor.poll();                         // attaches and offers the link
    t_ += 1'000'000;
    other.tick(t_, t_);                        // the tick adopts it
    held = other.linkInUse();
    ASSERT_NE(held, nullptr);
    mapped = held->segment.data();
  }                                            // the tick stalls: it never lets go
  const long page = ::sysconf(_SC_PAGESIZE);
  void* first_page = reinterpret_cast<void*>(reinterpret_cast<std::uintptr_t>(mapped) &
                                             ~static_cast<std::uintptr_t>(page - 1));
  unsigned char resident = 0;
  EXPECT_EQ(::mincore(first_page, static_cast<std::size_t>(page), &resident), 0)
      << "the link the tick holds was unmapped";
  t_ += 1'000'000;
  other.tick(t_, t_);                          // the tick lets go at last (it was offered none)
  EXPECT_EQ(other.linkInUse(), nullptr);
  delete held;                                 // (the supervisor left it to the process)
  // a loop that has stopped lets go (HapticLoop::stopped): then the link is freed at once
  ScriptedDevice third_device;
  HapticLoop third(third_device, settings_);
  {
    Supervisor supervisor(third, name_);
    supervisor.poll();
    t_ += 1'000'000;
    third.tick(t_, t_);
    ASSERT_NE(third.linkInUse(), nullptr);
    third.stopped();
    EXPECT_EQ(third.linkInUse(), nullptr);
  }
}

TEST_F(HapticLoopTest, TheSimulationSeesTheDeviceAndEveryTickWritesAStatsRecord) {
  auto samples = sim_->deviceReader();
  auto stats = sim_->statsReader(shared::StatsRingReader::Start::kOldest);
  device_.state.pos_m = {0.01, 0.02, 0.03};
  device_.state.gripper_rad = 0.25;
  publish(0.001, 1e-3, 0.0);
  tickFor(10);
  const shared::DeviceSample& s = samples.latest();
  EXPECT_EQ(s.seq, 10u);
  EXPECT_NE(s.status & shared::kDevicePoseValid, 0u);
  EXPECT_DOUBLE_EQ(s.pos_m[1], 0.02);
  EXPECT_DOUBLE_EQ(s.gripper_rad, 0.25);
  std::vector<shared::StatsRecord> recs(64);
  EXPECT_EQ(stats.poll(recs.data(), recs.size()), 10u);
  EXPECT_EQ(recs[9].tick, 9u);
  EXPECT_EQ(recs[9].contacts, 1);
}

// HapticSettings::snapshot_blend_ms: the step between two snapshots' wrenches is rendered as a
// linear ramp over the blend's ticks (5 here), ending on the new model's wrench; allocation-free.
TEST_F(HapticLoopTest, ANewSnapshotsForceIsBlendedInOverTheBlendTime) {
  settings_.snapshot_blend_ms = 5.0;
  restartLoop();
  device_.state.pos_m = {0.0, 0.0, 0.01};
  publish(0.0, 1e-3, 0.01);            // touching: engages at zero force
  tickFor(20);
  test::AllocScope scope;
  publish(-0.002, 1e-3, 0.01);         // the new model renders 2 N
  for (int k = 1; k <= 5; ++k) EXPECT_NEAR(tickFor(1).force_n[2], 0.4 * k, 1e-9) << k;
  EXPECT_NEAR(tickFor(3).force_n[2], 2.0, 1e-9);
  publish(-0.001, 1e-3, 0.01);         // 1 N: blended down from 2 N
  for (int k = 1; k <= 5; ++k) EXPECT_NEAR(tickFor(1).force_n[2], 2.0 - 0.2 * k, 1e-9) << k;
  // a switch in the middle of a blend starts from what was rendered last
  publish(-0.003, 1e-3, 0.01);         // 3 N
  EXPECT_NEAR(tickFor(1).force_n[2], 1.0 + 2.0 * 0.2, 1e-9);
  EXPECT_NEAR(tickFor(1).force_n[2], 1.0 + 2.0 * 0.4, 1e-9);
  publish(-0.0005, 1e-3, 0.01);        // 0.5 N, from 1.8 N
  EXPECT_NEAR(tickFor(1).force_n[2], 0.5 + 1.3 * 0.8, 1e-9);
  EXPECT_NEAR(tickFor(10).force_n[2], 0.5, 1e-9);
  EXPECT_EQ(scope.allocations(), 0);
  // without blending the new snapshot's force is rendered at once
  settings_.snapshot_blend_ms = 0.0;
  restartLoop();
  publish(0.0, 1e-3, 0.01);
  tickFor(20);
  publish(-0.002, 1e-3, 0.01);
  EXPECT_NEAR(tickFor(1).force_n[2], 2.0, 1e-9);
}

TEST_F(HapticLoopTest, ATickAllocatesNothing) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.0, 1e-3, 0.0);
  tickFor(10);
  test::AllocScope scope;
  for (int i = 0; i < 200; ++i) {
    if (i % 20 == 0) publish(-0.001 * (i % 3), 1e-3, 0.0);
    device_.state.pos_m = {0.0, 0.0, -0.0001 * (i % 7)};
    tickFor(1);
  }
  EXPECT_EQ(scope.allocations(), 0);
  EXPECT_EQ(scope.cAllocations(), 0);
}

// Row offsets stepping by 2 (neither 1 nor 3 rows per contact): NSGS refuses the problem
// (kEmpty) and the wrench must not be built from those offsets (here the snapshot's own f,
// copied as the warm start, would render 3 N).
TEST_F(HapticLoopTest, InconsistentRowOffsetsRenderNoForce) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.001, 1e-3, 0.0);                     // engage at zero force
  tickFor(10);
  publishProblem({0, 2}, {1e-3, 0.0, 0.0, 1e-3}, {-0.003, 0.0}, {3.0, 0.0},
                 {{0.0, 0.0, 1.0}}, shared::kSnapshotValid | shared::kSnapshotSymmetricW);
  const TickOutput out = tickFor(20);
  EXPECT_EQ(out.contacts, 1);
  EXPECT_EQ(out.force_n, (std::array<double, 3>{0.0, 0.0, 0.0}));
  EXPECT_EQ(device_.last.force_n, (std::array<double, 3>{0.0, 0.0, 0.0}));
}

// A W whose diagonal NSGS cannot use (here a negative compliance, W_nn = -1e-3) is a corrupt
// snapshot: the solver reports kIllPosed, and the loop must render no force from it (the
// snapshot's own f of 3 N, copied as the warm start, would otherwise reach the hand), count every
// such solve and raise the event once for the snapshot, not once per tick.
TEST_F(HapticLoopTest, IllPosedSnapshotRendersNoForceAndIsReportedOnce) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.001, 1e-3, 0.0);                     // engage at zero force
  tickFor(10);
  shared::RtEvent e;
  while (loop_->events().tryPop(&e)) {
  }
  publishProblem({0, 1}, {-1e-3}, {-0.003}, {3.0}, {{0.0, 0.0, 1.0}},
                 shared::kSnapshotValid | shared::kSnapshotSymmetricW);
  const TickOutput out = tickFor(20);
  EXPECT_EQ(out.contacts, 1);
  EXPECT_EQ(out.force_n, (std::array<double, 3>{0.0, 0.0, 0.0}));
  EXPECT_EQ(device_.last.force_n, (std::array<double, 3>{0.0, 0.0, 0.0}));
  EXPECT_EQ(loop_->counters().ill_posed_solves.load(), 20u);
  int ill_posed_events = 0;
  while (loop_->events().tryPop(&e)) ill_posed_events += e.code == kEventIllPosedSnapshot;
  EXPECT_EQ(ill_posed_events, 1);
}

// Without kSnapshotSymmetricW the loop must not assume W == W^T. Two frictionless contacts
// (normals z and x) coupled one way only: W f + delta_free = 0 gives f = (0.5, 1) N, so the
// force is (1, 0, 0.5) N; the symmetric sweep (which reads W^T) would give (0.5, 0, 1) N.
TEST_F(HapticLoopTest, WithoutTheSymmetricFlagTheGeneralSweepSolvesANonSymmetricW) {
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.001, 1e-3, 0.0);                     // engage at zero force
  tickFor(10);
  publishProblem({0, 1, 2}, {1e-3, 0.5e-3, 0.0, 1e-3}, {-1e-3, -1e-3}, {0.0, 0.0},
                 {{0.0, 0.0, 1.0}, {1.0, 0.0, 0.0}}, shared::kSnapshotValid);
  const TickOutput out = tickFor(30);
  EXPECT_NEAR(out.force_n[0], 1.0, 1e-6);
  EXPECT_NEAR(out.force_n[1], 0.0, 1e-9);
  EXPECT_NEAR(out.force_n[2], 0.5, 1e-6);
}

// The hazard-pointer handover: the real-time thread stalls after reading an offered link and
// before announcing it; meanwhile the supervisor withdraws the link and, seeing linkInUse() !=
// link, would free it. The tick must then not use it at all.
TEST_F(HapticLoopTest, AWithdrawnLinkIsNeverUsedEvenIfTheTickStalledWhileAdoptingIt) {
  const std::string other = name_ + "_b";
  shared::Segment::remove(other);
  shared::Segment sim_b =
      shared::Segment::create(other, shared::SegmentCapacity::forContacts(4, true));
  auto samples_b = sim_b.deviceReader();
  auto link_b = std::make_unique<AttachedSegment>(shared::Segment::open(other));
  struct Supervisor {
    HapticLoop* loop;
    AttachedSegment* link;
    bool would_free = false;
  } supervisor{&*loop_, link_b.get()};
  HapticLoopTestAccess::setAdoptionHook(
      *loop_,
      [](void* context) {
        auto* s = static_cast<Supervisor*>(context);
        s->loop->offerLink(nullptr);                       // withdraw
        s->would_free = s->loop->linkInUse() != s->link;   // the supervisor's free test
      },
      &supervisor);
  tickFor(2);                                             // on link_ (the fixture's)
  loop_->offerLink(link_b.get());
  tickFor(1);
  EXPECT_TRUE(supervisor.would_free);
  EXPECT_EQ(loop_->linkInUse(), nullptr);
  tickFor(3);
  EXPECT_EQ(samples_b.latest().seq, 0u) << "the tick wrote into a link that may be freed";
  EXPECT_EQ(loop_->linkInUse(), nullptr);
  // the check can see writes: offered and not withdrawn, the link is adopted and written
  HapticLoopTestAccess::setAdoptionHook(*loop_, nullptr, nullptr);
  loop_->offerLink(link_b.get());
  tickFor(2);
  EXPECT_EQ(loop_->linkInUse(), link_b.get());
  EXPECT_GT(samples_b.latest().seq, 0u);
  loop_->offerLink(nullptr);
  tickFor(1);
  EXPECT_EQ(loop_->linkInUse(), nullptr);
  link_b.reset();
  shared::Segment::remove(other);
}

// The protocol's event codes and flags are raised by the loop: force clamped (event, stats
// flag, device-sample flag), solver not converged, device without data, overrun (a tick whose
// work ends more than one period after its scheduled start).
TEST_F(HapticLoopTest, ClampSolverNoDataAndOverrunRaiseTheirEventsAndFlags) {
  auto drain = [this] {
    std::vector<std::uint32_t> codes;
    shared::RtEvent e;
    while (loop_->events().tryPop(&e)) codes.push_back(e.code);
    return codes;
  };
  auto samples = sim_->deviceReader();
  // the simulated clock runs a second ahead of the real one: no tick ends late by accident
  t_ = shared::monotonicNs() + 1'000'000'000;
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publish(0.0, 1e-3, 0.0);
  tickFor(10);
  drain();
  publish(-0.01, 1e-3, 0.0);                       // 10 N against a 5 N clamp
  TickOutput out = tickFor(20);
  EXPECT_NE(out.flags & shared::kStatsForceClamped, 0u);
  tickFor(1);
  EXPECT_NE(samples.latest().status & shared::kDeviceForceClamped, 0u);
  std::vector<std::uint32_t> codes = drain();
  EXPECT_EQ(std::count(codes.begin(), codes.end(), shared::kEventForceClamped), 1)
      << "one event when the clamping starts, not one per tick";

  device_.no_data = true;
  out = tickFor(3);
  EXPECT_NE(out.flags & shared::kStatsDeviceNoData, 0u);
  codes = drain();
  EXPECT_EQ(std::count(codes.begin(), codes.end(), shared::kEventDeviceNoData), 1);
  device_.no_data = false;

  EXPECT_EQ(loop_->counters().overruns.load(), 0u);
  t_ += 1'000'000;
  out = loop_->tick(shared::monotonicNs() - 10 * settings_.period_ns, t_);   // 10 periods late
  EXPECT_EQ(loop_->counters().overruns.load(), 1u);
  codes = drain();
  EXPECT_EQ(std::count(codes.begin(), codes.end(), shared::kEventOverrun), 1);

  // a loop allowed one sweep on a strongly coupled two-contact problem does not converge once
  // the device has moved away from where the snapshot was prepared (the full re-solve)
  loop_->offerLink(nullptr);
  tickFor(1);
  settings_.max_sweeps = 1;
  settings_.local_model = LocalModelKind::kFull;
  loop_.emplace(device_, settings_);
  loop_->offerLink(link_.get());
  device_.state.pos_m = {0.0, 0.0, 0.0};
  publishProblem({0, 1, 2}, {1e-3, 0.9e-3, 0.9e-3, 1e-3}, {-2e-3, -2e-3}, {0.0, 0.0},
                 {{0.0, 0.0, 1.0}, {0.0, 0.0, 1.0}},
                 shared::kSnapshotValid | shared::kSnapshotSymmetricW |
                     shared::kSnapshotHasJacobian,
                 1.0);
  out = tickFor(1);
  EXPECT_EQ(out.flags & shared::kStatsSolverNotConverged, 0u) << "prepared at this pose";
  device_.state.pos_m = {0.0, 0.0, -5e-4};
  out = tickFor(1);
  EXPECT_NE(out.flags & shared::kStatsSolverNotConverged, 0u);
  tickFor(1);
  codes = drain();
  EXPECT_EQ(std::count(codes.begin(), codes.end(), shared::kEventSolverNotConverged), 1);
}

// The counter really sees the C allocator (otherwise the checks above could not fail).
TEST(AllocCounter, CountsMallocCallocAndRealloc) {
  test::AllocScope scope;
  void* volatile a = std::malloc(16);
  void* volatile b = std::calloc(4, 8);
  void* volatile c = std::realloc(a, 64);
  std::free(b);
  std::free(c);
  EXPECT_EQ(scope.cAllocations(), 3);
  EXPECT_EQ(scope.allocations(), 3);
  int* volatile p = new int(3);   // volatile: a new/delete pair may otherwise be elided
  delete p;
  EXPECT_EQ(scope.allocations(), 4);
  EXPECT_EQ(scope.cAllocations(), 3);
}

// A 150-contact frictional problem (450 rows, symmetric W = coupling(i, j) between rows i, j) in
// a segment, published at a depth, with the haptic loop attached to it.
class LargeProblemRig {
 public:
  static constexpr int kContacts = 150;
  static constexpr int kRows = 3 * kContacts;
  using Coupling = double (*)(int i, int j);
  /// Contact c's instrument (-1: an obstacle's or another body's contact, no instrument)
  using Tool = int (*)(int c);

  LargeProblemRig(const std::string& tag, Coupling coupling, Tool tool = nullptr,
                  LocalModelKind kind = LocalModelKind::kFull, int contacts = kContacts)
      : name_("tactus_haptic_large_" + tag + std::to_string(::getpid())), coupling_(coupling),
        tool_(tool), contacts_(contacts) {
    shared::Segment::remove(name_);
    sim_.emplace(
        shared::Segment::create(name_, shared::SegmentCapacity::forContacts(contacts_, true)));
    publisher_ = sim_->snapshotPublisher();
    settings_.solve_budget_ns = 0;   // sweeps bound the solve, not the clock
    settings_.max_sweeps = 20;
    settings_.local_model = kind;
    loop_.emplace(device_, settings_);
    link_ = std::make_unique<AttachedSegment>(shared::Segment::open(name_));
    loop_->offerLink(link_.get());
  }
  ~LargeProblemRig() {
    loop_->offerLink(nullptr);
    tick();
    link_.reset();
    sim_.reset();
    shared::Segment::remove(name_);
  }

  void publish(double depth_m) {
    const int kContacts = contacts_;
    const int kRows = 3 * contacts_;
    auto slot = publisher_.slot();
    ASSERT_TRUE(slot.setSize(kRows, kContacts));
    auto& h = slot.header();
    h.seq = ++seq_;
    h.t_ns = t_;
    h.flags = shared::kSnapshotValid | shared::kSnapshotHasJacobian | shared::kSnapshotSymmetricW;
    const int ld = slot.ld();
    for (int c = 0; c <= kContacts; ++c) slot.rowOffset()[c] = 3 * c;
    for (int c = 0; c < kContacts; ++c) {
      slot.contactId()[c] = static_cast<std::uint64_t>(c + 1);
      slot.contactInstrument()[c] = tool_ != nullptr ? tool_(c) : 0;
      slot.mu()[c] = 0.5;
      for (int k = 0; k < 3; ++k) {
        slot.contactPoint()[3 * c + k] = k == 0 ? 1e-3 * c : 0.0;
        slot.contactNormal()[3 * c + k] = k == 2 ? 1.0 : 0.0;
        slot.contactTangent()[6 * c + k] = k == 0 ? 1.0 : 0.0;
        slot.contactTangent()[6 * c + 3 + k] = k == 1 ? 1.0 : 0.0;
      }
    }
    for (int i = 0; i < kRows; ++i) {
      for (int j = 0; j < kRows; ++j) slot.W()[i * ld + j] = coupling_(i, j);
      const bool normal = i % 3 == 0;
      slot.deltaFree()[i] = normal ? -depth_m : 1e-5 * ((i % 5) - 2);
      slot.f()[i] = 0.0;
      for (int k = 0; k < 6; ++k) slot.J()[6 * i + k] = (normal ? k == 2 : k == (i % 3) - 1);
    }
    publisher_.publish();
  }

  TickOutput tick() {
    t_ += 1'000'000;
    return loop_->tick(t_, t_);
  }

  ScriptedDevice& device() { return device_; }
  AttachedSegment& link() { return *link_; }
  const PreparedSnapshot& prepared() { return *link_->model.adopted(); }
  HapticLoop& loop() { return *loop_; }

 private:
  std::string name_;
  Coupling coupling_;
  Tool tool_;
  int contacts_ = kContacts;
  std::optional<shared::Segment> sim_;
  shared::SnapshotPublisher publisher_;
  ScriptedDevice device_;
  HapticSettings settings_;
  std::optional<HapticLoop> loop_;
  std::unique_ptr<AttachedSegment> link_;
  std::uint64_t seq_ = 0;
  std::int64_t t_ = shared::monotonicNs();
};

// Publishes a new snapshot every 10 ticks while the device moves: 50 ticks without allocation.
TickOutput tickWithoutAllocating(LargeProblemRig& rig) {
  rig.device().state.pos_m = {0.0, 0.0, 0.0};
  rig.publish(1e-4);
  for (int i = 0; i < 5; ++i) (void)rig.tick();
  test::AllocScope scope;
  TickOutput out;
  for (int i = 0; i < 50; ++i) {
    if (i % 10 == 0) rig.publish(1e-4 * (1 + i % 3));
    rig.device().state.pos_m = {1e-5 * (i % 4), 0.0, -1e-5 * (i % 7)};
    out = rig.tick();
  }
  EXPECT_EQ(scope.allocations(), 0);
  EXPECT_EQ(scope.cAllocations(), 0);
  return out;
}

// Many warm-started ticks at the snapshot's pose on one problem (republished within the 50 ms
// watchdog at 0.2 mm), and the norm of the contact force of the instrument's contacts [0,
// tool_contacts) in the whole problem solved densely to 1e-10: the tick's unlimited force must
// match it.
struct SettledAndReference {
  TickOutput settled;
  double reference_n = 0.0;
};
SettledAndReference settleAndSolveDense(LargeProblemRig& rig, LargeProblemRig::Coupling coupling,
                                        int tool_contacts) {
  SettledAndReference out;
  rig.device().state.pos_m = {0.0, 0.0, 0.0};
  for (int i = 0; i < 400; ++i) {
    if (i % 40 == 0) rig.publish(2e-4);
    out.settled = rig.tick();
  }
  const int m = LargeProblemRig::kRows;
  std::vector<double> W(static_cast<std::size_t>(m) * m), q(m);
  std::vector<double> mu(LargeProblemRig::kContacts, 0.5);
  std::vector<int> ro(LargeProblemRig::kContacts + 1);
  for (int c = 0; c <= LargeProblemRig::kContacts; ++c) ro[c] = 3 * c;
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j < m; ++j) W[static_cast<std::size_t>(i) * m + j] = coupling(i, j);
    q[i] = i % 3 == 0 ? -2e-4 : 1e-5 * ((i % 5) - 2);
  }
  const shared::ContactProblemView v = shared::denseProblemView(
      LargeProblemRig::kContacts, m, ro.data(), W.data(), m, q.data(), mu.data());
  shared::NsgsWorkspace ws(m, v.contacts);
  std::vector<double> f(m, 0.0);
  shared::NsgsSettings s;
  s.tolerance = 1e-10;
  s.max_sweeps = 10000;
  EXPECT_EQ(shared::solveNsgs(v, s, ws, f.data()).status, shared::NsgsStatus::kConverged);
  double fx = 0.0, fy = 0.0, fz = 0.0;
  for (int c = 0; c < tool_contacts; ++c) {
    fz += f[3 * c];
    fx += f[3 * c + 1];
    fy += f[3 * c + 2];
  }
  out.reference_n = std::hypot(fx, fy, fz);
  return out;
}

// One tissue: every row coupled with every other (dense W, the dense storage).
double tissueCoupling(int i, int j) {
  return i == j ? 1e-3 : 0.5e-3 * std::exp(-std::abs(i - j));
}

// One tissue whose rows couple over a long range (a smooth compliance: W = 1e-3 exp(-|i - j| / 10)
// plus 5e-5 on the diagonal, positive definite), slow for Gauss-Seidel like the grasp's W.
double smoothTissueCoupling(int i, int j) {
  return 1e-3 * std::exp(-std::abs(i - j) / 10.0) + (i == j ? 5e-5 : 0.0);
}

// Ten bodies of 15 contacts: rows coupled only within a body (10 % of the blocks: the blocks).
double bodiesCoupling(int i, int j) {
  return i / 45 == j / 45 ? tissueCoupling(i, j) : 0.0;
}

// Every tick solves the large frictional problem with NSGS, computes the wrench and runs the
// safety chain without any allocation.
TEST(HapticLoopLarge, AFrictionalTickOf450RowsAllocatesNothing) {
  LargeProblemRig rig("dense", tissueCoupling);
  const TickOutput out = tickWithoutAllocating(rig);
  // it did solve the large frictional problem every tick
  EXPECT_EQ(out.contacts, LargeProblemRig::kContacts);
  EXPECT_GT(out.sweeps, 0);
  EXPECT_GT(out.unlimited_force_norm_n, 0.0);
  EXPECT_FALSE(rig.prepared().usesBlocks());   // one tissue: dense
}

// Several bodies: each new snapshot's W is converted to blocks (by the preparation) and the tick
// solves on them without allocating; the rendered force is the dense solution's.
TEST(HapticLoopLarge, ASeveralBodiesTickSolvesOnTheBlocksWithoutAllocating) {
  LargeProblemRig rig("blocks", bodiesCoupling);
  const TickOutput out = tickWithoutAllocating(rig);
  EXPECT_EQ(out.contacts, LargeProblemRig::kContacts);
  EXPECT_GT(out.sweeps, 0);
  EXPECT_TRUE(rig.prepared().usesBlocks());
  EXPECT_EQ(rig.prepared().blocks().blocks(), 10 * 15 * 15);
  // at the snapshot's pose the force is the dense solve's
  const SettledAndReference r =
      settleAndSolveDense(rig, bodiesCoupling, LargeProblemRig::kContacts);
  EXPECT_GT(r.reference_n, 0.0);
  EXPECT_EQ(r.settled.flags & shared::kStatsSolverNotConverged, 0u);
  // the contact wrench before the safety chain's clamp (normals +z, tangents x and y)
  EXPECT_NEAR(r.settled.unlimited_force_norm_n, r.reference_n, 1e-4 * r.reference_n);
}

// Three bodies of 50 contacts; only the first body's contacts belong to the instrument (the others:
// an organ on its support, which no device moves, marked so by the simulation).
double threeBodies(int i, int j) { return i / 150 == j / 150 ? tissueCoupling(i, j) : 0.0; }
// (the simulation marks the contacts of a group without instrument kContactUnreachable)
int firstBodyTool(int c) { return c < 50 ? 0 : shared::kContactUnreachable; }
int outerBodiesTool(int c) { return c < 50 || c >= 100 ? 0 : shared::kContactUnreachable; }

// The tick re-solves only the contacts a device can move (the first body), in place on W's block,
// without allocating; the force is the whole problem's.
TEST(HapticLoopLarge, ContactsNoDeviceCanMoveAreNotReSolved) {
  LargeProblemRig rig("reach", threeBodies, firstBodyTool);
  const TickOutput out = tickWithoutAllocating(rig);
  EXPECT_EQ(out.contacts, LargeProblemRig::kContacts);
  EXPECT_TRUE(rig.prepared().reachOnly());
  EXPECT_EQ(rig.prepared().reachBegin(), 0);
  EXPECT_EQ(rig.prepared().reachEnd(), 50);
  // at the snapshot's pose the force is the whole problem's (its first body's contacts)
  const SettledAndReference r = settleAndSolveDense(rig, threeBodies, 50);
  EXPECT_GT(r.reference_n, 0.0);
  EXPECT_EQ(r.settled.flags & shared::kStatsSolverNotConverged, 0u);
  EXPECT_NEAR(r.settled.unlimited_force_norm_n, r.reference_n, 1e-4 * r.reference_n);
}

// A new snapshot, the device off the snapshot's pose: the preparation solved it at the device's
// latest pose, so the first tick on it starts from that solution and is converged at once (where
// 20 sweeps from the simulation's f* = 0 are not), at the force the ticks settle to.
TEST(HapticLoopLarge, ANewSnapshotStartsFromThePreparedSolutionAtTheDevicesPose) {
  LargeProblemRig rig("carry", smoothTissueCoupling);
  rig.device().state.pos_m = {0.0, 0.0, -5e-5};
  (void)rig.tick();   // the device's pose reaches the preparation
  rig.publish(2e-4);
  const TickOutput first = rig.tick();
  EXPECT_EQ(first.flags & shared::kStatsSolverNotConverged, 0u);
  EXPECT_LE(first.sweeps, 2);
  EXPECT_TRUE(rig.prepared().preparedConverged());
  EXPECT_GT(rig.prepared().preparedSweeps(), 20);
  TickOutput settled = first;
  for (int i = 0; i < 20; ++i) settled = rig.tick();
  EXPECT_EQ(settled.flags & shared::kStatsSolverNotConverged, 0u);
  EXPECT_NEAR(first.unlimited_force_norm_n, settled.unlimited_force_norm_n,
              1e-4 * settled.unlimited_force_norm_n);
  EXPECT_GT(rig.link().model.forces()[0], 0.0);
}

// The linearised model at 900 rows (300 frictional contacts): ticks where it holds and ticks
// where it falls back to the re-solve (the device beyond the linearisation's range), new
// snapshots prepared in between, and no tick allocates.
TEST(HapticLoopLarge, ALinearisedTickOf900RowsAndItsFallbackAllocateNothing) {
  LargeProblemRig rig("lin900", tissueCoupling, nullptr, LocalModelKind::kLinearized, 300);
  rig.device().state.pos_m = {0.0, 0.0, 0.0};
  rig.publish(1e-4);
  for (int i = 0; i < 3; ++i) (void)rig.tick();
  ASSERT_TRUE(rig.prepared().linearized());
  // the preparation runs in the tick here (no preparer thread): publish outside the scope and
  // count only the ticks that do not prepare
  test::AllocScope scope;
  std::int64_t allocations = 0, c_allocations = 0;
  TickOutput out;
  int out_of_range = 0;   // far ticks that fell back and said why
  for (int i = 0; i < 40; ++i) {
    if (i % 10 == 0) {
      const std::int64_t a = scope.allocations(), ca = scope.cAllocations();
      rig.publish(1e-4 * (1 + i % 3));
      out = rig.tick();
      allocations -= scope.allocations() - a;
      c_allocations -= scope.cAllocations() - ca;
      continue;
    }
    // every fourth tick 3 mm away: out of the linearisation's range, re-solved
    const double far = i % 4 == 0 ? -3e-3 : 0.0;
    rig.device().state.pos_m = {1e-6 * (i % 4), 0.0, -1e-6 * (i % 7) + far};
    out = rig.tick();
    if (far != 0.0 && out.model_used == LocalModelUsed::kFallback &&
        out.fallback_reason == FallbackReason::kOutOfRange && out.correction_rounds == 0) {
      ++out_of_range;
    }
  }
  EXPECT_EQ(scope.allocations() + allocations, 0);
  EXPECT_EQ(scope.cAllocations() + c_allocations, 0);
  EXPECT_EQ(out.contacts, 300);
  EXPECT_GT(rig.loop().counters().linearized_ticks.load(), 10u);
  EXPECT_GT(rig.loop().counters().model_fallbacks.load(), 3u);
  EXPECT_GE(out_of_range, 6);   // 8 far ticks, 2 of them also publish
}

// Contacts a device can move in the first and the last body: not contiguous, so the whole
// problem is solved.
TEST(HapticLoopLarge, ReachedContactsThatAreNotContiguousSolveTheWholeProblem) {
  LargeProblemRig rig("reach_split", threeBodies, outerBodiesTool);
  const TickOutput out = tickWithoutAllocating(rig);
  EXPECT_EQ(out.contacts, LargeProblemRig::kContacts);
  EXPECT_FALSE(rig.prepared().reachOnly());
  EXPECT_GT(out.sweeps, 0);
}

// A device whose read blocks (against the contract) until halt() is called from another thread.
class BlockingDevice : public ScriptedDevice {
 public:
  device::IoStatus read(device::DeviceState* out) noexcept override {
    if (block.load()) {
      while (!halted.load()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
      block.store(false);
      return device::IoStatus::kFault;
    }
    return ScriptedDevice::read(out);
  }
  bool halt() noexcept override {
    if (!haltable) return false;
    halted.store(true);
    return true;
  }
  std::atomic<bool> block{false};
  std::atomic<bool> halted{false};
  bool haltable = true;
};

// One tick of `loop` on a thread of its own (as the real-time thread runs it), which sets
// `returned` once the tick comes back: the watchdog tests' tick blocks.
std::thread tickOnItsOwnThread(HapticLoop& loop, std::atomic<bool>& returned) {
  return std::thread([&loop, &returned] {
    const std::int64_t now = shared::monotonicNs();
    loop.tick(now, now);
    returned.store(true);
  });
}

// Polls `done` every millisecond for up to 5 s; returns its last value.
template <class Done>
bool pollFor5s(Done done) {
  bool d = false;
  for (int i = 0; i < 5000 && !d; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    d = done();
  }
  return d;
}

// The supervisor's watchdog: a tick stuck in a device read past the watchdog is reported and the
// device asked to halt, which lets the tick return (the force then fades like on any fault); a
// device that cannot be halted is reported as such. No durations are asserted: the watchdog is
// polled until it reports.
TEST(HapticWatchdog, ATickStuckInADeviceReadIsReportedAndTheDeviceHalted) {
  for (bool haltable : {true, false}) {
    SCOPED_TRACE(haltable);
    BlockingDevice device;
    device.haltable = haltable;
    HapticSettings settings;
    settings.watchdog_ms = 5.0;
    HapticLoop loop(device, settings);
    Supervisor supervisor(loop, "tactus_watchdog_test_" + std::to_string(::getpid()));
    EXPECT_FALSE(supervisor.watchTick(shared::monotonicNs())) << "no tick runs";
    device.block.store(true);
    std::atomic<bool> returned{false};
    std::thread rt = tickOnItsOwnThread(loop, returned);
    const bool stuck = pollFor5s([&] { return supervisor.watchTick(shared::monotonicNs()); });
    EXPECT_TRUE(stuck);
    if (!haltable) {
      EXPECT_EQ(loop.tickProgress(shared::monotonicNs()).device, 0) << "stuck in device 0";
      EXPECT_FALSE(returned.load());
    }
    EXPECT_EQ(device.halted.load(), haltable) << "the watchdog asks a haltable device to halt";
    device.halted.store(true);   // the test lets it go (also when the watchdog failed)
    rt.join();
    EXPECT_TRUE(returned.load());
    EXPECT_EQ(loop.counters().device_faults.load(), 1u);
    EXPECT_FALSE(supervisor.watchTick(shared::monotonicNs()));
    loop.stopped();
  }
}

// A tick first seen stuck outside a device call (here held in the link adoption, as a tick
// preempted before its device read would be) and then stuck in a device's read: the watchdog
// still asks that device to halt, and the tick returns.
TEST(HapticWatchdog, ATickFirstStuckOutsideADeviceCallIsHaltedOnceInOne) {
  const std::string name = "tactus_watchdog_late_" + std::to_string(::getpid());
  shared::Segment::remove(name);
  shared::Segment sim = shared::Segment::create(name, shared::SegmentCapacity::forContacts(4, true));
  // offered to the tick, which adopts it (and runs the hook) at its start; outlives the loop
  auto link = std::make_unique<AttachedSegment>(shared::Segment::open(name));
  BlockingDevice device;
  HapticSettings settings;
  settings.watchdog_ms = 5.0;
  HapticLoop loop(device, settings);
  Supervisor supervisor(loop, name + "_none");
  struct Gate {
    std::atomic<bool> entered{false};
    std::atomic<bool> open{false};
  } gate;
  HapticLoopTestAccess::setAdoptionHook(
      loop,
      [](void* context) {
        auto* g = static_cast<Gate*>(context);
        g->entered.store(true);
        while (!g->open.load()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
      },
      &gate);
  loop.offerLink(link.get());
  device.block.store(true);
  std::atomic<bool> returned{false};
  std::thread rt = tickOnItsOwnThread(loop, returned);
  const bool stuck_outside = pollFor5s(
      [&] { return gate.entered.load() && supervisor.watchTick(shared::monotonicNs()); });
  EXPECT_TRUE(stuck_outside);
  EXPECT_EQ(loop.tickProgress(shared::monotonicNs()).device, -1) << "held before the read";
  EXPECT_FALSE(device.halted.load()) << "no device call to halt yet";
  gate.open.store(true);   // the tick goes on into the blocking read
  for (int i = 0; i < 5000 && !device.halted.load(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    EXPECT_TRUE(supervisor.watchTick(shared::monotonicNs()) || returned.load());
  }
  EXPECT_TRUE(device.halted.load()) << "the watchdog asks the device it is stuck in to halt";
  device.halted.store(true);   // the test lets it go (also when the watchdog failed)
  rt.join();
  EXPECT_TRUE(returned.load());
  EXPECT_EQ(loop.counters().device_faults.load(), 1u);
  EXPECT_FALSE(supervisor.watchTick(shared::monotonicNs()));
  HapticLoopTestAccess::setAdoptionHook(loop, nullptr, nullptr);
  loop.offerLink(nullptr);
  loop.stopped();
  shared::Segment::remove(name);
}

}  // namespace
}  // namespace tactus::haptic
