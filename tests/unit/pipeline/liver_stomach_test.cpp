// scenes/liver_on_stomach.yaml: the paper's liver settles with its right lobe
// on a second, soft organ (an ellipsoidal stomach, free, lying on a rigid support) through
// tissue_contact; the stomach carries part of the liver's weight and deforms under it, the
// support carries the stomach, that share and part of the liver directly; the grasper lifts the
// lobe's tip off the stomach. Both organs' contacts are in one contact problem, solved to its tolerance at every
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
  double stomach_sag_m = 0.0, worst_resting_penetration = 0.0, support_resting = 0.0;
  double stomach_weight = 0.0, support_total = 0.0;
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
      const ReactionForces reactions = sim.reactions();
      stomach_resting = reactions.tissues[1].from_tissues_n.z();
      // the support's force on the stomach: its contact force less the liver's
      support_resting = reactions.tissues[1].contact_force_n.rowwise().sum().z() - stomach_resting;
      support_total = reactions.obstacle_force_n.at(0).z();
      stomach_weight = -reactions.tissues[1].weight_n.z();
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
  std::printf("[stomach] at rest the support carries %.4f N of the stomach (its weight %.4f N and "
              "the liver's push %.4f N) and %.4f N of the liver\n", support_resting,
              stomach_weight, -stomach_resting, support_total - support_resting);
  EXPECT_LT(stomach_resting, -0.1) << "the lobe presses on the stomach";
  // the support carries the stomach and the liver's push on it (measured 3.3 % more at t = 1 s:
  // the soft stomach still rocks on the support (+-0.15 N over 0.1 s), and the warped
  // correction does not conserve momentum (README.md, "Known limits")); and part of the liver itself
  EXPECT_NEAR(support_resting, stomach_weight - stomach_resting, 0.06 * stomach_weight);
  EXPECT_GT(support_total - support_resting, 0.05) << "the liver rests on the support too";
  EXPECT_GT(pair_contacts_resting, 3);
  EXPECT_GT(stomach_sag_m, 1e-4) << "the stomach deforms under the liver";
  EXPECT_LT(worst_resting_penetration, spec.solver.penetration_tolerance_m);
  EXPECT_GT(lobe_held, lobe_resting + 0.005) << "lifted";
  EXPECT_GT(stomach_held, stomach_resting) << "the stomach carries less once the lobe is lifted";
  EXPECT_EQ(unconverged, 0);
}

// scenes/liver_stomach_two_hands.yaml: a probe presses the stomach's side while
// the grasper lifts the lobe off it. While the lobe lies on the stomach everything is one group;
// once it is lifted off, the grasper's contacts (liver) and the probe's (stomach) share no body
// and are solved apart. The run follows the one that solves the whole W every step to the
// solver's tolerance (the forces of each group are the same problem's solution).
TEST(LiverStomachTest, TwoHandsOnTwoOrgansAreSolvedApartOnceTheLobeIsLifted) {
  SceneSpec spec =
      loadScene(std::string(TACTUS_SOURCE_DIR) + "/scenes/liver_stomach_two_hands.yaml");
  ASSERT_TRUE(spec.solver.split_contact_groups);
  Simulation split(spec);
  spec.solver.split_contact_groups = false;
  Simulation whole(spec);
  ASSERT_EQ(split.instrumentCount(), 2);
  const test_support::LiverLobe split_lobe(split.tissue(0)), whole_lobe(whole.tissue(0));
  double lobe_resting = 0.0, lobe_held = 0.0;
  int split_steps = 0, joined_steps = 0, probe_on_stomach = 0;
  double largest_difference_m = 0.0, largest_lobe_difference_m = 0.0;
  for (int k = 0; k < 600; ++k) {
    for (Simulation* sim : {&split, &whole}) {
      for (int i = 0; i < 2; ++i) sim->setDeviceTarget(i, sim->scriptedTarget(i, sim->time()));
    }
    const StepReport a = split.step();
    const StepReport b = whole.step();
    ASSERT_EQ(a.nsgs.status, shared::NsgsStatus::kConverged) << "step " << k;
    ASSERT_EQ(b.nsgs.status, shared::NsgsStatus::kConverged) << "step " << k;
    EXPECT_LE(b.contact_groups, 1);
    const ContactProblemData& p = split.lastProblem();
    int probe = 0, pairs = 0;
    for (int c = 0; c < p.contacts; ++c) {
      probe += p.contact_instrument[c] == 1 ? 1 : 0;
      pairs += (p.contact_id[c] >> 56 & 3) == 3 ? 1 : 0;
    }
    probe_on_stomach += probe > 0 ? 1 : 0;
    if (a.contact_groups == 2) {
      EXPECT_EQ(pairs, 0) << "step " << k << ": the organs touch, yet were solved apart";
      ++split_steps;
    } else if (pairs > 0 && probe > 0) {
      EXPECT_EQ(a.contact_groups, 1) << "step " << k;
      ++joined_steps;
    }
    for (int t = 0; t < 2; ++t) {
      largest_difference_m = std::max(
          largest_difference_m,
          (split.tissue(t).positions() - whole.tissue(t).positions()).cwiseAbs().maxCoeff());
    }
    largest_lobe_difference_m =
        std::max(largest_lobe_difference_m, std::abs(split_lobe.meanZ() - whole_lobe.meanZ()));
    if (k == 99) lobe_resting = split_lobe.meanZ();   // settled on the stomach
    if (k == 559) lobe_held = split_lobe.meanZ();     // the tool held 2 cm up
  }
  const double lift_m = lobe_held - lobe_resting;
  std::printf("[two hands] %d steps split in two groups, %d joined by the organs' contact, probe on "
              "the stomach in %d; lobe lifted %.2f mm; largest difference from the whole solve: "
              "%.3g m at a node, %.3g m in the lobe's mean height\n",
              split_steps, joined_steps, probe_on_stomach, 1e3 * lift_m, largest_difference_m,
              largest_lobe_difference_m);
  EXPECT_GT(split_steps, 100);
  EXPECT_GT(joined_steps, 50);
  // both solve to 1e-6, the grasp's forces are not unique (its rows are redundant), and the runs
  // part from the first split step by what that leaves: far less than the motion
  EXPECT_GT(lift_m, 0.005);
  EXPECT_LT(largest_lobe_difference_m, 0.05 * lift_m);
  EXPECT_LT(largest_difference_m, 0.1 * lift_m);
}

}  // namespace
}  // namespace tactus::sim
