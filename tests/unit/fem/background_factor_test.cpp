// The CHOLMOD wrapper with background factorisations (sim_server/src/fem/linear_solver.h): a
// supernodal factor (CHOLMOD's BLAS path) is handed over in the simplicial form and solves as the
// direct factorisation does; two workers (two bodies) factorising while the calling thread solves
// with its own factors and factorises synchronously never corrupt a factor. The BLAS that Debian
// installs (serial OpenBLAS) is not safe with two threads in it at once: without the solver
// module's lock around CHOLMOD's BLAS calls, or with a step-thread solve through BLAS, this test
// sees wrong factors now and then, and helgrind (valgrind --tool=helgrind) reports the races.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <algorithm>
#include <string>
#include <vector>

#include "../../../sim_server/src/fem/linear_solver.h"
#include "tactus/sim/fem.h"

namespace tactus::sim::fem_detail {
namespace {

using LowerMatrix = CholmodSolver::Sparse;

// The lower triangle of the 7-point Laplacian on a g x g x g grid plus `shift` on the diagonal
// (symmetric positive definite). From g = 14 on CHOLMOD chooses a supernodal factor (dense
// blocks through BLAS), which this file needs.
LowerMatrix gridLaplacianLower(int g, double shift) {
  const int n = g * g * g;
  auto id = [g](int i, int j, int k) { return (k * g + j) * g + i; };
  std::vector<Eigen::Triplet<double, int>> t;
  t.reserve(static_cast<std::size_t>(4 * n));
  for (int k = 0; k < g; ++k)
    for (int j = 0; j < g; ++j)
      for (int i = 0; i < g; ++i) {
        const int c = id(i, j, k);
        t.emplace_back(c, c, 6.0 + shift);
        if (i + 1 < g) t.emplace_back(id(i + 1, j, k), c, -1.0);
        if (j + 1 < g) t.emplace_back(id(i, j + 1, k), c, -1.0);
        if (k + 1 < g) t.emplace_back(id(i, j, k + 1), c, -1.0);
      }
  LowerMatrix a(n, n);
  a.setFromTriplets(t.begin(), t.end());
  a.makeCompressed();
  return a;
}

Eigen::VectorXd rampRhs(Eigen::Index n) {
  Eigen::VectorXd b(n);
  for (Eigen::Index i = 0; i < n; ++i) b[i] = 1.0 + 0.001 * static_cast<double>(i % 97);
  return b;
}

// ||A x - b|| / ||b|| with A given by its lower triangle.
double relativeResidual(const LowerMatrix& a, const Eigen::VectorXd& x, const Eigen::VectorXd& b) {
  const Eigen::VectorXd r = b - a.selfadjointView<Eigen::Lower>() * x;
  return r.norm() / b.norm();
}

constexpr int kGrid = 22;

TEST(BackgroundFactorTest, HandsOverASimplicialFactorThatSolvesLikeTheDirectOne) {
  LowerMatrix a0 = gridLaplacianLower(kGrid, 0.5), a1 = gridLaplacianLower(kGrid, 2.0);
  const Eigen::VectorXd b = rampRhs(a0.rows());
  CholmodSolver step;
  step.analyze(a0);
  ASSERT_TRUE(step.factorize(a0));
  ASSERT_TRUE(step.supernodal()) << "the grid must be large enough for CHOLMOD's BLAS path";
  Eigen::VectorXd x_super(b.size());
  step.solve(b.data(), x_super.data(), 1);

  BackgroundFactoriser worker;
  worker.start(a1, step);
  double waited_s = 0.0, factorisation_s = 0.0;
  ASSERT_TRUE(worker.collect(step, waited_s, factorisation_s));
  EXPECT_FALSE(step.supernodal());   // handed over simplicial: its solves make no BLAS call
  Eigen::VectorXd x1(b.size());
  step.solve(b.data(), x1.data(), 1);
  EXPECT_LT(relativeResidual(a1, x1, b), 1e-13);

  // the caller's next synchronous factorisation is supernodal again, and equals the first
  ASSERT_TRUE(step.factorize(a0));
  EXPECT_TRUE(step.supernodal());
  Eigen::VectorXd x0(b.size());
  step.solve(b.data(), x0.data(), 1);
  EXPECT_EQ(x0, x_super);

  // a solver set to solve without BLAS converts what it holds and each new factor
  step.setBlasFreeSolves(true);
  EXPECT_FALSE(step.supernodal());
  Eigen::VectorXd x0_simplicial(b.size());
  step.solve(b.data(), x0_simplicial.data(), 1);
  EXPECT_LT((x0_simplicial - x_super).norm(), 1e-13 * x_super.norm());
  ASSERT_TRUE(step.factorize(a1));
  EXPECT_FALSE(step.supernodal());
  step.solve(b.data(), x1.data(), 1);
  EXPECT_LT(relativeResidual(a1, x1, b), 1e-13);
}

// Two bodies' workers factorise at once while the calling thread solves with the factors they
// handed over and factorises (supernodal, BLAS) a third matrix of its own, round after round;
// every factor must solve its own matrix.
TEST(BackgroundFactorTest, TwoWorkersAndTheCallersFactorisationsNeverCorruptAFactor) {
  constexpr int kRounds = 12;
  auto shiftOf = [](int body, int round) { return 0.2 + 0.7 * body + 0.05 * round; };
  std::vector<LowerMatrix> first(kRounds), second(kRounds), own(kRounds);
  for (int r = 0; r < kRounds; ++r) {
    first[r] = gridLaplacianLower(kGrid, shiftOf(0, r));
    second[r] = gridLaplacianLower(kGrid, shiftOf(1, r));
    own[r] = gridLaplacianLower(kGrid, shiftOf(2, r));
  }
  const Eigen::VectorXd b = rampRhs(first[0].rows());
  CholmodSolver body0, body1, caller;
  for (CholmodSolver* s : {&body0, &body1, &caller}) s->analyze(first[0]);
  body0.setBlasFreeSolves(true);
  body1.setBlasFreeSolves(true);
  ASSERT_TRUE(body0.factorize(first[0]));
  ASSERT_TRUE(body1.factorize(second[0]));
  BackgroundFactoriser worker0, worker1;
  Eigen::VectorXd x(b.size());
  double worst = 0.0;
  for (int r = 1; r < kRounds; ++r) {
    worker0.start(first[r], body0);
    worker1.start(second[r], body1);
    // the step thread meanwhile: solves with the factors it holds (no BLAS), and a synchronous
    // supernodal factorisation and solve (BLAS, under the lock)
    for (int k = 0; k < 2; ++k) {
      body0.solve(b.data(), x.data(), 1);
      worst = std::max(worst, relativeResidual(first[r - 1], x, b));
      body1.solve(b.data(), x.data(), 1);
      worst = std::max(worst, relativeResidual(second[r - 1], x, b));
      ASSERT_TRUE(caller.factorize(own[r]));
      ASSERT_TRUE(caller.supernodal());
      caller.solve(b.data(), x.data(), 1);
      worst = std::max(worst, relativeResidual(own[r], x, b));
    }
    double waited_s = 0.0, factorisation_s = 0.0;
    ASSERT_TRUE(worker0.collect(body0, waited_s, factorisation_s));
    ASSERT_TRUE(worker1.collect(body1, waited_s, factorisation_s));
    body0.solve(b.data(), x.data(), 1);
    worst = std::max(worst, relativeResidual(first[r], x, b));
    body1.solve(b.data(), x.data(), 1);
    worst = std::max(worst, relativeResidual(second[r], x, b));
  }
  EXPECT_LT(worst, 1e-12);
  RecordProperty("worst_relative_residual", std::to_string(worst));
}

}  // namespace
}  // namespace tactus::sim::fem_detail
