// The paper's scene (scenes/liver_grasp.yaml) with its former round kinematic jaws (the flat
// pads' grasp is pad_grasp_test's): the grasper closes on the right lobe's tip and
// lifts it 2 cm. The hinged jaws form a wedge that squeezes the tissue out toward their tips
// unless friction holds it: with mu = 0.8 the lobe stays in the jaws and rises with them; with
// mu = 0.05 it slips out. Every step keeps the contact laws of the solved problem (gaps of the
// linearised problem >= -tolerance, NSGS residual below its tolerance), and after every step a
// fresh collision query finds no gap below -solver.penetration_tolerance (0.1 mm): the scene
// re-linearises the contact problem at the corrected state (solver.contact_iterations). With a
// single pass, squeezing the thin lobe left up to 5 mm of geometric penetration.
#include <gtest/gtest.h>

#include <cmath>

#include "../../support/liver_lobe.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

const std::string kScene = std::string(TACTUS_SOURCE_DIR) + "/scenes/liver_grasp.yaml";
constexpr double kTolerance_m = 1e-4;   // the scene's solver.penetration_tolerance

struct GraspResult {
  double lobe_rise_m = 0.0;       ///< mean rise of the lobe tip nodes during the hold
  double tool_rise_m = 0.0;
  double worst_gap_m = 0.0;            ///< geometric (fresh query), every step
  double worst_reported_m = 0.0;       ///< StepReport::geometric_penetration_m, every step
  int max_passes = 0;
  double worst_linear_gap_m = 0.0;     ///< of the solved (linearised) problem, every step
  double worst_residual = 0.0;
  int max_contacts = 0;
};

GraspResult runGrasp(double mu) {
  SceneSpec spec = loadScene(kScene);
  spec.haptics.enabled = false;
  test_support::useRoundKinematicJaws(spec);
  spec.instrument.friction_mu = mu;
  for (auto& t : spec.tissues) t.compliance_cache_dir.clear();
  EXPECT_EQ(spec.solver.penetration_tolerance_m, kTolerance_m);
  Simulation sim(spec);
  const test_support::LiverLobe lobe(sim.tissue(0));
  auto lobe_z = [&] { return lobe.meanZ(); };
  GraspResult out;
  double z_before = 0.0;
  double tool_before = 0.0;
  const int steps = static_cast<int>(std::lround(5.8 / spec.time_step_s));
  for (int k = 0; k < steps; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    const StepReport r = sim.step();
    EXPECT_TRUE(r.finite) << "step " << k;
    if (r.contacts > 0) {
      out.worst_linear_gap_m = std::min(out.worst_linear_gap_m, -r.max_penetration_m);
      out.worst_residual = std::max(out.worst_residual, r.nsgs.error);
    }
    out.worst_gap_m = std::min(out.worst_gap_m, sim.geometricMinGap());
    out.worst_reported_m = std::max(out.worst_reported_m, r.geometric_penetration_m);
    out.max_passes = std::max(out.max_passes, r.contact_passes);
    out.max_contacts = std::max(out.max_contacts, r.contacts);
    if (std::abs(sim.time() - 2.95) < 0.5 * spec.time_step_s) {   // jaws closed, before the lift
      z_before = lobe_z();
      tool_before = sim.instrument()->pose().pos_m.z();
    }
  }
  out.lobe_rise_m = lobe_z() - z_before;   // at 5.8 s: lifted and held for 1.3 s
  out.tool_rise_m = sim.instrument()->pose().pos_m.z() - tool_before;
  return out;
}

TEST(LiverGraspTest, HighFrictionHoldsTheLiftedLobe) {
  const GraspResult r = runGrasp(0.8);
  EXPECT_GT(r.tool_rise_m, 0.018);
  // the lobe follows the jaws: at least 75% of the lift (slip bounded by 5 mm)
  EXPECT_GT(r.lobe_rise_m, 0.75 * r.tool_rise_m) << "lobe rose " << r.lobe_rise_m;
  EXPECT_GT(r.max_contacts, 4);
  EXPECT_GT(r.worst_linear_gap_m, -1e-5);
  EXPECT_GT(r.worst_gap_m, -kTolerance_m) << "geometric penetration beyond the tolerance";
  EXPECT_LE(r.worst_reported_m, kTolerance_m);
  EXPECT_GT(r.max_passes, 1) << "the scene never needed a second contact pass";
  EXPECT_LT(r.worst_residual, 1e-6);
}

TEST(LiverGraspTest, LowFrictionLetsTheLobeSlipOut) {
  const GraspResult r = runGrasp(0.05);
  EXPECT_GT(r.tool_rise_m, 0.018);
  EXPECT_LT(r.lobe_rise_m, 0.2 * r.tool_rise_m) << "lobe rose " << r.lobe_rise_m;
  EXPECT_GT(r.worst_linear_gap_m, -1e-5);
  EXPECT_GT(r.worst_gap_m, -kTolerance_m);
  EXPECT_LE(r.worst_reported_m, kTolerance_m);
  EXPECT_LT(r.worst_residual, 1e-6);
}

}  // namespace
}  // namespace tactus::sim
