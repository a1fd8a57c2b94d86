// Reaction forces: a tissue at rest on fixed nodes, on an obstacle, and on
// both, carries its weight: weight + reactions = 0 to 1e-6 relative. The VTU frames and the run's
// statistics JSON carry the reactions.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "tactus/sim/mesh_gen.h"
#include "tactus/sim/pipeline.h"
#include "../../support/test_dir.h"
#include "../../../sim_server/src/app/output_writer.h"
#include "tactus/sim/runner.h"
#include "tactus/sim/vtk_writer.h"

namespace tactus::sim {
namespace {

struct ReactionsDir : test_support::TestDir {
  ReactionsDir() : TestDir("tactus_reactions") {}
};

// A 4 x 4 x 3 cm block (E = 30 kPa) under gravity, settled for `steps` steps with strong mass
// damping; `fixed` and `obstacles` are the scene's text. The exact compliance by default: with it
// the correction is exactly the implicit Euler step under f, so the contact forces are the
// impulses per step the tissue receives (the warped model's R C0 R^T with per-node rotations is
// not, to ~1e-4 relative: see WarpedContactForcesBalanceTheWeightToTheWarpingError).
std::unique_ptr<Simulation> settle(const ReactionsDir& dir, const std::string& fixed,
                                   const std::string& obstacles, int steps,
                                   const std::string& extra = "",
                                   const std::string& compliance = "exact") {
  const TetMesh mesh = makeBoxTetMesh(4, 4, 3, Eigen::Vector3d(0.04, 0.04, 0.03),
                                      Eigen::Vector3d(-0.02, -0.02, 0.0));
  writeVtu(dir.path / "block.vtu", mesh, mesh.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
  const std::string yaml = "time_step: 0.01\n"
                           "gravity: [0, 0, -9.81]\n"
                           "tissues:\n"
                           "  - name: block\n"
                           "    mesh: block.vtu\n"
                           "    material: {young_modulus: 30000, poisson_ratio: 0.4}\n"
                           "    damping: {rayleigh_mass: 8, rayleigh_stiffness: 0.005}\n"
                           "    compliance: {model: " + compliance + "}\n" +
                           fixed + obstacles +
                           "solver: {nsgs_tolerance: 1.0e-12, nsgs_max_sweeps: 20000}\n" + extra;
  auto sim = std::make_unique<Simulation>(parseScene(yaml, "reactions.yaml", dir.path));
  for (int k = 0; k < steps; ++k) EXPECT_TRUE(sim->step().finite);
  return sim;
}

double relativeImbalance(const ReactionForces& r) {
  return r.imbalance_n().norm() / r.weight_n.norm();
}

TEST(ReactionsTest, FixedNodesCarryTheWeightOfATissueAtRest) {
  ReactionsDir dir;
  auto sim = settle(dir, "    fixed: {regions: [{lowest: z}]}\n", "", 400);
  const ReactionForces r = sim->reactions();
  std::printf("[reactions] fixed base: weight %.9g N, fixed %.9g N, imbalance %.3g\n",
              r.weight_n.z(), r.fixed_total_n.z(), relativeImbalance(r));
  EXPECT_NEAR(r.weight_n.z(), -9.81 * 1000 * 0.04 * 0.04 * 0.03, 1e-9);
  EXPECT_LT(relativeImbalance(r), 1e-6);
  EXPECT_GT(r.fixed_total_n.z(), 0.0);
}

TEST(ReactionsTest, AnObstacleCarriesTheWeightOfATissueRestingOnIt) {
  ReactionsDir dir;
  auto sim = settle(dir, "",
                    "obstacles: [{name: table, plane: {point: [0, 0, -0.0005], normal: [0, 0, 1]}, "
                    "friction: 0.5}]\n",
                    300);
  const ReactionForces r = sim->reactions();
  ASSERT_EQ(r.obstacle_force_n.size(), 1u);
  EXPECT_EQ(r.obstacle_names[0], "table");
  std::printf("[reactions] on a table: weight %.9g N, table %.9g N, imbalance %.3g\n",
              r.weight_n.z(), r.obstacle_force_n[0].z(), relativeImbalance(r));
  EXPECT_LT(relativeImbalance(r), 1e-6);
  EXPECT_EQ(r.fixed_total_n, Eigen::Vector3d::Zero());
}

TEST(ReactionsTest, FixedNodesAndAnObstacleShareTheWeight) {
  // fixed along one side (x = -0.02), resting on a table: both carry a part
  ReactionsDir dir;
  auto sim = settle(dir, "    fixed: {regions: [{lowest: x}]}\n",
                    "obstacles: [{name: table, plane: {point: [0, 0, -0.0005], normal: [0, 0, 1]}, "
                    "friction: 0.5}]\n",
                    400);
  const ReactionForces r = sim->reactions();
  std::printf("[reactions] side and table: weight %.9g N, fixed %.9g N, table %.9g N, imbalance "
              "%.3g\n",
              r.weight_n.z(), r.fixed_total_n.z(), r.obstacle_force_n[0].z(), relativeImbalance(r));
  EXPECT_LT(relativeImbalance(r), 1e-6);
  EXPECT_GT(r.fixed_total_n.z(), 0.05 * -r.weight_n.z());
  EXPECT_GT(r.obstacle_force_n[0].z(), 0.05 * -r.weight_n.z());
}

TEST(ReactionsTest, WarpedContactForcesBalanceTheWeightToTheWarpingError) {
  // the default compliance model: f solves the warped problem, the tissue moves by R C0 R^T H^T f
  ReactionsDir dir;
  auto sim = settle(dir, "",
                    "obstacles: [{name: table, plane: {point: [0, 0, -0.0005], normal: [0, 0, 1]}, "
                    "friction: 0.5}]\n",
                    300, "", "warped");
  const ReactionForces r = sim->reactions();
  std::printf("[reactions] on a table, warped compliance: weight %.9g N, table %.9g N, imbalance "
              "%.3g\n", r.weight_n.z(), r.obstacle_force_n[0].z(), relativeImbalance(r));
  EXPECT_LT(relativeImbalance(r), 1e-3);
  EXPECT_GT(relativeImbalance(r), 0.0);
}

TEST(ReactionsTest, TheVtuFramesAndTheStatisticsCarryTheReactions) {
  ReactionsDir dir;
  auto sim = settle(dir, "    fixed: {regions: [{lowest: x}]}\n",
                    "obstacles: [{name: table, plane: {point: [0, 0, -0.0005], normal: [0, 0, 1]}, "
                    "friction: 0.5}]\n",
                    20, "output: {vtk: " + (dir.path / "out").string() + ", every: 10}\n");
  OutputWriter().writeIfDue(*sim);
  std::ifstream in(dir.path / "out" / "block_000000.vtu");
  std::stringstream text;
  text << in.rdbuf();
  EXPECT_NE(text.str().find("Name=\"reaction_force\""), std::string::npos);
  EXPECT_NE(text.str().find("Name=\"contact_force\""), std::string::npos);
  RunStatistics stats;
  const ReactionForces r = sim->reactions();
  stats.setReactions(r);
  const std::string json = stats.json("reactions.yaml");
  EXPECT_NE(json.find("\"reactions\": {\"weight_n\": ["), std::string::npos) << json;
  EXPECT_NE(json.find("\"obstacles_n\": {\"table\": ["), std::string::npos) << json;
}

}  // namespace
}  // namespace tactus::sim
