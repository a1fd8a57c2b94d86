// Strain limiting on volume (sim_server/src/pipeline/strain_limit.h) on a bite the grasp crushed:
// the tets of liver_grasp_23k around the jaws at a contact pass of its grasp-anywhere grid's worst
// corner ((-5, -5) mm rolled -20 deg, the scenes' grip), as the pass's correction left them and
// before the limiter ran (tests/data/strain_limit/README.md). Dozens of tets there are crushed
// or inverted, held between the pads' contact nodes. The limiter lifts every one of them back to
// its bound, where before it stopped at its sweep limit with a tet still inverted (a tet its
// neighbour's projection pushed back below waited for the next sweep's scan, and the pair was
// lifted by turns; docs/design.md, "Strain limiting").
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "../../../sim_server/src/pipeline/strain_limit.h"
#include "tactus/sim/fem.h"

namespace tactus::sim {
namespace {

struct CrushedBite {
  TetMesh mesh;                  ///< rest positions [m]
  Eigen::VectorXd valid;         ///< at the step's start, every tet at its bound or above (3n)
  Eigen::VectorXd deformed;      ///< after the pass's correction (3n)
  std::vector<int> fixed;        ///< the patch's border (and the liver's fixed nodes)
  std::vector<TissueRow> rows;   ///< one row per contact node
  std::vector<int> row_offset;   ///< one contact per row (frictionless: free to slide)
};

// The fixture's format: '#' comments; "nodes N"; N lines "rest xyz, step start xyz, deformed xyz,
// flag" (0 free, 1 a contact row's node, 2 fixed); "tets M"; M lines of four node indices.
CrushedBite loadCrushedBite(const std::string& path) {
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << path;
  CrushedBite bite;
  std::string line, word;
  auto next = [&] {
    while (std::getline(in, line)) {
      if (!line.empty() && line[0] != '#') return true;
    }
    return false;
  };
  std::size_t count = 0;
  if (next()) std::istringstream(line) >> word >> count;
  bite.mesh.nodes.resize(3, static_cast<Eigen::Index>(count));
  bite.deformed.resize(3 * static_cast<Eigen::Index>(count));
  bite.valid.resize(3 * static_cast<Eigen::Index>(count));
  for (std::size_t i = 0; i < count && next(); ++i) {
    std::istringstream s(line);
    const auto c = static_cast<Eigen::Index>(i);
    int flag = 0;
    s >> bite.mesh.nodes(0, c) >> bite.mesh.nodes(1, c) >> bite.mesh.nodes(2, c) >>
        bite.valid[3 * c] >> bite.valid[3 * c + 1] >> bite.valid[3 * c + 2] >>
        bite.deformed[3 * c] >> bite.deformed[3 * c + 1] >> bite.deformed[3 * c + 2] >> flag;
    if (flag == 2) bite.fixed.push_back(static_cast<int>(i));
    if (flag == 1) bite.rows.push_back({{static_cast<int>(i), -1, -1}, {1.0, 0.0, 0.0}, Eigen::Vector3d::UnitZ()});
  }
  for (std::size_t r = 0; r <= bite.rows.size(); ++r) bite.row_offset.push_back(static_cast<int>(r));
  if (next()) std::istringstream(line) >> word >> count;
  for (std::size_t i = 0; i < count && next(); ++i) {
    std::array<int, 4> t{};
    std::istringstream(line) >> t[0] >> t[1] >> t[2] >> t[3];
    bite.mesh.tets.push_back(t);
  }
  bite.mesh.source = path;
  return bite;
}

double smallestVolumeRatio(const FemBody& body, const std::vector<double>& rest6) {
  double worst = 1e300;
  const Eigen::VectorXd& q = body.positions();
  const auto& tets = body.mesh().tets;
  for (std::size_t i = 0; i < tets.size(); ++i) {
    const auto& t = tets[i];
    const Eigen::Vector3d a = q.segment<3>(3 * t[0]);
    const double v6 = (q.segment<3>(3 * t[1]) - a).dot((q.segment<3>(3 * t[2]) - a).cross(q.segment<3>(3 * t[3]) - a));
    worst = std::min(worst, v6 / rest6[i]);
  }
  return worst;
}

TEST(StrainLimit, LiftsEveryTetOfABiteCrushedBetweenThePadsBackToItsBound) {
  const CrushedBite bite = loadCrushedBite(std::string(TACTUS_SOURCE_DIR) +
                                           "/tests/data/strain_limit/grasp_23k_crushed_bite.txt");
  ASSERT_GT(bite.mesh.tets.size(), 100u);
  ASSERT_FALSE(bite.rows.empty());
  // liver_grasp_23k's material (the limiter uses the lumped masses)
  FemMaterial material;
  material.young_pa = 15000.0;
  material.poisson = 0.45;
  material.density_kgpm3 = 1000.0;
  const std::vector<double> rest6 = restVolumes6(bite.mesh);
  const double h = 0.01;
  auto limit = [&](FemBody& body, const Eigen::VectorXd* valid) {
    body.positions() = bite.deformed;
    body.velocities().setZero();
    StrainLimitScratch scratch;
    return limitVolumes(body, rest6, 0.5, h, bite.rows, bite.row_offset, scratch, valid);
  };
  // the sweeps alone (no valid state to go back to) leave tets below the bound, inverted ones
  FemBody sweeps_only(bite.mesh, material, bite.fixed, nullptr);
  sweeps_only.positions() = bite.valid;
  const double at_start = smallestVolumeRatio(sweeps_only, rest6);
  sweeps_only.positions() = bite.deformed;
  const double before = smallestVolumeRatio(sweeps_only, rest6);
  const StrainLimitResult alone = limit(sweeps_only, nullptr);
  std::printf("[strain limit] smallest tet at the step's start %.3f, after the correction %.3f; "
              "the sweeps alone: %d tets below 0.5, %d sweeps, %d left, smallest %.3f\n",
              at_start, before, alone.limited, alone.sweeps, alone.unresolved,
              smallestVolumeRatio(sweeps_only, rest6));
  ASSERT_GE(at_start, 0.5);
  ASSERT_LT(before, 0.0);   // the correction inverted tets
  EXPECT_EQ(alone.rolled_back, 0);
  // with the step's start: every tet at the bound or above, the sweeps' tets and those the
  // nodes moved back left below
  FemBody body(bite.mesh, material, bite.fixed, nullptr);
  const StrainLimitResult r = limit(body, &bite.valid);
  const double after = smallestVolumeRatio(body, rest6);
  std::printf("[strain limit] with the step's start: %d sweeps, %d nodes moved back, %d left; "
              "smallest tet %.3f\n", r.sweeps, r.rolled_back, r.unresolved, after);
  EXPECT_GT(r.limited, 10);
  EXPECT_EQ(r.unresolved, 0);
  EXPECT_GE(after, 0.5);
  // a node moved back sits where the step started; fixed nodes never move; the velocities took
  // the displacement over the step
  const Eigen::VectorXd moved = body.positions() - bite.deformed;
  int at_valid = 0;
  for (int k = 0; k < body.nodeCount(); ++k) {
    if (moved.segment<3>(3 * k).norm() > 0.0 && body.positions().segment<3>(3 * k) == bite.valid.segment<3>(3 * k)) ++at_valid;
  }
  EXPECT_EQ(at_valid, r.rolled_back);
  for (int k : bite.fixed) EXPECT_EQ(moved.segment<3>(3 * k).norm(), 0.0) << "node " << k;
  EXPECT_NEAR((body.velocities() - moved / h).norm(), 0.0, 1e-9 * (moved / h).norm());
}


// A tet squeezed between two pads, all four nodes in contact: three on the lower pad, one on the
// upper, leaning sideways so that its volume's gradient has tangential parts. With friction the
// limiter lifts it by moving the nodes along the pads' normal only (the friction solve decided
// how far they slide); frictionless contacts let them slide, which the same tet then does.
TEST(StrainLimit, NodesOfFrictionalContactsMoveAlongTheirNormalOnly) {
  TetMesh mesh;
  mesh.nodes.resize(3, 4);
  mesh.nodes.col(0) = Eigen::Vector3d(0.0, 0.0, 0.0);
  mesh.nodes.col(1) = Eigen::Vector3d(0.004, 0.0, 0.0);
  mesh.nodes.col(2) = Eigen::Vector3d(0.0, 0.004, 0.0);
  mesh.nodes.col(3) = Eigen::Vector3d(0.001, 0.001, 0.004);
  mesh.tets.push_back({0, 1, 2, 3});
  mesh.source = "one tet";
  FemMaterial material;
  material.young_pa = 15000.0;
  material.poisson = 0.45;
  material.density_kgpm3 = 1000.0;
  const std::vector<double> rest6 = restVolumes6(mesh);
  // crushed to a fifth of its height, the top node pushed sideways
  Eigen::VectorXd crushed(12);
  crushed << 0.0, 0.0, 0.0, 0.004, 0.0, 0.0, 0.0, 0.004, 0.0, 0.003, 0.002, 0.0008;
  // n from the tissue to the tool: the lower pad's -z, the upper's +z; (t1, t2) along x, y
  auto contactRows = [](bool friction, std::vector<TissueRow>& rows, std::vector<int>& offset) {
    rows.clear();
    offset.assign(1, 0);
    for (int node = 0; node < 4; ++node) {
      const Eigen::Vector3d n(0.0, 0.0, node == 3 ? 1.0 : -1.0);
      rows.push_back({{node, -1, -1}, {-1.0, 0.0, 0.0}, n});
      if (friction) {
        rows.push_back({{node, -1, -1}, {-1.0, 0.0, 0.0}, Eigen::Vector3d::UnitX()});
        rows.push_back({{node, -1, -1}, {-1.0, 0.0, 0.0}, Eigen::Vector3d::UnitY()});
      }
      offset.push_back(static_cast<int>(rows.size()));
    }
  };
  auto limit = [&](bool friction) {
    FemBody body(mesh, material, {}, nullptr);
    body.positions() = crushed;
    body.velocities().setZero();
    std::vector<TissueRow> rows;
    std::vector<int> offset;
    contactRows(friction, rows, offset);
    StrainLimitScratch scratch;
    const StrainLimitResult r = limitVolumes(body, rest6, 0.5, 0.01, rows, offset, scratch);
    EXPECT_EQ(r.limited, 1);
    EXPECT_EQ(r.unresolved, 0);
    EXPECT_GE(smallestVolumeRatio(body, rest6), 0.5);
    return Eigen::VectorXd(body.positions() - crushed);
  };
  const Eigen::VectorXd with_friction = limit(true);
  double slid = 0.0, lifted = 0.0;
  for (int k = 0; k < 4; ++k) {
    slid = std::max(slid, with_friction.segment<2>(3 * k).norm());
    lifted = std::max(lifted, std::abs(with_friction[3 * k + 2]));
  }
  EXPECT_EQ(slid, 0.0);
  EXPECT_GT(lifted, 1e-4);
  const Eigen::VectorXd frictionless = limit(false);
  double slid_frictionless = 0.0;
  for (int k = 0; k < 4; ++k) slid_frictionless = std::max(slid_frictionless, frictionless.segment<2>(3 * k).norm());
  EXPECT_GT(slid_frictionless, 1e-5);
}
}  // namespace
}  // namespace tactus::sim
