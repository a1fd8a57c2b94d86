// FEM free motion (one implicit Euler step) on the livers for every linear strategy (CHOLMOD,
// PCG with each preconditioner, PCG on a reused CHOLMOD factor), with the per-stage breakdown as
// counters (assembly_ms and assembly_ns_per_tet, factor_ms, solve_ms, cg_iters, refresh_frac: the
// fraction of steps that factorised); warped-compliance precompute and W build for 450 rows.
//   build/tests/bench/fem_bench --benchmark_filter=FemStep_Liver
// OpenBLAS 0.3.21 does not recognise this VM's CPU and falls back to SSE3 kernels: export
// OPENBLAS_CORETYPE=SkylakeX (or Haswell) for the large factorisations.
#include <benchmark/benchmark.h>

#include <Eigen/Geometry>
#include <filesystem>
#include <map>
#include <memory>
#include <random>

#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {
namespace {

const double kH = 0.01;

/// Compliance options for kH without the progress bar.
ComplianceOptions quietOptions() {
  ComplianceOptions o;
  o.h_s = kH;
  o.show_progress = false;
  return o;
}

TetMesh loadLiver(const char* name) {
  static std::map<std::string, TetMesh> cache;
  auto it = cache.find(name);
  if (it != cache.end()) return it->second;
  TetMesh mesh = loadTetMesh(std::filesystem::path(TACTUS_TEST_DATA_DIR) / "meshes" / name);
  transformMesh(mesh, 0.1, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero());  // dm -> m
  cache[name] = mesh;
  return mesh;
}

// The small box the "Small" rows run on (6 x 3 x 3 cells, 12 x 6 x 6 cm).
const TetMesh& smallBox() {
  static const TetMesh mesh = makeBoxTetMesh(6, 3, 3, Eigen::Vector3d(0.12, 0.06, 0.06));
  return mesh;
}

std::vector<int> lowestX(const TetMesh& mesh, int count) {
  std::vector<std::pair<double, int>> by_x;
  for (int i = 0; i < mesh.nodeCount(); ++i) by_x.emplace_back(mesh.nodes(0, i), i);
  std::sort(by_x.begin(), by_x.end());
  std::vector<int> out;
  for (int i = 0; i < count && i < mesh.nodeCount(); ++i) out.push_back(by_x[i].second);
  return out;
}

std::unique_ptr<FemBody> makeBody(const TetMesh& mesh, LinearSolverKind solver,
                                  PcgPreconditioner pre, int fixed, double cg_tolerance = 1e-6) {
  FemMaterial mat;
  mat.law = MaterialLaw::kCorotational;
  mat.young_pa = 3000.0;
  mat.poisson = 0.45;
  mat.density_kgpm3 = 1000.0;
  mat.damping = RayleighSpec{0.1, 0.01};
  FemSolverOptions opt;
  opt.linear = solver;
  opt.pcg_preconditioner = pre;
  opt.cg_tolerance = cg_tolerance;
  opt.cg_max_iterations = 1000;
  static const Eigen::Vector3d gravity(0, 0, -9.81);
  return std::make_unique<FemBody>(mesh, mat, lowestX(mesh, fixed), &gravity, opt);
}

// The reuse strategy runs at the scenes' default tolerance (1e-8); the fixed-preconditioner PCG
// rows keep their historical 1e-6.
void runStep(benchmark::State& state, const TetMesh& mesh, LinearSolverKind solver,
             PcgPreconditioner pre = PcgPreconditioner::kJacobi) {
  const double tol = solver == LinearSolverKind::kCholmodReuse ? 1e-8 : 1e-6;
  auto body = makeBody(mesh, solver, pre, std::max(4, mesh.nodeCount() / 30), tol);
  for (int s = 0; s < 5; ++s) body->freeMotion(kH);  // sagging, rotated state
  double assembly = 0, factor = 0, solve = 0, iters = 0, refreshes = 0;
  for (auto _ : state) {
    const FemStepStats st = body->freeMotion(kH);
    if (!st.ok) state.SkipWithError("step failed");
    assembly += st.assembly_s;
    factor += st.factorisation_s;
    solve += st.solve_s;
    iters += st.cg_iterations;
    refreshes += st.factor_refreshed ? 1.0 : 0.0;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["assembly_ms"] = 1e3 * assembly / n;
  state.counters["assembly_ns_per_tet"] = 1e9 * assembly / n / mesh.tetCount();
  state.counters["factor_ms"] = 1e3 * factor / n;
  state.counters["solve_ms"] = 1e3 * solve / n;
  state.counters["cg_iters"] = iters / n;
  if (solver == LinearSolverKind::kCholmodReuse) state.counters["refresh_frac"] = refreshes / n;
  state.counters["dofs"] = body->freeDofCount();
  state.counters["tets"] = mesh.tetCount();
  if (solver != LinearSolverKind::kPcg)
    state.counters["factor_nnz"] = static_cast<double>(body->factorNonzeros());
}

void BM_FemStep_Small(benchmark::State& state) {
  runStep(state, smallBox(), LinearSolverKind::kCholmod);
}
void BM_FemStep_Small_Pcg(benchmark::State& state) {
  runStep(state, smallBox(), LinearSolverKind::kPcg);
}
void BM_FemStep_Liver2_Cholmod(benchmark::State& s) {
  runStep(s, loadLiver("liver2.msh"), LinearSolverKind::kCholmod);
}
void BM_FemStep_Liver2_PcgJacobi(benchmark::State& s) {
  runStep(s, loadLiver("liver2.msh"), LinearSolverKind::kPcg, PcgPreconditioner::kJacobi);
}
void BM_FemStep_Liver2_PcgRestChol(benchmark::State& s) {
  runStep(s, loadLiver("liver2.msh"), LinearSolverKind::kPcg, PcgPreconditioner::kRestCholesky);
}
void BM_FemStep_Liver23k_Cholmod(benchmark::State& s) {
  runStep(s, loadLiver("liver_23k.msh"), LinearSolverKind::kCholmod);
}
void BM_FemStep_Liver23k_PcgJacobi(benchmark::State& s) {
  runStep(s, loadLiver("liver_23k.msh"), LinearSolverKind::kPcg, PcgPreconditioner::kJacobi);
}
void BM_FemStep_Liver23k_PcgRestChol(benchmark::State& s) {
  runStep(s, loadLiver("liver_23k.msh"), LinearSolverKind::kPcg,
          PcgPreconditioner::kRestCholesky);
}
void BM_FemStep_Small_CholmodReuse(benchmark::State& state) {
  runStep(state, smallBox(), LinearSolverKind::kCholmodReuse);
}
void BM_FemStep_Liver2_CholmodReuse(benchmark::State& s) {
  runStep(s, loadLiver("liver2.msh"), LinearSolverKind::kCholmodReuse);
}
void BM_FemStep_Liver23k_CholmodReuse(benchmark::State& s) {
  runStep(s, loadLiver("liver_23k.msh"), LinearSolverKind::kCholmodReuse);
}
void BM_FemStep_Liver2_PcgWarpedChol(benchmark::State& s) {
  runStep(s, loadLiver("liver2.msh"), LinearSolverKind::kPcg, PcgPreconditioner::kWarpedCholesky);
}
void BM_FemStep_Liver23k_PcgWarpedChol(benchmark::State& s) {
  runStep(s, loadLiver("liver_23k.msh"), LinearSolverKind::kPcg,
          PcgPreconditioner::kWarpedCholesky);
}
// The scene's own tissue (material, damping, fixed box, gravity, h) settling from rest under
// gravity: the first second of the liver_grasp scenes, 100 steps from the rest shape (each
// repetition starts again from rest). The stages are averaged over the 100 steps.
// The tissue's element and law as the scene chose them (kScene), or changed to one of the
// alternatives a scene may choose (material.tangent, material.law, element).
enum class TissueVariant { kScene, kConsistentTangent, kInvertibleLaw, kEdgeSmoothed };

void runScene(benchmark::State& state, const char* scene, LinearSolverKind solver,
              TissueVariant variant = TissueVariant::kScene) {
  SceneSpec spec = loadScene(std::filesystem::path(TACTUS_SOURCE_DIR) / "scenes" / scene);
  TissueSpec& ts = spec.tissues.at(0);
  if (variant == TissueVariant::kConsistentTangent) ts.tangent = TangentKind::kConsistent;
  if (variant == TissueVariant::kInvertibleLaw) ts.law = MaterialLaw::kInvertibleNeoHookean;
  if (variant == TissueVariant::kEdgeSmoothed) ts.element = ElementKind::kEdgeSmoothedTet;
  TetMesh mesh = loadTetMesh(ts.mesh_path);
  transformMesh(mesh, ts.scale, ts.rotation_deg, ts.translation_m);
  const FemMaterial mat = femMaterial(ts);
  FemSolverOptions opt = femSolverOptions(spec.solver);
  opt.linear = solver;
  const Eigen::Vector3d gravity = spec.gravity_mps2.value_or(Eigen::Vector3d::Zero());
  const double h = spec.time_step_s;
  constexpr int kSteps = 100;
  double assembly = 0, factor = 0, solve = 0, iters = 0, refreshes = 0, steps = 0;
  for (auto _ : state) {
    FemBody body(mesh, mat, nodesInBoxes(mesh, ts.fixed_boxes), &gravity, opt);
    for (int s = 0; s < kSteps; ++s) {
      const FemStepStats st = body.freeMotion(h);
      if (!st.ok) state.SkipWithError("step failed");
      assembly += st.assembly_s;
      factor += st.factorisation_s;
      solve += st.solve_s;
      iters += st.cg_iterations;
      refreshes += st.factor_refreshed ? 1.0 : 0.0;
      steps += 1.0;
    }
  }
  state.counters["step_ms"] = 1e3 * (assembly + factor + solve) / steps;
  state.counters["assembly_ms"] = 1e3 * assembly / steps;
  state.counters["assembly_ns_per_tet"] = 1e9 * assembly / steps / mesh.tetCount();
  state.counters["factor_ms"] = 1e3 * factor / steps;
  state.counters["solve_ms"] = 1e3 * solve / steps;
  state.counters["cg_iters"] = iters / steps;
  if (solver == LinearSolverKind::kCholmodReuse) state.counters["refresh_frac"] = refreshes / steps;
}
void BM_Settle_Liver2_Cholmod(benchmark::State& s) {
  runScene(s, "liver_grasp.yaml", LinearSolverKind::kCholmod);
}
void BM_Settle_Liver2_CholmodReuse(benchmark::State& s) {
  runScene(s, "liver_grasp.yaml", LinearSolverKind::kCholmodReuse);
}
void BM_Settle_Liver23k_Cholmod(benchmark::State& s) {
  runScene(s, "liver_grasp_23k.yaml", LinearSolverKind::kCholmod);
}
void BM_Settle_Liver23k_CholmodReuse(benchmark::State& s) {
  runScene(s, "liver_grasp_23k.yaml", LinearSolverKind::kCholmodReuse);
}
// The factor solves of the liver_grasp_23k scene's system matrix (its tissue, settled 5 steps
// from rest), through solveComplianceBatch (reduce, CHOLMOD solve, expand): Arg 0 = 0 the
// supernodal factor solved by CHOLMOD (its BLAS path: a synchronous refresh's), 1 the same
// factor solved without BLAS as the background refresh solves it on the step's thread
// (CholmodSolver::setBlasFreeSolves); Arg 1: right-hand sides per solve (1: a PCG
// preconditioner solve).
//   fem_bench --benchmark_filter=FactorSolve
void BM_FactorSolve_Liver23k(benchmark::State& state) {
  static std::map<int, std::unique_ptr<FemBody>> bodies;
  const int blas_free = static_cast<int>(state.range(0));
  auto& body = bodies[blas_free];
  if (!body) {
    SceneSpec spec = loadScene(std::filesystem::path(TACTUS_SOURCE_DIR) / "scenes" /
                               "liver_grasp_23k.yaml");
    const TissueSpec& ts = spec.tissues.at(0);
    TetMesh mesh = loadTetMesh(ts.mesh_path);
    transformMesh(mesh, ts.scale, ts.rotation_deg, ts.translation_m);
    FemSolverOptions opt = femSolverOptions(spec.solver);
    opt.linear = LinearSolverKind::kCholmod;
    // the background refresh's setting: the body's factors solved without BLAS (CHOLMOD's
    // supernodal sweeps with Eigen's kernels)
    if (blas_free) {
      opt.linear = LinearSolverKind::kCholmodReuse;
      opt.background_refactor_lag_steps = 2;
    }
    const Eigen::Vector3d gravity = spec.gravity_mps2.value_or(Eigen::Vector3d::Zero());
    body = std::make_unique<FemBody>(mesh, femMaterial(ts), nodesInBoxes(mesh, ts.fixed_boxes),
                                     &gravity, opt);
    for (int s = 0; s < 5; ++s) body->freeMotion(spec.time_step_s);
  }
  const int cols = static_cast<int>(state.range(1));
  Eigen::MatrixXd r = Eigen::MatrixXd::Zero(body->dofCount(), cols), x;
  for (int c = 0; c < cols; ++c)
    for (int i = 0; i < body->nodeCount(); i += 5 + c) r(3 * i + c % 3, c) = 1.0;
  // the step's factor is current after kCholmod's step; with the reuse strategy the first
  // steps refresh it (a solve that found it stale would factorise: not timed)
  body->solveComplianceBatch(r, x);
  for (auto _ : state) body->solveComplianceBatch(r, x);
  state.counters["factor_nnz"] = static_cast<double>(body->factorNonzeros());
}
BENCHMARK(BM_FactorSolve_Liver23k)
    ->ArgsProduct({{0, 1}, {1, 3}})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Settle_Liver2_Cholmod)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_Settle_Liver2_CholmodReuse)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_Settle_Liver23k_Cholmod)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_Settle_Liver23k_CholmodReuse)->Unit(benchmark::kMillisecond)->Iterations(1);
// The same settle with each tissue alternative, beside the scene's own choice in the same run
// (Arg: 0 the scene's, 1 tangent consistent, 2 law invertible_neo_hookean, 3 edge_smoothed_tet):
//   fem_bench --benchmark_filter=Settle.*Variant
void BM_Settle_Liver2_Variant(benchmark::State& s) {
  runScene(s, "liver_grasp.yaml", LinearSolverKind::kCholmodReuse,
           static_cast<TissueVariant>(s.range(0)));
}
void BM_Settle_Liver23k_Variant(benchmark::State& s) {
  runScene(s, "liver_grasp_23k.yaml", LinearSolverKind::kCholmodReuse,
           static_cast<TissueVariant>(s.range(0)));
}
BENCHMARK(BM_Settle_Liver2_Variant)
    ->DenseRange(0, 3)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3);
BENCHMARK(BM_Settle_Liver23k_Variant)
    ->DenseRange(0, 3)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1);

BENCHMARK(BM_FemStep_Small)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Small_Pcg)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Small_CholmodReuse)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver2_Cholmod)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver2_PcgJacobi)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver2_PcgRestChol)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver2_PcgWarpedChol)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver2_CholmodReuse)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver23k_Cholmod)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver23k_PcgJacobi)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver23k_PcgRestChol)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver23k_PcgWarpedChol)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FemStep_Liver23k_CholmodReuse)->Unit(benchmark::kMillisecond);

// 150 contacts x (n, t1, t2) on random surface triangles around one area (a grasp).
std::vector<TissueRow> rows450(const FemBody& body) {
  const auto& surf = body.surfaceNodes();
  const Eigen::VectorXd& q = body.positions();
  // the 60 surface nodes closest to the first surface node: a local contact patch
  std::vector<std::pair<double, int>> by_d;
  const Eigen::Vector3d c = q.segment<3>(3 * surf[0]);
  for (int i : surf) by_d.emplace_back((q.segment<3>(3 * i) - c).squaredNorm(), i);
  std::sort(by_d.begin(), by_d.end());
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> pick(0, std::min<int>(60, static_cast<int>(by_d.size())) - 1);
  std::vector<TissueRow> rows;
  for (int k = 0; k < 150; ++k) {
    TissueRow r;
    r.node = {by_d[pick(rng)].second, by_d[pick(rng)].second, by_d[pick(rng)].second};
    r.weight = {0.5, 0.3, 0.2};
    const Eigen::Vector3d n = Eigen::Vector3d(0.1 * k, 1.0, 0.3).normalized();
    const Eigen::Vector3d t1 = n.unitOrthogonal(), t2 = n.cross(t1);
    for (const Eigen::Vector3d& d : {n, t1, t2}) {
      r.dir = d;
      rows.push_back(r);
    }
  }
  return rows;
}

void precompute(benchmark::State& state, const char* name) {
  const TetMesh mesh = loadLiver(name);
  std::size_t bytes = 0;
  int surface = 0;
  for (auto _ : state) {
    auto body = makeBody(mesh, LinearSolverKind::kCholmod, PcgPreconditioner::kJacobi, 20);
    auto model = makeCompliance(ComplianceKind::kWarped, *body, quietOptions());
    bytes = model->memoryBytes();
    surface = model->buildInfo().surface_nodes;
  }
  state.counters["surface_nodes"] = surface;
  state.counters["memory_MB"] = static_cast<double>(bytes) / 1e6;
}
// liver_23k: 4795 surface nodes, 14385 solves; C0 takes 1.66 GB in double (0.83 GB in float,
// ComplianceOptions::c0_single_precision). Minutes: not part of the smoke run.
void BM_WarpedPrecompute_Liver2(benchmark::State& s) { precompute(s, "liver2.msh"); }
void BM_WarpedPrecompute_Liver23k(benchmark::State& s) { precompute(s, "liver_23k.msh"); }
BENCHMARK(BM_WarpedPrecompute_Liver2)->Unit(benchmark::kMillisecond)->Iterations(1);
BENCHMARK(BM_WarpedPrecompute_Liver23k)->Unit(benchmark::kMillisecond)->Iterations(1);

void buildW(benchmark::State& state, const TetMesh& mesh, ComplianceKind kind) {
  auto body = makeBody(mesh, LinearSolverKind::kCholmod, PcgPreconditioner::kJacobi, 20);
  for (int s = 0; s < 5; ++s) body->freeMotion(kH);
  auto model = makeCompliance(kind, *body, quietOptions());
  model->update(*body);
  const auto rows = rows450(*body);
  Eigen::MatrixXd w(rows.size(), rows.size());
  for (auto _ : state) {
    w.setZero();
    model->addW(rows, w);
    benchmark::DoNotOptimize(w.data());
  }
  state.counters["rows"] = static_cast<double>(rows.size());
}
void BM_W450_Small_Warped(benchmark::State& s) {
  buildW(s, smallBox(), ComplianceKind::kWarped);
}
void BM_W450_Liver2_Warped(benchmark::State& s) {
  buildW(s, loadLiver("liver2.msh"), ComplianceKind::kWarped);
}
void BM_W450_Liver2_Uncoupled(benchmark::State& s) {
  buildW(s, loadLiver("liver2.msh"), ComplianceKind::kUncoupled);
}
void BM_W450_Liver2_Exact(benchmark::State& s) {
  buildW(s, loadLiver("liver2.msh"), ComplianceKind::kExact);
}
BENCHMARK(BM_W450_Small_Warped)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_W450_Liver2_Warped)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_W450_Liver2_Uncoupled)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_W450_Liver2_Exact)->Unit(benchmark::kMicrosecond);

// The warped model's per-step rotations (FemBody::nodeRotations) without and with the rotation
// smoothing (ComplianceOptions::rotation_smoothing_passes), after a few steps under gravity.
void nodeRotations(benchmark::State& state, const char* name) {
  const int passes = static_cast<int>(state.range(0));
  auto body = makeBody(loadLiver(name), LinearSolverKind::kCholmod, PcgPreconditioner::kJacobi, 20);
  for (int s = 0; s < 3; ++s) body->freeMotion(kH);
  std::vector<Eigen::Matrix3d> r;
  for (auto _ : state) {
    body->nodeRotations(r, nullptr, passes);
    benchmark::DoNotOptimize(r.data());
  }
  state.counters["tets"] = body->mesh().tetCount();
}
void BM_NodeRotations_Liver23k(benchmark::State& s) { nodeRotations(s, "liver_23k.msh"); }
BENCHMARK(BM_NodeRotations_Liver23k)->Arg(0)->Arg(2)->Unit(benchmark::kMillisecond);

// The same from the last free motion's element rotations (FemBody::stepNodeRotations, what the
// warped compliance's update reads): no polar decomposition per element; the node sums are
// kept from the step's first call (the preconditioner's), so this is the smoothing and the
// polar factor per node.
void stepNodeRotations(benchmark::State& state, const char* name) {
  const int passes = static_cast<int>(state.range(0));
  auto body = makeBody(loadLiver(name), LinearSolverKind::kCholmod, PcgPreconditioner::kJacobi, 20);
  for (int s = 0; s < 3; ++s) body->freeMotion(kH);
  std::vector<Eigen::Matrix3d> r;
  for (auto _ : state) {
    body->stepNodeRotations(r, nullptr, passes);
    benchmark::DoNotOptimize(r.data());
  }
  state.counters["tets"] = body->mesh().tetCount();
}
void BM_StepNodeRotations_Liver23k(benchmark::State& s) { stepNodeRotations(s, "liver_23k.msh"); }
BENCHMARK(BM_StepNodeRotations_Liver23k)->Arg(0)->Arg(2)->Unit(benchmark::kMillisecond);

// What the warped compliance's update now runs (FemBody::fittedNodeRotations): the polar factor of
// each node's sum of v_e F_e at the current positions, no polar decomposition per element.
void fittedNodeRotations(benchmark::State& state, const char* name) {
  const int passes = static_cast<int>(state.range(0));
  auto body = makeBody(loadLiver(name), LinearSolverKind::kCholmod, PcgPreconditioner::kJacobi, 20);
  for (int s = 0; s < 3; ++s) body->freeMotion(kH);
  std::vector<Eigen::Matrix3d> r;
  for (auto _ : state) {
    body->fittedNodeRotations(r, passes);
    benchmark::DoNotOptimize(r.data());
  }
  state.counters["tets"] = body->mesh().tetCount();
}
void BM_FittedNodeRotations_Liver23k(benchmark::State& s) {
  fittedNodeRotations(s, "liver_23k.msh");
}
BENCHMARK(BM_FittedNodeRotations_Liver23k)->Arg(0)->Arg(2)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace tactus::sim

BENCHMARK_MAIN();
