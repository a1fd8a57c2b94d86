// The workspace mapping (scale, offset, rotation, clutch) on its own and inside the real haptic
// tick: the simulation and the local model see the mapped scene pose, the clutch holds the
// instrument and releases it without a jump, the force goes back to the device frame with the
// inverse rotation and the scale convention of docs/design.md, and the clamp applies after it.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <optional>
#include <string>

#include "../../support/alloc_counter.h"
#include "../../support/one_contact_rig.h"
#include "../../support/scripted_device.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/haptic/workspace_mapping.h"
#include "tactus/shared/clock.h"

namespace tactus::haptic {
namespace {

using shared::WorkspaceMappingParams;

// 90 degrees about x: device +y -> scene +z, device +z -> scene -y
const std::array<double, 4> kQuarterTurnX{std::sqrt(0.5), std::sqrt(0.5), 0.0, 0.0};

double mappingNorm3(const std::array<double, 3>& v) {
  return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

TEST(WorkspaceMappingParams, RejectsNonFiniteOrOutOfRangeValues) {
  EXPECT_EQ(WorkspaceMappingParams{}.problem(), "");
  auto bad = [](auto edit) {
    WorkspaceMappingParams p;
    edit(p);
    return p.problem();
  };
  EXPECT_NE(bad([](auto& p) { p.scale = 0.0; }).find("scale"), std::string::npos);
  EXPECT_NE(bad([](auto& p) { p.scale = NAN; }).find("scale"), std::string::npos);
  EXPECT_NE(bad([](auto& p) { p.scale = 1e3; }).find("scale"), std::string::npos);
  EXPECT_NE(bad([](auto& p) { p.offset_m[1] = INFINITY; }).find("offset[1]"), std::string::npos);
  EXPECT_NE(bad([](auto& p) { p.rotation_wxyz = {1, 0, 0, 0.1}; }).find("unit"),
            std::string::npos);
  EXPECT_NE(bad([](auto& p) { p.rotation_wxyz = {NAN, 0, 0, 0}; }).find("finite"),
            std::string::npos);
  EXPECT_NE(bad([](auto& p) { p.clutch_button = 32; }).find("clutch"), std::string::npos);
  WorkspaceMapping mapping;
  WorkspaceMappingParams p;
  p.scale = -1.0;
  EXPECT_THROW(mapping.configure(p), Error);
}

// A scene-frame script taken to the device frame (sim_server --export-trajectory) comes back
// where it was written once the device's mapping takes it to the scene again.
TEST(WorkspaceMapping, SceneToDeviceIsTheInverseOfThePoseMap) {
  WorkspaceMappingParams p;
  p.scale = 3.0;
  p.offset_m = {0.2, -0.1, 0.05};
  const double a = 0.3;
  p.rotation_wxyz = {std::cos(a), 0.0, std::sin(a) * 0.6, std::sin(a) * 0.8};
  WorkspaceMapping mapping;
  mapping.configure(p);
  for (int i = 0; i < 20; ++i) {
    const double b = 0.1 * i;
    std::array<double, 3> pos{0.01 * i - 0.05, 0.3 - 0.02 * i, 0.07 * std::sin(b)};
    std::array<double, 4> q{std::cos(b), std::sin(b), 0.0, 0.0};
    const auto scene_pos = pos;
    const auto scene_q = q;
    p.sceneToDevice(pos, q);
    device::DeviceState s;
    s.pos_m = pos;
    s.quat_wxyz = q;
    mapping.toScene(s);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(s.pos_m[k], scene_pos[k], 1e-15) << i;
    for (int k = 0; k < 4; ++k) EXPECT_NEAR(s.quat_wxyz[k], scene_q[k], 1e-15) << i;
  }
}

TEST(WorkspaceMapping, MapsThePoseAndBringsTheWrenchBackExactly) {
  WorkspaceMapping mapping;
  WorkspaceMappingParams p;
  p.scale = 2.5;
  p.offset_m = {0.1, -0.2, 0.3};
  p.rotation_wxyz = kQuarterTurnX;
  mapping.configure(p);
  device::DeviceState s;
  s.pos_m = {0.01, 0.02, 0.03};
  s.vel_mps = {0.0, 1.0, 0.0};
  s.angvel_radps = {0.0, 0.0, 2.0};
  mapping.toScene(s);
  // p_scene = offset + scale R p: R (x, y, z) = (x, -z, y)
  EXPECT_NEAR(s.pos_m[0], 0.1 + 2.5 * 0.01, 1e-15);
  EXPECT_NEAR(s.pos_m[1], -0.2 - 2.5 * 0.03, 1e-15);
  EXPECT_NEAR(s.pos_m[2], 0.3 + 2.5 * 0.02, 1e-15);
  EXPECT_NEAR(s.vel_mps[2], 2.5, 1e-15);
  EXPECT_NEAR(s.angvel_radps[1], -2.0, 1e-15);
  // the orientation: R applied to the identity device orientation
  EXPECT_NEAR(s.quat_wxyz[0], kQuarterTurnX[0], 1e-15);
  EXPECT_NEAR(s.quat_wxyz[1], kQuarterTurnX[1], 1e-15);
  // round trip of a wrench: a scene force R f becomes f / scale at the device; torque R t -> t
  std::array<double, 3> force{0.3, -0.4, 1.2};      // R (0.3, 1.2, 0.4)
  std::array<double, 3> torque{0.0, -0.05, 0.0};    // R (0, 0, 0.05)
  mapping.wrenchToDevice(force, torque);
  EXPECT_NEAR(force[0], 0.3 / 2.5, 1e-15);
  EXPECT_NEAR(force[1], 1.2 / 2.5, 1e-15);
  EXPECT_NEAR(force[2], 0.4 / 2.5, 1e-15);
  EXPECT_NEAR(torque[2], 0.05, 1e-15);
  EXPECT_NEAR(torque[0], 0.0, 1e-15);
}

// The real loop with one contact along scene +z (tests/support/one_contact_rig.h).
class MappedLoopTest : public ::testing::Test {
 protected:
  void start(const WorkspaceMappingParams& params) {
    settings_.max_force_n = 5.0;
    settings_.slew_n_per_s = 1e6;
    settings_.fade_ms = 1.0;
    rig_.reset();
    rig_ = std::make_unique<test::OneContactRig>(device_, settings_, "mapping_test");
    loop_ = &rig_->loop();
    loop_->workspaceMapping().configure(params);
  }
  void publish(double gap_m, double w_m_per_n, double z_star) {
    rig_->publish(gap_m, w_m_per_n, z_star, t_);
  }
  TickOutput tick(int n) { return rig_->tickEveryMs(n, t_); }
  shared::DeviceSample sample() { return rig_->sample(); }
  // Starts with a quarter turn about x, the hand at the device origin touching the tissue at
  // scene z = 0 (forces engaged).
  void startTouching(double scale, std::array<double, 3> offset_m, int clutch_button) {
    WorkspaceMappingParams p;
    p.scale = scale;
    p.offset_m = offset_m;
    p.rotation_wxyz = kQuarterTurnX;
    p.clutch_button = clutch_button;
    start(p);
    device_.state.pos_m = {0.0, 0.0, 0.0};
    publish(0.0, 1e-3, 0.0);
    tick(10);
  }

  test::ScriptedDevice device_;
  HapticSettings settings_;
  std::unique_ptr<test::OneContactRig> rig_;
  HapticLoop* loop_ = nullptr;
  std::int64_t t_ = shared::monotonicNs();
};

// The felt stiffness is the scene's (1 / W) whatever the scale, the force comes back along the
// inverse rotation, and the device-frame command stays within the clamp even when the scene
// force is far below it (a small scale amplifies the force at the hand).
TEST_F(MappedLoopTest, ForceGoesBackRotatedAndScaledAndIsClampedAfterTheMapping) {
  for (double scale : {0.01, 0.1, 1.0, 10.0}) {
    SCOPED_TRACE(scale);
    startTouching(scale, {0.0, 0.0, 0.0}, -1);
    device_.state.pos_m = {0.0, -0.001, 0.0};       // 1 mm down into the tissue (device -y)
    TickOutput out = tick(3);
    EXPECT_NEAR(sample().pos_m[2], -0.001 * scale, 1e-15);   // the simulation sees scene -z
    // scene force scale * 1 mm / W along +z; at the hand 1 mm / W = 1 N along device +y
    EXPECT_NEAR(out.force_n[1], 1.0, 1e-9);
    EXPECT_NEAR(out.force_n[0], 0.0, 1e-12);
    EXPECT_NEAR(out.force_n[2], 0.0, 1e-12);
    device_.state.pos_m = {0.0, -0.02, 0.0};        // 20 mm: 20 N at the hand before the clamp
    out = tick(3);
    EXPECT_LE(mappingNorm3(out.force_n), settings_.max_force_n);
    EXPECT_NEAR(out.force_n[1], settings_.max_force_n, 1e-9);
    EXPECT_TRUE(out.flags & shared::kStatsForceClamped);
    EXPECT_NEAR(device_.last.force_n[1], out.force_n[1], 0.0);   // what the device received
  }
}

TEST_F(MappedLoopTest, TheClutchHoldsTheInstrumentAndReleasesWithoutAJump) {
  startTouching(2.0, {0.1, 0.0, 0.0}, 2);
  device_.state.pos_m = {0.0, -0.001, 0.0};   // pressing: 2 mm into the tissue in the scene
  const TickOutput pressing = tick(3);
  EXPECT_NEAR(pressing.force_n[1], 1.0, 1e-9);
  const shared::DeviceSample before = sample();

  device_.state.buttons = 1u << 2;            // clutch: the hand moves and turns freely
  for (int i = 1; i <= 20; ++i) {
    device_.state.pos_m = {0.003 * i, -0.001 + 0.002 * i, -0.001 * i};
    const double a = 0.02 * i;
    device_.state.quat_wxyz = {std::cos(a), 0.0, std::sin(a), 0.0};
    const TickOutput out = tick(1);
    const shared::DeviceSample s = sample();
    for (int k = 0; k < 3; ++k) EXPECT_DOUBLE_EQ(s.pos_m[k], before.pos_m[k]);
    for (int k = 0; k < 4; ++k) EXPECT_DOUBLE_EQ(s.quat_wxyz[k], before.quat_wxyz[k]);
    EXPECT_EQ(mappingNorm3(out.force_n), 0.0);  // no force while clutched
  }
  EXPECT_TRUE(loop_->workspaceMapping().clutched());

  device_.state.buttons = 0;                  // release far from where the clutch engaged
  TickOutput out = tick(1);
  const shared::DeviceSample after = sample();
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(after.pos_m[k], before.pos_m[k], 1e-15);
  for (int k = 0; k < 4; ++k) EXPECT_NEAR(after.quat_wxyz[k], before.quat_wxyz[k], 1e-15);
  EXPECT_NEAR(out.force_n[1], 1.0, 1e-9);     // the same contact, the same force
  // from here on the instrument follows the hand again, scaled and rotated from the new origin
  const auto held = device_.state.pos_m;
  device_.state.pos_m = {held[0], held[1] - 0.0005, held[2]};
  out = tick(2);
  EXPECT_NEAR(sample().pos_m[2], before.pos_m[2] - 2.0 * 0.0005, 1e-12);
  EXPECT_NEAR(out.force_n[1], 1.5, 1e-9);

  // the same with a key (the clutch request) instead of a button
  loop_->workspaceMapping().setClutchRequest(true);
  const shared::DeviceSample held_key = sample();
  tick(1);
  device_.state.pos_m = {0.5, 0.5, 0.5};
  tick(3);
  EXPECT_NEAR(sample().pos_m[2], held_key.pos_m[2], 1e-15);
  loop_->workspaceMapping().setClutchRequest(false);
  tick(1);
  EXPECT_NEAR(sample().pos_m[2], held_key.pos_m[2], 1e-12);
}

TEST_F(MappedLoopTest, AMappedTickWithTheClutchAllocatesNothing) {
  startTouching(0.5, {0.0, 0.01, -0.02}, 0);
  test::AllocScope scope;
  for (int i = 0; i < 200; ++i) {
    if (i % 20 == 0) publish(-0.001 * (i % 3), 1e-3, 0.0);
    device_.state.pos_m = {0.0, -0.0001 * (i % 7), 0.0};
    device_.state.buttons = (i / 30) % 2;   // clutch engaged and released
    tick(1);
  }
  EXPECT_EQ(scope.allocations(), 0);
  EXPECT_EQ(scope.cAllocations(), 0);
}

}  // namespace
}  // namespace tactus::haptic
