// The CHOLMOD wrapper with background factorisations (sim_server/src/fem/linear_solver.h): a
// supernodal factor (CHOLMOD's BLAS path) is handed over and solved without BLAS as CHOLMOD's
// own supernodal solve does; two workers (two bodies) factorising while the calling thread solves
// with its own factors and factorises synchronously never corrupt a factor. The BLAS that Debian
// installs (serial OpenBLAS) is not safe with two threads in it at once: without the solver
// module's lock around CHOLMOD's BLAS calls, or with a step-thread solve through BLAS, this test
// sees wrong factors now and then, and helgrind (valgrind --tool=helgrind) reports the races.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
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

// A solver set to solve without BLAS keeps CHOLMOD's supernodal factor and solves it with its own
// sweeps (Eigen's dense kernels): the same solution as CHOLMOD's supernodal solve (BLAS) to
// rounding, for one right-hand side and several, in place too; the worker's factor is handed
// over supernodal, and the caller's own factorisations stay supernodal.
TEST(BackgroundFactorTest, BlasFreeSolvesOfTheSupernodalFactorMatchCholmods) {
  LowerMatrix a0 = gridLaplacianLower(kGrid, 0.5), a1 = gridLaplacianLower(kGrid, 2.0);
  const Eigen::Index n = a0.rows();
  const Eigen::VectorXd b = rampRhs(n);
  CholmodSolver step, reference;
  step.analyze(a0);
  reference.analyze(a0);
  ASSERT_TRUE(step.factorize(a0));
  ASSERT_TRUE(reference.factorize(a1));
  ASSERT_TRUE(step.supernodal()) << "the grid must be large enough for CHOLMOD's BLAS path";
  Eigen::VectorXd x_super(n);
  step.solve(b.data(), x_super.data(), 1);

  step.setBlasFreeSolves(true);
  EXPECT_TRUE(step.supernodal());
  Eigen::VectorXd x_own(n);
  step.solve(b.data(), x_own.data(), 1);
  EXPECT_LT((x_own - x_super).norm(), 1e-13 * x_super.norm());
  EXPECT_LT(relativeResidual(a0, x_own, b), 1e-13);

  // three right-hand sides at once, solved in place: each column as CHOLMOD solves it
  Eigen::MatrixXd rhs(n, 3), x_cholmod(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) {
    rhs(i, 0) = b[i];
    rhs(i, 1) = std::sin(0.01 * static_cast<double>(i));
    rhs(i, 2) = (i % 13 == 0) ? 1.0 : 0.0;
  }
  reference.solve(rhs.data(), x_cholmod.data(), 3);

  BackgroundFactoriser worker;
  worker.start(a1, step);
  double waited_s = 0.0, factorisation_s = 0.0;
  ASSERT_TRUE(worker.collect(step, waited_s, factorisation_s));
  EXPECT_TRUE(step.supernodal());   // handed over supernodal, solved without BLAS
  Eigen::MatrixXd x_many = rhs;
  step.solve(x_many.data(), x_many.data(), 3);
  for (int c = 0; c < 3; ++c) {
    EXPECT_LT((x_many.col(c) - x_cholmod.col(c)).norm(), 1e-13 * x_cholmod.col(c).norm())
        << "column " << c;
    EXPECT_LT(relativeResidual(a1, x_many.col(c), rhs.col(c)), 1e-13) << "column " << c;
  }
  // the rest compliance's precomputation solves many columns through CHOLMOD's own (BLAS) solve,
  // also on a solver set to solve without BLAS: the reference's bits, not the sweeps' rounding
  Eigen::MatrixXd x_blas(n, 3);
  step.solveWithBlas(rhs.data(), x_blas.data(), 3);
  EXPECT_TRUE(step.blasFreeSolves());
  EXPECT_TRUE(x_blas == x_cholmod);

  // the caller's own factorisation and its solves: the first factor's solution again
  ASSERT_TRUE(step.factorize(a0));
  EXPECT_TRUE(step.supernodal());
  Eigen::VectorXd x0(n);
  step.solve(b.data(), x0.data(), 1);
  EXPECT_EQ(x0, x_own);
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

// The factor taken when ready (FactorReusePolicy::background_when_ready): no step waits for the
// worker. Another thread holds the BLAS lock, so the worker's supernodal factorisation cannot
// finish; the steps go on with PCG on the factor they have, every one returns, matches the direct
// solve and takes no factor, and each due step is counted as not ready. Once the lock is released
// and the worker has finished, the next step takes its factor. A step that waited for the worker
// (or factorised on its own thread, which needs the lock too) would hang until the holder gives up
// after kHoldLimit, which the test then reports: it counts, it does not time. (A FemBody set so,
// FemSolverOptions::background_refactor_when_ready: linear_solver_test.cpp.)
TEST(BackgroundFactorTest, AStepNeverWaitsForTheWorkerWhenTheFactorIsTakenWhenReady) {
  constexpr int kSteps = 12;
  constexpr double kTolerance = 1e-10;
  constexpr auto kHoldLimit = std::chrono::seconds(120);
  std::vector<LowerMatrix> a(kSteps);
  for (int k = 0; k < kSteps; ++k) a[k] = gridLaplacianLower(kGrid, 0.5 + 0.03 * k);
  const Eigen::VectorXd b = rampRhs(a[0].rows());
  // the direct solves, before the lock is held
  std::vector<Eigen::VectorXd> direct(kSteps, Eigen::VectorXd(b.size()));
  {
    CholmodSolver exact;
    exact.analyze(a[0]);
    for (int k = 0; k < kSteps; ++k) {
      ASSERT_TRUE(exact.factorize(a[k]));
      exact.solve(b.data(), direct[k].data(), 1);
    }
  }
  auto relativeError = [&](const Eigen::VectorXd& x, int k) {
    return (x - direct[k]).norm() / direct[k].norm();
  };

  CholmodSolver factor;
  factor.setBlasFreeSolves(true);
  BackgroundFactoriser worker;
  FactorReusePolicy policy;
  policy.tolerance = kTolerance;
  policy.refactor_iterations = 6;
  policy.background_lag_steps = 1;
  policy.background_when_ready = true;
  ReusedFactorSolver reuse(policy);
  reuse.setBackground(&worker);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(b.size());
  double waited_s = 0.0, factorisation_s = 0.0;
  // the first step factorises on its own thread (there is no factor yet)
  ASSERT_FALSE(reuse.adoptDue(factor, waited_s, factorisation_s));
  ReuseSolveResult r = reuse.solve(factor, a[0], b, x);
  ASSERT_TRUE(r.ok && r.refreshed);
  {
    // the worker's factor is supernodal until it hands it over: its factorisation needs the lock
    CholmodSolver probe;
    probe.analyzeLike(factor);
    ASSERT_TRUE(probe.factorize(a[0]));
    ASSERT_TRUE(probe.supernodal()) << "the grid must be large enough for CHOLMOD's BLAS path";
  }

  std::mutex m;
  std::condition_variable cv;
  bool held = false, release = false, gave_up = false;
  std::thread holder([&] {
    auto blas = lockCholmodBlas();
    std::unique_lock<std::mutex> lock(m);
    held = true;
    cv.notify_all();
    gave_up = !cv.wait_for(lock, kHoldLimit, [&] { return release; });
  });
  {
    std::unique_lock<std::mutex> lock(m);
    cv.wait(lock, [&] { return held; });
  }
  int started = 0, taken = 0;
  double worst = 0.0;
  for (int k = 1; k < kSteps; ++k) {
    if (reuse.adoptDue(factor, waited_s, factorisation_s)) ++taken;
    r = reuse.solve(factor, a[k], b, x);
    EXPECT_TRUE(r.ok) << "step " << k;
    EXPECT_FALSE(r.refreshed) << "step " << k;
    EXPECT_LE(r.residual, kTolerance) << "step " << k;
    if (r.background_started) ++started;
    worst = std::max(worst, relativeError(x, k));
  }
  {
    std::lock_guard<std::mutex> lock(m);
    release = true;
  }
  cv.notify_all();
  holder.join();
  EXPECT_FALSE(gave_up) << "a step waited for the worker while it could not finish";
  EXPECT_EQ(started, 1);   // the drift started one job, which could not finish
  EXPECT_EQ(taken, 0);
  EXPECT_GT(reuse.notReadySteps(), 0);
  EXPECT_LT(worst, 1e-8);

  // released: once the worker has finished, the next step takes its factor
  const auto until = std::chrono::steady_clock::now() + kHoldLimit;
  while (!worker.finished() && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ASSERT_TRUE(worker.finished());
  const long not_ready = reuse.notReadySteps();
  EXPECT_TRUE(reuse.adoptDue(factor, waited_s, factorisation_s));
  EXPECT_EQ(reuse.notReadySteps(), not_ready);
  // handed over supernodal, solved without BLAS
  EXPECT_TRUE(factor.supernodal());
  r = reuse.solve(factor, a[kSteps - 1], b, x);
  EXPECT_TRUE(r.ok && !r.refreshed);
  EXPECT_LT(relativeError(x, kSteps - 1), 1e-8);
  RecordProperty("worst_relative_error_while_held", std::to_string(worst));
}

// The lagged takeover with a longer lag out of contact (FactorReusePolicy::
// background_free_lag_steps): the steps since a job's start are weighed by whether the step
// before each was in contact, and the job is taken at the step at which they add up to the lag:
// lag 2 in contact, 4 out of it, 3 for a step out of contact then two in it; without the free
// lag every step counts alike. Counts, not times: the worker's speed decides nothing (collect
// waits for it).
TEST(BackgroundFactorTest, TheLaggedTakeoverWeighsStepsOutOfContactByTheFreeLag) {
  constexpr int kSteps = 8;
  std::vector<LowerMatrix> a(kSteps);
  for (int k = 0; k < kSteps; ++k) a[k] = gridLaplacianLower(8, 0.5 + 0.03 * k);
  const Eigen::VectorXd b = rampRhs(a[0].rows());
  // the adoptDue call (1: the step after the job's start) at which the job is taken
  auto takenAt = [&](int free_lag, const std::vector<bool>& after_contact) {
    CholmodSolver factor;
    factor.setBlasFreeSolves(true);
    BackgroundFactoriser worker;
    FactorReusePolicy policy;
    policy.tolerance = 1e-10;
    policy.refactor_every_steps = 1;   // every step due: the second step starts a job
    policy.background_lag_steps = 2;
    policy.background_free_lag_steps = free_lag;
    ReusedFactorSolver reuse(policy);
    reuse.setBackground(&worker);
    Eigen::VectorXd x = Eigen::VectorXd::Zero(b.size());
    double waited_s = 0.0, factorisation_s = 0.0;
    EXPECT_TRUE(reuse.solve(factor, a[0], b, x).refreshed);   // no factor yet: on this thread
    EXPECT_FALSE(reuse.adoptDue(factor, waited_s, factorisation_s, after_contact[0]));
    EXPECT_TRUE(reuse.solve(factor, a[1], b, x).background_started);
    for (int k = 1; k < kSteps - 1; ++k) {
      const bool contact = after_contact[static_cast<std::size_t>(k)];
      if (reuse.adoptDue(factor, waited_s, factorisation_s, contact)) return k;
      const ReuseSolveResult r = reuse.solve(factor, a[k + 1], b, x);
      EXPECT_TRUE(r.ok && !r.refreshed) << "step " << k + 1;
    }
    return -1;
  };
  const std::vector<bool> free(kSteps, false), contact(kSteps, true);
  std::vector<bool> free_then_contact(kSteps, true);
  free_then_contact[1] = false;
  EXPECT_EQ(takenAt(4, contact), 2);
  EXPECT_EQ(takenAt(4, free), 4);
  EXPECT_EQ(takenAt(4, free_then_contact), 3);
  EXPECT_EQ(takenAt(0, free), 2);
  EXPECT_EQ(takenAt(0, contact), 2);
  EXPECT_EQ(takenAt(2, free), 2);
}

}  // namespace
}  // namespace tactus::sim::fem_detail
