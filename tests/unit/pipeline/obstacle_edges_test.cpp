// The obstacles' edges against the tissues' faces (obstacles.h "Edges"): a coarse soft block (one cell, 2 cm) dropped onto a bar narrower than
// the block's bottom face, under its middle: no vertex of the block is over the bar, so with
// vertex contacts only the bar passes through the face and the block falls; with
// obstacle_contact.edges the bar's top edges hold the face, the block rests on the bar, and
// the bar carries its weight. The same with the bar as a triangle surface (OBJ), whose sharp
// edges are found from the dihedral angles.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"
#include "tactus/sim/obstacles.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/vtk_writer.h"
#include "../../support/test_dir.h"

namespace tactus::sim {
namespace {

struct EdgesDir : test_support::TestDir {
  EdgesDir() : TestDir("tactus_obstacle_edges") {}
};

// A bar 6 cm long (x), 8 mm wide (y), top at z = 0, as an OBJ: a box whose top face is split
// into a 4 x 1 grid of quads (flat interior edges that are not sharp).
const char* kBarObj =
    "v -0.03 -0.004 -0.01\nv 0.03 -0.004 -0.01\nv 0.03 0.004 -0.01\nv -0.03 0.004 -0.01\n"
    "v -0.03 -0.004 0\nv -0.015 -0.004 0\nv 0 -0.004 0\nv 0.015 -0.004 0\nv 0.03 -0.004 0\n"
    "v -0.03 0.004 0\nv -0.015 0.004 0\nv 0 0.004 0\nv 0.015 0.004 0\nv 0.03 0.004 0\n"
    // bottom (normal -z)
    "f 1 4 3 2\n"
    // top, four quads (normal +z)
    "f 5 6 11 10\nf 6 7 12 11\nf 7 8 13 12\nf 8 9 14 13\n"
    // sides y = -0.004 (normal -y) and y = +0.004 (normal +y)
    "f 1 2 9 8 7 6 5\nf 3 4 10 11 12 13 14\n"
    // ends x = -0.03 (normal -x) and x = +0.03 (normal +x)
    "f 1 5 10 4\nf 2 3 14 9\n";

struct DropRun {
  double centroid_z_m = 0.0;        ///< the block's mean node height at the end
  double bar_carries = 0.0;         ///< the bar's vertical force / the block's weight
  double worst_penetration_m = 0.0; ///< max over the last 50 steps of StepReport::max_penetration_m
  int edge_contacts = 0;            ///< contacts of the last problem with the edge bit set
  int unconverged = 0;
};

DropRun dropOnBar(const std::string& bar, bool edges) {
  EdgesDir dir;
  dir.write("bar.obj", kBarObj);
  // one 2 cm cell, its bottom face 1 mm above the bar; its bottom vertices at y = +-1 cm, beside
  // the 8 mm bar
  const TetMesh block = makeBoxTetMesh(1, 1, 1, Eigen::Vector3d(0.02, 0.02, 0.02),
                                       Eigen::Vector3d(-0.01, -0.01, 0.001));
  writeVtu(dir.path / "block.vtu", block, block.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
  const std::string yaml =
      "time_step: 0.01\n"
      "gravity: [0, 0, -9.81]\n"
      "tissues:\n"
      "  - name: block\n"
      "    mesh: block.vtu\n"
      "    material: {young_modulus: 20000, poisson_ratio: 0.3}\n"
      "    damping: {rayleigh_mass: 8, rayleigh_stiffness: 0.005}\n"
      "    compliance: {model: exact}\n"
      "obstacles: [{name: bar, " + bar + ", friction: 0.5}]\n"
      "obstacle_contact: {alarm_distance: 0.002, edges: " + std::string(edges ? "true" : "false") +
      ", edge_spacing: 0.002}\n"
      "solver: {nsgs_tolerance: 1.0e-6, nsgs_max_sweeps: 20000}\n";
  Simulation sim(parseScene(yaml, "drop.yaml", dir.path));
  DropRun out;
  for (int k = 0; k < 200; ++k) {
    const StepReport r = sim.step();
    EXPECT_TRUE(r.finite);
    if (r.rows > 0 && r.nsgs.status != shared::NsgsStatus::kConverged) ++out.unconverged;
    if (k >= 150) out.worst_penetration_m = std::max(out.worst_penetration_m, r.max_penetration_m);
  }
  const FemBody& body = sim.tissue(0);
  for (int i = 0; i < body.nodeCount(); ++i) out.centroid_z_m += body.positions()[3 * i + 2];
  out.centroid_z_m /= body.nodeCount();
  const ReactionForces reactions = sim.reactions();
  out.bar_carries = reactions.obstacle_force_n.empty()
                        ? 0.0
                        : -reactions.obstacle_force_n[0].z() / reactions.weight_n.z();
  const ContactProblemData& p = sim.lastProblem();
  for (int c = 0; c < p.contacts; ++c) out.edge_contacts += (p.contact_id[c] >> 58 & 1) ? 1 : 0;
  std::printf("[edges] %s, edges %s: centroid z %.4f m, bar carries %.9f of the weight, "
              "%d edge contacts, penetration <= %.3g m, %d steps unconverged\n",
              bar.c_str(), edges ? "on" : "off", out.centroid_z_m, out.bar_carries,
              out.edge_contacts, out.worst_penetration_m, out.unconverged);
  return out;
}

const std::string kBoxBar = "box: {min: [-0.03, -0.004, -0.01], max: [0.03, 0.004, 0]}";
const std::string kMeshBar = "mesh: {file: bar.obj}";

TEST(ObstacleEdgesTest, ABarBetweenTheVerticesPassesThroughTheFaceWithoutEdges) {
  for (const std::string& bar : {kBoxBar, kMeshBar}) {
    const DropRun run = dropOnBar(bar, false);
    EXPECT_LT(run.centroid_z_m, -0.02) << bar << ": the block should fall past the bar";
    EXPECT_EQ(run.edge_contacts, 0);
  }
}

TEST(ObstacleEdgesTest, TheBarsEdgesHoldTheFaceAndCarryTheWeight) {
  for (const std::string& bar : {kBoxBar, kMeshBar}) {
    const DropRun run = dropOnBar(bar, true);
    // resting on the bar: its centroid about 1 cm above the bar's top (it sags around the bar)
    EXPECT_GT(run.centroid_z_m, 0.005) << bar;
    EXPECT_LT(run.centroid_z_m, 0.0115) << bar;
    EXPECT_GT(run.edge_contacts, 4) << bar;
    EXPECT_NEAR(run.bar_carries, 1.0, 1e-4) << bar;   // to the solver tolerance (1e-6)
    EXPECT_LT(run.worst_penetration_m, 1e-6) << bar;
    EXPECT_EQ(run.unconverged, 0) << bar;
  }
}

TEST(ObstacleEdgesTest, EdgePointsAreTheCornersAndTheSharpEdges) {
  EdgesDir dir;
  dir.write("bar.obj", kBarObj);
  ObstacleContactSpec options;
  options.edges = true;
  options.edge_spacing_m = 0.002;
  std::vector<ObstacleSpec> specs(3);
  specs[0].kind = ObstacleKind::kPlane;
  specs[1].kind = ObstacleKind::kBox;
  specs[1].min_m = Eigen::Vector3d(-0.03, -0.004, -0.01);
  specs[1].max_m = Eigen::Vector3d(0.03, 0.004, 0.0);
  specs[2].kind = ObstacleKind::kMesh;
  specs[2].mesh_path = dir.path / "bar.obj";
  const Obstacles obstacles(specs, options);
  EXPECT_TRUE(obstacles.edgePoints(0).empty()) << "a plane has no edge";
  // 8 corners; 4 edges of 6 cm (29 points each), 4 of 8 mm (3), 4 of 1 cm (4)
  EXPECT_EQ(obstacles.edgePoints(1).size(), 8u + 4 * 29 + 4 * 3 + 4 * 4);
  // the mesh: the same 12 edges (its long edges pass through the top grid's vertices, so they
  // are split in 4 and sampled per piece: 4 x 7 points, plus the 3 grid vertices on each of the
  // two long top edges); the top's flat grid edges and diagonals are not sharp
  const auto& mesh_points = obstacles.edgePoints(2);
  EXPECT_EQ(mesh_points.size(), 8u + 2 * (4 * 7 + 3) + 2 * 29 + 4 * 3 + 4 * 4);
  for (const Eigen::Vector3d& p : mesh_points) {
    const bool on_x_edge = std::abs(std::abs(p.y()) - 0.004) < 1e-12 &&
                           (std::abs(p.z()) < 1e-12 || std::abs(p.z() + 0.01) < 1e-12);
    const bool on_y_edge = std::abs(std::abs(p.x()) - 0.03) < 1e-12 &&
                           (std::abs(p.z()) < 1e-12 || std::abs(p.z() + 0.01) < 1e-12);
    const bool on_z_edge =
        std::abs(std::abs(p.x()) - 0.03) < 1e-12 && std::abs(std::abs(p.y()) - 0.004) < 1e-12;
    EXPECT_TRUE(on_x_edge || on_y_edge || on_z_edge) << p.transpose();
  }
}

TEST(ObstacleEdgesTest, TheSceneChecksTheEdgeOptions) {
  EdgesDir dir;
  const TetMesh block = makeBoxTetMesh(1, 1, 1, Eigen::Vector3d(0.02, 0.02, 0.02),
                                       Eigen::Vector3d::Zero());
  writeVtu(dir.path / "block.vtu", block, block.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
  const std::string head = "time_step: 0.01\ntissues: [{name: block, mesh: block.vtu}]\n";
  const auto message = [&](const std::string& yaml) {
    try {
      parseScene(head + yaml, "s.yaml", dir.path);
    } catch (const SceneError& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  EXPECT_NE(message("obstacle_contact: {edge_spacing: 1.0e-6}\n")
                .find("obstacle_contact.edge_spacing"),
            std::string::npos);
  EXPECT_NE(message("obstacle_contact: {edge_depth: -1}\n").find("obstacle_contact.edge_depth"),
            std::string::npos);
  EXPECT_NE(message("obstacle_contact: {edges: maybe}\n").find("obstacle_contact.edges"),
            std::string::npos);
  const SceneSpec spec =
      parseScene(head + "obstacle_contact: {edges: true, edge_spacing: 0.003, edge_depth: 0.004}\n",
                 "s.yaml", dir.path);
  EXPECT_TRUE(spec.obstacle_contact.edges);
  EXPECT_EQ(spec.obstacle_contact.edge_spacing_m, 0.003);
  EXPECT_EQ(spec.obstacle_contact.edge_depth_m, 0.004);
}

}  // namespace
}  // namespace tactus::sim
