// The element loop's batched kernels (fem_assembly.cpp) against its reference constitutive step:
// the same forces, system matrix and rotations on a deformed, turned and moving liver; the AVX
// and generic kernels give the same bits; the warm-started rotations equal the robust polar
// decomposition's; elements the batches cannot finish (inverted, flat, a half turn from their
// last rotation) go through the reference path.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>
#include <random>
#include <string>

#include "../../../sim_server/src/fem/fem_internal.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim {
namespace {

// Switches the element kernel for one scope and restores the process's own afterwards.
class KernelScope {
 public:
  explicit KernelScope(const char* name) : previous_(femElementKernelName()) {
    ok_ = setFemElementKernel(name);
  }
  ~KernelScope() { setFemElementKernel(previous_.c_str()); }
  bool ok() const { return ok_; }

 private:
  std::string previous_;
  bool ok_ = false;
};

TetMesh elementLoopLiver() {
  TetMesh mesh = loadTetMesh(std::filesystem::path(TACTUS_TEST_DATA_DIR) / "meshes" / "liver2.msh");
  transformMesh(mesh, 0.1, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero());
  return mesh;
}

FemMaterial elementLoopMaterial() {
  FemMaterial m;
  m.law = MaterialLaw::kCorotational;
  m.young_pa = 3000.0;
  m.poisson = 0.45;
  m.density_kgpm3 = 1000.0;
  m.damping = RayleighSpec{0.1, 0.01};
  return m;
}

std::vector<int> lowestX(const TetMesh& mesh, int count) {
  std::vector<std::pair<double, int>> by_x;
  for (int i = 0; i < mesh.nodeCount(); ++i) by_x.emplace_back(mesh.nodes(0, i), i);
  std::sort(by_x.begin(), by_x.end());
  std::vector<int> out;
  for (int i = 0; i < count; ++i) out.push_back(by_x[static_cast<std::size_t>(i)].second);
  return out;
}

// The liver turned by 40 deg, bent (a position-dependent rotation up to 0.5 rad more), squashed,
// with random velocities: the elements' rotations differ from one another and from identity.
void deform(FemBody& body, unsigned seed) {
  const TetMesh& mesh = body.mesh();
  const Eigen::Vector3d centre = mesh.nodes.rowwise().mean();
  const Eigen::Matrix3d base =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, -1).normalized()).toRotationMatrix();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < mesh.nodeCount(); ++i) {
    const Eigen::Vector3d p = mesh.nodes.col(i) - centre;
    const Eigen::Matrix3d bend =
        Eigen::AngleAxisd(5.0 * p.x(), Eigen::Vector3d::UnitZ()).toRotationMatrix();
    body.positions().segment<3>(3 * i) =
        centre + base * bend * Eigen::Vector3d(p.x(), p.y(), 0.85 * p.z());
    body.velocities().segment<3>(3 * i) = 0.05 * Eigen::Vector3d(u(rng), u(rng), u(rng));
  }
}

FemSolverOptions direct() {
  FemSolverOptions o;
  o.linear = LinearSolverKind::kCholmod;
  return o;
}

struct StepOutcome {
  Eigen::VectorXd q, v, force, compliance;
  std::vector<Eigen::Matrix3d> rotations;
  long fallbacks = 0;
};

// Three free motions from the deformed state under gravity with `kernel`; then the elastic
// force and one compliance solve (which reads the last step's A).
StepOutcome run(const char* kernel) {
  KernelScope scope(kernel);
  EXPECT_TRUE(scope.ok()) << kernel;
  const TetMesh mesh = elementLoopLiver();
  const Eigen::Vector3d gravity(0, 0, -9.81);
  FemBody body(mesh, elementLoopMaterial(), lowestX(mesh, 30), &gravity, direct());
  deform(body, 7);
  for (int s = 0; s < 3; ++s) EXPECT_TRUE(body.freeMotion(0.01).ok);
  StepOutcome out;
  out.q = body.positions();
  out.v = body.velocities();
  body.elasticForce(body.positions(), out.force);
  Eigen::VectorXd r = Eigen::VectorXd::Zero(body.dofCount());
  for (int i = 0; i < body.dofCount(); ++i) r[i] = std::sin(0.37 * i);
  body.solveCompliance(r, out.compliance);
  out.rotations = body.elementRotations();
  out.fallbacks = body.counters().fallback_elements;
  return out;
}

double relDiff(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return (a - b).norm() / std::max(b.norm(), 1e-300);
}

TEST(ElementLoop, BatchedKernelMatchesTheReferenceStep) {
  const StepOutcome ref = run("reference");
  const StepOutcome batched = run("generic");
  EXPECT_LT(relDiff(batched.force, ref.force), 1e-11);
  EXPECT_LT(relDiff(batched.compliance, ref.compliance), 1e-11);
  EXPECT_LT(relDiff(batched.q, ref.q), 1e-13);
  EXPECT_LT(relDiff(batched.v, ref.v), 1e-10);
  double worst = 0.0;
  for (std::size_t e = 0; e < ref.rotations.size(); ++e)
    worst = std::max(worst, (batched.rotations[e] - ref.rotations[e]).norm());
  EXPECT_LT(worst, 1e-12);
  // the turned start: the first step's warm start (identity) is 0.7 rad and more off, so some
  // elements need the reference path; later steps start from their own rotation
  std::printf("elements left to the reference path over 3 steps and a force query: %ld of %zu "
              "per loop\n", batched.fallbacks, ref.rotations.size());
  EXPECT_LT(batched.fallbacks, static_cast<long>(4 * ref.rotations.size()));
}

TEST(ElementLoop, AvxAndGenericKernelsGiveTheSameBits) {
  {
    KernelScope probe("avx");
    if (!probe.ok()) GTEST_SKIP() << "this CPU has no AVX: the generic kernel alone runs";
  }
  const StepOutcome avx = run("avx");
  const StepOutcome generic = run("generic");
  EXPECT_EQ(avx.q, generic.q);
  EXPECT_EQ(avx.v, generic.v);
  EXPECT_EQ(avx.force, generic.force);
  EXPECT_EQ(avx.compliance, generic.compliance);
  EXPECT_EQ(avx.fallbacks, generic.fallbacks);
}

TEST(ElementLoop, WarmStartedRotationsArePolarFactors) {
  const TetMesh mesh = elementLoopLiver();
  FemBody body(mesh, elementLoopMaterial(), lowestX(mesh, 30), nullptr, direct());
  deform(body, 3);
  body.velocities().setZero();   // the loop then evaluates at q: F is the test's own
  ASSERT_TRUE(body.freeMotion(0.01).ok);   // cold start (identity): many fall back
  body.positions() = body.positions() - 0.01 * body.velocities();   // back to the loop's q
  body.velocities().setZero();
  const long before = body.counters().fallback_elements;
  const Eigen::VectorXd q = body.positions();
  ASSERT_TRUE(body.freeMotion(0.01).ok);   // warm: every element from its own last rotation
  EXPECT_LT(body.counters().fallback_elements - before, mesh.tetCount() / 100 + 1);
  const std::vector<Eigen::Matrix3d>& rot = body.elementRotations();
  double worst = 0.0;
  for (int e = 0; e < mesh.tetCount(); ++e) {
    const auto& t = mesh.tets[static_cast<std::size_t>(e)];
    Eigen::Matrix3d dm, dx;
    for (int k = 0; k < 3; ++k) {
      dm.col(k) = mesh.nodes.col(t[k + 1]) - mesh.nodes.col(t[0]);
      dx.col(k) = q.segment<3>(3 * t[k + 1]) - q.segment<3>(3 * t[0]);
    }
    const Eigen::Matrix3d f = dx * dm.inverse();
    worst = std::max(worst, (rot[static_cast<std::size_t>(e)] - fem_detail::polarRotation(f)).norm());
    EXPECT_LT((rot[static_cast<std::size_t>(e)].transpose() * rot[static_cast<std::size_t>(e)] -
               Eigen::Matrix3d::Identity()).norm(), 1e-13);
  }
  EXPECT_LT(worst, 1e-11);
}

TEST(ElementLoop, InvertedAndHalfTurnedElementsTakeTheReferencePath) {
  // one tet: its rotation a half turn from identity (a saddle of tr(R^T F) the Newton steps
  // cannot leave), then inverted; the reference path gives the force either way
  TetMesh mesh;
  mesh.nodes.resize(3, 4);
  mesh.nodes << 0, 0.01, 0, 0, 0, 0, 0.01, 0, 0, 0, 0, 0.01;
  mesh.tets = {{0, 1, 2, 3}};
  for (const char* kernel : {"generic", "reference"}) {
    KernelScope scope(kernel);
    FemBody body(mesh, elementLoopMaterial(), {}, nullptr, direct());
    const Eigen::Matrix3d half = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();
    Eigen::VectorXd q(12), f;
    for (int i = 0; i < 4; ++i) q.segment<3>(3 * i) = half * mesh.nodes.col(i);
    body.elasticForce(q, f);
    EXPECT_LT(f.norm(), 1e-12) << kernel;   // a rigid half turn carries no force
    for (int i = 0; i < 4; ++i) q.segment<3>(3 * i) = mesh.nodes.col(i);
    q.segment<3>(9) = Eigen::Vector3d(0, 0, -0.004);   // node 3 through the opposite face
    body.elasticForce(q, f);
    EXPECT_GT(f[11], 0.0) << kernel;   // pushed back out
  }
}

}  // namespace
}  // namespace tactus::sim
