// Several devices, one local model: the real haptic loop serving two scripted
// devices on the contact problem of tests/data/scenes/press_cube_bimanual.yaml (two probes
// pressing a soft cube from its -x and +x faces), published by the real simulation:
//  * each hand feels the wrench on its own instrument (the simulation's, per instrument);
//  * hand A pressing deeper changes hand B's force only through the tissue (W's coupling), with
//    the sign and size of a full simulation step;
//  * faulting or silencing one device fades only that device's force;
//  * each device has its own workspace mapping (pose in, force back, clamp);
//  * the two-device tick allocates nothing; the stats record carries each device's force;
//  * sim_server's side reads each device's samples for its own instrument.
#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "../../support/alloc_counter.h"
#include "../../support/scripted_device.h"
#include "../../../sim_server/src/app/segment_host.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/workspace_mapping.h"
#include "tactus/shared/segment.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/scene.h"

namespace tactus {
namespace {

using haptic::TickOutput;
using test::ScriptedDevice;

const std::string kScene = std::string(TACTUS_TEST_DATA_DIR) + "/scenes/press_cube_bimanual.yaml";

sim::SceneSpec bimanualScene() {
  sim::SceneSpec spec = sim::loadScene(kScene);
  spec.haptics.enabled = false;
  spec.solver.nsgs_tolerance = 1e-12;
  spec.solver.nsgs_max_sweeps = 5000;
  return spec;
}

// Both probes pressed in and settled at their scripts' end (deterministic: two calls give two
// identical simulations). Returns each instrument's device target.
std::vector<sim::DeviceTarget> settle(sim::Simulation& s) {
  std::vector<sim::DeviceTarget> targets;
  for (int i = 0; i < s.instrumentCount(); ++i) targets.push_back(s.scriptedTarget(i, 1.0));
  for (int k = 0; k < 100; ++k) {
    for (int i = 0; i < s.instrumentCount(); ++i) s.setDeviceTarget(i, targets[i]);
    s.step();
  }
  return targets;
}

Eigen::Vector3d vec(const std::array<double, 3>& a) { return {a[0], a[1], a[2]}; }

// The simulation's contact force on each instrument, from its own contacts (scene frame).
std::array<Eigen::Vector3d, 2> instrumentForces(const sim::ContactProblemData& p) {
  std::array<Eigen::Vector3d, 2> f = {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
  for (int c = 0; c < p.contacts; ++c) {
    const int r0 = p.row_offset[c];
    f[static_cast<std::size_t>(p.contact_instrument[c])] +=
        p.f[r0] * p.normal[c] + p.f[r0 + 1] * p.tangent1[c] + p.f[r0 + 2] * p.tangent2[c];
  }
  return f;
}

class BimanualHapticTest : public ::testing::Test {
 protected:
  void SetUp() override {
    sim_.emplace(bimanualScene());
    targets_ = settle(*sim_);
    name_ = "tactus_bimanual_test_" + std::to_string(::getpid());
    shared::Segment::remove(name_);
    shared::SegmentCapacity cap = shared::SegmentCapacity::forContacts(
        sim::problemContactCapacity(sim_->spec()), sim::anyFriction(sim_->spec()));
    cap.devices = 2;
    segment_.emplace(shared::Segment::create(name_, cap));
    publisher_ = segment_->snapshotPublisher();
    settings_.max_force_n = 20.0;
    settings_.slew_n_per_s = 1e6;
    settings_.fade_ms = 10.0;
    settings_.engage_threshold_n = 1e9;   // engage at once: the test starts pressed
    // each snapshot is solved to 1e-13 by the preparation; the tick goes on from there
    settings_.max_sweeps = haptic::HapticSettingsLimits::kMaxSweepsWithoutBudget;
    settings_.tolerance = 1e-12;
    settings_.solve_budget_ns = 0;        // sweeps bound the solve, not the clock
    device::Device* devices[] = {&hands_[0], &hands_[1]};
    loop_.emplace(std::span<device::Device* const>(devices, 2), settings_);
    link_ = std::make_unique<haptic::AttachedSegment>(shared::Segment::open(name_));
    loop_->offerLink(link_.get());
    for (int i = 0; i < 2; ++i) place(i, targets_[static_cast<std::size_t>(i)].pose.pos_m);
    publish();
  }
  void TearDown() override {
    loop_->offerLink(nullptr);
    tick();
    link_.reset();
    segment_.reset();
    shared::Segment::remove(name_);
  }

  void place(int i, const Eigen::Vector3d& p) {
    hands_[static_cast<std::size_t>(i)].state.pos_m = {p.x(), p.y(), p.z()};
  }
  // The simulation's last problem; `cut` zeroes W between the two instruments' rows (as if the
  // tissue did not couple them).
  void publish(bool cut = false) {
    cut_ = cut;
    shared::SnapshotWriter slot = publisher_.slot();
    ASSERT_TRUE(sim::writeSnapshot(*sim_, 1.0, ++seq_, t_, 0, slot));
    if (cut) {
      const sim::ContactProblemData& p = sim_->lastProblem();
      for (int a = 0; a < p.contacts; ++a) {
        for (int b = 0; b < p.contacts; ++b) {
          if (p.contact_instrument[a] == p.contact_instrument[b]) continue;
          for (int i = p.row_offset[a]; i < p.row_offset[a + 1]; ++i) {
            for (int j = p.row_offset[b]; j < p.row_offset[b + 1]; ++j) {
              slot.W()[i * slot.ld() + j] = 0.0;
            }
          }
        }
      }
    }
    publisher_.publish();
  }
  // One 1 ms tick; the same problem is published again every 10 ms (as the simulation would at
  // 100 Hz), so the snapshot never goes stale.
  TickOutput tick() {
    t_ += 1'000'000;
    if (++ticks_ % 10 == 0) publish(cut_);
    for (ScriptedDevice& h : hands_) {
      if (!frozen_[static_cast<std::size_t>(&h - hands_)]) h.state.t_ns = t_;
    }
    return loop_->tick(t_, t_);
  }
  TickOutput tickFor(int n) {
    TickOutput out;
    for (int i = 0; i < n; ++i) out = tick();
    return out;
  }

  std::optional<sim::Simulation> sim_;
  std::vector<sim::DeviceTarget> targets_;
  std::string name_;
  std::optional<shared::Segment> segment_;
  shared::SnapshotPublisher publisher_;
  ScriptedDevice hands_[2];
  bool frozen_[2] = {false, false};   ///< the hand's time stamps stop (a dead driver)
  haptic::HapticSettings settings_;
  std::optional<haptic::HapticLoop> loop_;
  std::unique_ptr<haptic::AttachedSegment> link_;
  std::uint64_t seq_ = 0;
  std::int64_t t_ = shared::monotonicNs();
  long ticks_ = 0;
  bool cut_ = false;   ///< the published problem has W's coupling between instruments cut
};

TEST_F(BimanualHapticTest, EachHandFeelsTheWrenchOnItsOwnInstrument) {
  auto stats = segment_->statsReader(shared::StatsRingReader::Start::kOldest);
  const TickOutput out = tickFor(30);
  ASSERT_EQ(out.devices, 2);
  ASSERT_FALSE(out.stale);
  const std::array<Eigen::Vector3d, 2> expected = instrumentForces(sim_->lastProblem());
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector3d felt = vec(out.device[static_cast<std::size_t>(i)].force_n);
    std::printf("hand %d feels (%.5f, %.5f, %.5f) N, the simulation's instrument %d (%.5f, %.5f, "
                "%.5f) N\n", i, felt.x(), felt.y(), felt.z(), i, expected[i].x(),
                expected[i].y(), expected[i].z());
    EXPECT_GT(expected[i].norm(), 0.5);
    EXPECT_LT((felt - expected[i]).norm(), 1e-6 * expected[i].norm()) << "hand " << i;
    EXPECT_DOUBLE_EQ(out.device[static_cast<std::size_t>(i)].gain, 1.0);
    // and it is what the device was told to render
    EXPECT_EQ(hands_[i].last.force_n, out.device[static_cast<std::size_t>(i)].force_n);
  }
  EXPECT_LT(out.device[0].force_n[0], -0.5);   // the left hand is pushed back toward -x
  EXPECT_GT(out.device[1].force_n[0], 0.5);    // the right one toward +x
  EXPECT_EQ(out.force_n, out.device[0].force_n);
  // the stats record carries both devices' forces
  std::vector<shared::StatsRecord> recs(64);
  const std::size_t n = stats.poll(recs.data(), recs.size());
  ASSERT_GT(n, 0u);
  EXPECT_EQ(recs[n - 1].devices, 2);
  EXPECT_DOUBLE_EQ(recs[n - 1].device_force_norm_n[1], vec(out.device[1].force_n).norm());
  EXPECT_DOUBLE_EQ(recs[n - 1].force_norm_n, vec(out.device[0].force_n).norm());
  // each hand's sample reached its own device buffer
  auto sample1 = segment_->deviceReader(1);
  EXPECT_DOUBLE_EQ(sample1.latest().pos_m[0], targets_[1].pose.pos_m.x());
  auto sample0 = segment_->deviceReader(0);
  EXPECT_DOUBLE_EQ(sample0.latest().pos_m[0], targets_[0].pose.pos_m.x());
}

TEST_F(BimanualHapticTest, HandAPressingShowsAtHandBOnlyThroughTheTissue) {
  const double dx_m = 3e-4;   // hand A (left) presses 0.3 mm deeper, toward +x
  const Eigen::Vector3d b_before = vec(tickFor(30).device[1].force_n);
  const Eigen::Vector3d a_before = vec(tickFor(1).device[0].force_n);
  place(0, targets_[0].pose.pos_m + Eigen::Vector3d(dx_m, 0.0, 0.0));
  const TickOutput moved = tickFor(30);
  const Eigen::Vector3d db_haptic = vec(moved.device[1].force_n) - b_before;
  const Eigen::Vector3d da_haptic = vec(moved.device[0].force_n) - a_before;

  // a full simulation step from the same state, with and without A's displacement
  sim::Simulation with(bimanualScene());
  sim::Simulation without(bimanualScene());
  std::vector<sim::DeviceTarget> tw = settle(with);
  const std::vector<sim::DeviceTarget> to = settle(without);
  tw[0].pose.pos_m.x() += dx_m;
  for (int i = 0; i < 2; ++i) {
    with.setDeviceTarget(i, tw[static_cast<std::size_t>(i)]);
    without.setDeviceTarget(i, to[static_cast<std::size_t>(i)]);
  }
  const sim::StepReport rw = with.step();
  const sim::StepReport ro = without.step();
  const Eigen::Vector3d db_full = rw.tool_wrenches[1].head<3>() - ro.tool_wrenches[1].head<3>();
  const Eigen::Vector3d da_full = rw.tool_wrenches[0].head<3>() - ro.tool_wrenches[0].head<3>();
  std::printf("hand A presses %.1f mm: A's force changes by %.7f N (full step %.7f N), B's by "
              "%.7f N (full step %.7f N)\n", 1e3 * dx_m, da_haptic.x(), da_full.x(),
              db_haptic.x(), db_full.x());
  EXPECT_LT(da_haptic.x(), -0.05);    // A pushed back harder
  EXPECT_GT(db_haptic.x(), 1e-3);     // B pushed harder toward +x, through the cube
  EXPECT_GT(db_full.x(), 1e-3);
  // the local model's change of force, each hand's, is the full step's to within 1 %
  EXPECT_NEAR(db_haptic.x(), db_full.x(), 0.01 * db_full.x());
  EXPECT_NEAR(da_haptic.x(), da_full.x(), 0.01 * std::abs(da_full.x()));
  EXPECT_LT((db_haptic - db_full).norm(), 0.01 * db_full.norm());

  // the same snapshot without the tissue's coupling between the instruments: A's motion no
  // longer reaches B (B's rows never move with A's device; only W carried it)
  place(0, targets_[0].pose.pos_m);
  publish(/*cut=*/true);
  const TickOutput cut_before = tickFor(30);
  const Eigen::Vector3d b_cut = vec(cut_before.device[1].force_n);
  place(0, targets_[0].pose.pos_m + Eigen::Vector3d(dx_m, 0.0, 0.0));
  const TickOutput cut_moved = tickFor(30);
  // A still presses harder
  EXPECT_LT(cut_moved.device[0].force_n[0], cut_before.device[0].force_n[0] - 0.05);
  EXPECT_LT((vec(cut_moved.device[1].force_n) - b_cut).norm(), 1e-9);
}

TEST_F(BimanualHapticTest, FaultingOrSilencingOneDeviceFadesOnlyItsForce) {
  const TickOutput before = tickFor(30);
  const Eigen::Vector3d a = vec(before.device[0].force_n);
  ASSERT_GT(vec(before.device[1].force_n).norm(), 0.5);
  // hand B reports a fault: its force fades to zero (10 ms fade), hand A's stays
  hands_[1].fault = true;
  TickOutput out = tickFor(30);
  EXPECT_EQ(vec(out.device[1].force_n).norm(), 0.0);
  EXPECT_EQ(out.device[1].gain, 0.0);
  EXPECT_EQ(vec(hands_[1].last.force_n).norm(), 0.0);
  EXPECT_DOUBLE_EQ(out.device[0].gain, 1.0);
  EXPECT_LT((vec(out.device[0].force_n) - a).norm(), 1e-9 * a.norm());
  // B back: it engages and feels its force again
  hands_[1].fault = false;
  out = tickFor(30);
  EXPECT_DOUBLE_EQ(out.device[1].gain, 1.0);
  EXPECT_GT(vec(out.device[1].force_n).norm(), 0.5);
  // B's driver dies (its time stamps stop): past the 50 ms watchdog its force fades, A's not
  frozen_[1] = true;
  out = tickFor(40);
  EXPECT_GT(vec(out.device[1].force_n).norm(), 0.0) << "still within the watchdog";
  out = tickFor(40);
  EXPECT_EQ(vec(out.device[1].force_n).norm(), 0.0);
  EXPECT_DOUBLE_EQ(out.device[0].gain, 1.0);
  EXPECT_LT((vec(out.device[0].force_n) - a).norm(), 1e-9 * a.norm());
  // and silencing A instead fades A only
  frozen_[1] = false;
  hands_[0].fault = true;
  out = tickFor(40);
  EXPECT_EQ(vec(out.device[0].force_n).norm(), 0.0);
  EXPECT_DOUBLE_EQ(out.device[1].gain, 1.0);
  EXPECT_GT(vec(out.device[1].force_n).norm(), 0.5);
}

// Each device its own workspace mapping: device 0 the identity, device 1 scale
// 2, a quarter turn about z and an offset. Hand 1 is held where its mapping puts the instrument
// at its settled pose: the simulation sees both instruments where they were (each device's pose
// mapped with its own mapping), hand 0 feels the scene force, hand 1 the scene force turned back
// by its own inverse rotation and divided by its own scale; a small scale that would amplify
// hand 1's force past the clamp is clamped on device 1 only.
TEST_F(BimanualHapticTest, EachDeviceHasItsOwnWorkspaceMapping) {
  const double h = std::sqrt(0.5);
  shared::WorkspaceMappingParams turned;
  turned.scale = 2.0;
  turned.offset_m = {0.01, -0.02, 0.005};
  turned.rotation_wxyz = {h, 0.0, 0.0, h};   // device x -> scene y, device y -> scene -x
  const Eigen::Matrix3d r = Eigen::Quaterniond(h, 0.0, 0.0, h).toRotationMatrix();
  const auto hold = [&](const shared::WorkspaceMappingParams& w) {
    loop_->workspaceMapping(1).configure(w);
    const Eigen::Vector3d p = targets_[1].pose.pos_m;
    std::array<double, 3> pos{p.x(), p.y(), p.z()};
    std::array<double, 4> quat{1.0, 0.0, 0.0, 0.0};   // the scene orientation of the identity
    w.sceneToDevice(pos, quat);
    hands_[1].state.pos_m = pos;
    hands_[1].state.quat_wxyz = quat;
  };
  hold(turned);
  const Eigen::Vector3d device_pos(hands_[1].state.pos_m[0], hands_[1].state.pos_m[1],
                                   hands_[1].state.pos_m[2]);
  // the hand is not where the instrument is: the mapping, not the identity, brings it there
  ASSERT_GT((device_pos - targets_[1].pose.pos_m).norm(), 0.01);
  EXPECT_LT((vec(turned.offset_m) + 2.0 * r * device_pos - targets_[1].pose.pos_m).norm(), 1e-12);
  TickOutput out = tickFor(30);
  ASSERT_EQ(out.devices, 2);
  ASSERT_FALSE(out.stale);
  // the simulation's side sees each instrument where it settled
  auto sample1 = segment_->deviceReader(1);
  auto sample0 = segment_->deviceReader(0);
  EXPECT_LT((vec(sample1.latest().pos_m) - targets_[1].pose.pos_m).norm(), 1e-12);
  EXPECT_NEAR(std::abs(sample1.latest().quat_wxyz[0]), 1.0, 1e-12);
  EXPECT_EQ(vec(sample0.latest().pos_m), targets_[0].pose.pos_m);
  // the forces: device 0's the scene's, device 1's R^T f / scale
  const std::array<Eigen::Vector3d, 2> scene = instrumentForces(sim_->lastProblem());
  const Eigen::Vector3d expected1 = r.transpose() * scene[1] / 2.0;
  const Eigen::Vector3d felt0 = vec(out.device[0].force_n);
  const Eigen::Vector3d felt1 = vec(out.device[1].force_n);
  std::printf("scene force on instrument 1 (%.5f, %.5f, %.5f) N; hand 1 feels (%.5f, %.5f, "
              "%.5f) N\n", scene[1].x(), scene[1].y(), scene[1].z(), felt1.x(), felt1.y(),
              felt1.z());
  EXPECT_GT(scene[1].x(), 0.5);
  EXPECT_LT((felt0 - scene[0]).norm(), 1e-6 * scene[0].norm());
  EXPECT_LT((felt1 - expected1).norm(), 1e-6 * expected1.norm());
  EXPECT_LT(felt1.y(), -0.25);   // scene +x is device -y for this rotation
  EXPECT_EQ(hands_[1].last.force_n, out.device[1].force_n);   // what device 1 was told
  EXPECT_LE(felt1.norm(), loop_->forceLimitN(1));

  // scale 0.01: the hand would feel 100 times the scene force, past the 20 N clamp; device 1 is
  // clamped along the same direction, device 0 keeps its force
  shared::WorkspaceMappingParams small = turned;
  small.scale = 0.01;
  hold(small);
  ASSERT_GT(scene[1].norm() / 0.01, 2.0 * loop_->forceLimitN(1));
  out = tickFor(30);
  const Eigen::Vector3d clamped = vec(out.device[1].force_n);
  EXPECT_LT((vec(sample1.latest().pos_m) - targets_[1].pose.pos_m).norm(), 1e-12);
  EXPECT_NEAR(clamped.norm(), loop_->forceLimitN(1), 1e-9);
  EXPECT_GT(clamped.normalized().dot(expected1.normalized()), 1.0 - 1e-9);
  EXPECT_TRUE(out.flags & shared::kStatsForceClamped);
  EXPECT_EQ(hands_[1].last.force_n, out.device[1].force_n);
  EXPECT_LT((vec(out.device[0].force_n) - scene[0]).norm(), 1e-6 * scene[0].norm());
}

TEST_F(BimanualHapticTest, TheTwoDeviceTickAllocatesNothing) {
  tickFor(10);
  long allocations = 0;
  long c_allocations = 0;
  TickOutput out;
  for (int round = 0; round < 5; ++round) {
    publish(round % 2 == 1);   // a new snapshot each round (adopted inside the counted ticks)
    test::AllocScope scope;
    for (int i = 0; i < 10; ++i) {
      place(0, targets_[0].pose.pos_m + Eigen::Vector3d(1e-5 * (i % 4), 0.0, 0.0));
      place(1, targets_[1].pose.pos_m - Eigen::Vector3d(1e-5 * (i % 3), 0.0, 0.0));
      hands_[1].fault = round == 3 && i < 5;   // the fault path too
      out = tick();
    }
    allocations += scope.allocations();
    c_allocations += scope.cAllocations();
  }
  EXPECT_EQ(allocations, 0);
  EXPECT_EQ(c_allocations, 0);
  EXPECT_GT(out.contacts, 1);
  EXPECT_GT(vec(out.device[1].force_n).norm(), 0.0);
}

TEST(BimanualSegmentHost, EachDeviceDrivesItsOwnInstrument) {
  const sim::SceneSpec spec = bimanualScene();
  sim::Simulation s(spec);
  const std::string name = "tactus_bimanual_host_" + std::to_string(::getpid());
  shared::Segment::remove(name);
  sim::SegmentHost host(name, spec, {s.instrument(0).workspace(), s.instrument(1).workspace()});
  ASSERT_EQ(host.segment().capacity().devices, 2);
  shared::Segment haptic = shared::Segment::open(name);
  auto writer1 = haptic.deviceWriter(1);
  EXPECT_THROW(haptic.deviceWriter(2), SegmentError);
  shared::DeviceSample sample;
  sample.seq = 1;
  sample.t_ns = shared::monotonicNs();
  sample.pos_m = {0.040, -0.002, 0.012};   // near instrument 1's start (a plausible jump)
  sample.status = shared::kDeviceOk | shared::kDevicePoseValid;
  writer1.publish(sample);
  sim::DeviceTarget t0 = s.scriptedTarget(0, 0.0);
  sim::DeviceTarget t1 = s.scriptedTarget(1, 0.0);
  const Eigen::Vector3d script0 = t0.pose.pos_m;
  EXPECT_FALSE(host.deviceTarget(0, t0));    // device 0 silent: instrument 0 keeps its script
  EXPECT_EQ(t0.pose.pos_m, script0);
  EXPECT_TRUE(host.deviceTarget(1, t1));     // device 1 drives instrument 1
  EXPECT_DOUBLE_EQ(t1.pose.pos_m.x(), 0.040);
  EXPECT_FALSE(host.deviceTarget(2, t1));    // no such device
  // the published snapshot carries both instruments' blocks and each contact's instrument
  for (int k = 0; k < 60; ++k) {
    for (int i = 0; i < 2; ++i) s.setDeviceTarget(i, s.scriptedTarget(i, s.time()));
    s.step();
  }
  host.publish(s);
  auto sub = haptic.snapshotSubscriber();
  const shared::SnapshotView v = sub.latest();
  ASSERT_EQ(v.header().instruments, 2);
  EXPECT_EQ(v.header().instrument[1].tool_pose.pos_m[0], s.instrument(1).pose().pos_m.x());
  EXPECT_EQ(v.header().instrument[0].tool_pose.pos_m[0], v.header().tool_pose.pos_m[0]);
  int per[2] = {0, 0};
  for (int c = 0; c < v.contacts(); ++c) ++per[v.contactInstrument()[c]];
  EXPECT_GT(per[0], 0);
  EXPECT_GT(per[1], 0);
  shared::Segment::remove(name);
}

}  // namespace
}  // namespace tactus
