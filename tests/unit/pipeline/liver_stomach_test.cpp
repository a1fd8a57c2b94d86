// scenes/liver_on_stomach.yaml (issue 20, item 5): the paper's liver settles with its right lobe
// on a second, soft organ (an ellipsoidal stomach fixed at its base) through tissue_contact; the
// stomach carries part of the liver's weight and deforms under it; the grasper lifts the lobe's
// tip off it. Both organs' contacts are in one contact problem, solved to its tolerance at every
// step; while the lobe rests, no contact penetrates beyond the penetration tolerance.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "../../support/liver_lobe.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

TEST(LiverStomachTest, TheLobeRestsOnTheStomachAndIsLiftedOffIt) {
  const SceneSpec spec = loadScene(std::string(TACTUS_SOURCE_DIR) + "/scenes/liver_on_stomach.yaml");
  ASSERT_EQ(spec.tissues.size(), 2u);
  ASSERT_EQ(spec.tissue_contacts.size(), 1u);
  Simulation sim(spec);
  const FemBody& liver = sim.tissue(0);
  const FemBody& stomach = sim.tissue(1);
  const test_support::LiverLobe lobe(liver);
  const Eigen::VectorXd stomach_rest = stomach.positions();
  double lobe_resting = 0.0, lobe_held = 0.0, stomach_resting = 0.0, stomach_held = 0.0;
  double stomach_sag_m = 0.0, worst_resting_penetration = 0.0;
  int pair_contacts_resting = 0, unconverged = 0;
  for (int k = 0; k < 560; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    const StepReport r = sim.step();
    ASSERT_TRUE(r.finite);
    if (r.nsgs.status != shared::NsgsStatus::kConverged && r.rows > 0) {
      if (unconverged < 50) {
        std::printf("[stomach] step %d: NSGS stopped after %d sweeps at error %.3g, %d contacts\n",
                    k, r.nsgs.sweeps, r.nsgs.error, r.contacts);
      }
      ++unconverged;
    }
    if (k >= 50 && k < 100) {   // resting, before the grasper arrives
      worst_resting_penetration = std::max(worst_resting_penetration, r.max_penetration_m);
    }
    if (k == 99) {   // t = 1 s: settled
      lobe_resting = lobe.meanZ();
      stomach_resting = sim.reactions().tissues[1].from_tissues_n.z();
      const ContactProblemData& p = sim.lastProblem();
      for (int c = 0; c < p.contacts; ++c) {
        if ((p.contact_id[c] >> 56 & 3) == 3 && p.f[p.row_offset[c]] > 0.0) ++pair_contacts_resting;
      }
      for (int i = 0; i < stomach.nodeCount(); ++i) {
        stomach_sag_m = std::max(stomach_sag_m, stomach_rest[3 * i + 2] - stomach.positions()[3 * i + 2]);
      }
    }
    if (k == 559) {  // t = 5.6 s: the tool held 2 cm up
      lobe_held = lobe.meanZ();
      stomach_held = sim.reactions().tissues[1].from_tissues_n.z();
    }
  }
  std::printf("[stomach] lobe tip mean z resting %.4f m, held %.4f m; the liver's force on the "
              "stomach %.3f N -> %.3f N; %d pair contacts carry force at rest; the stomach sags "
              "%.2f mm; penetration at rest <= %.3g m; %d steps unconverged\n",
              lobe_resting, lobe_held, stomach_resting, stomach_held, pair_contacts_resting,
              1e3 * stomach_sag_m, worst_resting_penetration, unconverged);
  EXPECT_LT(stomach_resting, -0.1) << "the lobe presses on the stomach";
  EXPECT_GT(pair_contacts_resting, 3);
  EXPECT_GT(stomach_sag_m, 1e-4) << "the stomach deforms under the liver";
  EXPECT_LT(worst_resting_penetration, spec.solver.penetration_tolerance_m);
  EXPECT_GT(lobe_held, lobe_resting + 0.005) << "lifted";
  EXPECT_GT(stomach_held, stomach_resting) << "the stomach carries less once the lobe is lifted";
  EXPECT_EQ(unconverged, 0);
}

}  // namespace
}  // namespace tactus::sim
