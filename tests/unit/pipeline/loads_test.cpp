// Loads: a pressure on a block's top and a prescribed displacement of it give
// the uniaxial static answer (exact for linear tetrahedra with Poisson's ratio 0), and a tip force
// on a cantilever converges to beam theory with refinement. The scene checks the loads.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <string>

#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/vtk_writer.h"
#include "../../support/test_dir.h"

namespace tactus::sim {
namespace {

struct LoadsDir : test_support::TestDir {
  LoadsDir() : TestDir("tactus_loads") {}
};

constexpr double kSide = 0.02;    // block edge [m]
constexpr double kLoadsE = 1e4;   // [Pa]

// A kSide cube (3 x 3 x 3 cells), linear material, Poisson 0, fixed at its base, with `loads`.
std::unique_ptr<Simulation> block(const LoadsDir& dir, const std::string& loads) {
  const TetMesh mesh = makeBoxTetMesh(3, 3, 3, Eigen::Vector3d::Constant(kSide));
  writeVtu(dir.path / "block.vtu", mesh, mesh.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
  const std::string yaml = "time_step: 0.01\n"
                           "tissues:\n"
                           "  - name: block\n"
                           "    mesh: block.vtu\n"
                           "    material: {law: linear, young_modulus: 10000, poisson_ratio: 0, "
                           "density: 1000}\n"
                           "    damping: {rayleigh_mass: 20}\n"
                           "    fixed: {regions: [{lowest: z}]}\n"
                           "    loads:\n" + loads;
  return std::make_unique<Simulation>(parseScene(yaml, "loads.yaml", dir.path));
}

TEST(LoadsTest, APressureOnTheTopCompressesABlockBy_pH_over_E) {
  LoadsDir dir;
  const double p = 100.0;
  auto sim = block(dir, "      - {region: {highest: z}, pressure: 100, ramp: 0.2}\n");
  for (int k = 0; k < 300; ++k) ASSERT_TRUE(sim->step().finite);
  const FemBody& b = sim->tissue(0);
  const double expected = -p * kSide / kLoadsE;  // uniform strain: exact for linear tets, nu = 0
  double worst = 0.0;
  for (int i = 0; i < b.nodeCount(); ++i) {
    const double z0 = b.restPositions()[3 * i + 2];
    const double uz = b.positions()[3 * i + 2] - z0;
    worst = std::max(worst, std::abs(uz - expected * z0 / kSide));
    EXPECT_NEAR(b.positions()[3 * i] - b.restPositions()[3 * i], 0.0, 1e-9);
  }
  std::printf("[loads] pressure: top displacement %.6g m (p H / E = %.6g m), worst node error "
              "%.3g m\n", b.positions()[3 * (b.nodeCount() - 1) + 2] - kSide, expected, worst);
  EXPECT_LT(worst, 1e-4 * std::abs(expected));
  // the base carries the load: reaction p A up
  const ReactionForces r = sim->reactions();
  EXPECT_NEAR(r.applied_load_n.z(), -p * kSide * kSide, 1e-12);
  EXPECT_NEAR(r.fixed_total_n.z(), p * kSide * kSide, 1e-4 * p * kSide * kSide);
}

TEST(LoadsTest, APrescribedDisplacementLoadsTheSupportWith_EA_delta_over_H) {
  LoadsDir dir;
  const double delta = -2e-4;
  auto sim = block(dir, "      - region: {highest: z}\n"
                        "        displacement: [{t: 0, offset: [0, 0, 0]}, "
                        "{t: 0.2, offset: [0, 0, -0.0002]}]\n");
  for (int k = 0; k < 10; ++k) ASSERT_TRUE(sim->step().finite);
  const FemBody& b = sim->tissue(0);
  // along the path: at t = 0.1 s half way
  EXPECT_NEAR(b.positions()[3 * (b.nodeCount() - 1) + 2] - kSide, delta / 2, 1e-15);
  for (int k = 10; k < 300; ++k) ASSERT_TRUE(sim->step().finite);
  EXPECT_NEAR(b.positions()[3 * (b.nodeCount() - 1) + 2] - kSide, delta, 1e-15);
  const ReactionForces r = sim->reactions();
  double base = 0.0, top = 0.0;
  for (int i = 0; i < b.nodeCount(); ++i) {
    const double z0 = b.restPositions()[3 * i + 2];
    if (z0 < 1e-9) base += r.tissues[0].fixed_reaction_n(2, i);
    if (z0 > kSide - 1e-9) top += r.tissues[0].fixed_reaction_n(2, i);
  }
  const double expected =
      kLoadsE * kSide * kSide * -delta / kSide;  // compression: the base pushes up
  std::printf("[loads] displacement: base reaction %.6g N, top %.6g N (E A d / H = %.6g N)\n",
              base, top, expected);
  EXPECT_NEAR(base, expected, 1e-4 * expected);
  EXPECT_NEAR(top, -expected, 1e-4 * expected);
}

// A cantilever L x b x b fixed at x = 0, total tip force P (down) spread over the end face's
// nodes; tip deflection against Timoshenko's P L^3 / (3 E I) + P L / (k G A).
double cantileverTip(int cells_along, int cells_across) {
  LoadsDir dir;
  const double L = 0.1, b = 0.01;
  const TetMesh mesh = makeBoxTetMesh(cells_along, cells_across, cells_across,
                                      Eigen::Vector3d(L, b, b), Eigen::Vector3d(0, -b / 2, -b / 2));
  writeVtu(dir.path / "beam.vtu", mesh, mesh.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
  const std::string yaml = "time_step: 0.01\n"
                           "tissues:\n"
                           "  - name: beam\n"
                           "    mesh: beam.vtu\n"
                           "    material: {law: linear, young_modulus: 1.0e6, poisson_ratio: 0, "
                           "density: 1000}\n"
                           "    damping: {rayleigh_mass: 40}\n"
                           "    fixed: {regions: [{lowest: x}]}\n"
                           "    loads: [{region: {highest: x}, force: [0, 0, -0.0025], ramp: 0.5}]\n";
  Simulation sim(parseScene(yaml, "beam.yaml", dir.path));
  for (int k = 0; k < 500; ++k) EXPECT_TRUE(sim.step().finite);
  const FemBody& body = sim.tissue(0);
  double sum = 0.0;
  int count = 0;
  for (int i = 0; i < body.nodeCount(); ++i) {
    if (body.restPositions()[3 * i] > L - 1e-9) {
      sum += body.positions()[3 * i + 2] - body.restPositions()[3 * i + 2];
      ++count;
    }
  }
  return sum / count;
}

TEST(LoadsTest, ATipForceBendsACantileverAsBeamTheorySaysWithinTheDiscretisationError) {
  const double P = 0.0025, L = 0.1, b = 0.01, E = 1e6;
  const double I = b * b * b * b / 12.0;
  const double G = E / 2.0;   // nu = 0
  const double theory = -(P * L * L * L / (3 * E * I) + P * L / (5.0 / 6.0 * G * b * b));
  std::vector<double> errors;
  for (const auto& [along, across] : std::vector<std::pair<int, int>>{{10, 1}, {20, 2}, {40, 4}}) {
    const double tip = cantileverTip(along, across);
    errors.push_back(std::abs(tip / theory - 1.0));
    std::printf("[loads] cantilever %d x %d x %d cells: tip %.6g m, theory %.6g m, error %.1f%%\n",
                along, across, across, tip, theory, 100 * errors.back());
  }
  // linear tetrahedra lock in bending: too stiff, less so with every refinement
  EXPECT_LT(errors[1], errors[0]);
  EXPECT_LT(errors[2], errors[1]);
  EXPECT_LT(errors[2], 0.25);
}

TEST(LoadsTest, BadLoadsAreSceneErrorsWithTheirPlace) {
  LoadsDir dir;
  auto error = [&](const std::string& loads) {
    try {
      block(dir, loads);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(error("      - {region: {highest: z}, pressure: 1, force: [0, 0, 1]}\n"),
            "loads.yaml:9:9: tissues[0].loads[0]: must have exactly one of force, pressure, "
            "displacement (got 2)");
  EXPECT_EQ(error("      - {region: {box: {min: [1, 1, 1], max: [2, 2, 2]}}, force: [0, 0, 1]}\n"),
            "loads.yaml:9:18: tissues[0].loads[0].region: the load region, the box [1, 1, 1].."
            "[2, 2, 2] m, selects no node of tissue 'block' (its placed mesh spans [0, 0, 0].."
            "[0.02, 0.02, 0.02] m)");
  EXPECT_NE(error("      - {region: {box: {min: [0, 0, 0.01], max: [0.001, 0.001, 0.03]}}, "
                  "pressure: 5}\n")
                .find("the pressure load's region selects 2 nodes of tissue 'block' but no "
                      "boundary triangle"),
            std::string::npos);
  EXPECT_EQ(error("      - region: {highest: z}\n"
                  "        displacement: [{t: 0.2, offset: [0, 0, 0]}, {t: 0.1, offset: [0, 0, 1]}]\n"),
            "loads.yaml:10:57: tissues[0].loads[0].displacement[1].t: must be greater than the "
            "previous key's t");
  EXPECT_NE(error("      - {region: {highest: z}, pressure: .nan}\n").find("pressure: must be"),
            std::string::npos);
  // the fixed base moved by a displacement load too: refused (it was accepted silently)
  EXPECT_NE(error("      - region: {lowest: z}\n"
                  "        displacement: [{t: 0, offset: [0, 0, 0]}, {t: 1, offset: [0, 0, 1e-3]}]\n")
                .find("node(s) are both fixed and given a prescribed displacement"),
            std::string::npos);
}

}  // namespace
}  // namespace tactus::sim
