// PCG's preconditioner solve (CholmodSolver::solvePreconditioner), which the factor-reuse
// strategy runs once per PCG iteration: the supernodal forward and backward sweeps over the
// whole factor, in double, over the float copy and over the half-precision copy (HalfFactor,
// with the kernel this CPU runs, its name the label; TACTUS_HALF_SWEEP_KERNEL=generic|f16c|avx512
// picks another). The matrix has the free-motion system's pattern on liver_grasp_23k (a 3x3
// block per pair of free nodes sharing a tet, liver_23k_repaired.msh placed and fixed as the
// scene does) and diagonally dominant values: the sweeps' cost follows the pattern alone. Small:
// a 12 x 6 x 6 box (the smoke test).
//   build/tests/bench/preconditioner_bench
#include <benchmark/benchmark.h>

#include <Eigen/SparseCore>
#include <filesystem>
#include <map>
#include <memory>
#include <vector>

#include "../../sim_server/src/fem/linear_solver.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/mesh_gen.h"
#include "tactus/sim/scene.h"

namespace tactus::sim::fem_detail {
namespace {

// The lower triangle of a matrix with the step matrix's pattern over the mesh's free nodes
// (`fixed` left out, the others numbered in order).
CholmodSolver::Sparse patternLower(const TetMesh& mesh, const std::vector<int>& fixed) {
  std::vector<int> index(static_cast<std::size_t>(mesh.nodeCount()), 0);
  for (int i : fixed) index[static_cast<std::size_t>(i)] = -1;
  int n = 0;
  for (int& f : index)
    if (f == 0) f = n++;
  std::vector<double> degree(static_cast<std::size_t>(n), 0.0);
  std::vector<Eigen::Triplet<double, int>> t;
  for (const auto& tet : mesh.tets)
    for (int a : tet)
      for (int b : tet) {
        const int i = index[static_cast<std::size_t>(a)], j = index[static_cast<std::size_t>(b)];
        if (i <= j || j < 0) continue;
        degree[static_cast<std::size_t>(i)] += 1.0;
        degree[static_cast<std::size_t>(j)] += 1.0;
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) t.emplace_back(3 * i + r, 3 * j + c, r == c ? -1.0 : -0.1);
      }
  for (int i = 0; i < n; ++i)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c <= r; ++c)
        t.emplace_back(3 * i + r, 3 * i + c,
                       r == c ? 1.5 * degree[static_cast<std::size_t>(i)] + 1.0 : 0.05);
  CholmodSolver::Sparse a(3 * n, 3 * n);
  a.setFromTriplets(t.begin(), t.end());
  a.makeCompressed();
  return a;
}

CholmodSolver::Sparse liverPatternLower() {
  const SceneSpec spec =
      loadScene(std::filesystem::path(TACTUS_SOURCE_DIR) / "scenes" / "liver_grasp_23k.yaml");
  const TissueSpec& ts = spec.tissues.at(0);
  TetMesh mesh = loadTetMesh(ts.mesh_path);
  transformMesh(mesh, ts.scale, ts.rotation_deg, ts.translation_m);
  return patternLower(mesh, nodesInBoxes(mesh, ts.fixed_boxes));
}

CholmodSolver::Sparse smallPatternLower() {
  return patternLower(makeBoxTetMesh(12, 6, 6, Eigen::Vector3d(0.12, 0.06, 0.06)), {});
}

// Arg 0: 0 the double sweeps (solve), 1 the float copy's, 2 the half copy's
void preconditionerSolve(benchmark::State& state, CholmodSolver::Sparse (*matrix)()) {
  static std::map<std::pair<CholmodSolver::Sparse (*)(), int>, std::unique_ptr<CholmodSolver>>
      solvers;
  const int precision = static_cast<int>(state.range(0));
  auto& solver = solvers[{matrix, precision}];
  static std::map<CholmodSolver::Sparse (*)(), CholmodSolver::Sparse> matrices;
  if (!matrices.count(matrix)) matrices[matrix] = matrix();
  CholmodSolver::Sparse& a = matrices[matrix];
  if (!solver) {
    solver = std::make_unique<CholmodSolver>();
    solver->setBlasFreeSolves(true);
    if (precision == 1) solver->setSinglePrecisionPreconditioner(true);
    if (precision == 2) solver->setHalfPrecisionPreconditioner(true);
    solver->analyze(a);
    if (!solver->factorize(a)) {
      state.SkipWithError("the matrix is not positive definite");
      return;
    }
    solver->prepareSolveWorkspaces();
  }
  if (precision == 2 && !solver->holdsHalfPrecisionCopy()) {
    state.SkipWithError("no half-precision copy (not supernodal, or beyond half's range)");
    return;
  }
  Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(a.rows(), -1.0, 1.0), x(a.rows());
  for (auto _ : state) {
    solver->solvePreconditioner(b.data(), x.data());
    benchmark::DoNotOptimize(x.data());
  }
  state.counters["factor_nnz"] = static_cast<double>(solver->factorNonzeros());
  state.SetLabel(precision == 0 ? "double" : precision == 1 ? "float"
                                                            : std::string("half, ") +
                                                                  halfSweepKernelName());
}

void BM_PreconditionerSolve_Liver23k(benchmark::State& state) {
  preconditionerSolve(state, &liverPatternLower);
}
void BM_PreconditionerSolve_Small(benchmark::State& state) {
  preconditionerSolve(state, &smallPatternLower);
}
BENCHMARK(BM_PreconditionerSolve_Liver23k)->DenseRange(0, 2)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_PreconditionerSolve_Small)->DenseRange(0, 2)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace tactus::sim::fem_detail

BENCHMARK_MAIN();
