// Numerics: the simulation's numeric libraries stay on one thread whatever the
// environment says (a multi-threaded OpenBLAS worker spinning in sched_yield took the haptic
// loop's core), checked in-process and on the real sim_server.
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <dlfcn.h>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/vtk_writer.h"
#include "tactus/sim/pipeline.h"
#include "../../sim_server/src/app/output_writer.h"
#include "tactus/sim/runner.h"
#include "tactus/sim/scene.h"

extern char** environ;

namespace tactus::sim {
namespace {

namespace fs = std::filesystem;

bool processHasOpenBlas() { return dlsym(RTLD_DEFAULT, "openblas_get_num_threads") != nullptr; }

TEST(NumericThreads, TheLimitLeavesOneBlasThreadAndNoOpenMpRegions) {
  const NumericThreads applied = limitNumericThreads();
  const NumericThreads now = queryNumericThreads();
  if (processHasOpenBlas()) {
    EXPECT_EQ(applied.blas_threads, 1) << applied.blas_config;
    EXPECT_EQ(now.blas_threads, 1);
    EXPECT_FALSE(now.blas_config.empty());
  } else {
    EXPECT_EQ(now.blas_threads, -1);
  }
  if (dlsym(RTLD_DEFAULT, "omp_get_max_active_levels") != nullptr) {
    EXPECT_EQ(now.omp_max_active_levels, 0);
  }
}

// Runs sim_server offline for a few steps with an environment asking for 4 BLAS/OpenMP threads;
// returns its exit status (-1: did not finish in time, killed) and its output.
int runSimServer(const fs::path& log, std::string& output) {
  const std::string exe = std::string(TACTUS_BINARY_DIR) + "/sim_server/sim_server";
  const std::string scene = std::string(TACTUS_TEST_DATA_DIR) + "/scenes/press_cube.yaml";
  std::vector<std::string> args = {exe, scene, "--steps", "3", "--log-level", "info"};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  std::vector<std::string> env_store;
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string kv = *e;
    if (kv.rfind("OPENBLAS_NUM_THREADS=", 0) == 0 || kv.rfind("OMP_NUM_THREADS=", 0) == 0 ||
        kv.rfind("GOTO_NUM_THREADS=", 0) == 0) {
      continue;
    }
    env_store.push_back(kv);
  }
  env_store.push_back("OPENBLAS_NUM_THREADS=4");
  env_store.push_back("OMP_NUM_THREADS=4");
  std::vector<char*> envp;
  for (auto& e : env_store) envp.push_back(e.data());
  envp.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, exe.c_str(), &actions, nullptr, argv.data(), envp.data());
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) return -2;
  int status = 0;
  int code = -1;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (true) {
    const pid_t w = waitpid(pid, &status, WNOHANG);
    if (w == pid) {
      code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      break;
    }
    if (std::chrono::steady_clock::now() > deadline) {
      kill(pid, SIGKILL);
      waitpid(pid, &status, 0);
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::ifstream in(log);
  std::stringstream ss;
  ss << in.rdbuf();
  output = ss.str();
  return code;
}

TEST(NumericThreads, SimServerReportsOneBlasThreadWhateverTheEnvironment) {
  const fs::path dir = fs::temp_directory_path() /
                       ("tactus_numerics_" + std::to_string(getpid()));
  fs::create_directories(dir);
  std::string out;
  const int code = runSimServer(dir / "sim_server.log", out);
  fs::remove_all(dir);
  ASSERT_EQ(code, 0) << out;
  const auto at = out.find("numeric threads: BLAS ");
  ASSERT_NE(at, std::string::npos) << out;
  const std::string line = out.substr(at, out.find('\n', at) - at);
  if (processHasOpenBlas()) {
    // sim_server links the same CHOLMOD, hence the same BLAS, as this test
    EXPECT_EQ(line.rfind("numeric threads: BLAS 1 (", 0), 0u) << line;
  }
  if (dlsym(RTLD_DEFAULT, "omp_get_max_active_levels") != nullptr) {
    EXPECT_NE(line.find("OpenMP max active levels 0"), std::string::npos) << line;
  }
}

// Inverted tetrahedra are counted and reported: a tet flipped by hand in a running scene shows
// up in the step report, the stats JSON and the VTU cell fields "volume_ratio" / "inverted".
TEST(InvertedElements, AreCountedInTheStepReportTheStatsJsonAndTheVtu) {
  const fs::path dir = fs::temp_directory_path() /
                       ("tactus_inverted_" + std::to_string(getpid()));
  fs::remove_all(dir);
  SceneSpec spec = loadScene(std::string(TACTUS_TEST_DATA_DIR) + "/scenes/minimal_scene.yaml");
  spec.output.enabled = true;
  spec.output.directory = dir;
  spec.output.every_n_steps = 1;
  Simulation sim(spec);
  ASSERT_GE(sim.tissueCount(), 1);
  FemBody& body = sim.tissue(0);
  ASSERT_EQ(body.invertedElementCount(), 0);
  // mirror the first free node of tet 0 through the plane of its three other nodes
  const auto& mesh = body.mesh();
  int node = -1;
  int others[3] = {0, 0, 0};
  for (int a = 0; a < 4 && node < 0; ++a) {
    if (body.fixedMask()[mesh.tets[0][a]]) continue;
    node = mesh.tets[0][a];
    for (int b = 0, k = 0; b < 4; ++b) {
      if (b != a) others[k++] = mesh.tets[0][b];
    }
  }
  ASSERT_GE(node, 0);
  const Eigen::Vector3d p0 = body.positions().segment<3>(3 * others[0]);
  const Eigen::Vector3d n = (body.positions().segment<3>(3 * others[1]) - p0)
                                .cross(body.positions().segment<3>(3 * others[2]) - p0)
                                .normalized();
  const Eigen::Vector3d x = body.positions().segment<3>(3 * node);
  body.positions().segment<3>(3 * node) = x - 2.0 * (x - p0).dot(n) * n;
  const int inverted = body.invertedElementCount();
  ASSERT_GE(inverted, 1);

  const StepReport report = sim.step();
  EXPECT_EQ(report.inverted_elements, inverted);
  RunStatistics stats;
  stats.add(report);
  EXPECT_EQ(stats.maxInvertedElements(), inverted);
  const std::string js = stats.json("flipped");
  EXPECT_NE(js.find("\"inverted_elements_max\": " + std::to_string(inverted)), std::string::npos)
      << js;
  OutputWriter output;
  output.writeIfDue(sim);
  output.finish(sim.spec());
  // the VTU of that step carries the per-cell fields, with as many 1s as inverted cells now
  std::string vtu;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() == ".vtu") {
      std::ifstream in(e.path());
      std::stringstream ss;
      ss << in.rdbuf();
      vtu = ss.str();
    }
  }
  fs::remove_all(dir);
  ASSERT_FALSE(vtu.empty());
  EXPECT_NE(vtu.find("Name=\"volume_ratio\""), std::string::npos);
  const auto at = vtu.find("Name=\"inverted\"");
  ASSERT_NE(at, std::string::npos);
  const auto begin = vtu.find('>', at) + 1;
  const std::string flags = vtu.substr(begin, vtu.find("</DataArray>", begin) - begin);
  int ones = 0;
  for (char c : flags) ones += c == '1' ? 1 : 0;
  EXPECT_EQ(ones, body.invertedElementCount());
  EXPECT_GE(ones, 1);
  // a volume-ratio field of the wrong size is refused, not written short
  fs::create_directories(dir);
  EXPECT_THROW(writeVtu(dir / "bad.vtu", mesh, mesh.nodes, Eigen::Matrix3Xd(3, 0),
                        Eigen::VectorXd(), Eigen::VectorXd::Ones(mesh.tetCount() + 1)),
               Error);
  EXPECT_FALSE(fs::exists(dir / "bad.vtu"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace tactus::sim
