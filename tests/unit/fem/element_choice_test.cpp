// Bending at a few elements across (docs/design.md, "Element choice"): a clamped beam
// 0.1 x 0.01 x 0.01 m (10 n x n x n cells), Poisson 0, under a small tip load, static. Its tip
// deflection against Euler-Bernoulli's P L^3 / (3 E I): linear tetrahedra lock (83 % at 4 cells
// across, 55 % at 2), edge-smoothed ones do not (within 5 % at 4 cells across, 15 % at 2), on
// both hexahedron splits and with both laws.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::sim {
namespace {

constexpr double kLength = 0.1, kSide = 0.01, kYoung = 1e6, kTipForce = 0.0025;

double tipOverEulerBernoulli(ElementKind element, MaterialLaw law, HexSplit split, int across) {
  const TetMesh mesh =
      makeBoxTetMesh(10 * across, across, across, Eigen::Vector3d(kLength, kSide, kSide),
                     Eigen::Vector3d(0, -kSide / 2, -kSide / 2), split);
  std::vector<int> fixed, tip;
  for (int i = 0; i < mesh.nodeCount(); ++i) {
    if (mesh.nodes(0, i) < 1e-12) fixed.push_back(i);
    if (mesh.nodes(0, i) > kLength - 1e-9) tip.push_back(i);
  }
  FemMaterial mat;
  mat.law = law;
  mat.element = element;
  mat.young_pa = kYoung;
  mat.poisson = 0.0;
  FemBody body(mesh, mat, fixed, nullptr);
  Eigen::VectorXd force = Eigen::VectorXd::Zero(body.dofCount());
  for (int i : tip) force[3 * i + 2] = -kTipForce / static_cast<double>(tip.size());
  EXPECT_TRUE(body.solveStatic(&force, 20, 1e-12).ok);
  double z = 0.0;
  for (int i : tip) z += body.positions()[3 * i + 2] - body.restPositions()[3 * i + 2];
  z /= static_cast<double>(tip.size());
  const double inertia = kSide * kSide * kSide * kSide / 12.0;
  return -z / (kTipForce * kLength * kLength * kLength / (3.0 * kYoung * inertia));
}

TEST(ElementChoice, EdgeSmoothedTetsBendWithinFivePercentAtFourCellsAcross) {
  for (const HexSplit split : {HexSplit::kSix, HexSplit::kFive}) {
    for (const MaterialLaw law : {MaterialLaw::kLinear, MaterialLaw::kCorotational}) {
      const double smoothed2 = tipOverEulerBernoulli(ElementKind::kEdgeSmoothedTet, law, split, 2);
      const double smoothed4 = tipOverEulerBernoulli(ElementKind::kEdgeSmoothedTet, law, split, 4);
      const double linear2 = tipOverEulerBernoulli(ElementKind::kLinearTet, law, split, 2);
      const double linear4 = tipOverEulerBernoulli(ElementKind::kLinearTet, law, split, 4);
      std::printf("[element] %s split, %s law: tip / Euler-Bernoulli at 2 and 4 cells across: "
                  "linear tets %.3f %.3f, edge-smoothed %.3f %.3f\n",
                  split == HexSplit::kSix ? "six-tet" : "five-tet",
                  law == MaterialLaw::kLinear ? "linear" : "corotational", linear2, linear4,
                  smoothed2, smoothed4);
      EXPECT_NEAR(smoothed4, 1.0, 0.05);
      EXPECT_NEAR(smoothed2, 1.0, 0.15);
      EXPECT_LT(linear4, 0.9);   // the locking the smoothed strain removes
    }
  }
}

}  // namespace
}  // namespace tactus::sim
