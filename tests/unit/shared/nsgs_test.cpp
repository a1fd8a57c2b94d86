// NSGS frictional contact solver: analytic one-contact cases, exact LCP cross-checks, the FCLIB
// set against Siconos' reference solutions, physics (block on an incline), warm start, status
// codes and the no-allocation guarantee. The stagnation (relaxation) rule: nsgs_stagnation_test.cpp.

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <limits>
#include <new>
#include <random>
#include <string>
#include <vector>

#include "tactus/shared/fclib.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/nsgs_clock.h"

#include "../../support/alloc_counter.h"
#include "../../support/fclib_set.h"
#include "../../support/sphere_pile.h"


namespace tactus::shared {
namespace {

namespace fs = std::filesystem;
const fs::path kFclibDir = fs::path(TACTUS_TEST_DATA_DIR) / "fclib";

using test::DenseProblem;
using Problem = DenseProblem;

// One 3-row contact with block `w` (row-major) and free velocity `q`.
Problem oneContact(const Eigen::Matrix3d& w, const Eigen::Vector3d& q, double mu) {
  Problem p;
  p.row_offset = {0, 3};
  p.W.resize(9);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) p.W[r * 3 + c] = w(r, c);
  }
  p.q = {q[0], q[1], q[2]};
  p.mu = {mu};
  return p;
}

struct Solved {
  NsgsResult result;
  std::vector<double> f, u;
};

Solved solve(const Problem& p, NsgsSettings s = {}, std::vector<double> warm = {}) {
  Solved out;
  out.f = warm.empty() ? std::vector<double>(p.rows(), 0.0) : warm;
  NsgsWorkspace ws(p.rows(), p.contacts());
  out.result = solveNsgs(p.view(), s, ws, out.f.data());
  out.u.assign(ws.delta.begin(), ws.delta.begin() + p.rows());
  return out;
}

// B B^T + I / 2 with B's entries standard normal: symmetric positive definite.
Eigen::MatrixXd randomSpd(int m, std::mt19937& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::MatrixXd b(m, m);
  for (int r = 0; r < m; ++r) {
    for (int c = 0; c < m; ++c) b(r, c) = g(rng);
  }
  return b * b.transpose() + 0.5 * Eigen::MatrixXd::Identity(m, m);
}

double norm(const std::vector<double>& v) {
  double s = 0.0;
  for (double x : v) s += x * x;
  return std::sqrt(s);
}

double diffNorm(const std::vector<double>& a, const std::vector<double>& b) {
  double s = 0.0;
  for (std::size_t k = 0; k < a.size(); ++k) s += (a[k] - b[k]) * (a[k] - b[k]);
  return std::sqrt(s);
}

NsgsSettings tight() {
  NsgsSettings s;
  s.tolerance = 1e-13;
  s.max_sweeps = 1000;
  return s;
}

// ---------------------------------------------------------------- one contact, analytic cases

TEST(NsgsOneContact, SeparatesWhenMovingApart) {
  Eigen::Matrix3d w;
  w << 2.0, 0.3, -0.2, 0.3, 1.5, 0.1, -0.2, 0.1, 1.2;
  const Problem p = oneContact(w, {0.5, -3.0, 2.0}, 0.6);
  const Solved s = solve(p, tight(), {1.0, 0.1, 0.2});  // warm start that must be undone
  ASSERT_EQ(s.result.status, NsgsStatus::kConverged);
  EXPECT_EQ(s.f[0], 0.0);
  EXPECT_EQ(s.f[1], 0.0);
  EXPECT_EQ(s.f[2], 0.0);
  EXPECT_NEAR(s.u[0], 0.5, 1e-15);
}

TEST(NsgsOneContact, SticksInsideTheCone) {
  Eigen::Matrix3d w;
  w << 2.0, 0.3, -0.2, 0.3, 1.5, 0.1, -0.2, 0.1, 1.2;
  const Eigen::Vector3d q(-1.0, 0.1, -0.05);
  const Problem p = oneContact(w, q, 0.5);
  const Solved s = solve(p, tight());
  ASSERT_EQ(s.result.status, NsgsStatus::kConverged);
  const Eigen::Vector3d f_expected = -w.lu().solve(q);
  ASSERT_LT(std::hypot(f_expected[1], f_expected[2]), 0.5 * f_expected[0]);  // really inside
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(s.f[k], f_expected[k], 1e-12);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(s.u[k], 0.0, 1e-12);
}

TEST(NsgsOneContact, SlipsOnTheConeEdgeOpposingTheSliding) {
  Eigen::Matrix3d w;  // anisotropic, coupled normal/tangent block
  w << 2.0, 0.3, -0.2, 0.3, 1.5, 0.4, -0.2, 0.4, 0.8;
  const double mu = 0.3;
  const Problem p = oneContact(w, {-1.0, 2.0, 1.0}, mu);
  const Solved s = solve(p, tight());
  ASSERT_EQ(s.result.status, NsgsStatus::kConverged);
  const double ft = std::hypot(s.f[1], s.f[2]);
  const double ut = std::hypot(s.u[1], s.u[2]);
  EXPECT_GT(s.f[0], 0.0);
  EXPECT_NEAR(ft, mu * s.f[0], 1e-12);           // on the edge of the cone
  EXPECT_NEAR(s.u[0], 0.0, 1e-12);                // in contact
  EXPECT_GT(ut, 0.1);                             // sliding
  // force exactly opposite to the sliding velocity
  EXPECT_NEAR((s.f[1] * s.u[1] + s.f[2] * s.u[2]) / (ft * ut), -1.0, 1e-12);
  EXPECT_LE(naturalMapError(p.view(), s.f.data()), 1e-13);
}

// The local solver is exact: any single contact is solved by one sweep, including strongly
// anisotropic, coupled, slightly unsymmetric blocks and large friction coefficients.
TEST(NsgsOneContact, LocalSolveIsExactOnRandomBlocks) {
  std::mt19937 rng(2024);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  int slips = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    Eigen::Matrix3d b;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) b(r, c) = g(rng);
    }
    Eigen::Matrix3d skew = Eigen::Matrix3d::Zero();
    skew(0, 1) = 0.05 * g(rng);
    skew(1, 0) = -skew(0, 1);
    const Eigen::Matrix3d w = b * b.transpose() + 0.05 * Eigen::Matrix3d::Identity() + skew;
    const double mu = 2.0 * u01(rng);
    const Eigen::Vector3d q(g(rng), g(rng), g(rng));
    const Problem p = oneContact(w, q, mu);
    NsgsSettings s = tight();
    s.tolerance = 1e-10;
    const Solved sol = solve(p, s);
    ASSERT_EQ(sol.result.status, NsgsStatus::kConverged) << "trial " << trial;
    EXPECT_EQ(sol.result.sweeps, 1) << "trial " << trial << std::setprecision(17) << "\nw=\n"
                                    << w << "\nq=" << q.transpose() << " mu=" << mu;
    const double ft = std::hypot(sol.f[1], sol.f[2]);
    slips += sol.f[0] > 0.0 && std::abs(ft - mu * sol.f[0]) < 1e-9 * sol.f[0];
  }
  EXPECT_GT(slips, 500);  // the slip branch is well exercised
}

TEST(NsgsOneContact, FrictionlessOneRowIsTheScalarProjection) {
  Problem p;
  p.row_offset = {0, 1};
  p.W = {4.0};
  p.q = {-2.0};
  p.mu = {0.0};
  Solved s = solve(p, tight());
  ASSERT_EQ(s.result.status, NsgsStatus::kConverged);
  EXPECT_DOUBLE_EQ(s.f[0], 0.5);
  p.q = {2.0};
  s = solve(p, tight(), {3.0});
  EXPECT_EQ(s.f[0], 0.0);
  EXPECT_DOUBLE_EQ(s.u[0], 2.0);
}

TEST(NsgsOneContact, ThreeRowsWithZeroFrictionCarryNoTangentialForce) {
  Eigen::Matrix3d w;
  w << 2.0, 0.3, -0.2, 0.3, 1.5, 0.1, -0.2, 0.1, 1.2;
  const Problem p = oneContact(w, {-1.0, 2.0, 1.0}, 0.0);
  const Solved s = solve(p, tight());
  ASSERT_EQ(s.result.status, NsgsStatus::kConverged);
  EXPECT_DOUBLE_EQ(s.f[0], 0.5);
  EXPECT_EQ(s.f[1], 0.0);
  EXPECT_EQ(s.f[2], 0.0);
}

// W = w I: stick if ||q_T|| <= mu (-q_N) (r = -q / w), else r_N = -q_N / w,
// r_T = -mu r_N q_T / ||q_T|| (README of the FCLIB data).
TEST(NsgsOneContact, DiagonalClosedFormOverManyRandomCases) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  for (int trial = 0; trial < 200; ++trial) {
    const double w = 0.1 + std::abs(u(rng));
    const double mu = 0.05 + 0.5 * std::abs(u(rng));
    const Eigen::Vector3d q(u(rng), u(rng), u(rng));
    const Problem p = oneContact(w * Eigen::Matrix3d::Identity(), q, mu);
    const Solved s = solve(p, tight());
    ASSERT_EQ(s.result.status, NsgsStatus::kConverged) << "trial " << trial;
    Eigen::Vector3d r = Eigen::Vector3d::Zero();
    const double qt = std::hypot(q[1], q[2]);
    if (q[0] < 0.0 && qt <= mu * -q[0]) {
      r = -q / w;
    } else if (q[0] < 0.0) {
      r[0] = -q[0] / w;
      r[1] = -mu * r[0] * q[1] / qt;
      r[2] = -mu * r[0] * q[2] / qt;
    }
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(s.f[k], r[k], 1e-12 * (1.0 + r.norm())) << trial;
  }
}

TEST(NsgsFclib, Example1MatchesTheClosedForm) {
  const FclibProblem p = readFclibText(kFclibDir / "problems/FC3D_Example1.fc3d.txt");
  std::vector<double> f(p.rows(), 0.0);
  NsgsWorkspace ws(p.rows(), p.contacts);
  const NsgsResult res = solveNsgs(p.view(), tight(), ws, f.data());
  ASSERT_EQ(res.status, NsgsStatus::kConverged);
  const double w = p.W[0];
  for (int i = 0; i < p.contacts; ++i) {
    ASSERT_EQ(p.W[(3 * i + 1) * p.rows() + 3 * i + 1], w);  // W = w I indeed
    const double* q = &p.q[3 * i];
    const double qt = std::hypot(q[1], q[2]);
    const double mu = p.mu[i];
    ASSERT_LT(q[0], 0.0);
    if (qt <= mu * -q[0]) {
      for (int k = 0; k < 3; ++k) EXPECT_NEAR(f[3 * i + k], -q[k] / w, 1e-14);
    } else {
      const double rn = -q[0] / w;
      EXPECT_NEAR(f[3 * i], rn, 1e-14);
      EXPECT_NEAR(f[3 * i + 1], -mu * rn * q[1] / qt, 1e-14);
      EXPECT_NEAR(f[3 * i + 2], -mu * rn * q[2] / qt, 1e-14);
    }
  }
}

// ---------------------------------------------------------------- frictionless = LCP

// Exact LCP solution by enumerating active sets (f_S > 0, w_N >= 0).
std::vector<double> bruteForceLcp(const Eigen::MatrixXd& a, const Eigen::VectorXd& q) {
  const int m = static_cast<int>(q.size());
  for (int mask = 0; mask < (1 << m); ++mask) {
    std::vector<int> act;
    for (int j = 0; j < m; ++j) {
      if (mask & (1 << j)) act.push_back(j);
    }
    Eigen::VectorXd f = Eigen::VectorXd::Zero(m);
    if (!act.empty()) {
      const int k = static_cast<int>(act.size());
      Eigen::MatrixXd ass(k, k);
      Eigen::VectorXd qs(k);
      for (int r = 0; r < k; ++r) {
        qs[r] = q[act[r]];
        for (int c = 0; c < k; ++c) ass(r, c) = a(act[r], act[c]);
      }
      const Eigen::VectorXd fs = ass.ldlt().solve(-qs);
      for (int r = 0; r < k; ++r) f[act[r]] = fs[r];
    }
    const Eigen::VectorXd w = a * f + q;
    bool ok = true;
    for (int j = 0; j < m && ok; ++j) ok = f[j] >= -1e-12 && w[j] >= -1e-12;
    if (ok) return {f.data(), f.data() + m};
  }
  return {};
}

TEST(NsgsFrictionless, RandomSpdProblemsMatchTheExactLcpSolution) {
  std::mt19937 rng(42);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int trial = 0; trial < 60; ++trial) {
    const int m = 1 + trial % 10;
    Eigen::MatrixXd b(m, m);
    for (int r = 0; r < m; ++r) {
      for (int c = 0; c < m; ++c) b(r, c) = g(rng);
    }
    const Eigen::MatrixXd a = b * b.transpose() + 0.1 * Eigen::MatrixXd::Identity(m, m);
    Eigen::VectorXd q(m);
    for (int j = 0; j < m; ++j) q[j] = g(rng);
    const std::vector<double> exact = bruteForceLcp(a, q);
    ASSERT_EQ(static_cast<int>(exact.size()), m) << "no LCP solution found, trial " << trial;

    Problem p;
    p.row_offset.resize(m + 1);
    for (int j = 0; j <= m; ++j) p.row_offset[j] = j;
    p.W.resize(m * m);
    for (int r = 0; r < m; ++r) {
      for (int c = 0; c < m; ++c) p.W[r * m + c] = a(r, c);
    }
    p.q.assign(q.data(), q.data() + m);
    p.mu.assign(m, 0.0);
    NsgsSettings s = tight();
    s.tolerance = 1e-12;
    s.max_sweeps = 200000;
    const Solved sol = solve(p, s);
    ASSERT_EQ(sol.result.status, NsgsStatus::kConverged) << "trial " << trial;
    for (int j = 0; j < m; ++j) EXPECT_NEAR(sol.f[j], exact[j], 1e-6) << "trial " << trial;
  }
}

TEST(NsgsFrictionless, ThreeRowContactsWithZeroMuSolveTheNormalLcp) {
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0.0, 1.0);
  const int nc = 4;
  const int m = 3 * nc;
  Eigen::MatrixXd b(m, m);
  for (int r = 0; r < m; ++r) {
    for (int c = 0; c < m; ++c) b(r, c) = g(rng);
  }
  const Eigen::MatrixXd a = b * b.transpose() + 0.1 * Eigen::MatrixXd::Identity(m, m);
  Problem p;
  p.row_offset = {0, 3, 6, 9, 12};
  p.W.assign(a.data(), a.data() + m * m);  // symmetric: storage order is irrelevant
  for (int j = 0; j < m; ++j) p.q.push_back(g(rng));
  p.mu.assign(nc, 0.0);
  const Solved sol = solve(p, tight());
  ASSERT_EQ(sol.result.status, NsgsStatus::kConverged);
  Eigen::MatrixXd ann(nc, nc);
  Eigen::VectorXd qn(nc);
  for (int i = 0; i < nc; ++i) {
    qn[i] = p.q[3 * i];
    for (int k = 0; k < nc; ++k) ann(i, k) = a(3 * i, 3 * k);
  }
  const std::vector<double> exact = bruteForceLcp(ann, qn);
  ASSERT_EQ(static_cast<int>(exact.size()), nc);
  for (int i = 0; i < nc; ++i) {
    EXPECT_NEAR(sol.f[3 * i], exact[i], 1e-9);
    EXPECT_EQ(sol.f[3 * i + 1], 0.0);
    EXPECT_EQ(sol.f[3 * i + 2], 0.0);
  }
}

// ---------------------------------------------------------------- FCLIB set vs Siconos

std::vector<fs::path> fclibProblems() { return test::fclibProblemFiles(TACTUS_TEST_DATA_DIR); }
std::string stem(const fs::path& p) { return test::fclibStem(p); }

// README: r is unique (W positive definite) for these.
bool referenceForceIsUnique(const std::string& name) {
  for (const char* prefix : {"CubeH8", "LMGC_GlobalFrictionContactProblem00046", "Confeti",
                             "Rover", "FC3D_Example1"}) {
    if (name.rfind(prefix, 0) == 0) return true;
  }
  return false;
}

bool positiveDefinite(const FclibProblem& p) {
  const int m = p.rows();
  const Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>
      w(p.W.data(), m, m);
  const Eigen::MatrixXd sym = 0.5 * (w + w.transpose());
  const Eigen::VectorXd ev = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(sym).eigenvalues();
  return ev.minCoeff() > 1e-10 * ev.cwiseAbs().maxCoeff();
}

TEST(NsgsFclib, AllProblemsConvergeAndMatchSiconos) {
  const auto problems = fclibProblems();
  ASSERT_EQ(problems.size(), 25u);
  int compared_u = 0;
  int compared_r = 0;
  for (const fs::path& path : problems) {
    const std::string name = stem(path);
    SCOPED_TRACE(name);
    const FclibProblem p = readFclibText(path);
    const FclibReference ref = readFclibReference(kFclibDir / "reference" / (name + ".ref.txt"));
    ASSERT_EQ(static_cast<int>(ref.u.size()), p.rows());

    // default tolerance: the required accuracy
    std::vector<double> f(p.rows(), 0.0);
    NsgsWorkspace ws(p.rows(), p.contacts);
    NsgsSettings s;
    s.max_sweeps = 5000;
    const NsgsResult res = solveNsgs(p.view(), s, ws, f.data());
    ASSERT_EQ(res.status, NsgsStatus::kConverged);
    EXPECT_LE(res.error, 1e-6);
    EXPECT_NEAR(naturalMapError(p.view(), f.data()), res.error, 1e-9);

    // tighter, for the comparison with the reference solution
    NsgsSettings s2 = s;
    s2.tolerance = 1e-11;
    const NsgsResult res2 = solveNsgs(p.view(), s2, ws, f.data());
    ASSERT_EQ(res2.status, NsgsStatus::kConverged);
    std::vector<double> u(ws.delta.begin(), ws.delta.begin() + p.rows());
    const bool pd = positiveDefinite(p);
    const bool r_unique = referenceForceIsUnique(name);
    const double du = diffNorm(u, ref.u) / std::max(norm(p.q), norm(ref.u));
    const double dr = diffNorm(f, ref.r) / std::max(norm(ref.r), 1e-300);
    std::printf("  %-46s nc %3d  sweeps(1e-6) %3d  error %.1e  |  W pd %d  du %.1e  dr %.1e%s\n",
                name.c_str(), p.contacts, res.sweeps, res.error, pd ? 1 : 0, du, dr,
                r_unique ? " (r unique)" : "");
    RecordProperty(name + "_sweeps", res.sweeps);
    // u is unique on all 25 problems in practice; the positive definite ones guarantee it
    EXPECT_LE(du, 1e-6);
    compared_u += pd ? 1 : 0;
    if (r_unique) {
      EXPECT_LE(dr, 1e-6);
      ++compared_r;
    }
  }
  EXPECT_GE(compared_u, 5);
  EXPECT_GE(compared_r, 5);
}

// ---------------------------------------------------------------- physics: block on an incline

// A block of mass m on a slope theta, one time step h: impulse f (local frame n = slope normal,
// t1 = down the slope), compliance W = (1/m) I, free velocity q = h g (-cos, sin, 0).
Solved incline(double theta, double mu) {
  const double mass = 2.0, h = 1e-3, g = 9.81;
  const Problem p = oneContact(Eigen::Matrix3d::Identity() / mass,
                               {-h * g * std::cos(theta), h * g * std::sin(theta), 0.0}, mu);
  return solve(p, tight());
}

TEST(NsgsPhysics, BlockOnInclineSticksBelowAndSlidesAboveTheFrictionAngle) {
  const double mu = 0.4, h = 1e-3, g = 9.81, mass = 2.0;
  const double friction_angle = std::atan(mu);
  for (const double scale : {0.5, 0.99}) {  // tan(theta) < mu: sticks
    const double theta = std::atan(scale * mu);
    const Solved s = incline(theta, mu);
    ASSERT_EQ(s.result.status, NsgsStatus::kConverged);
    EXPECT_NEAR(s.u[1], 0.0, 1e-15) << "theta " << theta;
    EXPECT_NEAR(s.u[0], 0.0, 1e-15);
    EXPECT_NEAR(s.f[1], -mass * h * g * std::sin(theta), 1e-15);  // friction holds it
    EXPECT_LT(std::abs(s.f[1]), mu * s.f[0]);
  }
  for (const double scale : {1.01, 2.0}) {  // tan(theta) > mu: slides down
    const double theta = std::atan(scale * mu);
    ASSERT_GT(theta, friction_angle);
    const Solved s = incline(theta, mu);
    ASSERT_EQ(s.result.status, NsgsStatus::kConverged);
    const double expected = h * g * (std::sin(theta) - mu * std::cos(theta));
    EXPECT_GT(s.u[1], 0.0);
    EXPECT_NEAR(s.u[1], expected, 1e-12 * h * g) << "theta " << theta;
    EXPECT_NEAR(s.u[0], 0.0, 1e-15);
    EXPECT_NEAR(s.f[1], -mu * s.f[0], 1e-15);  // kinetic friction, up the slope
    EXPECT_NEAR(s.f[0], mass * h * g * std::cos(theta), 1e-15);
  }
}

// ---------------------------------------------------------------- warm start, settings

TEST(NsgsWarmStart, ResolvingIsNoSlowerAndUnchangedProblemsTakeOneSweep) {
  for (const char* name : {"Box_Stacks-i0122-82-5.local", "Confeti-ex13-Fc3D-SBM",
                           "NESpheres_10_1", "Rover1040"}) {
    SCOPED_TRACE(name);
    FclibProblem p = readFclibText(kFclibDir / "problems" / (std::string(name) + ".fc3d.txt"));
    NsgsWorkspace ws(p.rows(), p.contacts);
    NsgsSettings s;
    s.max_sweeps = 5000;
    std::vector<double> f(p.rows(), 0.0);
    const NsgsResult cold = solveNsgs(p.view(), s, ws, f.data());
    ASSERT_EQ(cold.status, NsgsStatus::kConverged);
    ASSERT_GT(cold.sweeps, 1);

    // nothing changed: one sweep confirms the solution
    const NsgsResult again = solveNsgs(p.view(), s, ws, f.data());
    EXPECT_EQ(again.status, NsgsStatus::kConverged);
    EXPECT_EQ(again.sweeps, 1);

    // slightly moved problem (like the next haptic tick): warm <= cold. The change of q is
    // W g (a change of the free motion: rigid problems stay feasible, unlike an arbitrary dq)
    const int m = p.rows();
    const double f_max = std::abs(*std::max_element(f.begin(), f.end(), [](double a, double b) {
      return std::abs(a) < std::abs(b);
    }));
    for (int r = 0; r < m; ++r) {
      for (int c = 0; c < m; ++c) p.q[r] += p.W[r * m + c] * 1e-3 * f_max * std::sin(3.0 * c);
    }
    std::vector<double> f_cold(p.rows(), 0.0);
    const NsgsResult cold2 = solveNsgs(p.view(), s, ws, f_cold.data());
    const NsgsResult warm2 = solveNsgs(p.view(), s, ws, f.data());
    ASSERT_EQ(cold2.status, NsgsStatus::kConverged);
    ASSERT_EQ(warm2.status, NsgsStatus::kConverged);
    EXPECT_LE(warm2.sweeps, cold2.sweeps);
    std::printf("  %-32s cold %3d  unchanged %d  perturbed: cold %3d warm %3d\n", name,
                cold.sweeps, again.sweeps, cold2.sweeps, warm2.sweeps);
  }
}

FclibProblem boxStacks() { return test::fclibBoxStacks(TACTUS_TEST_DATA_DIR); }

TEST(NsgsSettingsTest, ACurrentDeltaSkipsTheEntryPassAndGivesTheSameSolution) {
  // the haptic loop's pattern: solve, shift delta_free, solve again with the exit delta shifted
  FclibProblem p = boxStacks();
  NsgsWorkspace ws(p.rows(), p.contacts);
  NsgsSettings s;
  s.tolerance = 1e-10;
  s.max_sweeps = 2000;
  std::vector<double> f(p.rows(), 0.0);
  ASSERT_EQ(solveNsgs(p.view(), s, ws, f.data()).status, NsgsStatus::kConverged);
  std::vector<double> shifted = p.q;
  for (std::size_t j = 0; j < shifted.size(); ++j) shifted[j] += 1e-3 * std::sin(0.7 * j);
  // reference: a fresh solve from the same warm start
  std::vector<double> f_ref = f;
  NsgsWorkspace ws_ref(p.rows(), p.contacts);
  ContactProblemView v = p.view();
  v.delta_free = shifted.data();
  ASSERT_EQ(solveNsgs(v, s, ws_ref, f_ref.data()).status, NsgsStatus::kConverged);
  // incremental: delta += shift, no entry pass
  for (std::size_t j = 0; j < shifted.size(); ++j) ws.delta[j] += shifted[j] - p.q[j];
  s.delta_is_current = true;
  ASSERT_EQ(solveNsgs(v, s, ws, f.data()).status, NsgsStatus::kConverged);
  for (std::size_t j = 0; j < f.size(); ++j) EXPECT_NEAR(f[j], f_ref[j], 1e-9);
  EXPECT_LE(naturalMapError(v, f.data()), 1e-10);
  // a wrong promise is not silently "converged" on the true problem: the exit error is that of
  // the delta it was given, so callers must keep the invariant (documented)
}

// An absolute deadline already past: no entry pass over W is started (kTimeBudget, f untouched);
// with W f + q current, no contact is visited either: the clock is looked at before every block
// of kDeadlineCheckContacts contacts, the first one included. With and without Anderson
// acceleration. (Before that look existed, a tick whose deadline had passed still solved 7
// contacts of a 900-row problem.) Then a deadline inside the first sweep stops it there, leaving
// a consistent iterate (delta = W f + q).
TEST(NsgsSettingsTest, APastDeadlineVisitsNoContactWithOrWithoutAnderson) {
  const FclibProblem p = boxStacks();
  ASSERT_GT(p.contacts, 2 * kDeadlineCheckContacts);
  for (const int depth : {0, kMaxAndersonDepth}) {
    SCOPED_TRACE(depth);
    NsgsWorkspace ws(p.rows(), p.contacts);
    NsgsSettings s;
    s.tolerance = 1e-12;
    s.max_sweeps = 1000;
    s.anderson_depth = depth;
    s.deadline_ns = 1;   // long past
    std::vector<double> f(p.rows(), 0.0);
    NsgsResult r = solveNsgs(p.view(), s, ws, f.data());
    EXPECT_EQ(r.status, NsgsStatus::kTimeBudget);
    EXPECT_EQ(r.sweeps, 0);
    EXPECT_EQ(std::count(f.begin(), f.end(), 0.0), static_cast<long>(f.size()));
    // delta = W f + q for f = 0 is q
    std::copy(p.q.begin(), p.q.end(), ws.delta.begin());
    s.delta_is_current = true;
    r = solveNsgs(p.view(), s, ws, f.data());
    EXPECT_EQ(r.status, NsgsStatus::kTimeBudget);
    EXPECT_EQ(r.sweeps, 0);
    EXPECT_EQ(std::count(f.begin(), f.end(), 0.0), static_cast<long>(f.size()));
    for (int j = 0; j < p.rows(); ++j) EXPECT_EQ(ws.delta[j], p.q[j]);
  }
}

// The clock solveNsgs reads (nsgs_clock.h) set to a scripted one for a scope.
struct ScopedNsgsClock {
  ScopedNsgsClock(NsgsClockFn clock, void* context) { setNsgsClockForTesting(clock, context); }
  ~ScopedNsgsClock() { setNsgsClockForTesting(nullptr, nullptr); }
  ScopedNsgsClock(const ScopedNsgsClock&) = delete;
  ScopedNsgsClock& operator=(const ScopedNsgsClock&) = delete;
};

// A scripted clock for solveNsgs (nsgs_clock.h): each read advances it by kTickNs; at the first read
// at or past `deadline_ns` it keeps a copy of f and delta, so a test can tell whether the solve
// wrote anything after it saw the deadline pass. Allocation-free (the copies are sized first).
struct ScriptedClock {
  static constexpr std::int64_t kTickNs = 1000;
  std::int64_t now_ns = 0;
  std::int64_t deadline_ns = 0;
  const double* f = nullptr;
  const double* delta = nullptr;
  std::vector<double> f_seen, delta_seen;
  bool passed = false;
  int reads = 0;
  static std::int64_t read(void* context) noexcept {
    auto& c = *static_cast<ScriptedClock*>(context);
    c.now_ns += kTickNs;
    ++c.reads;
    if (!c.passed && c.now_ns >= c.deadline_ns) {
      c.passed = true;
      std::copy(c.f, c.f + c.f_seen.size(), c.f_seen.begin());
      std::copy(c.delta, c.delta + c.delta_seen.size(), c.delta_seen.begin());
    }
    return c.now_ns;
  }
};

// Wherever the deadline falls (at every clock read of the solve in turn: inside a sweep, at its
// end, before an Anderson step or its restart, before the confirmation pass), once the solve has
// seen it pass it writes nothing more: f and delta = W f + q are returned as they were then, with
// kTimeBudget, and they are consistent. With and without Anderson acceleration, from zero and
// with W f + q current. Counts work (what was written), not time.
TEST(NsgsSettingsTest, NothingIsWrittenAfterTheDeadlineIsSeen) {
  const FclibProblem p = boxStacks();
  const int m = p.rows();
  int stopped = 0, anderson_stops = 0;
  for (const int depth : {0, kMaxAndersonDepth}) {
    for (const bool current : {false, true}) {
      for (int k = 1; k <= 100; ++k) {
        SCOPED_TRACE(testing::Message() << "depth " << depth << " current " << current
                                        << " deadline at read " << k);
        NsgsWorkspace ws(m, p.contacts);
        std::vector<double> f(static_cast<std::size_t>(m), 0.0);
        std::copy(p.q.begin(), p.q.end(), ws.delta.begin());   // W f + q for f = 0
        ScriptedClock clock;
        clock.deadline_ns = k * ScriptedClock::kTickNs;
        clock.f = f.data();
        clock.delta = ws.delta.data();
        clock.f_seen.assign(f.size(), 0.0);
        clock.delta_seen.assign(f.size(), 0.0);
        NsgsSettings s;
        s.tolerance = 1e-12;
        s.max_sweeps = 1000;
        s.anderson_depth = depth;
        s.delta_is_current = current;
        s.deadline_ns = clock.deadline_ns;
        const ScopedNsgsClock scripted(&ScriptedClock::read, &clock);
        const NsgsResult r = solveNsgs(p.view(), s, ws, f.data());
        ASSERT_TRUE(clock.passed);   // 1e-12 is not reached in 100 reads
        EXPECT_EQ(r.status, NsgsStatus::kTimeBudget);
        for (int j = 0; j < m; ++j) {
          ASSERT_EQ(f[j], clock.f_seen[j]) << "row " << j;
          ASSERT_EQ(ws.delta[j], clock.delta_seen[j]) << "row " << j;
        }
        std::vector<double> delta(f.size());
        (void)naturalMapError(p.view(), f.data(), delta.data());
        for (int j = 0; j < m; ++j) ASSERT_NEAR(ws.delta[j], delta[j], 1e-10) << "row " << j;
        ++stopped;
        anderson_stops += depth > 0 && r.sweeps > 2 ? 1 : 0;
      }
    }
  }
  EXPECT_EQ(stopped, 4 * 100);
  EXPECT_GT(anderson_stops, 50);    // the deadlines fell among Anderson steps too
}

// A clock that stands for the work done: each read advances it by one unit for the read and one
// per contact whose force changed since the previous read (an Anderson step that moves every
// contact costs as much as a sweep; a block of contacts its size). The solve's last read (its
// elapsed time, at every exit) therefore shows all the work it did.
struct WorkClock {
  std::int64_t now = 0;
  const double* f = nullptr;
  const int* row_offset = nullptr;
  int contacts = 0;
  std::vector<double> f_last;
  static std::int64_t read(void* context) noexcept {
    auto& c = *static_cast<WorkClock*>(context);
    c.now += 1;
    for (int i = 0; i < c.contacts; ++i) {
      bool changed = false;
      for (int r = c.row_offset[i]; r < c.row_offset[i + 1]; ++r) {
        changed = changed || c.f[r] != c.f_last[static_cast<std::size_t>(r)];
        c.f_last[static_cast<std::size_t>(r)] = c.f[r];
      }
      c.now += changed ? 1 : 0;
    }
    return c.now;
  }
};

// Wherever the deadline falls in the first sweeps (every unit of the work clock in turn), the
// work done past it is at most one block of kDeadlineCheckContacts contacts and the reads that
// stop the solve: never an Anderson step nor the start of a sweep before a look at the clock.
// With and without Anderson acceleration. (With Anderson depth 8 the tick's fallback used to mix
// every contact and solve 7 more after its last look at the clock, the whole step past the
// deadline when it fell just after a sweep's end.)
TEST(NsgsSettingsTest, WorkPastTheDeadlineIsAtMostOneBlockOfContacts) {
  const FclibProblem p = boxStacks();
  const int m = p.rows();
  constexpr std::int64_t kReads = 4;   // the stop's reads: sweep end, guard, elapsed (+1 spare)
  for (const int depth : {0, kMaxAndersonDepth}) {
    int anderson_steps_fitted = 0;
    for (std::int64_t deadline = 2; deadline <= 4 * p.contacts; ++deadline) {
      SCOPED_TRACE(testing::Message() << "depth " << depth << " deadline " << deadline);
      NsgsWorkspace ws(m, p.contacts);
      std::vector<double> f(static_cast<std::size_t>(m), 0.0);
      std::copy(p.q.begin(), p.q.end(), ws.delta.begin());   // W f + q for f = 0
      WorkClock clock;
      clock.f = f.data();
      clock.row_offset = p.row_offset.data();
      clock.contacts = p.contacts;
      clock.f_last.assign(f.size(), 0.0);
      NsgsSettings s;
      s.tolerance = 1e-14;
      s.max_sweeps = 1000;
      s.anderson_depth = depth;
      s.delta_is_current = true;
      s.deadline_ns = deadline;
      const ScopedNsgsClock scripted(&WorkClock::read, &clock);
      const NsgsResult r = solveNsgs(p.view(), s, ws, f.data());
      ASSERT_EQ(r.status, NsgsStatus::kTimeBudget);
      ASSERT_LE(clock.now - deadline, kDeadlineCheckContacts + kReads);
      anderson_steps_fitted += depth > 0 && r.sweeps >= 3 ? 1 : 0;
    }
    if (depth > 0) {
      EXPECT_GT(anderson_steps_fitted, 0);   // deadlines after mixed sweeps too
    }
  }
}

TEST(NsgsSettingsTest, MaxSweepsTimeBudgetAndCheckEvery) {
  const FclibProblem p = boxStacks();
  NsgsWorkspace ws(p.rows(), p.contacts);
  NsgsSettings s;
  s.tolerance = 1e-12;
  s.max_sweeps = 3;
  std::vector<double> f(p.rows(), 0.0);
  NsgsResult r = solveNsgs(p.view(), s, ws, f.data());
  EXPECT_EQ(r.status, NsgsStatus::kMaxSweeps);
  EXPECT_EQ(r.sweeps, 3);
  EXPECT_GT(r.error, s.tolerance);
  EXPECT_NEAR(r.error, naturalMapError(p.view(), f.data()), 1e-12);

  // a 1 ns budget is crossed by the first sweep, whatever the machine
  s.max_sweeps = 1000;
  s.time_budget_ns = 1;
  std::fill(f.begin(), f.end(), 0.0);
  r = solveNsgs(p.view(), s, ws, f.data());
  EXPECT_EQ(r.status, NsgsStatus::kTimeBudget);
  EXPECT_EQ(r.sweeps, 1);
  EXPECT_GT(r.elapsed_ns, 0);

  s.time_budget_ns = 0;
  s.tolerance = 1e-8;
  s.check_every = 7;
  std::fill(f.begin(), f.end(), 0.0);
  r = solveNsgs(p.view(), s, ws, f.data());
  EXPECT_EQ(r.status, NsgsStatus::kConverged);
  EXPECT_EQ(r.sweeps % 7, 0);
  EXPECT_LE(r.error, 1e-8);
}

TEST(NsgsSettingsTest, RowGatherAndOverRelaxationReachTheSameSolution) {
  const FclibProblem p = readFclibText(kFclibDir / "problems/Rover1040.fc3d.txt");
  NsgsWorkspace ws(p.rows(), p.contacts);
  NsgsSettings s;
  s.tolerance = 1e-11;
  std::vector<double> f_col(p.rows(), 0.0), f_row(p.rows(), 0.0), f_sor(p.rows(), 0.0);
  const NsgsResult col = solveNsgs(p.view(), s, ws, f_col.data());
  s.coupling = NsgsCoupling::kRowGather;
  const NsgsResult row = solveNsgs(p.view(), s, ws, f_row.data());
  s.coupling = NsgsCoupling::kColumnUpdate;
  s.sor = 0.8;
  const NsgsResult sor = solveNsgs(p.view(), s, ws, f_sor.data());
  ASSERT_EQ(col.status, NsgsStatus::kConverged);
  ASSERT_EQ(row.status, NsgsStatus::kConverged);
  ASSERT_EQ(sor.status, NsgsStatus::kConverged);
  EXPECT_NEAR(row.sweeps, col.sweeps, 1);  // same iterates up to rounding
  EXPECT_LE(diffNorm(f_col, f_row) / norm(f_col), 1e-8);
  EXPECT_LE(diffNorm(f_col, f_sor) / norm(f_col), 1e-6);  // Rover: r unique
}

TEST(NsgsSettingsTest, MixedOneAndThreeRowContacts) {
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0.0, 1.0);
  Problem p;
  p.row_offset = {0, 3, 4, 7, 8, 11};
  const int m = p.rows();
  const Eigen::MatrixXd a = randomSpd(m, rng);
  p.W.assign(a.data(), a.data() + m * m);
  for (int j = 0; j < m; ++j) p.q.push_back(g(rng) - 0.5);
  p.mu = {0.3, 0.0, 0.8, 0.0, 0.5};
  const Solved s = solve(p, tight());
  ASSERT_EQ(s.result.status, NsgsStatus::kConverged);
  EXPECT_LE(naturalMapError(p.view(), s.f.data()), 1e-13);
  // W is symmetric here: the row-update variant follows the same iterates
  NsgsSettings sym = tight();
  sym.coupling = NsgsCoupling::kSymmetricRowUpdate;
  const Solved s_sym = solve(p, sym);
  ASSERT_EQ(s_sym.result.status, NsgsStatus::kConverged);
  EXPECT_NEAR(s_sym.result.sweeps, s.result.sweeps, 1);
  EXPECT_LE(diffNorm(s_sym.f, s.f), 1e-10 * norm(s.f));
  for (int j : {3, 7}) {  // 1-row contacts: complementarity
    EXPECT_GE(s.f[j], 0.0);
    EXPECT_GE(s.u[j], -1e-12);
    EXPECT_NEAR(s.f[j] * s.u[j], 0.0, 1e-12);
  }
  // a perturbed force has a clearly positive error
  std::vector<double> bad = s.f;
  bad[0] += 0.1;
  EXPECT_GT(naturalMapError(p.view(), bad.data()), 1e-4);
}

// The symmetric sweep forms delta = W f + q from the rows of the contacts with a nonzero force
// only: warm-started with some contacts at zero, it must still give the column sweep's delta
// (the exact one, checked here) and converge to the same forces.
TEST(NsgsSettingsTest, SymmetricSweepFormsDeltaFromTheLoadedContactsRows) {
  std::mt19937 rng(23);
  std::normal_distribution<double> g(0.0, 1.0);
  Problem p;
  p.row_offset = {0, 3, 6, 9, 12, 15, 18};
  const int m = p.rows();
  const Eigen::MatrixXd a = randomSpd(m, rng);
  p.W.assign(a.data(), a.data() + m * m);
  for (int j = 0; j < m; ++j) p.q.push_back(g(rng) - 1.0);
  p.mu = {0.3, 0.8, 0.5, 0.6, 0.2, 0.9};
  // a warm start with contacts 1 and 4 at zero and the others loaded
  std::vector<double> warm(m, 0.0);
  for (int c : {0, 2, 3, 5}) warm[3 * c] = 0.5 + 0.1 * c;
  NsgsSettings one = tight();
  one.max_sweeps = 1;   // stops after one sweep: delta is the start's W f + q plus its updates
  NsgsSettings col = one;
  NsgsSettings sym = one;
  sym.coupling = NsgsCoupling::kSymmetricRowUpdate;
  const Solved c1 = solve(p, col, warm);
  const Solved s1 = solve(p, sym, warm);
  EXPECT_LE(diffNorm(c1.f, s1.f), 1e-12 * norm(c1.f));
  EXPECT_LE(diffNorm(c1.u, s1.u), 1e-12 * norm(c1.u));
  Eigen::VectorXd f1 = Eigen::Map<const Eigen::VectorXd>(s1.f.data(), m);
  const Eigen::VectorXd u1 = a * f1 + Eigen::Map<const Eigen::VectorXd>(p.q.data(), m);
  for (int j = 0; j < m; ++j) EXPECT_NEAR(s1.u[j], u1[j], 1e-12 * u1.norm()) << j;
  const Solved cs = solve(p, tight(), warm);
  NsgsSettings sym_tight = tight();
  sym_tight.coupling = NsgsCoupling::kSymmetricRowUpdate;
  const Solved ss = solve(p, sym_tight, warm);
  ASSERT_EQ(cs.result.status, NsgsStatus::kConverged);
  ASSERT_EQ(ss.result.status, NsgsStatus::kConverged);
  EXPECT_LE(diffNorm(cs.f, ss.f), 1e-10 * norm(cs.f));
}

// ---------------------------------------------------------------- faults

TEST(NsgsFaults, NonFiniteInputZeroesTheForce) {
  const FclibProblem base = readFclibText(kFclibDir / "problems/Rover1040.fc3d.txt");
  NsgsWorkspace ws(base.rows(), base.contacts);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  for (int which = 0; which < 4; ++which) {
    FclibProblem p = base;
    std::vector<double> f(p.rows(), 1.0);
    if (which == 0) p.W[5 * p.rows() + 7] = nan;
    if (which == 1) p.q[4] = inf;
    if (which == 2) p.mu[1] = nan;
    if (which == 3) f[2] = nan;
    const NsgsResult r = solveNsgs(p.view(), NsgsSettings{}, ws, f.data());
    EXPECT_EQ(r.status, NsgsStatus::kNonFinite) << "case " << which;
    for (double v : f) EXPECT_EQ(v, 0.0) << "case " << which;
    EXPECT_FALSE(std::isfinite(r.error));
  }
}

// A zero, negative, denormal or negligible diagonal entry of W cannot be divided by: such a
// problem must never come back kConverged, and its error must be the real one.
TEST(NsgsFaults, IllPosedDiagonalIsNeverReportedConverged) {
  const FclibProblem base = readFclibText(kFclibDir / "problems/Rover1040.fc3d.txt");
  const int m = base.rows();
  NsgsWorkspace ws(m, base.contacts);
  // the contact whose free normal velocity is the most negative (it must push)
  int worst = 0;
  for (int i = 1; i < base.contacts; ++i) {
    if (base.q[base.row_offset[i]] < base.q[base.row_offset[worst]]) worst = i;
  }
  const int r = base.row_offset[worst];
  ASSERT_LT(base.q[r], 0.0);
  const double denormal = std::numeric_limits<double>::denorm_min() * 1e3;
  ASSERT_EQ(std::fpclassify(denormal), FP_SUBNORMAL);
  const double diag_cases[] = {0.0, -1.0, -1e-9, denormal, 1e-20 * base.W[r * m + r]};
  for (int row = 0; row < 3; ++row) {
    for (double d : diag_cases) {
      FclibProblem p = base;
      p.W[(r + row) * m + r + row] = d;
      for (bool warm : {false, true}) {
        std::vector<double> f(m, warm ? 0.5 : 0.0);
        const NsgsResult res = solveNsgs(p.view(), NsgsSettings{}, ws, f.data());
        SCOPED_TRACE(::testing::Message() << "row " << row << " diag " << d << " warm " << warm);
        EXPECT_EQ(res.status, NsgsStatus::kIllPosed);
        EXPECT_EQ(res.ill_posed_contacts, 1);
        for (int k = 0; k < 3; ++k) EXPECT_EQ(f[r + k], 0.0);
        // the error reported is the real one, and the unsolvable contact keeps it large
        const double real = naturalMapError(p.view(), f.data());
        EXPECT_NEAR(res.error, real, 1e-9 * real);
        EXPECT_GT(res.error, 1e-3);
      }
    }
  }
  EXPECT_EQ(toString(NsgsStatus::kIllPosed), "ill_posed");
  // non-finite diagonal entries stay kNonFinite (f zeroed)
  FclibProblem p = base;
  p.W[r * m + r] = std::numeric_limits<double>::infinity();
  std::vector<double> f(m, 0.0);
  EXPECT_EQ(solveNsgs(p.view(), NsgsSettings{}, ws, f.data()).status, NsgsStatus::kNonFinite);
  // the unmodified problem is well posed and converges, with its real error
  f.assign(m, 0.0);
  const NsgsResult ok = solveNsgs(base.view(), NsgsSettings{}, ws, f.data());
  EXPECT_EQ(ok.status, NsgsStatus::kConverged);
  EXPECT_EQ(ok.ill_posed_contacts, 0);
  EXPECT_LE(naturalMapError(base.view(), f.data()), NsgsSettings{}.tolerance);
}

// One-row contacts too: a zero or negative W_ii is ill-posed, frictionless 3-row contacts only
// look at W_nn.
TEST(NsgsFaults, IllPosedOneRowAndFrictionlessContacts) {
  Problem p;
  p.row_offset = {0, 1, 4};
  p.W = {0.0, 0.0, 0.0, 0.0,
         0.0, 2.0, 0.0, 0.0,
         0.0, 0.0, 0.0, 0.0,    // W_t1t1 = 0, harmless when mu = 0
         0.0, 0.0, 0.0, 0.0};
  p.q = {-1.0, -1.0, 0.3, 0.0};
  p.mu = {0.0, 0.0};
  Solved s = solve(p);
  EXPECT_EQ(s.result.status, NsgsStatus::kIllPosed);
  EXPECT_EQ(s.result.ill_posed_contacts, 1);
  EXPECT_EQ(s.f[0], 0.0);
  EXPECT_NEAR(s.f[1], 0.5, 1e-12);   // the well-posed contact is still solved
  EXPECT_NEAR(s.result.error, naturalMapError(p.view(), s.f.data()), 1e-12);
  EXPECT_GT(s.result.error, 0.1);
  p.W[0] = 1.0;
  s = solve(p);
  EXPECT_EQ(s.result.status, NsgsStatus::kConverged);
  EXPECT_NEAR(s.f[0], 1.0, 1e-12);
  p.mu[1] = 0.5;   // now the zero tangential diagonal matters
  s = solve(p);
  EXPECT_EQ(s.result.status, NsgsStatus::kIllPosed);
}

TEST(NsgsFaults, ProblemsLargerThanTheWorkspaceOrInconsistentAreRefused) {
  const FclibProblem p = boxStacks();
  NsgsWorkspace small(p.rows() - 3, p.contacts);
  std::vector<double> f(p.rows(), 0.25);
  EXPECT_EQ(solveNsgs(p.view(), NsgsSettings{}, small, f.data()).status, NsgsStatus::kEmpty);
  for (double v : f) EXPECT_EQ(v, 0.25);  // untouched
  NsgsWorkspace ws(p.rows(), p.contacts);
  ContactProblemView bad = p.view();
  bad.ld = p.rows() - 1;
  EXPECT_EQ(solveNsgs(bad, NsgsSettings{}, ws, f.data()).status, NsgsStatus::kEmpty);
  std::vector<int> offsets = p.row_offset;
  offsets[1] = 2;  // a 2-row contact
  bad = p.view();
  bad.row_offset = offsets.data();
  EXPECT_EQ(solveNsgs(bad, NsgsSettings{}, ws, f.data()).status, NsgsStatus::kEmpty);
  bad = p.view();
  bad.contacts = 0;
  EXPECT_EQ(solveNsgs(bad, NsgsSettings{}, ws, f.data()).status, NsgsStatus::kEmpty);
  EXPECT_EQ(toString(NsgsStatus::kEmpty), "empty");
}

// ---------------------------------------------------------------- real-time: no allocation

TEST(NsgsRealtime, SolveAndErrorNeverAllocate) {
  const FclibProblem p = boxStacks();
  NsgsWorkspace ws(p.rows() + 30, p.contacts + 10);  // a larger capacity than needed
  std::vector<double> f(p.rows(), 0.0), delta(p.rows(), 0.0);
  NsgsSettings s;
  s.time_budget_ns = 1'000'000'000;

  // the counter sees allocations (else the test below could not fail)
  {
    const tactus::test::AllocScope probe;
    auto* v = new std::vector<double>(100);
    delete v;
    ASSERT_GE(probe.allocations(), 1);
  }

  const tactus::test::AllocScope scope;
  const NsgsResult cold = solveNsgs(p.view(), s, ws, f.data());
  const NsgsResult warm = solveNsgs(p.view(), s, ws, f.data());
  s.coupling = NsgsCoupling::kRowGather;
  s.sor = 1.2;
  const NsgsResult other = solveNsgs(p.view(), s, ws, f.data());
  const double e1 = naturalMapError(p.view(), f.data());
  const double e2 = naturalMapError(p.view(), f.data(), delta.data());
  EXPECT_EQ(scope.allocations(), 0);
  EXPECT_EQ(cold.status, NsgsStatus::kConverged);
  EXPECT_EQ(warm.status, NsgsStatus::kConverged);
  EXPECT_EQ(other.status, NsgsStatus::kConverged);
  EXPECT_NEAR(e1, e2, 1e-15);
}

}  // namespace
}  // namespace tactus::shared
