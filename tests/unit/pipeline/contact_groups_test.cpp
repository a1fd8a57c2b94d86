// The contact problem solved per group of coupled bodies (contact_groups.h):
// the solver on a block-diagonal problem whose groups interleave gives the whole problem's
// solution, to the whole problem's tolerance; the simulation splits two blocks resting apart on a
// table into two groups and follows the same motion as one solve over the whole W; a probe
// pressing on both blocks, or a tissue_contact pair between them, makes them one group.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "../../../sim_server/src/pipeline/contact_groups.h"
#include "tactus/sim/mesh_gen.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/vtk_writer.h"
#include "../../support/test_dir.h"

namespace tactus::sim {
namespace {

// A frictional problem of `contacts` contacts in `groups` groups (contact c in group
// label[c]): W = H_g H_g^T + 0.05 I inside a group (H random, a few shared "nodes" per group),
// exactly 0 between groups; every fourth contact has one row (mu unused), the others three.
struct GroupedProblem {
  std::vector<int> label, row_offset;
  std::vector<double> W, delta_free, mu;
  int rows = 0;
  shared::ContactProblemView view() const {
    return shared::denseProblemView(static_cast<int>(label.size()), rows, row_offset.data(),
                                    W.data(), rows, delta_free.data(), mu.data());
  }
};

GroupedProblem makeProblem(const std::vector<int>& label, unsigned seed) {
  GroupedProblem p;
  p.label = label;
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  p.row_offset.assign(1, 0);
  for (std::size_t c = 0; c < label.size(); ++c) {
    p.row_offset.push_back(p.row_offset.back() + (c % 4 == 3 ? 1 : 3));
    p.mu.push_back(c % 2 == 0 ? 0.4 : 0.8);
  }
  p.rows = p.row_offset.back();
  const int dofs = 12;   // per group: H maps onto a 12-dof body shared by the group's contacts
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(p.rows, dofs);
  for (int r = 0; r < p.rows; ++r) {
    for (int k = 0; k < dofs; ++k) H(r, k) = normal(rng);
  }
  p.W.assign(static_cast<std::size_t>(p.rows) * p.rows, 0.0);
  for (std::size_t a = 0; a < label.size(); ++a) {
    for (std::size_t b = 0; b < label.size(); ++b) {
      if (label[a] != label[b]) continue;
      for (int i = p.row_offset[a]; i < p.row_offset[a + 1]; ++i) {
        for (int j = p.row_offset[b]; j < p.row_offset[b + 1]; ++j) {
          p.W[static_cast<std::size_t>(i) * p.rows + j] =
              H.row(i).dot(H.row(j)) + (i == j ? 0.05 : 0.0);
        }
      }
    }
  }
  for (int c = 0; c + 1 < static_cast<int>(p.row_offset.size()); ++c) {
    const int r0 = p.row_offset[c];
    p.delta_free.push_back(normal(rng) - 0.5);   // most contacts start penetrating
    for (int r = r0 + 1; r < p.row_offset[c + 1]; ++r) p.delta_free.push_back(normal(rng));
  }
  return p;
}

double relativeDifference(const std::vector<double>& a, const std::vector<double>& b) {
  double diff = 0.0, norm = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    diff = std::max(diff, std::abs(a[i] - b[i]));
    norm = std::max(norm, std::abs(b[i]));
  }
  return diff / norm;
}

TEST(ContactGroupsTest, InterleavedGroupsGiveTheWholeProblemsSolution) {
  // three groups, interleaved (gathered copies) and then in runs (in-place diagonal blocks)
  std::vector<int> interleaved, runs;
  for (int c = 0; c < 36; ++c) {
    interleaved.push_back((c * 7) % 3 + 5);   // labels need not start at 0
    runs.push_back(c / 12);
  }
  for (const auto& label : {interleaved, runs}) {
    const GroupedProblem p = makeProblem(label, 7);
    shared::NsgsSettings settings;
    settings.tolerance = 1e-10;
    settings.max_sweeps = 20000;
    shared::NsgsWorkspace workspace(p.rows, static_cast<int>(label.size()));
    std::vector<double> whole(static_cast<std::size_t>(p.rows), 0.0);
    const shared::NsgsResult whole_res =
        shared::solveNsgs(p.view(), settings, workspace, whole.data());
    ASSERT_EQ(whole_res.status, shared::NsgsStatus::kConverged);

    ContactGroups groups;
    groups.assign(label);
    ASSERT_EQ(groups.count(), 3);
    EXPECT_EQ(groups.groupSize(0) + groups.groupSize(1) + groups.groupSize(2), 36);
    std::vector<double> split(static_cast<std::size_t>(p.rows), 0.0);
    const shared::NsgsResult res = groups.solve(p.view(), settings, workspace, split.data());
    ASSERT_EQ(res.status, shared::NsgsStatus::kConverged);
    // the whole problem's error, to the whole problem's tolerance
    EXPECT_LE(res.error, settings.tolerance);
    EXPECT_NEAR(res.error, shared::naturalMapError(p.view(), split.data()), 1e-15);
    // W is positive definite: one solution
    EXPECT_LT(relativeDifference(split, whole), 1e-7);
    double force = 0.0;
    for (double x : split) force += std::abs(x);
    EXPECT_GT(force, 1.0) << "a problem with no contact force tests nothing";
    std::printf("[groups] whole: %d sweeps; split: at most %d sweeps in a group, error %.3g\n",
                whole_res.sweeps, res.sweeps, res.error);

    // a NaN in one group fails the whole solve and zeroes every force (as solveNsgs does)
    GroupedProblem bad = p;
    bad.delta_free[static_cast<std::size_t>(bad.row_offset[4])] =
        std::numeric_limits<double>::quiet_NaN();
    std::vector<double> f(static_cast<std::size_t>(p.rows), 1.0);
    const shared::NsgsResult bad_res = groups.solve(bad.view(), settings, workspace, f.data());
    EXPECT_EQ(bad_res.status, shared::NsgsStatus::kNonFinite);
    for (double x : f) ASSERT_EQ(x, 0.0);
  }
}

TEST(ContactGroupsTest, OneGroupIsTheWholeSolve) {
  const GroupedProblem p = makeProblem(std::vector<int>(20, 0), 3);
  shared::NsgsSettings settings;
  settings.tolerance = 1e-9;
  settings.max_sweeps = 20000;
  shared::NsgsWorkspace workspace(p.rows, 20);
  std::vector<double> whole(static_cast<std::size_t>(p.rows), 0.0), split = whole;
  const shared::NsgsResult a = shared::solveNsgs(p.view(), settings, workspace, whole.data());
  ContactGroups groups;
  groups.assign(p.label);
  EXPECT_EQ(groups.count(), 1);
  const shared::NsgsResult b = groups.solve(p.view(), settings, workspace, split.data());
  EXPECT_EQ(a.sweeps, b.sweeps);
  EXPECT_EQ(whole, split);
}

// One group whose W is sparse by blocks (ten sub-bodies of four contacts that the grouping does
// not separate, as in a chain of organs): NSGS sweeps the blocks (chooseStorage's rule, fill 0.1)
// and gives the dense solve's forces.
TEST(ContactGroupsTest, AGroupSparseByBlocksIsSweptOnItsBlocks) {
  std::vector<int> body;
  for (int c = 0; c < 40; ++c) body.push_back(c / 4);
  const GroupedProblem p = makeProblem(body, 11);   // W zero between the sub-bodies
  shared::NsgsSettings settings;
  settings.tolerance = 1e-10;
  settings.max_sweeps = 20000;
  shared::NsgsWorkspace workspace(p.rows, 40);
  std::vector<double> dense(static_cast<std::size_t>(p.rows), 0.0), chosen = dense;
  ASSERT_EQ(shared::solveNsgs(p.view(), settings, workspace, dense.data()).status,
            shared::NsgsStatus::kConverged);
  ContactGroups groups;
  groups.assign(std::vector<int>(40, 0));   // one group
  ASSERT_EQ(groups.solve(p.view(), settings, workspace, chosen.data()).status,
            shared::NsgsStatus::kConverged);
  EXPECT_EQ(groups.solvedOnBlocks(), 1);
  EXPECT_LT(relativeDifference(chosen, dense), 1e-7);
  // a dense group (one body) stays on the dense W
  const GroupedProblem full = makeProblem(std::vector<int>(40, 0), 11);
  std::fill(chosen.begin(), chosen.end(), 0.0);
  groups.solve(full.view(), settings, workspace, chosen.data());
  EXPECT_EQ(groups.solvedOnBlocks(), 0);
}

struct TempDir : test_support::TestDir {
  TempDir() : TestDir("tactus_contact_groups") {}
};

// Two 2 x 2 x 2 cm blocks 2 mm apart along x (centres at x = -/+11 mm), 0.5 mm above a table.
void writeBlocks(const TempDir& dir) {
  const TetMesh left = makeBoxTetMesh(2, 2, 2, Eigen::Vector3d(0.02, 0.02, 0.02),
                                      Eigen::Vector3d(-0.021, -0.01, 0.0));
  const TetMesh right = makeBoxTetMesh(2, 2, 2, Eigen::Vector3d(0.02, 0.02, 0.02),
                                       Eigen::Vector3d(0.001, -0.01, 0.0));
  writeVtu(dir.path / "left.vtu", left, left.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
  writeVtu(dir.path / "right.vtu", right, right.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
}

std::string blocksScene(bool split, const std::string& extra,
                        const std::string& tolerance = "1.0e-10") {
  const std::string material =
      "    material: {young_modulus: 30000, poisson_ratio: 0.4}\n"
      "    damping: {rayleigh_mass: 8, rayleigh_stiffness: 0.005}\n"
      "    compliance: {model: exact}\n";
  return "time_step: 0.01\n"
         "gravity: [0, 0, -9.81]\n"
         "tissues:\n"
         "  - name: left\n"
         "    mesh: left.vtu\n" + material +
         "  - name: right\n"
         "    mesh: right.vtu\n" + material +
         "obstacles: [{name: table, plane: {point: [0, 0, -0.0005], normal: [0, 0, 1]}, "
         "friction: 0.5}]\n"
         "solver: {nsgs_tolerance: " + tolerance + ", nsgs_max_sweeps: 20000, split_contact_groups: " +
         std::string(split ? "true" : "false") + "}\n" + extra;
}

TEST(ContactGroupsTest, TwoBlocksApartAreTwoGroupsAndMoveAsOneSolveMovesThem) {
  TempDir dir;
  writeBlocks(dir);
  Simulation split(parseScene(blocksScene(true, ""), "split.yaml", dir.path));
  Simulation whole(parseScene(blocksScene(false, ""), "whole.yaml", dir.path));
  double largest_difference_m = 0.0;
  int split_steps = 0;
  for (int k = 0; k < 150; ++k) {
    const StepReport a = split.step();
    const StepReport b = whole.step();
    ASSERT_EQ(a.nsgs.status, shared::NsgsStatus::kConverged) << "step " << k;
    ASSERT_EQ(b.nsgs.status, shared::NsgsStatus::kConverged) << "step " << k;
    EXPECT_EQ(b.contact_groups, b.contacts > 0 ? 1 : 0);
    if (a.contacts > 0) {
      // both blocks reach the table in the same step (same height, same material)
      EXPECT_EQ(a.contact_groups, 2) << "step " << k;
      split_steps += a.contact_groups == 2 ? 1 : 0;
    }
    for (int t = 0; t < 2; ++t) {
      largest_difference_m = std::max(
          largest_difference_m,
          (split.tissue(t).positions() - whole.tissue(t).positions()).cwiseAbs().maxCoeff());
    }
  }
  std::printf("[groups] two blocks: %d steps split in two, largest position difference %.3g m\n",
              split_steps, largest_difference_m);
  EXPECT_GT(split_steps, 100);
  EXPECT_LT(largest_difference_m, 1e-8);
  // both rest on the table: it carries both weights
  const ReactionForces r = split.reactions();
  EXPECT_LT(r.imbalance_n().norm() / r.weight_n.norm(), 1e-6);
}

TEST(ContactGroupsTest, AProbeOnBothBlocksOrAContactPairJoinsThem) {
  TempDir dir;
  writeBlocks(dir);
  // a 4 mm probe tip pressed into the 2 mm gap between the blocks' top edges, 1.5 mm toward the
  // right block (it touches that one first)
  const std::string probe =
      "instrument:\n"
      "  type: probe\n"
      "  friction: 0.3\n"
      "  probe: {tip_radius: 0.004, shaft_length: 0.03}\n"
      "  coupling: {stiffness: 300, damping: 3, rotational_stiffness: 0.5, "
      "rotational_damping: 0.005}\n"
      "  initial_pose: {position: [0.0015, 0, 0.03]}\n"
      "  trajectory:\n"
      "    - {t: 0.0, position: [0.0015, 0, 0.03]}\n"
      "    - {t: 1.0, position: [0.0015, 0, 0.018]}\n";
  Simulation pressed(parseScene(blocksScene(true, probe, "1.0e-6"), "probe.yaml", dir.path));
  int joined = 0, one_side = 0;
  for (int k = 0; k < 120; ++k) {
    pressed.setDeviceTarget(pressed.scriptedTarget(pressed.time()));
    const StepReport r = pressed.step();
    ASSERT_EQ(r.nsgs.status, shared::NsgsStatus::kConverged) << "step " << k;
    const ContactProblemData& p = pressed.lastProblem();
    bool on_left = false, on_right = false;
    for (int c = 0; c < p.contacts; ++c) {
      if (p.contact_instrument[c] != 0) continue;
      (p.point_m[c].x() < 0.0 ? on_left : on_right) = true;
    }
    // the contacts no device can move, for the haptic loop: a group without the probe's
    int unreachable = 0;
    for (int c = 0; c < p.contacts; ++c) unreachable += p.unreachable.at(c);
    if (on_left && on_right) {
      EXPECT_EQ(r.contact_groups, 1) << "step " << k;
      EXPECT_EQ(unreachable, 0) << "step " << k;
      ++joined;
    } else if (r.contacts > 0 && !on_left && !on_right) {
      EXPECT_EQ(r.contact_groups, 2) << "step " << k;
      EXPECT_EQ(unreachable, p.contacts) << "step " << k;
    } else if (r.contacts > 0) {   // the probe on one block: the other block's contacts
      EXPECT_GT(unreachable, 0) << "step " << k;
      EXPECT_LT(unreachable, p.contacts) << "step " << k;
      ++one_side;
    }
  }
  EXPECT_GT(joined, 10) << "the probe never touched both blocks";
  std::printf("[groups] probe: %d steps on both blocks, %d on one\n", joined, one_side);

  // side by side, touching through a tissue_contact pair: one group
  const TetMesh left = makeBoxTetMesh(2, 2, 2, Eigen::Vector3d(0.02, 0.02, 0.02),
                                      Eigen::Vector3d(-0.0205, -0.01, 0.0));
  writeVtu(dir.path / "left.vtu", left, left.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
  const TetMesh right = makeBoxTetMesh(2, 2, 2, Eigen::Vector3d(0.02, 0.02, 0.02),
                                       Eigen::Vector3d(0.0, -0.01, 0.0));
  writeVtu(dir.path / "right.vtu", right, right.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
  Simulation paired(parseScene(
      blocksScene(true, "tissue_contact: [{between: [left, right], alarm_distance: 0.001}]\n"),
      "paired.yaml", dir.path));
  int pair_steps = 0;
  for (int k = 0; k < 60; ++k) {
    const StepReport r = paired.step();
    const ContactProblemData& p = paired.lastProblem();
    int pair_contacts = 0;
    for (int c = 0; c < p.contacts; ++c) pair_contacts += (p.contact_id[c] >> 56 & 3) == 3 ? 1 : 0;
    if (pair_contacts > 0) {
      EXPECT_EQ(r.contact_groups, 1) << "step " << k;
      ++pair_steps;
    }
  }
  EXPECT_GT(pair_steps, 10);
}

}  // namespace
}  // namespace tactus::sim
