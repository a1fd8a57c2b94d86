// The public C++ API (api/include/tactus; docs/api.md): a Model compiled from a file or a string,
// Simulations stepped from it and read in place, and States copied, saved, loaded and restored
// (bit for bit: the simulation's own tests are tests/unit/pipeline/state_test.cpp).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <fstream>
#include <sstream>
#include <utility>
#include <vector>

#include "../../support/test_dir.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/vtk_writer.h"
#include "tactus/sim/mesh_gen.h"
#include "tactus/tactus.h"

namespace tactus {
namespace {

const std::filesystem::path kScenes = std::filesystem::path(TACTUS_SOURCE_DIR) / "scenes";

std::string readText(const std::filesystem::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// A soft 4 cm block resting on a plate, in a folder of its own.
struct BlockScene {
  test_support::TestDir dir{"tactus_api"};
  std::string yaml;
  BlockScene() {
    const sim::TetMesh mesh = sim::makeBoxTetMesh(
        3, 3, 2, Eigen::Vector3d(0.04, 0.04, 0.02), Eigen::Vector3d(-0.02, -0.02, 0.0005));
    sim::writeVtu(dir.path / "block.vtu", mesh, mesh.nodes, Eigen::Matrix3Xd(),
                  Eigen::VectorXd());
    yaml = "time_step: 0.01\n"
           "gravity: [0, 0, -9.81]\n"
           "tissues:\n"
           "  - name: block\n"
           "    mesh: block.vtu\n"
           "    material: {young_modulus: 3000, poisson_ratio: 0.45}\n"
           "    damping: {rayleigh_mass: 2, rayleigh_stiffness: 0.02}\n"
           "    compliance: {model: warped}\n"
           "obstacles:\n"
           "  - {name: table, plane: {point: [0, 0, 0], normal: [0, 0, 1]}, friction: 0.5}\n";
  }
  Model model() const { return Model::fromString(yaml, dir.path, "block.yaml"); }
};

TEST(ApiTest, AModelFromAFileOrItsTextIsTheSameModel) {
  const Model m = Model::fromFile(kScenes / "liver_grasp.yaml");
  EXPECT_EQ(m.name(), "liver_grasp.yaml");
  EXPECT_EQ(m.timeStep(), 0.01);
  ASSERT_EQ(m.tissueCount(), 1);
  EXPECT_EQ(m.tissueName(0), "liver");
  EXPECT_EQ(m.nodeCount(0), 507);
  EXPECT_EQ(m.restPositions(0).cols(), 507);
  EXPECT_EQ(m.tetrahedra(0).size(), 1493u);
  EXPECT_FALSE(m.surfaceTriangles(0).empty());
  EXPECT_TRUE(std::is_sorted(m.fixedNodes(0).begin(), m.fixedNodes(0).end()));
  EXPECT_EQ(m.fixedNodes(0).size(), 161u);
  EXPECT_EQ(m.instrumentCount(), 1);
  EXPECT_THROW(m.nodeCount(1), std::out_of_range);
  const Model same = Model::fromString(readText(kScenes / "liver_grasp.yaml"), kScenes,
                                       "liver_grasp.yaml");
  EXPECT_EQ(same.identity(), m.identity());
  const Model other = Model::fromFile(kScenes / "liver_on_support.yaml");
  EXPECT_NE(other.identity(), m.identity());
  try {
    Model::fromString("time_step: -1\n", kScenes, "bad.yaml");
    ADD_FAILURE() << "a negative time step was accepted";
  } catch (const SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.yaml"), std::string::npos) << e.what();
  }
}

TEST(ApiTest, StepsReadInPlaceAndAStateRestoresTheRun) {
  const BlockScene scene;
  const Model model = scene.model();
  Simulation sim(model);
  const double* q = sim.positions(0).data();
  for (int k = 0; k < 30; ++k) sim.step();
  EXPECT_EQ(sim.positions(0).data(), q);   // the view is the state's memory
  EXPECT_EQ(sim.stepIndex(), 30);
  EXPECT_GT(sim.lastProblem().contacts, 0);   // the block rests on the table
  const State saved = sim.state();
  EXPECT_EQ(saved.stepIndex(), 30);
  EXPECT_NEAR(saved.time(), 0.3, 1e-12);
  EXPECT_EQ(saved.modelIdentity(), model.identity());
  EXPECT_EQ(saved.modelName(), "block.yaml");
  for (int k = 0; k < 20; ++k) sim.step();
  const Eigen::Matrix3Xd q50 = sim.positions(0);
  const Eigen::Matrix3Xd v50 = sim.velocities(0);
  const State end = sim.state();

  // rewound: the contact problem of the run that made it is gone until the next step
  sim.setState(saved);
  EXPECT_EQ(sim.stepIndex(), 30);
  EXPECT_EQ(sim.lastProblem().contacts, 0);
  for (int k = 0; k < 20; ++k) sim.step();
  EXPECT_TRUE(sim.positions(0) == q50);
  EXPECT_TRUE(sim.velocities(0) == v50);
  EXPECT_TRUE(sim.state() == end);

  // through a file, into another simulation of the model
  const std::filesystem::path file = scene.dir.path / "rest.state";
  saved.save(file);
  EXPECT_THROW(saved.save(file), FileError);   // never overwritten unasked
  saved.save(file, true);
  Simulation other(model);
  other.setState(State::load(file));
  for (int k = 0; k < 20; ++k) other.step();
  EXPECT_TRUE(other.positions(0) == q50);

  // at rest the table carries the weight
  const ReactionForces r = other.reactions();
  ASSERT_EQ(r.obstacle_force_n.size(), 1u);
  EXPECT_NEAR(r.obstacle_force_n[0].z(), -r.weight_n.z(), 0.05 * std::abs(r.weight_n.z()));
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  const ContactProblem& p = other.lastProblem();
  for (int c = 0; c < p.contacts; ++c) sum += p.forceOnTissue(c);
  EXPECT_TRUE(sum.isApprox(r.obstacle_force_n[0], 1e-9));
}

TEST(ApiTest, AStateOfAnotherModelOrNotAStateIsRefused) {
  const BlockScene scene;
  Simulation block(scene.model());
  const State mine = block.state();
  Simulation liver(Model::fromFile(kScenes / "liver_on_support.yaml"));
  try {
    block.setState(liver.state());
    ADD_FAILURE() << "a state of another model was restored";
  } catch (const StateError& e) {
    EXPECT_NE(std::string(e.what()).find("liver_on_support.yaml"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("block.yaml"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(block.state() == mine);
  const std::filesystem::path junk = scene.dir.path / "junk.state";
  scene.dir.write("junk.state", "not a state at all");
  EXPECT_THROW(State::load(junk), StateError);
  EXPECT_THROW(State::load(scene.dir.path), FileError);   // a folder
  EXPECT_THROW(block.setState(State()), StateError);
}

// A problem written into a snapshot slot says its W is exactly symmetric (kSnapshotSymmetricW:
// the haptic side's sweep may then read one triangle) when it is, and only then: one entry off
// its mirror anywhere, in a tile of the comparison or across tiles, clears the flag.
TEST(ApiTest, ASnapshotSaysWIsSymmetricOnlyWhenItIs) {
  constexpr int kContacts = 30;
  ContactProblem p;
  p.contacts = kContacts;
  p.rows = 3 * kContacts;
  for (int c = 0; c <= kContacts; ++c) p.row_offset.push_back(3 * c);
  p.mu.assign(kContacts, 0.3);
  Eigen::MatrixXd w(p.rows, p.rows);
  for (int i = 0; i < p.rows; ++i)
    for (int j = 0; j <= i; ++j)
      w(i, j) = w(j, i) = i == j ? 1.0 + 0.01 * i : 1e-3 * std::sin(0.7 * i + 1.3 * j);
  p.W = w;
  p.delta_free = Eigen::VectorXd::LinSpaced(p.rows, -1e-3, 1e-3);
  p.f = Eigen::VectorXd::Zero(p.rows);
  const shared::SnapshotLayout layout = shared::SnapshotLayout::forCapacity(128, 40);
  std::vector<unsigned char> bytes(layout.total_bytes + 64, 0);
  void* base = bytes.data() + (64 - reinterpret_cast<std::uintptr_t>(bytes.data()) % 64) % 64;
  const auto symmetricFlag = [&](const Eigen::MatrixXd& written) {
    p.W = written;
    shared::SnapshotWriter slot(base, layout);
    EXPECT_TRUE(writeSnapshotSlot(p, 1, 0, 0, slot));
    return (slot.header().flags & shared::kSnapshotSymmetricW) != 0;
  };
  EXPECT_TRUE(symmetricFlag(w));
  for (const auto& [i, j] : {std::pair{3, 70}, std::pair{40, 41}, std::pair{89, 0},
                             std::pair{33, 64}}) {
    Eigen::MatrixXd off = w;
    off(i, j) = std::nextafter(off(i, j), 1.0);
    EXPECT_FALSE(symmetricFlag(off)) << "W(" << i << ", " << j << ") off its mirror";
  }
}

}  // namespace
}  // namespace tactus
