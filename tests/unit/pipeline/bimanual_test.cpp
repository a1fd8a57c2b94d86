// Several instruments in one simulation: each god object has its own coupling,
// friction and contacts, and all contacts form ONE contact problem whose W couples the
// instruments through the tissue (tests/data/scenes/press_cube_bimanual.yaml: two probes press a
// soft cube from its -x and +x faces).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <set>

#include "tactus/sim/instrument.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {
namespace {

const std::filesystem::path kBimanualScene =
    std::filesystem::path(TACTUS_TEST_DATA_DIR) / "scenes" / "press_cube_bimanual.yaml";

// Runs `steps` steps, each instrument following its script (an instrument whose script is
// overridden by `hold` stays where it starts).
void run(Simulation& sim, int steps) {
  for (int k = 0; k < steps; ++k) {
    for (int i = 0; i < sim.instrumentCount(); ++i) {
      sim.setDeviceTarget(i, sim.scriptedTarget(i, sim.time()));
    }
    const StepReport r = sim.step();
    ASSERT_TRUE(r.finite);
  }
}

// The scene with instrument `i`'s script moved `dx_m` further along its pressing direction.
SceneSpec pressDeeper(SceneSpec spec, int i, double dx_m) {
  InstrumentSpec& in = instrumentSpec(spec, i);
  const double dir = in.trajectory.back().pose.position_m.x() < 0.0 ? 1.0 : -1.0;
  in.trajectory.back().pose.position_m.x() += dir * dx_m;
  return spec;
}

// The scene with instrument `i` moved out of reach (its script held 5 cm further out).
SceneSpec withdraw(SceneSpec spec, int i) {
  InstrumentSpec& in = instrumentSpec(spec, i);
  const double dir = in.initial_pose.position_m.x() < 0.0 ? -1.0 : 1.0;
  in.initial_pose.position_m.x() += dir * 0.05;
  for (TrajectoryKey& k : in.trajectory) k.pose.position_m.x() += dir * 0.05;
  return spec;
}

TEST(Bimanual, BothInstrumentsContactsFormOneCoupledProblem) {
  const SceneSpec spec = loadScene(kBimanualScene);
  ASSERT_EQ(instrumentCount(spec), 2);
  Simulation sim(spec);
  ASSERT_EQ(sim.instrumentCount(), 2);
  run(sim, 40);
  const ContactProblemData& p = sim.lastProblem();
  ASSERT_GT(p.contacts, 0);
  ASSERT_EQ(p.contact_instrument.size(), static_cast<std::size_t>(p.contacts));
  int per[2] = {0, 0};
  std::set<std::uint64_t> ids;
  for (int c = 0; c < p.contacts; ++c) {
    ++per[p.contact_instrument[c]];
    ids.insert(p.contact_id[c]);
    EXPECT_EQ(p.row_offset[c + 1] - p.row_offset[c], 3);   // both have friction
  }
  EXPECT_GT(per[0], 0);
  EXPECT_GT(per[1], 0);
  EXPECT_EQ(ids.size(), static_cast<std::size_t>(p.contacts));   // ids distinct across tools
  // W couples rows of different instruments only through the tissue: their block is nonzero
  // (the cube transmits), and it equals what the tissue alone gives (no tool term between them)
  double cross = 0.0;
  for (int a = 0; a < p.contacts; ++a) {
    for (int b = 0; b < p.contacts; ++b) {
      if (p.contact_instrument[a] == 0 && p.contact_instrument[b] == 1) {
        cross = std::max(cross, std::abs(p.W(p.row_offset[a], p.row_offset[b])));
        EXPECT_EQ(p.W(p.row_offset[a], p.row_offset[b]), p.W(p.row_offset[b], p.row_offset[a]));
      }
    }
  }
  std::printf("contacts %d + %d, largest W entry between the instruments %.3g m/N\n", per[0],
              per[1], cross);
  EXPECT_GT(cross, 0.0);
  // each row's J is its own instrument's: J (H_tool G) is nonzero on every normal row
  for (int c = 0; c < p.contacts; ++c) EXPECT_GT(p.J.row(p.row_offset[c]).norm(), 0.0);
  // each instrument is pushed back along its own pressing direction (left toward -x, right +x)
  EXPECT_EQ(p.instruments.size(), 2u);
  const StepReport r = sim.step();
  ASSERT_EQ(r.tool_wrenches.size(), 2u);
  EXPECT_LT(r.tool_wrenches[0][0], -0.05);
  EXPECT_GT(r.tool_wrenches[1][0], 0.05);
  EXPECT_EQ(r.tool_wrench, r.tool_wrenches[0]);
  // what the instrument's coupling renders agrees with the contact wrench once settled
  EXPECT_NEAR(sim.renderedWrench(1)[0], r.tool_wrenches[1][0],
              0.2 * std::abs(r.tool_wrenches[1][0]));
}

TEST(Bimanual, AnInstrumentOutOfReachChangesNothingForTheOther) {
  // the right probe withdrawn: the left one's contacts, forces and motion are those of the scene
  // with the left probe alone, bit for bit (the merge tags, it does not reorder or mix)
  const SceneSpec both = withdraw(loadScene(kBimanualScene), 1);
  SceneSpec alone = both;
  alone.additional_instruments.clear();
  Simulation a(both);
  Simulation b(alone);
  for (int k = 0; k < 40; ++k) {
    a.setDeviceTarget(0, a.scriptedTarget(0, a.time()));
    a.setDeviceTarget(1, a.scriptedTarget(1, a.time()));
    b.setDeviceTarget(b.scriptedTarget(b.time()));
    const StepReport ra = a.step();
    const StepReport rb = b.step();
    ASSERT_EQ(ra.contacts, rb.contacts) << "step " << k;
    ASSERT_EQ(ra.tool_wrenches[1], shared::Vector6d::Zero());
    ASSERT_EQ(ra.tool_wrench, rb.tool_wrench) << "step " << k;
    ASSERT_EQ(ra.nsgs.sweeps, rb.nsgs.sweeps);
  }
  EXPECT_GT(b.lastProblem().contacts, 0);
  EXPECT_EQ(a.lastProblem().W, b.lastProblem().W);
  EXPECT_EQ(a.lastProblem().f, b.lastProblem().f);
  EXPECT_EQ(a.instrument(0).pose().pos_m, b.instrument(0).pose().pos_m);
  EXPECT_EQ(a.tissue(0).positions(), b.tissue(0).positions());
}

TEST(Bimanual, PushingWithOneHandLoadsTheOtherThroughTheTissue) {
  // the right probe holds the same target in both runs; the left one presses 3 mm deeper in the
  // second: the cube, pushed toward +x, presses harder on the right probe (larger +x force)
  const SceneSpec spec = loadScene(kBimanualScene);
  Simulation shallow(spec);
  Simulation deep(pressDeeper(spec, 0, 0.003));
  run(shallow, 60);
  run(deep, 60);
  const double right_shallow = shallow.step().tool_wrenches[1][0];
  const double right_deep = deep.step().tool_wrenches[1][0];
  const double left_shallow = -shallow.step().tool_wrenches[0][0];
  const double left_deep = -deep.step().tool_wrenches[0][0];
  std::printf("left %.4f -> %.4f N, right %.4f -> %.4f N\n", left_shallow, left_deep,
              right_shallow, right_deep);
  EXPECT_GT(left_deep, left_shallow + 0.1);    // the left hand pushes harder
  EXPECT_GT(right_deep, right_shallow * 1.05);  // and the right one feels it through the cube
  // without the right probe, the left one pressing deeper does not invent a force on it
  Simulation lone(withdraw(pressDeeper(spec, 0, 0.003), 1));
  run(lone, 60);
  EXPECT_EQ(lone.step().tool_wrenches[1], shared::Vector6d::Zero());
}

}  // namespace
}  // namespace tactus::sim
