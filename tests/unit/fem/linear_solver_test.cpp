// The factor-reuse linear strategy (LinearSolverKind::kCholmodReuse): PCG on a recent CHOLMOD
// factor matches the exact CHOLMOD solve to the CG tolerance through large rotations, refreshes
// its factor when the matrix drifts (and only then, or on its schedule), and leaves the exact
// compliance path exact; refreshed in the background, it still matches the direct solve, the
// steps do not factorise, and the results do not depend on the worker's timing (or, with the
// factor taken when ready, no step waits for the worker).
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::sim {
namespace {

constexpr double kSolverTimeStep = 0.01;

FemMaterial softMaterial() {
  FemMaterial m;
  m.law = MaterialLaw::kCorotational;
  m.young_pa = 2e4;
  m.poisson = 0.4;
  m.density_kgpm3 = 1000.0;
  m.damping = RayleighSpec{0.1, 0.002};
  return m;
}

FemSolverOptions options(LinearSolverKind kind, double tol = 1e-10, int background_lag = 0) {
  FemSolverOptions o;
  o.linear = kind;
  o.cg_tolerance = tol;
  o.background_refactor_lag_steps = background_lag;
  return o;
}

const TetMesh& beamMesh() {
  static const TetMesh mesh = makeBoxTetMesh(8, 3, 3, Eigen::Vector3d(0.16, 0.06, 0.06));
  return mesh;
}

// A free beam (no fixed nodes) stretched by 15 % along x and spinning at `omega_radps` about an
// axis off its principal axes: it tumbles through large rotations while it vibrates.
void tumble(FemBody& body, double omega_radps) {
  Eigen::VectorXd& q = body.positions();
  Eigen::VectorXd& v = body.velocities();
  const Eigen::Vector3d omega = omega_radps * Eigen::Vector3d(0.3, 1.0, 0.5).normalized();
  const Eigen::Vector3d center(0.08, 0.03, 0.03);
  for (int i = 0; i < body.nodeCount(); ++i) {
    Eigen::Vector3d p = q.segment<3>(3 * i) - center;
    p.x() *= 1.15;
    q.segment<3>(3 * i) = center + p;
    v.segment<3>(3 * i) = omega.cross(p);
  }
}

double maxRotationAngle(const FemBody& body) {
  double out = 0.0;
  for (const Eigen::Matrix3d& r : body.elementRotations())
    out = std::max(out, Eigen::AngleAxisd(r).angle());
  return out;
}

TEST(CholmodReuse, MatchesTheExactSolveThroughLargeRotations) {
  const double tol = 1e-10;
  FemBody reuse(beamMesh(), softMaterial(), {}, nullptr,
                options(LinearSolverKind::kCholmodReuse, tol, 0));
  FemBody exact(beamMesh(), softMaterial(), {}, nullptr, options(LinearSolverKind::kCholmod));
  tumble(reuse, 4.0);
  int reused = 0, steps = 200;
  double max_angle = 0.0, worst = 0.0;
  for (int s = 0; s < steps; ++s) {
    // the exact body steps from the reuse body's state: dv of both from the same A and b
    exact.positions() = reuse.positions();
    exact.velocities() = reuse.velocities();
    const Eigen::VectorXd v0 = reuse.velocities();
    const FemStepStats sr = reuse.freeMotion(kSolverTimeStep);
    const FemStepStats se = exact.freeMotion(kSolverTimeStep);
    ASSERT_TRUE(sr.ok) << "step " << s;
    ASSERT_TRUE(se.ok) << "step " << s;
    if (!sr.factor_refreshed) {
      ++reused;
      EXPECT_GT(sr.cg_iterations, 0) << "step " << s;
      EXPECT_LE(sr.cg_residual, tol) << "step " << s;
    }
    const Eigen::VectorXd dv_r = reuse.velocities() - v0, dv_e = exact.velocities() - v0;
    const double rel = (dv_r - dv_e).norm() / dv_e.norm();
    worst = std::max(worst, rel);
    // relative residual 1e-10 bounds the relative error by cond(A) * 1e-10
    ASSERT_LT(rel, 1e-6) << "step " << s;
    max_angle = std::max(max_angle, maxRotationAngle(reuse));
  }
  EXPECT_GT(max_angle, 0.5 * M_PI);          // the elements went through large rotations
  // a quarter of the steps or more were PCG on the factor of an earlier A (at this spin and
  // tolerance about half: the comparison covers both paths)
  EXPECT_GE(reused, steps / 4);
  EXPECT_LT(reuse.counters().factorisations, exact.counters().factorisations);
  RecordProperty("worst_relative_dv_error", std::to_string(worst));
}

TEST(CholmodReuse, RefreshesTheFactorOnlyWhenTheMatrixDrifts) {
  // drifting: the tumbling beam's A rotates away from the factor's
  FemBody moving(beamMesh(), softMaterial(), {}, nullptr,
                 options(LinearSolverKind::kCholmodReuse, 1e-10, 0));
  tumble(moving, 4.0);
  int refreshed_after_first = 0, max_iterations = 0;
  for (int s = 0; s < 200; ++s) {
    const FemStepStats st = moving.freeMotion(kSolverTimeStep);
    ASSERT_TRUE(st.ok);
    if (s == 0) {
      EXPECT_TRUE(st.factor_refreshed);  // no factor yet
    }
    if (s > 0 && st.factor_refreshed) ++refreshed_after_first;
    if (!st.factor_refreshed) max_iterations = std::max(max_iterations, st.cg_iterations);
  }
  EXPECT_GT(refreshed_after_first, 0);
  EXPECT_EQ(moving.counters().factorisations, 1 + refreshed_after_first);
  EXPECT_LE(max_iterations, FemSolverOptions{}.refactor_iterations);

  // still: a cantilever at its static equilibrium under gravity keeps one A, so one
  // factorisation serves every step
  const Eigen::Vector3d gravity(0, 0, -9.81);
  std::vector<int> fixed;
  for (int i = 0; i < beamMesh().nodeCount(); ++i)
    if (beamMesh().nodes(0, i) < 1e-9) fixed.push_back(i);
  FemBody still(beamMesh(), softMaterial(), fixed, &gravity,
                options(LinearSolverKind::kCholmodReuse, 1e-8, 0));
  still.solveStatic();
  const long before = still.counters().factorisations;
  for (int s = 0; s < 40; ++s) {
    const FemStepStats st = still.freeMotion(kSolverTimeStep);
    ASSERT_TRUE(st.ok);
    EXPECT_EQ(st.factor_refreshed, s == 0) << "step " << s;
  }
  EXPECT_EQ(still.counters().factorisations, before + 1);

  // the schedule refreshes a still body's factor every refactor_every_steps steps
  FemSolverOptions every4 = options(LinearSolverKind::kCholmodReuse, 1e-8, 0);
  every4.refactor_every_steps = 4;
  FemBody scheduled(beamMesh(), softMaterial(), fixed, &gravity, every4);
  scheduled.solveStatic();
  const long before4 = scheduled.counters().factorisations;
  for (int s = 0; s < 20; ++s) {
    const FemStepStats st = scheduled.freeMotion(kSolverTimeStep);
    ASSERT_TRUE(st.ok);
    EXPECT_EQ(st.factor_refreshed, s % 4 == 0) << "step " << s;
  }
  EXPECT_EQ(scheduled.counters().factorisations, before4 + 5);
}

// The first step's factorisation made before it (FemBody::prepareFreeMotion, which a Simulation
// calls at set-up): that step solves directly with the prepared factor and factorises nothing
// on its own thread, and every step gives the same bits as a body that factorised in its first
// step (synchronous and background refreshes); a factor prepared for another state or another
// time step is not used (the step factorises its own A, the same bits as without preparing).
TEST(CholmodReuse, PreparedFirstFactorGivesTheSameStepsWithoutFactorising) {
  const double tol = 1e-8;
  for (const int lag : {0, 2}) {
    FemBody plain(beamMesh(), softMaterial(), {}, nullptr,
                  options(LinearSolverKind::kCholmodReuse, tol, lag));
    FemBody prepared(beamMesh(), softMaterial(), {}, nullptr,
                     options(LinearSolverKind::kCholmodReuse, tol, lag));
    tumble(plain, 4.0);
    tumble(prepared, 4.0);
    prepared.prepareFreeMotion(kSolverTimeStep);
    EXPECT_EQ(prepared.counters().prepared_factorisations, 1);
    EXPECT_EQ(prepared.counters().factorisations, 0);
    EXPECT_EQ(prepared.counters().rotation_extractions, 0);   // the preparation is no step
    for (int s = 0; s < 60; ++s) {
      const FemStepStats a = plain.freeMotion(kSolverTimeStep);
      const FemStepStats b = prepared.freeMotion(kSolverTimeStep);
      ASSERT_TRUE(a.ok && b.ok) << "lag " << lag << " step " << s;
      EXPECT_FALSE(a.factor_prepared);
      EXPECT_EQ(b.factor_prepared, s == 0) << "lag " << lag << " step " << s;
      EXPECT_EQ(a.factor_refreshed, b.factor_refreshed) << "lag " << lag << " step " << s;
      EXPECT_EQ(a.cg_iterations, b.cg_iterations) << "lag " << lag << " step " << s;
      ASSERT_EQ(plain.positions(), prepared.positions()) << "lag " << lag << " step " << s;
      ASSERT_EQ(plain.velocities(), prepared.velocities()) << "lag " << lag << " step " << s;
    }
    EXPECT_GE(plain.counters().factorisations, 1);
    EXPECT_EQ(prepared.counters().factorisations + 1, plain.counters().factorisations)
        << "lag " << lag;
    EXPECT_EQ(prepared.counters().rotation_extractions, plain.counters().rotation_extractions);
  }
  // prepared, then the state changed (or another h): the step factorises its own A
  for (const bool other_h : {false, true}) {
    FemBody reference(beamMesh(), softMaterial(), {}, nullptr,
                      options(LinearSolverKind::kCholmodReuse, tol, 0));
    FemBody stale(beamMesh(), softMaterial(), {}, nullptr,
                  options(LinearSolverKind::kCholmodReuse, tol, 0));
    if (other_h) tumble(stale, 4.0);
    stale.prepareFreeMotion(other_h ? 2.0 * kSolverTimeStep : kSolverTimeStep);
    if (!other_h) tumble(stale, 4.0);
    tumble(reference, 4.0);
    const FemStepStats st = stale.freeMotion(kSolverTimeStep);
    ASSERT_TRUE(st.ok);
    EXPECT_TRUE(st.factor_refreshed);
    EXPECT_FALSE(st.factor_prepared);
    EXPECT_EQ(stale.counters().factorisations, 1);
    ASSERT_TRUE(reference.freeMotion(kSolverTimeStep).ok);
    EXPECT_EQ(reference.positions(), stale.positions()) << "other h " << other_h;
    EXPECT_EQ(reference.velocities(), stale.velocities()) << "other h " << other_h;
  }
}

// Background refreshes: the worker factorises while the steps go on with PCG on the old factor;
// each step's dv still matches the direct solve, no step after the first factorises on its own
// thread, each factor is taken exactly `lag` steps after the step that started it, and two runs
// give the same bits whatever the worker's timing.
TEST(CholmodReuse, BackgroundRefreshMatchesTheDirectSolve) {
  const double tol = 1e-10;
  const int lag = 2, steps = 200;
  auto run = [&](std::vector<Eigen::VectorXd>* q_out) {
    FemBody reuse(beamMesh(), softMaterial(), {}, nullptr,
                  options(LinearSolverKind::kCholmodReuse, tol, lag));
    FemBody exact(beamMesh(), softMaterial(), {}, nullptr, options(LinearSolverKind::kCholmod));
    tumble(reuse, 4.0);
    int started = 0, taken = 0, synchronous = 0, last_start = -1;
    double worst = 0.0;
    for (int s = 0; s < steps; ++s) {
      exact.positions() = reuse.positions();
      exact.velocities() = reuse.velocities();
      const Eigen::VectorXd v0 = reuse.velocities();
      const FemStepStats sr = reuse.freeMotion(kSolverTimeStep);
      EXPECT_TRUE(exact.freeMotion(kSolverTimeStep).ok);
      EXPECT_TRUE(sr.ok) << "step " << s;
      if (s > 0 && sr.factor_refreshed) ++synchronous;
      if (sr.background_factor_taken) {
        ++taken;
        EXPECT_EQ(s, last_start + lag) << "taken at step " << s;
      }
      if (sr.background_factorisation_started) {
        ++started;
        last_start = s;
      }
      if (!sr.factor_refreshed) {
        EXPECT_LE(sr.cg_residual, tol) << "step " << s;
        EXPECT_LE(sr.cg_iterations, 3 * FemSolverOptions{}.refactor_iterations) << "step " << s;
      }
      const Eigen::VectorXd dv_r = reuse.velocities() - v0, dv_e = exact.velocities() - v0;
      worst = std::max(worst, (dv_r - dv_e).norm() / dv_e.norm());
      if (q_out) q_out->push_back(reuse.positions());
    }
    EXPECT_LT(worst, 1e-6);
    EXPECT_GE(started, 3);   // the tumbling drifts: the factor was refreshed (4 times here)
    EXPECT_GE(taken, started - 1);      // each start taken (the last perhaps after the run)
    EXPECT_EQ(synchronous, 0);
    EXPECT_EQ(reuse.counters().factorisations, 1);   // the first step's
    EXPECT_EQ(reuse.counters().background_factorisations, taken);
    RecordProperty("worst_relative_dv_error", std::to_string(worst));
  };
  std::vector<Eigen::VectorXd> first, second;
  run(&first);
  run(&second);
  ASSERT_EQ(first.size(), second.size());
  for (std::size_t s = 0; s < first.size(); ++s)
    ASSERT_EQ(first[s], second[s]) << "step " << s;
}

// Background refreshes taken when ready: no step waits for the worker (each takes a finished
// factor or goes on with the one it has), and each step's dv still matches the direct solve.
// Which steps a factor preconditions depends on the worker's timing, so the test holds what
// holds whatever the timing: every job started but the last is taken, the run goes on until one
// was (at most kMaxSteps steps: a worker that never finishes fails it), and a step whose PCG
// missed its bound while the worker was slow may have factorised on its own thread (counted,
// each one a direct solve). How many jobs start depends on the timing too: the drift that starts
// them ends as the tumbling settles, and a slow worker lets fewer start while it lasts.
TEST(CholmodReuse, BackgroundRefreshTakenWhenReadyMatchesTheDirectSolve) {
  const double tol = 1e-10;
  constexpr int kMinSteps = 200, kMaxSteps = 5000;
  FemSolverOptions o = options(LinearSolverKind::kCholmodReuse, tol, 1);
  o.background_refactor_when_ready = true;
  FemBody reuse(beamMesh(), softMaterial(), {}, nullptr, o);
  FemBody exact(beamMesh(), softMaterial(), {}, nullptr, options(LinearSolverKind::kCholmod));
  tumble(reuse, 4.0);
  int started = 0, taken = 0, synchronous = 0, steps = 0;
  double worst = 0.0;
  for (; steps < kMaxSteps && (steps < kMinSteps || taken < 1); ++steps) {
    const int s = steps;
    exact.positions() = reuse.positions();
    exact.velocities() = reuse.velocities();
    const Eigen::VectorXd v0 = reuse.velocities();
    const FemStepStats sr = reuse.freeMotion(kSolverTimeStep);
    ASSERT_TRUE(exact.freeMotion(kSolverTimeStep).ok) << "step " << s;
    ASSERT_TRUE(sr.ok) << "step " << s;
    if (s > 0 && sr.factor_refreshed) ++synchronous;
    if (sr.background_factor_taken) ++taken;
    if (sr.background_factorisation_started) ++started;
    if (!sr.factor_refreshed) {
      EXPECT_LE(sr.cg_residual, tol) << "step " << s;
    }
    const Eigen::VectorXd dv_r = reuse.velocities() - v0, dv_e = exact.velocities() - v0;
    worst = std::max(worst, (dv_r - dv_e).norm() / dv_e.norm());
  }
  EXPECT_LT(worst, 1e-6);
  EXPECT_GE(taken, 1) << "in " << steps << " steps";
  EXPECT_LE(taken, started);
  EXPECT_GE(taken, started - 1);
  EXPECT_EQ(reuse.counters().factorisations, 1 + synchronous);   // the first step's, and those
  EXPECT_EQ(reuse.counters().background_factorisations, taken);
  EXPECT_EQ(reuse.counters().background_waits, 0);
  RecordProperty("worst_relative_dv_error", std::to_string(worst));
  RecordProperty("steps", steps);
  RecordProperty("steps_not_ready", std::to_string(reuse.counters().background_not_ready));
  RecordProperty("synchronous_refreshes", synchronous);
}

// A body whose factor is taken when ready solves its steps without BLAS (the supernodal factor's
// sweeps, CholmodSolver::setBlasFreeSolves), so no step waits for a worker in BLAS. On a block
// large enough for CHOLMOD's supernodal (BLAS) factor, checked by the first step's factorisation
// waiting for the BLAS lock another thread holds, the lock is then held while the body tumbles:
// its worker cannot factorise, every step goes on with PCG on its first factor, and each dv
// matches the direct solve of the same state (made once the lock is released). A step that
// took the lock (a BLAS solve, or a factorisation of its own) would wait until the holder gives
// up after kHoldLimit, which the test reports: it counts, it does not time.
TEST(CholmodReuse, TakenWhenReadyTheStepsSolveWithoutBlas) {
  const double tol = 1e-10;
  constexpr int kSteps = 10;
  constexpr auto kHoldLimit = std::chrono::seconds(120);
  const TetMesh block = makeBoxTetMesh(12, 6, 6, Eigen::Vector3d(0.12, 0.06, 0.06));
  FemSolverOptions o = options(LinearSolverKind::kCholmodReuse, tol, 1);
  o.background_refactor_when_ready = true;
  FemBody reuse(block, softMaterial(), {}, nullptr, o);
  tumble(reuse, 4.0);
  std::mutex m;
  std::condition_variable cv;
  bool held = false, release = false, gave_up = false;
  // the holder takes the BLAS lock and keeps it until released (or kHoldLimit)
  auto hold = [&](std::chrono::milliseconds at_most) {
    auto blas = lockCholmodBlas();
    std::unique_lock<std::mutex> lock(m);
    held = true;
    cv.notify_all();
    gave_up = !cv.wait_for(lock, at_most, [&] { return release; });
  };
  auto waitHeld = [&] {
    std::unique_lock<std::mutex> lock(m);
    cv.wait(lock, [&] { return held; });
  };
  auto releaseHolder = [&](std::thread& holder) {
    {
      std::lock_guard<std::mutex> lock(m);
      release = true;
    }
    cv.notify_all();
    holder.join();
    held = release = false;
  };
  // the first step factorises on its own thread: it waits for the holder's 50 ms when the
  // factor is supernodal
  {
    const long contended = blasLockFigures().contended_calls;
    std::thread holder(hold, std::chrono::milliseconds(50));
    waitHeld();
    ASSERT_TRUE(reuse.freeMotion(kSolverTimeStep).ok);
    holder.join();
    held = false;
    ASSERT_GT(blasLockFigures().contended_calls, contended)
        << "the block must be large enough for CHOLMOD's supernodal (BLAS) factor";
  }
  std::vector<Eigen::VectorXd> q0, v0, dv;
  int started = 0, taken = 0, refreshed = 0;
  {
    std::thread holder(hold, std::chrono::milliseconds(kHoldLimit));
    waitHeld();
    for (int s = 0; s < kSteps; ++s) {
      q0.push_back(reuse.positions());
      v0.push_back(reuse.velocities());
      const FemStepStats sr = reuse.freeMotion(kSolverTimeStep);
      EXPECT_TRUE(sr.ok) << "step " << s;
      if (sr.factor_refreshed) ++refreshed;
      if (sr.background_factor_taken) ++taken;
      if (sr.background_factorisation_started) ++started;
      if (!sr.factor_refreshed) {
        EXPECT_LE(sr.cg_residual, tol) << "step " << s;
      }
      dv.push_back(reuse.velocities() - v0.back());
    }
    releaseHolder(holder);
    EXPECT_FALSE(gave_up) << "a step waited for the BLAS lock";
  }
  EXPECT_EQ(refreshed, 0);
  EXPECT_EQ(taken, 0);   // the worker could not factorise while the lock was held
  EXPECT_GE(started, 1) << "the tumbling must start a background factorisation";
  EXPECT_GT(reuse.counters().background_not_ready, 0);
  EXPECT_EQ(reuse.counters().background_waits, 0);
  FemBody exact(block, softMaterial(), {}, nullptr, options(LinearSolverKind::kCholmod));
  double worst = 0.0;
  for (int s = 0; s < kSteps; ++s) {
    exact.positions() = q0[static_cast<std::size_t>(s)];
    exact.velocities() = v0[static_cast<std::size_t>(s)];
    ASSERT_TRUE(exact.freeMotion(kSolverTimeStep).ok);
    const Eigen::VectorXd dv_e = exact.velocities() - v0[static_cast<std::size_t>(s)];
    worst = std::max(worst, (dv[static_cast<std::size_t>(s)] - dv_e).norm() / dv_e.norm());
  }
  EXPECT_LT(worst, 1e-6);
  RecordProperty("worst_relative_dv_error", std::to_string(worst));
}

// solveCompliance after a step that reused an old factor factorises the current A: the same
// compliance as the exact strategy's, and the next step is preconditioned by that fresh factor.
// The same with background refreshes (a job then in flight is dropped: the factor is newer).
TEST(CholmodReuse, ComplianceStaysExact) {
  for (const int lag : {0, 2}) {
    SCOPED_TRACE("background lag " + std::to_string(lag));
    FemBody reuse(beamMesh(), softMaterial(), {}, nullptr,
                  options(LinearSolverKind::kCholmodReuse, 1e-10, lag));
    FemBody exact(beamMesh(), softMaterial(), {}, nullptr, options(LinearSolverKind::kCholmod));
    tumble(reuse, 4.0);
    FemStepStats st;
    for (int s = 0; s < 5 || st.factor_refreshed; ++s) {
      exact.positions() = reuse.positions();
      exact.velocities() = reuse.velocities();
      st = reuse.freeMotion(kSolverTimeStep);
      exact.freeMotion(kSolverTimeStep);
      ASSERT_TRUE(st.ok);
      ASSERT_LT(s, 100) << "no step reused the factor";
    }
    Eigen::VectorXd r = Eigen::VectorXd::Zero(reuse.dofCount());
    for (int i = 0; i < reuse.nodeCount(); i += 7) r.segment<3>(3 * i) = Eigen::Vector3d(1, -2, 0.5);
    Eigen::VectorXd x_reuse, x_exact;
    const long before = reuse.counters().factorisations;
    reuse.solveCompliance(r, x_reuse);
    exact.solveCompliance(r, x_exact);
    EXPECT_EQ(reuse.counters().factorisations, before + 1);
    EXPECT_LT((x_reuse - x_exact).norm(), 1e-10 * x_exact.norm());
    // the factor is now of the current A: the next step reuses it
    const FemStepStats next = reuse.freeMotion(kSolverTimeStep);
    ASSERT_TRUE(next.ok);
    EXPECT_FALSE(next.factor_refreshed);
    EXPECT_FALSE(next.background_factor_taken);
  }
}

}  // namespace
}  // namespace tactus::sim
