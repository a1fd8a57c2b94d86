// The simulation's state (Simulation::saveState / restoreState; docs/design.md, "State: copy,
// save, restore"): a run restored from a saved state continues bit for bit as the run that saved
// it, in the same simulation (rewound) and in a new one (through a file), on scenes that use
// what a step carries to the next: the warm-started PCG on a reused CHOLMOD factor, the grasper's
// finite grip, the pads' side memory and the warm-start forces (liver_grasp over 200 contact
// steps), obstacles and contact between tissues (liver_on_stomach), and the other linear
// solvers. A state of another model, another format or truncated is refused, and leaves the
// simulation as it was.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <string>
#include <vector>

#include "../../support/test_dir.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

const std::string kScenes = std::string(TACTUS_SOURCE_DIR) + "/scenes/";

SceneSpec scene(const std::string& name) {
  SceneSpec spec = loadScene(kScenes + name);
  spec.haptics.enabled = false;
  for (auto& t : spec.tissues) t.compliance_cache_dir.clear();
  return spec;
}

// Everything a step leaves that a user reads, hashed bit for bit.
struct StepPrint {
  std::uint64_t hash = 0;
  int contacts = 0;
};

void mix(std::uint64_t& h, const void* data, std::size_t n) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 0x100000001b3ull;
  }
}

StepPrint print(const Simulation& sim, const StepReport& r) {
  StepPrint out;
  out.hash = 0xcbf29ce484222325ull;
  out.contacts = r.contacts;
  for (int t = 0; t < sim.tissueCount(); ++t) {
    const FemBody& b = sim.tissue(t);
    mix(out.hash, b.positions().data(), sizeof(double) * b.positions().size());
    mix(out.hash, b.velocities().data(), sizeof(double) * b.velocities().size());
  }
  for (int i = 0; i < sim.instrumentCount(); ++i) {
    const Instrument& tool = sim.instrument(i);
    mix(out.hash, tool.pose().pos_m.data(), 3 * sizeof(double));
    mix(out.hash, tool.pose().rot.coeffs().data(), 4 * sizeof(double));
    mix(out.hash, tool.twist().data(), 6 * sizeof(double));
    const double grip[2] = {tool.gripperOpening(), tool.gripRate()};
    mix(out.hash, grip, sizeof grip);
  }
  const ContactProblemData& p = sim.lastProblem();
  mix(out.hash, p.f.data(), sizeof(double) * p.f.size());
  mix(out.hash, p.contact_id.data(), sizeof(std::uint64_t) * p.contact_id.size());
  const double tim[2] = {sim.time(), static_cast<double>(sim.stepIndex())};
  mix(out.hash, tim, sizeof tim);
  return out;
}

std::vector<StepPrint> runPrinting(Simulation& sim, int steps) {
  std::vector<StepPrint> out;
  for (int k = 0; k < steps; ++k) {
    for (int i = 0; i < sim.instrumentCount(); ++i) {
      sim.setDeviceTarget(i, sim.scriptedTarget(i, sim.time()));
    }
    const StepReport r = sim.step();
    EXPECT_TRUE(r.finite) << "step " << sim.stepIndex();
    out.push_back(print(sim, r));
  }
  return out;
}

void expectSameRun(const std::vector<StepPrint>& a, const std::vector<StepPrint>& b,
                   const std::string& what) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t k = 0; k < a.size(); ++k) {
    ASSERT_EQ(a[k].contacts, b[k].contacts) << what << ": step " << k << " after the restore";
    ASSERT_EQ(a[k].hash, b[k].hash) << what << ": step " << k << " after the restore";
  }
}

// The first step's factorisation is made when the simulation is built (FemBody::
// prepareFreeMotion): the first step factorises nothing on its own thread, and gives the same
// bits as a first step that factorises (a simulation that stepped, its prepared factor used,
// rewound to the state before the first step: no prepared factor then, the step factorises).
TEST(SimulationStateTest, FirstStepUsesTheFactorMadeAtSetUpWithTheSameBits) {
  const SceneSpec spec = scene("liver_grasp.yaml");
  ASSERT_EQ(spec.solver.linear, LinearSolverKind::kCholmodReuse);
  Simulation sim(spec);
  EXPECT_EQ(sim.tissue(0).counters().prepared_factorisations, 1);
  // (the warped compliance's rest factorisation is counted too, at set-up)
  const long at_setup = sim.tissue(0).counters().factorisations;
  const std::string start = sim.saveState();
  sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
  const StepReport first = sim.step();
  EXPECT_EQ(first.fem_factorisations, 0);
  EXPECT_EQ(sim.tissue(0).counters().factorisations, at_setup);
  const StepPrint first_print = print(sim, first);
  const std::vector<StepPrint> prepared = runPrinting(sim, 30);

  sim.restoreState(start);
  const long before = sim.tissue(0).counters().factorisations;
  sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
  const StepReport again = sim.step();
  EXPECT_EQ(again.fem_factorisations, 1);   // no prepared factor: the step factorised
  EXPECT_EQ(sim.tissue(0).counters().factorisations, before + 1);
  EXPECT_EQ(print(sim, again).hash, first_print.hash) << "the first step";
  expectSameRun(prepared, runPrinting(sim, 30), "the first step factorising");
}

// The contact problem's W lives in storage reserved at set-up for the largest problem
// (shared::GrowOnlyMatrix): through a grasp whose rows change from step to step it never moves.
TEST(SimulationStateTest, TheContactProblemKeepsWsStorageWhileItsRowsChange) {
  Simulation sim(scene("liver_grasp.yaml"));
  const ContactProblemData& p = sim.lastProblem();
  const double* storage = p.W.data();
  ASSERT_NE(storage, nullptr);
  const std::size_t capacity = p.W.capacity();
  int sizes = 0, last_rows = -1, max_rows = 0;
  for (int k = 0; k < 400; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    const StepReport r = sim.step();
    if (r.rows != last_rows) ++sizes;
    last_rows = r.rows;
    max_rows = std::max(max_rows, r.rows);
    ASSERT_EQ(p.W.rows(), p.rows) << "step " << k;
    ASSERT_EQ(p.W.data(), storage) << "step " << k << ", " << p.rows << " rows";
    ASSERT_EQ(p.W.capacity(), capacity);
  }
  EXPECT_GT(sizes, 20);   // the problem changed size at many steps
  EXPECT_GE(capacity, static_cast<std::size_t>(max_rows) * static_cast<std::size_t>(max_rows));
}

// W is assembled in its upper triangle and mirrored (buildW) when no rows join two tissues, and
// summed into both halves otherwise: either way it is symmetric to the bit, with a positive
// diagonal, at every contact step of one grasper (liver_grasp), two graspers on one tissue
// (liver_bimanual), two tissues with an obstacle and without rows between them
// (liver_on_stomach without its tissue contact: every tissue's block its own, the blocks
// between them zero) and with them (liver_on_stomach).
TEST(SimulationStateTest, TheContactProblemsWIsSymmetricToTheBit) {
  struct Case {
    std::string scene;
    bool tissue_contact;
    int steps;
  };
  for (const Case& c : {Case{"liver_grasp.yaml", true, 260}, Case{"liver_bimanual.yaml", true, 300},
                        Case{"liver_on_stomach.yaml", false, 30},
                        Case{"liver_on_stomach.yaml", true, 30}}) {
    SCOPED_TRACE(c.scene + (c.tissue_contact ? "" : " without tissue contact"));
    SceneSpec spec = scene(c.scene);
    if (!c.tissue_contact) spec.tissue_contacts.clear();
    Simulation sim(spec);
    int checked = 0;
    for (int k = 0; k < c.steps; ++k) {
      for (int i = 0; i < sim.instrumentCount(); ++i) {
        sim.setDeviceTarget(i, sim.scriptedTarget(i, sim.time()));
      }
      const StepReport r = sim.step();
      if (r.rows == 0) continue;
      const ContactProblemData& p = sim.lastProblem();
      ASSERT_EQ(p.W.rows(), r.rows);
      for (int i = 0; i < r.rows; ++i) {
        ASSERT_GT(p.W(i, i), 0.0) << "step " << k << ", row " << i;
        for (int j = 0; j < i; ++j) ASSERT_EQ(p.W(i, j), p.W(j, i)) << "step " << k;
      }
      ++checked;
    }
    EXPECT_GT(checked, 10);
  }
}

TEST(SimulationStateTest, LiverGraspContinuesBitForBitOver200ContactSteps) {
  const SceneSpec spec = scene("liver_grasp.yaml");
  ASSERT_EQ(spec.solver.linear, LinearSolverKind::kCholmodReuse);
  ASSERT_GT(spec.instrument.grip_k_nmprad, 0.0);   // finite grip: the jaw angle is a DOF
  Simulation sim(spec);
  // into the grasp (the jaws pressing the lobe: warm-start forces that matter), then to a step
  // whose factor of record is some steps old (the preconditioner a restore must rebuild from
  // what it was computed from)
  int pressed = 0;
  for (int k = 0; k < 500 && pressed < 5; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    pressed = sim.step().total_normal_force_n > 0.5 ? pressed + 1 : 0;
  }
  ASSERT_EQ(pressed, 5) << "the grasper never pressed the lobe";
  for (int k = 0;; ++k) {
    ASSERT_LT(k, 50) << "no step without a refactorisation";
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    const StepReport r = sim.step();
    ASSERT_GT(r.contacts, 0);
    if (r.fem_factorisations == 0) break;
  }
  const std::string saved = sim.saveState();
  test_support::TestDir dir("tactus_state");
  shared::writeFileChecked(dir.path / "grasp.state", saved, "state");

  const std::vector<StepPrint> original = runPrinting(sim, 200);
  for (std::size_t k = 0; k < original.size(); ++k) {
    ASSERT_GT(original[k].contacts, 0) << "step " << k << " after the save is not in contact";
  }
  const std::string end = sim.saveState();

  // a new simulation, from the file
  Simulation other(spec);
  other.restoreState(shared::readFileChecked(dir.path / "grasp.state", "state", 1u << 30),
                     "grasp.state");
  EXPECT_EQ(other.stepIndex(), sim.stepIndex() - 200);
  expectSameRun(original, runPrinting(other, 200), "a new simulation");
  EXPECT_TRUE(other.saveState() == end) << "the states after the 200 steps differ";

  // the same simulation, rewound
  sim.restoreState(saved);
  expectSameRun(original, runPrinting(sim, 200), "the simulation rewound");
}

// The compliance update waits for a pass with contact rows (ensureCompliance, docs/design.md,
// "The compliance update only when a pass has rows"): a run that forces it after every step
// (Simulation::compliance makes a pending one) steps bit for bit as one that leaves it, through
// the approach (steps without contact) into the grasp, and both save the same state.
TEST(SimulationStateTest, TheDeferredComplianceUpdateChangesNothing) {
  const SceneSpec spec = scene("liver_grasp.yaml");
  Simulation deferred(spec);
  Simulation eager(spec);
  int without = 0, with = 0;
  for (int k = 0; k < 400 && with < 30; ++k) {
    deferred.setDeviceTarget(deferred.scriptedTarget(deferred.time()));
    eager.setDeviceTarget(eager.scriptedTarget(eager.time()));
    const StepReport a = deferred.step();
    const StepReport b = eager.step();
    ASSERT_NE(eager.compliance(0), nullptr);   // the update at this step's free state, now
    const StepPrint pa = print(deferred, a), pb = print(eager, b);
    ASSERT_EQ(pa.contacts, pb.contacts) << "step " << k;
    ASSERT_EQ(pa.hash, pb.hash) << "step " << k;
    (a.rows > 0 ? with : without) += 1;
  }
  EXPECT_GT(without, 10) << "no approach without contact rows";
  EXPECT_EQ(with, 30) << "the grasper never touched the lobe";
  EXPECT_TRUE(deferred.saveState() == eager.saveState());
}

TEST(SimulationStateTest, ObstaclesAndTissueContactContinueBitForBit) {
  const SceneSpec spec = scene("liver_on_stomach.yaml");
  ASSERT_FALSE(spec.obstacles.empty());
  ASSERT_FALSE(spec.tissue_contacts.empty());
  Simulation sim(spec);
  runPrinting(sim, 20);
  const std::string saved = sim.saveState();
  const std::vector<StepPrint> original = runPrinting(sim, 30);
  for (const StepPrint& p : original) ASSERT_GT(p.contacts, 0);
  // the run compared holds both kinds: the support carries the stomach, the organs press
  const ReactionForces r = sim.reactions();
  ASSERT_EQ(r.obstacle_force_n.size(), 1u);
  EXPECT_GT(r.obstacle_force_n[0].z(), 1.0) << "the support carries no weight";
  EXPECT_GT(r.tissues[1].from_tissues_n.norm(), 0.01) << "the liver does not press the stomach";
  Simulation other(spec);
  other.restoreState(saved);
  expectSameRun(original, runPrinting(other, 30), "a new simulation");
}

// The factor refreshed in the background at a fixed lag (solver.background_refactor_lag_steps,
// not when ready): a state saved while the worker factorises holds the values it factorises, and
// the restore starts that job again, so the factor takes over at the same step and the run
// continues bit for bit (without the job's restart the restored run kept its old factor longer).
// With a longer lag out of contact (solver.background_refactor_free_lag_steps) the job's weighed
// age and whether the last step was in contact are state too: saved in contact, a restore that
// counted its first step as one out of contact would take the factor a step later.
void expectBackgroundJobContinuesBitForBit(int free_lag_steps) {
  SCOPED_TRACE("background_refactor_free_lag_steps " + std::to_string(free_lag_steps));
  SceneSpec spec = scene("liver_grasp.yaml");
  spec.solver.background_refactor_lag_steps = 2;
  spec.solver.background_refactor_free_lag_steps = free_lag_steps;
  spec.solver.background_refactor_when_ready = false;
  Simulation sim(spec);
  // into the grasp, to a step that leaves a job in flight
  int pressed = 0;
  for (int k = 0; k < 600; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    pressed = sim.step().total_normal_force_n > 0.5 ? pressed + 1 : 0;
    if (pressed >= 5 && sim.tissue(0).backgroundFactorisationInFlight()) break;
  }
  ASSERT_GE(pressed, 5) << "the grasper never pressed the lobe";
  ASSERT_TRUE(sim.tissue(0).backgroundFactorisationInFlight());
  const long taken_before = sim.tissue(0).counters().background_factorisations;
  const std::string saved = sim.saveState();
  const std::vector<StepPrint> original = runPrinting(sim, 60);
  EXPECT_GT(sim.tissue(0).counters().background_factorisations, taken_before);
  const std::string end = sim.saveState();

  Simulation other(spec);
  other.restoreState(saved);
  EXPECT_TRUE(other.tissue(0).backgroundFactorisationInFlight());
  expectSameRun(original, runPrinting(other, 60), "a new simulation");
  EXPECT_TRUE(other.saveState() == end) << "the states after the 60 steps differ";

  sim.restoreState(saved);
  expectSameRun(original, runPrinting(sim, 60), "the simulation rewound");
}

TEST(SimulationStateTest, ABackgroundFactorisationInFlightContinuesBitForBit) {
  expectBackgroundJobContinuesBitForBit(0);
}

TEST(SimulationStateTest, ABackgroundFactorisationInFlightWithAFreeLagContinuesBitForBit) {
  expectBackgroundJobContinuesBitForBit(4);
}

// The other linear solves carry their own warm starts (PCG: the last dv) or none (CHOLMOD).
TEST(SimulationStateTest, EveryLinearSolverContinuesBitForBit) {
  for (const LinearSolverKind kind : {LinearSolverKind::kPcg, LinearSolverKind::kCholmod}) {
    SceneSpec spec = scene("liver_grasp.yaml");
    spec.solver.linear = kind;
    Simulation sim(spec);
    runPrinting(sim, 165);
    const std::string saved = sim.saveState();
    const std::vector<StepPrint> original = runPrinting(sim, 25);
    Simulation other(spec);
    other.restoreState(saved);
    expectSameRun(original, runPrinting(other, 25),
                  kind == LinearSolverKind::kPcg ? "pcg" : "cholmod");
  }
}

TEST(SimulationStateTest, ForeignTruncatedOrCorruptStatesAreRefusedAndChangeNothing) {
  Simulation grasp(scene("liver_grasp.yaml"));
  runPrinting(grasp, 3);
  const std::string before = grasp.saveState();
  const auto refused = [&](const std::string& bytes, const std::string& expected) {
    try {
      grasp.restoreState(bytes, "bad.state");
      ADD_FAILURE() << "accepted; expected '" << expected << "'";
    } catch (const StateError& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("bad.state"), std::string::npos) << e.what();
    }
    EXPECT_TRUE(grasp.saveState() == before) << "a refused state changed the simulation";
  };
  SceneSpec other_spec = scene("liver_grasp.yaml");
  other_spec.time_step_s = 0.005;
  Simulation other(other_spec);
  refused(other.saveState(), "a state of another model");
  refused(before.substr(0, before.size() / 2), "truncated");
  refused("hello", "not a Tactus simulation state");
  std::string version = before;
  version[8] = 99;
  refused(version, "format version 99");
  // a field's tag or size overwritten: the first field after the header is the time, then the
  // step index; break the first tissue's q count
  const StateHeader h = readStateHeader(before, "x");
  std::string corrupt = before;
  corrupt[h.body_offset] ^= 0x5a;
  refused(corrupt, "'t': not found where expected");
  std::string longer = before + "x";
  refused(longer, "bytes left after the last field");
}

}  // namespace
}  // namespace tactus::sim
