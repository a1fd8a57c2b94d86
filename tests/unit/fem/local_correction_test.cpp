// The factor-reuse PCG's local correction (ReusedFactorSolver, sim_server/src/fem/linear_solver.h):
// when the system matrix has moved away from the factor's at a few nodes only, the nodes whose
// diagonal block moved are found, solved exactly inside each preconditioner application, and PCG
// converges to the direct solve in far fewer iterations; where nothing moved, nothing changes.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <vector>

#include "../../../sim_server/src/fem/linear_solver.h"

namespace tactus::sim::fem_detail {
namespace pcg_local_correction_test {   // named: the fem tests are one unity build

using LowerMatrix = CholmodSolver::Sparse;

constexpr int kGrid = 12;   // nodes per side: 1728 nodes, 5184 unknowns

int nodeId(int i, int j, int k) { return (k * kGrid + j) * kGrid + i; }

// A 3x3 symmetric positive definite coupling between a node's three unknowns.
Eigen::Matrix3d coupling() {
  Eigen::Matrix3d b;
  b << 2.0, 0.5, 0.2, 0.5, 2.0, 0.3, 0.2, 0.3, 2.0;
  return b;
}

// The lower triangle of (grid Laplacian + shift I) (x) B: three unknowns per node, full 3x3
// blocks between neighbouring nodes (the pattern of a tet mesh's system matrix, in small).
LowerMatrix blockGridLower(double shift) {
  const Eigen::Matrix3d b = coupling();
  std::vector<Eigen::Triplet<double, int>> t;
  auto addBlock = [&](int row_node, int col_node, double w) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) {
        const int row = 3 * row_node + r, col = 3 * col_node + c;
        if (row >= col) t.emplace_back(row, col, w * b(r, c));
      }
  };
  for (int k = 0; k < kGrid; ++k)
    for (int j = 0; j < kGrid; ++j)
      for (int i = 0; i < kGrid; ++i) {
        const int c = nodeId(i, j, k);
        addBlock(c, c, 6.0 + shift);
        if (i + 1 < kGrid) addBlock(nodeId(i + 1, j, k), c, -1.0);
        if (j + 1 < kGrid) addBlock(nodeId(i, j + 1, k), c, -1.0);
        if (k + 1 < kGrid) addBlock(nodeId(i, j, k + 1), c, -1.0);
      }
  const int n = 3 * kGrid * kGrid * kGrid;
  LowerMatrix a(n, n);
  a.setFromTriplets(t.begin(), t.end());
  a.makeCompressed();
  return a;
}

// a + stiffness (e_i - e_j)(e_i - e_j)^T (x) (T B T^T) for the grid edge (i, j): a stiffer
// spring, turned by T, between two neighbouring nodes, within a's pattern. Only i's and j's
// diagonal blocks change.
void stiffenEdge(LowerMatrix& a, int i, int j, double stiffness,
                 const Eigen::Matrix3d& turn = Eigen::Matrix3d::Identity()) {
  const Eigen::Matrix3d b = stiffness * turn * coupling() * turn.transpose();
  const int hi = std::max(i, j), lo = std::min(i, j);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      if (r >= c) {
        a.coeffRef(3 * i + r, 3 * i + c) += b(r, c);
        a.coeffRef(3 * j + r, 3 * j + c) += b(r, c);
      }
      a.coeffRef(3 * hi + r, 3 * lo + c) -= b(r, c);
    }
}

struct Solved {
  Eigen::VectorXd x;
  ReuseSolveResult result;
};

// The factor of `factor_a`, then PCG on `a` from a zero start with that factor (identity warp).
Solved solveWithOldFactor(const LowerMatrix& factor_a, LowerMatrix a, const Eigen::VectorXd& b,
                          double threshold, int max_nodes = 96) {
  FactorReusePolicy policy;
  policy.tolerance = 1e-10;
  policy.refactor_iterations = 400;   // PCG runs to the tolerance: no refresh in the test
  policy.local_correction_threshold = threshold;
  policy.local_correction_max_nodes = max_nodes;
  ReusedFactorSolver reuse(policy);
  CholmodSolver factor;
  LowerMatrix first = factor_a;
  Eigen::VectorXd x = Eigen::VectorXd::Zero(b.size());
  const std::vector<Eigen::Matrix3d> identity(static_cast<std::size_t>(b.size() / 3),
                                              Eigen::Matrix3d::Identity());
  const ReuseSolveResult setup = reuse.solve(factor, first, b, x, identity.data(), nullptr);
  EXPECT_TRUE(setup.refreshed);   // no factor yet: factorises factor_a
  Solved out;
  out.x = Eigen::VectorXd::Zero(b.size());
  out.result = reuse.solve(factor, a, b, out.x, identity.data(), factor_a.valuePtr());
  return out;
}

Eigen::VectorXd directSolve(LowerMatrix a, const Eigen::VectorXd& b) {
  CholmodSolver direct;
  direct.analyze(a);
  EXPECT_TRUE(direct.factorize(a));
  Eigen::VectorXd x(b.size());
  direct.solve(b.data(), x.data(), 1);
  return x;
}

Eigen::VectorXd ramp(Eigen::Index n) {
  Eigen::VectorXd b(n);
  for (Eigen::Index i = 0; i < n; ++i) b[i] = 1.0 + 0.01 * static_cast<double>(i % 31);
  return b;
}

// The springs inside two 3 x 3 x 3 cubes of nodes made 20-400 times stiffer than the factor knows,
// each turned its own way (as crushed tets' rotations scatter): the 54 nodes' diagonal blocks
// moved. The correction takes exactly those nodes, meets the tolerance against the direct solve,
// and needs at most half of plain PCG's iterations.
TEST(PcgLocalCorrectionTest, AFewStiffenedNodesAreSolvedExactlyAndPcgConvergesSooner) {
  const LowerMatrix a_factor = blockGridLower(0.05);
  LowerMatrix a = a_factor;
  int spring = 0;
  for (const int corner : {2, 7})
    for (int k = corner; k < corner + 3; ++k)
      for (int j = corner; j < corner + 3; ++j)
        for (int i = corner; i < corner + 3; ++i) {
          const int c = nodeId(i, j, k);
          const int next[3] = {i + 1 < corner + 3 ? nodeId(i + 1, j, k) : -1,
                               j + 1 < corner + 3 ? nodeId(i, j + 1, k) : -1,
                               k + 1 < corner + 3 ? nodeId(i, j, k + 1) : -1};
          for (const int m : next) {
            if (m < 0) continue;
            ++spring;
            const Eigen::Matrix3d turn =
                Eigen::AngleAxisd(0.37 * spring, Eigen::Vector3d(1.0, 0.3 * (spring % 5), -0.7)
                                                     .normalized())
                    .toRotationMatrix();
            stiffenEdge(a, c, m, 20.0 + 38.0 * (spring % 11), turn);
          }
        }
  const Eigen::VectorXd b = ramp(a.rows());
  const Eigen::VectorXd x_direct = directSolve(a, b);

  const Solved plain = solveWithOldFactor(a_factor, a, b, 0.0);
  const Solved local = solveWithOldFactor(a_factor, a, b, 0.03);
  ASSERT_TRUE(plain.result.ok);
  ASSERT_TRUE(local.result.ok);
  EXPECT_FALSE(plain.result.refreshed);
  EXPECT_FALSE(local.result.refreshed);
  EXPECT_EQ(plain.result.local_nodes, 0);
  EXPECT_EQ(local.result.local_nodes, 54);
  EXPECT_LE(local.result.residual, 1e-10);
  EXPECT_LT((local.x - x_direct).norm(), 1e-8 * x_direct.norm());
  EXPECT_LT((plain.x - x_direct).norm(), 1e-8 * x_direct.norm());
  EXPECT_LE(2 * local.result.cg_iterations, plain.result.cg_iterations)
      << "plain " << plain.result.cg_iterations << ", corrected " << local.result.cg_iterations;
}

// More nodes qualify than allowed: the furthest off are taken, up to the cap, and PCG still
// meets the tolerance.
TEST(PcgLocalCorrectionTest, TheBlockIsCappedAtTheFurthestNodes) {
  const LowerMatrix a_factor = blockGridLower(0.05);
  LowerMatrix a = a_factor;
  stiffenEdge(a, nodeId(2, 2, 2), nodeId(3, 2, 2), 500.0);   // the furthest off
  for (int i = 0; i + 1 < kGrid; i += 2) stiffenEdge(a, nodeId(i, 7, 7), nodeId(i + 1, 7, 7), 5.0);
  const Eigen::VectorXd b = ramp(a.rows());
  const Solved capped = solveWithOldFactor(a_factor, a, b, 0.03, 2);
  ASSERT_TRUE(capped.result.ok);
  EXPECT_EQ(capped.result.local_nodes, 2);
  EXPECT_LE(capped.result.residual, 1e-10);
  EXPECT_LT((capped.x - directSolve(a, b)).norm(), 1e-8 * capped.x.norm());
}

// The matrix is the factor's: no node qualifies, and the solve is plain PCG's to the bit.
TEST(PcgLocalCorrectionTest, WhereNothingMovedTheSolveIsPlainPcgs) {
  const LowerMatrix a_factor = blockGridLower(0.05);
  LowerMatrix a = blockGridLower(0.05);
  const Eigen::VectorXd b = ramp(a.rows());
  const Solved plain = solveWithOldFactor(a_factor, a, b, 0.0);
  const Solved local = solveWithOldFactor(a_factor, a, b, 0.03);
  EXPECT_EQ(local.result.local_nodes, 0);
  EXPECT_EQ(local.result.cg_iterations, plain.result.cg_iterations);
  EXPECT_TRUE(local.x == plain.x);
}

}  // namespace pcg_local_correction_test
}  // namespace tactus::sim::fem_detail
