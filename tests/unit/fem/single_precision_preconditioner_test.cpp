// The reduced-precision preconditioners of the factor-reuse strategy (CholmodSolver::
// setSinglePrecisionPreconditioner and setHalfPrecisionPreconditioner,
// FemSolverOptions::preconditioner_precision) on a real mesh, liver_20k.msh as liver_grasp_20k
// places and fixes it: the float sweep pair is the double one to about 1e-7 relative, the half
// one to about 1e-3 (and each is really what it says: not bit-equal), the same bits on every
// call (and, for the half sweeps, with every kernel the CPU has), the background worker makes
// the copy and hands it over with its factor, and PCG preconditioned so matches the direct
// solve within its tolerance in the iterations of the double preconditioner.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "../../../sim_server/src/fem/half_factor.h"
#include "../../../sim_server/src/fem/linear_solver.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {
namespace {

// liver_grasp_20k's tissue: its mesh, placement, fixed box, material, damping and time step.
struct SinglePrecisionLiver {
  TetMesh mesh;
  std::vector<int> fixed;
  FemMaterial material;
};

const SinglePrecisionLiver& singlePrecisionLiver() {
  static const SinglePrecisionLiver liver = [] {
    SinglePrecisionLiver l;
    // one literal (GCC 12 warns falsely, -Warray-bounds, on a std::string + literal inlined here)
    l.mesh = loadTetMesh(TACTUS_SOURCE_DIR "/scenes/meshes/liver_20k.msh");
    transformMesh(l.mesh, 0.1, Eigen::Vector3d::Zero(), Eigen::Vector3d(0.0260, 0.0566, -1.5242));
    BoxSpec box;
    box.min_m = Eigen::Vector3d(-0.2, -0.2, -0.2);
    box.max_m = Eigen::Vector3d(-0.07, 0.2, 0.2);
    l.fixed = nodesInBoxes(l.mesh, {box});
    l.material.law = MaterialLaw::kCorotational;
    l.material.young_pa = 15000.0;
    l.material.poisson = 0.45;
    l.material.density_kgpm3 = 1000.0;
    l.material.damping = RayleighSpec{0.5, 0.005};
    return l;
  }();
  return liver;
}

constexpr double kLiverTimeStep = 0.01;

// The lower triangle of the liver's linear-elastic step matrix (1 + h alpha) M + (h beta + h^2) K
// (lumped mass) over its free nodes: the pattern and the scale of what its FemBody solves.
fem_detail::CholmodSolver::Sparse liverStepMatrixLower(double stiffness_scale) {
  const SinglePrecisionLiver& l = singlePrecisionLiver();
  const int nodes = l.mesh.nodeCount();
  std::vector<int> dof(static_cast<std::size_t>(nodes), 0);
  for (int i : l.fixed) dof[static_cast<std::size_t>(i)] = -1;
  int n = 0;
  for (int& d : dof)
    if (d == 0) {
      d = n;
      n += 3;
    }
  const FemMaterial& m = l.material;
  const double h = kLiverTimeStep, young = m.young_pa * stiffness_scale;
  const double lambda = young * m.poisson / ((1.0 + m.poisson) * (1.0 - 2.0 * m.poisson));
  const double mu = young / (2.0 * (1.0 + m.poisson));
  const double k_scale = h * m.damping->stiffness_beta_s + h * h;
  const double m_scale = 1.0 + h * m.damping->mass_alpha_per_s;
  std::vector<Eigen::Triplet<double, int>> t;
  for (const auto& tet : l.mesh.tets) {
    Eigen::Matrix3d d;
    for (int k = 0; k < 3; ++k) d.col(k) = l.mesh.nodes.col(tet[k + 1]) - l.mesh.nodes.col(tet[0]);
    const double volume = d.determinant() / 6.0;
    const Eigen::Matrix3d d_inv = d.inverse();
    Eigen::Vector3d g[4];
    for (int k = 0; k < 3; ++k) g[k + 1] = d_inv.row(k).transpose();
    g[0] = -(g[1] + g[2] + g[3]);
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) {
        const int da = dof[static_cast<std::size_t>(tet[a])];
        const int db = dof[static_cast<std::size_t>(tet[b])];
        if (da < 0 || db < 0) continue;
        Eigen::Matrix3d k = volume * (lambda * g[a] * g[b].transpose() +
                                      mu * g[b] * g[a].transpose() +
                                      mu * g[a].dot(g[b]) * Eigen::Matrix3d::Identity());
        k *= k_scale;
        if (a == b) k.diagonal().array() += m_scale * m.density_kgpm3 * volume / 4.0;
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j < 3; ++j)
            if (da + i >= db + j) t.emplace_back(da + i, db + j, k(i, j));
      }
  }
  fem_detail::CholmodSolver::Sparse a(n, n);
  a.setFromTriplets(t.begin(), t.end());
  a.makeCompressed();
  return a;
}

Eigen::VectorXd singlePrecisionRhs(Eigen::Index n) {
  Eigen::VectorXd b(n);
  for (Eigen::Index i = 0; i < n; ++i)
    b[i] = std::sin(0.37 * static_cast<double>(i)) + 0.1 * static_cast<double>(i % 7);
  return b;
}

double relativeDifference(const Eigen::VectorXd& x, const Eigen::VectorXd& y) {
  return (x - y).norm() / y.norm();
}

std::string scientific(double v) {
  char text[32];
  std::snprintf(text, sizeof text, "%.3g", v);
  return text;
}

// `solver` set to solve without BLAS, analysed and factorised on `a` (supernodal, as the liver's
// factor is).
void factorWithoutBlas(fem_detail::CholmodSolver& solver, fem_detail::CholmodSolver::Sparse& a) {
  solver.setBlasFreeSolves(true);
  solver.analyze(a);
  ASSERT_TRUE(solver.factorize(a));
  ASSERT_TRUE(solver.supernodal()) << "the liver's factor must be supernodal";
}

// The float sweeps against the double ones on the liver's supernodal factor: close (about 1e-7
// relative; the factor's rounding to float dominates), not the same bits (they did run in
// float), in place too, the same bits on every call and after a second factorisation of the
// same values; without the setting (or without the BLAS-free solves, which the float copy
// belongs to) solvePreconditioner is solve() bit for bit.
TEST(SinglePrecisionPreconditioner, FloatSweepsMatchTheDoubleSolveOnTheLiver) {
  fem_detail::CholmodSolver::Sparse a = liverStepMatrixLower(1.0);
  const Eigen::Index n = a.rows();
  const Eigen::VectorXd b = singlePrecisionRhs(n);
  fem_detail::CholmodSolver solver;
  factorWithoutBlas(solver, a);
  if (HasFatalFailure()) return;
  EXPECT_FALSE(solver.holdsSinglePrecisionCopy());
  Eigen::VectorXd x_double(n), x_off(n);
  solver.solve(b.data(), x_double.data(), 1);
  solver.solvePreconditioner(b.data(), x_off.data());
  EXPECT_EQ(x_off, x_double);

  solver.setSinglePrecisionPreconditioner(true);   // converts the factor held now
  ASSERT_TRUE(solver.holdsSinglePrecisionCopy());
  Eigen::VectorXd x_float(n);
  solver.solvePreconditioner(b.data(), x_float.data());
  const double difference = relativeDifference(x_float, x_double);
  EXPECT_LT(difference, 1e-6);
  EXPECT_GT(difference, 0.0) << "the float sweeps gave the double solve's bits";
  Eigen::VectorXd x_again = b;
  solver.solvePreconditioner(x_again.data(), x_again.data());   // in place
  EXPECT_EQ(x_again, x_float);
  ASSERT_TRUE(solver.factorize(a));   // the copy made again by the factorisation
  ASSERT_TRUE(solver.holdsSinglePrecisionCopy());
  solver.solvePreconditioner(b.data(), x_again.data());
  EXPECT_EQ(x_again, x_float);
  RecordProperty("float_against_double", scientific(difference));

  solver.setBlasFreeSolves(false);
  EXPECT_FALSE(solver.holdsSinglePrecisionCopy());
  solver.setBlasFreeSolves(true);   // the copy made again from the factor held
  ASSERT_TRUE(solver.holdsSinglePrecisionCopy());
  solver.solvePreconditioner(b.data(), x_again.data());
  EXPECT_EQ(x_again, x_float);
  solver.setSinglePrecisionPreconditioner(false);
  EXPECT_FALSE(solver.holdsSinglePrecisionCopy());
  solver.solvePreconditioner(b.data(), x_off.data());
  EXPECT_EQ(x_off, x_double);
}

// The worker factorises a stiffer matrix A1 and hands its factor over with the reduced copy it
// made (`half`: the half copy, else the float one): the caller's preconditioner solves then
// solve A1 (against the double solve: `close`, and not its bits), and PCG on the old matrix A0
// preconditioned by them converges to the direct solution of A0 within its tolerance, in at
// most one iteration more than with the double preconditioner.
void workerHandsOverItsCopyAndPcgConverges(bool half, double close) {
  fem_detail::CholmodSolver::Sparse a0 = liverStepMatrixLower(1.0), a1 = liverStepMatrixLower(1.3);
  const Eigen::Index n = a0.rows();
  const Eigen::VectorXd b = singlePrecisionRhs(n);
  fem_detail::CholmodSolver step, exact1, exact0;
  step.setBlasFreeSolves(true);
  if (half)
    step.setHalfPrecisionPreconditioner(true);
  else
    step.setSinglePrecisionPreconditioner(true);
  step.analyze(a0);
  exact1.analyze(a1);
  exact0.analyze(a0);
  ASSERT_TRUE(step.factorize(a0));
  ASSERT_TRUE(exact1.factorize(a1));
  ASSERT_TRUE(exact0.factorize(a0));

  fem_detail::BackgroundFactoriser worker;
  worker.start(a1, step);
  double waited_s = 0.0, factorisation_s = 0.0;
  ASSERT_TRUE(worker.collect(step, waited_s, factorisation_s));
  ASSERT_TRUE(half ? step.holdsHalfPrecisionCopy() : step.holdsSinglePrecisionCopy())
      << "the worker made no copy";
  Eigen::VectorXd z(n), z_double(n);
  step.solvePreconditioner(b.data(), z.data());
  exact1.solve(b.data(), z_double.data(), 1);
  EXPECT_LT(relativeDifference(z, z_double), close);
  EXPECT_GT(relativeDifference(z, z_double), 0.0);

  // A0 x = b by PCG preconditioned by A1's factor: reduced (step) and in double (exact1)
  Eigen::VectorXd x_direct(n);
  exact0.solve(b.data(), x_direct.data(), 1);
  const double tol = 1e-10;
  fem_detail::CgBuffers buffers;
  Eigen::VectorXd x_reduced = Eigen::VectorXd::Zero(n), x_double = Eigen::VectorXd::Zero(n);
  const fem_detail::CgResult reduced = fem_detail::conjugateGradient(
      a0, b, x_reduced, tol, 100, buffers,
      [&](const Eigen::VectorXd& r, Eigen::VectorXd& out) {
        step.solvePreconditioner(r.data(), out.data());
      });
  const fem_detail::CgResult in_double = fem_detail::conjugateGradient(
      a0, b, x_double, tol, 100, buffers,
      [&](const Eigen::VectorXd& r, Eigen::VectorXd& out) {
        exact1.solve(r.data(), out.data(), 1);
      });
  ASSERT_TRUE(reduced.converged) << reduced.iterations << " iterations, residual "
                                 << reduced.residual;
  ASSERT_TRUE(in_double.converged);
  EXPECT_GE(reduced.iterations, 3);   // A1's factor is not A0's: PCG has work to do
  EXPECT_LE(reduced.iterations, in_double.iterations + 1);
  EXPECT_LT(relativeDifference(x_reduced, x_direct), 1e-8);
  ::testing::Test::RecordProperty(half ? "pcg_iterations_half" : "pcg_iterations_float",
                                  reduced.iterations);
  ::testing::Test::RecordProperty("pcg_iterations_double", in_double.iterations);
}

TEST(SinglePrecisionPreconditioner, TheWorkerHandsOverItsFloatCopyAndPcgConverges) {
  workerHandsOverItsCopyAndPcgConverges(false, 1e-6);
}

FemSolverOptions singlePrecisionOptions(LinearSolverKind kind, bool single) {
  FemSolverOptions o;
  o.linear = kind;
  o.cg_tolerance = 1e-10;
  o.background_refactor_lag_steps = kind == LinearSolverKind::kCholmodReuse ? 2 : 0;
  o.preconditioner_precision = single ? PreconditionerPrecision::kFloat : PreconditionerPrecision::kDouble;
  return o;
}

// The liver settling under gravity with the background refresh (lag 2), its PCG preconditioned
// in float and, beside it, in double: each step's dv matches the direct solve from the same
// state within the PCG tolerance, the float preconditioner needs the double one's iterations
// (at most one more at a step, two more in all), and a second float run (without the direct
// solves beside it) gives the same bits.
TEST(SinglePrecisionPreconditioner, TheSettlingLiverMatchesTheDirectSolve) {
  const SinglePrecisionLiver& l = singlePrecisionLiver();
  const Eigen::Vector3d gravity(0.0, 0.0, -9.81);
  constexpr int kSteps = 20;
  auto run = [&](bool single, bool beside_exact, std::vector<int>* iterations,
                 std::vector<Eigen::VectorXd>* q, double* worst) {
    FemBody body(l.mesh, l.material, l.fixed, &gravity,
                 singlePrecisionOptions(LinearSolverKind::kCholmodReuse, single));
    FemBody exact(l.mesh, l.material, l.fixed, &gravity,
                  singlePrecisionOptions(LinearSolverKind::kCholmod, false));
    int taken = 0;
    for (int s = 0; s < kSteps; ++s) {
      const Eigen::VectorXd v0 = body.velocities();
      if (beside_exact) {
        exact.positions() = body.positions();
        exact.velocities() = v0;
        ASSERT_TRUE(exact.freeMotion(kLiverTimeStep).ok) << "step " << s;
      }
      const FemStepStats st = body.freeMotion(kLiverTimeStep);
      ASSERT_TRUE(st.ok) << "step " << s;
      if (s > 0) {
        EXPECT_FALSE(st.factor_refreshed) << "step " << s;
      }
      if (!st.factor_refreshed) {
        EXPECT_LE(st.cg_residual, 1e-10) << "step " << s;
      }
      if (st.background_factor_taken) ++taken;
      if (beside_exact)
        *worst = std::max(*worst, relativeDifference(body.velocities() - v0, exact.velocities() - v0));
      iterations->push_back(st.cg_iterations);
      if (q) q->push_back(body.positions());
    }
    EXPECT_GE(taken, 2) << "the settling liver refreshes its factor in the background";
  };
  std::vector<int> it_float, it_double, it_again;
  std::vector<Eigen::VectorXd> q_float, q_again;
  double worst_float = 0.0, worst_double = 0.0, worst_again = 0.0;
  run(true, true, &it_float, &q_float, &worst_float);
  run(false, true, &it_double, nullptr, &worst_double);
  run(true, false, &it_again, &q_again, &worst_again);
  EXPECT_LT(worst_float, 1e-6);
  EXPECT_LT(worst_double, 1e-6);
  int sum_float = 0, sum_double = 0;
  for (int s = 0; s < kSteps; ++s) {
    EXPECT_LE(it_float[static_cast<std::size_t>(s)], it_double[static_cast<std::size_t>(s)] + 1)
        << "step " << s;
    sum_float += it_float[static_cast<std::size_t>(s)];
    sum_double += it_double[static_cast<std::size_t>(s)];
  }
  EXPECT_LE(sum_float, sum_double + 2);
  EXPECT_EQ(it_again, it_float);
  ASSERT_EQ(q_again.size(), q_float.size());
  for (std::size_t s = 0; s < q_float.size(); ++s) ASSERT_EQ(q_again[s], q_float[s]) << "step " << s;
  RecordProperty("pcg_iterations_float", sum_float);
  RecordProperty("pcg_iterations_double", sum_double);
  RecordProperty("worst_relative_dv_error_float", scientific(worst_float));
}

// The forward sweep without BLAS passes over the supernodes whose part of the right-hand side is
// still zero (CholmodSolver::setSkipZeroSupernodes; the contact correction's right-hand side
// lies on the few nodes its rows touch): on the liver's factor, a right-hand side on a few
// hundred DOFs skips supernodes and gives the full sweep's bits (sign of zero included), in
// double and in the float sweeps; one holding a -0 and a dense one are swept in full.
TEST(SinglePrecisionPreconditioner, SkippingZeroSupernodesKeepsTheFullSweepsBits) {
  fem_detail::CholmodSolver::Sparse a = liverStepMatrixLower(1.0);
  const Eigen::Index n = a.rows();
  fem_detail::CholmodSolver solver;
  solver.setBlasFreeSolves(true);
  solver.setSinglePrecisionPreconditioner(true);
  solver.analyze(a);
  ASSERT_TRUE(solver.factorize(a));
  ASSERT_TRUE(solver.supernodal());
  // a contact correction's kind of right-hand side: 600 DOFs in one stretch of the numbering
  // (some zero among them), zero elsewhere
  Eigen::VectorXd sparse = Eigen::VectorXd::Zero(n);
  for (Eigen::Index i = n / 3; i < n / 3 + 600; ++i)
    sparse[i] = i % 5 == 0 ? 0.0 : std::sin(0.37 * static_cast<double>(i));
  Eigen::VectorXd with_negative_zero = sparse;
  with_negative_zero[n / 3 + 700] = -0.0;
  const auto sameBits = [](const Eigen::VectorXd& x, const Eigen::VectorXd& y) {
    const auto bytes = sizeof(double) * static_cast<std::size_t>(x.size());
    return x.size() == y.size() && std::memcmp(x.data(), y.data(), bytes) == 0;
  };
  struct Solved {
    Eigen::VectorXd x;
    long skipped;
  };
  const auto solveWith = [&](bool skip, const Eigen::VectorXd& b, bool in_float) {
    solver.setSkipZeroSupernodes(skip);
    Solved s{Eigen::VectorXd(n), 0};
    if (in_float) {
      solver.solvePreconditioner(b.data(), s.x.data());
    } else {
      solver.solve(b.data(), s.x.data(), 1);
    }
    s.skipped = solver.skippedSupernodes();
    return s;
  };
  for (const bool in_float : {false, true}) {
    SCOPED_TRACE(in_float ? "float sweeps" : "double sweeps");
    const Solved full = solveWith(false, sparse, in_float);
    const Solved skipping = solveWith(true, sparse, in_float);
    EXPECT_EQ(full.skipped, 0);
    EXPECT_GT(skipping.skipped, 0) << "nothing skipped: the test does not test skipping";
    EXPECT_TRUE(sameBits(skipping.x, full.x));
    EXPECT_GT(full.x.cwiseAbs().minCoeff(), 0.0);   // the solution is dense: all swept back

    const Solved full_nz = solveWith(false, with_negative_zero, in_float);
    const Solved skipping_nz = solveWith(true, with_negative_zero, in_float);
    EXPECT_EQ(skipping_nz.skipped, 0);
    EXPECT_TRUE(sameBits(skipping_nz.x, full_nz.x));

    const Solved dense = solveWith(true, singlePrecisionRhs(n), in_float);
    EXPECT_EQ(dense.skipped, 0);
  }
  solver.setSkipZeroSupernodes(true);
}

// ---- half precision ----

// binary16 from float: exact values kept, ties to even, below the smallest normal +0, beyond
// 65504 (after rounding) or not finite refused; and back, exactly.
TEST(HalfPrecisionPreconditioner, ConversionRoundsToNearestEvenWithinHalfsRange) {
  using fem_detail::floatToHalf;
  using fem_detail::halfToFloat;
  std::uint16_t h = 0;
  for (const float v : {1.0f, -2.5f, 0.099975586f, 65504.0f, -6.1035156e-5f, 0.0f}) {
    ASSERT_TRUE(floatToHalf(v, h)) << v;
    EXPECT_EQ(halfToFloat(h), v) << v;
  }
  ASSERT_TRUE(floatToHalf(1.0f, h));
  EXPECT_EQ(h, 0x3c00);
  // 1 + 2^-11 lies halfway between 1 and 1 + 2^-10: to the even one, 1; 1 + 3 2^-11 to 1 + 2^-9
  ASSERT_TRUE(floatToHalf(1.0f + 0x1p-11f, h));
  EXPECT_EQ(halfToFloat(h), 1.0f);
  ASSERT_TRUE(floatToHalf(1.0f + 3 * 0x1p-11f, h));
  EXPECT_EQ(halfToFloat(h), 1.0f + 0x1p-9f);
  ASSERT_TRUE(floatToHalf(-1.0f - 0x1p-11f - 0x1p-20f, h));   // past halfway: away from 1
  EXPECT_EQ(halfToFloat(h), -1.0f - 0x1p-10f);
  ASSERT_TRUE(floatToHalf(3.0e-5f, h));   // below 2^-14: +0
  EXPECT_EQ(h, 0);
  ASSERT_TRUE(floatToHalf(-3.0e-5f, h));
  EXPECT_EQ(h, 0);
  ASSERT_TRUE(floatToHalf(65519.0f, h));   // rounds down to the largest half
  EXPECT_EQ(halfToFloat(h), 65504.0f);
  EXPECT_FALSE(floatToHalf(65520.0f, h));
  EXPECT_FALSE(floatToHalf(-1e6f, h));
  EXPECT_FALSE(floatToHalf(std::numeric_limits<float>::infinity(), h));
  EXPECT_FALSE(floatToHalf(std::numeric_limits<float>::quiet_NaN(), h));
}

// The half sweeps on the liver's factor: the double solve to about 1e-3 relative (not its bits:
// they did run in half), in place too, the same bits on every call, and the same bits with each
// kernel this CPU has (the generic one always; F16C and AVX-512F where present).
TEST(HalfPrecisionPreconditioner, EveryKernelGivesTheSameBitsOnTheLiver) {
  fem_detail::CholmodSolver::Sparse a = liverStepMatrixLower(1.0);
  const Eigen::Index n = a.rows();
  const Eigen::VectorXd b = singlePrecisionRhs(n);
  fem_detail::CholmodSolver solver;
  factorWithoutBlas(solver, a);
  if (HasFatalFailure()) return;
  Eigen::VectorXd x_double(n);
  solver.solve(b.data(), x_double.data(), 1);
  solver.setHalfPrecisionPreconditioner(true);   // converts the factor held now
  ASSERT_TRUE(solver.holdsHalfPrecisionCopy());
  EXPECT_FALSE(solver.holdsSinglePrecisionCopy());
  const std::string kernel = fem_detail::halfSweepKernelName();
  Eigen::VectorXd x_half(n);
  solver.solvePreconditioner(b.data(), x_half.data());
  const double difference = relativeDifference(x_half, x_double);
  EXPECT_LT(difference, 3e-3);
  EXPECT_GT(difference, 1e-6) << "the half sweeps gave (nearly) the double solve";
  Eigen::VectorXd x_again = b;
  solver.solvePreconditioner(x_again.data(), x_again.data());   // in place
  EXPECT_EQ(x_again, x_half);
  std::string kernels;
  for (const char* name : {"generic", "f16c", "avx512"}) {
    if (!fem_detail::setHalfSweepKernel(name)) continue;   // not on this CPU
    kernels += std::string(kernels.empty() ? "" : " ") + name;
    Eigen::VectorXd x_kernel(n);
    solver.solvePreconditioner(b.data(), x_kernel.data());
    EXPECT_EQ(x_kernel, x_half) << name << " against " << kernel;
  }
  ASSERT_TRUE(fem_detail::setHalfSweepKernel(kernel.c_str()));
  EXPECT_NE(kernels.find("generic"), std::string::npos);
  RecordProperty("half_against_double", scientific(difference));
  RecordProperty("kernels_compared", kernels);

  solver.setSinglePrecisionPreconditioner(true);   // the float copy instead
  EXPECT_FALSE(solver.holdsHalfPrecisionCopy());
  ASSERT_TRUE(solver.holdsSinglePrecisionCopy());
  solver.setHalfPrecisionPreconditioner(false);
  EXPECT_FALSE(solver.holdsHalfPrecisionCopy());
}

// A factor with an entry of L D^-1 beyond half's range (one unknown scaled by 1e8: its row of
// L D^-1 grows by as much) keeps the float copy instead, and the preconditioner solves with it.
TEST(HalfPrecisionPreconditioner, AnEntryBeyondHalfsRangeKeepsTheFloatCopy) {
  fem_detail::CholmodSolver::Sparse a = liverStepMatrixLower(1.0);
  const Eigen::Index n = a.rows();
  const int scaled = static_cast<int>(n / 2);
  for (int c = 0; c < a.outerSize(); ++c)
    for (fem_detail::CholmodSolver::Sparse::InnerIterator it(a, c); it; ++it) {
      if (it.row() == scaled) it.valueRef() *= 1e8;
      if (it.col() == scaled) it.valueRef() *= 1e8;
    }
  const Eigen::VectorXd b = singlePrecisionRhs(n);
  fem_detail::CholmodSolver solver;
  solver.setBlasFreeSolves(true);
  solver.setHalfPrecisionPreconditioner(true);
  solver.analyze(a);
  ASSERT_TRUE(solver.factorize(a));
  ASSERT_TRUE(solver.supernodal());
  EXPECT_FALSE(solver.holdsHalfPrecisionCopy());
  ASSERT_TRUE(solver.holdsSinglePrecisionCopy());
  Eigen::VectorXd x_double(n), x(n);
  solver.solve(b.data(), x_double.data(), 1);
  solver.solvePreconditioner(b.data(), x.data());
  EXPECT_LT(relativeDifference(x, x_double), 1e-5);
}

TEST(HalfPrecisionPreconditioner, TheWorkerHandsOverItsHalfCopyAndPcgConverges) {
  workerHandsOverItsCopyAndPcgConverges(true, 3e-3);
}

}  // namespace
}  // namespace tactus::sim
