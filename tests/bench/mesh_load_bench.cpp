// Mesh loading, file to TetMesh (with the physical groups the Gmsh reader keeps): the shipped
// meshes by size. Figures in docs/measurements.md ("Soft tissue").
#include <benchmark/benchmark.h>
#include <spdlog/spdlog.h>

#include <filesystem>
#include <string>

#include "tactus/sim/mesh.h"

namespace {

void loadMesh(benchmark::State& state, const std::string& file) {
  spdlog::set_level(spdlog::level::err);   // the readers' repair warnings, once per load
  const std::filesystem::path path =
      std::filesystem::path(TACTUS_TEST_DATA_DIR) / "meshes" / file;
  int nodes = 0;
  for (auto _ : state) {
    const tactus::sim::TetMesh mesh = tactus::sim::loadTetMesh(path);
    nodes = mesh.nodeCount();
    benchmark::DoNotOptimize(mesh.groups.data());
  }
  state.counters["nodes"] = nodes;
}

void BM_LoadMesh_Small_BoxGroups(benchmark::State& s) { loadMesh(s, "box_groups.msh"); }
void BM_LoadMesh_Liver2(benchmark::State& s) { loadMesh(s, "liver2.msh"); }
void BM_LoadMesh_Liver23k(benchmark::State& s) { loadMesh(s, "liver_23k.msh"); }

}  // namespace

BENCHMARK(BM_LoadMesh_Small_BoxGroups)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LoadMesh_Liver2)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LoadMesh_Liver23k)->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();
