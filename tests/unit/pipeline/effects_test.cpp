// "Only the effects a scene calls for" (docs/design.md section 5.2): the pipeline's stage counters prove
// that an absent effect costs nothing (linear material: no rotation extraction; mu = 0: no
// tangential rows; no damping: no damping terms; no instrument: no collision and no solve; no
// output: no VTK frame), that each present effect does run, and that stages() lists exactly what
// runs. The sim_server binary, run on a scene without haptics, creates no shared-memory segment
// (watched with inotify on /dev/shm, with a haptic scene as the positive control).
#include <gtest/gtest.h>
#include <sys/inotify.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "tactus/shared/segment.h"
#include "../../../sim_server/src/app/output_writer.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

const std::filesystem::path kData = TACTUS_TEST_DATA_DIR;

// A 7 cm cube (cube_low_res.msh) fixed at its base; the optional blocks switch effects on.
std::string cubeScene(bool corotational, bool damping, bool instrument, double mu) {
  std::string s = "time_step: 0.01\n"
                  "tissues:\n"
                  "  - name: cube\n"
                  "    mesh: meshes/cube_low_res.msh\n"
                  "    transform: {scale: 0.01}\n";
  s += std::string("    material: {law: ") + (corotational ? "corotational" : "linear") +
       ", young_modulus: 50000, poisson_ratio: 0.4}\n";
  if (damping) s += "    damping: {rayleigh_mass: 1.0, rayleigh_stiffness: 0.01}\n";
  s += "    fixed: {boxes: [{min: [-1, -1, -1], max: [1, 1, -0.034]}]}\n";
  if (instrument) {
    // the probe starts 1 mm into the top face: contacts from the first step
    s += "instrument:\n"
         "  type: probe\n"
         "  friction: " + std::to_string(mu) + "\n"
         "  probe: {tip_radius: 0.006}\n"
         "  initial_pose: {position: [0.004, 0.003, 0.040]}\n";
  }
  return s;
}

SceneSpec parse(const std::string& yaml) { return parseScene(yaml, "effects.yaml", kData); }

bool anyContains(const std::vector<std::string>& v, const std::string& what) {
  return std::any_of(v.begin(), v.end(),
                     [&](const std::string& s) { return s.find(what) != std::string::npos; });
}

struct EffectsRun {
  PipelineCounters counters;
  long vtk_frames = 0;              ///< frames the run's VTK output wrote
  std::vector<std::string> stages;
  bool rows_equal_contacts = true;
  bool rows_three_per_contact = true;
  int max_contacts = 0;
  int contact_steps = 0;            ///< steps whose report had contact rows
  long elements = 0;                ///< tetrahedra of the first tissue
};

EffectsRun run(const SceneSpec& spec, int steps = 5) {
  Simulation sim(spec);
  OutputWriter output;
  EffectsRun out;
  out.stages = sim.stages();
  for (int k = 0; k < steps; ++k) {
    if (sim.hasInstrument()) sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    const StepReport r = sim.step();
    EXPECT_TRUE(r.finite);
    out.rows_equal_contacts = out.rows_equal_contacts && r.rows == r.contacts;
    out.rows_three_per_contact = out.rows_three_per_contact && r.rows == 3 * r.contacts;
    out.max_contacts = std::max(out.max_contacts, r.contacts);
    out.contact_steps += r.rows > 0;
    output.writeIfDue(sim);
  }
  output.finish(spec);
  out.vtk_frames = output.frames();
  out.counters = sim.counters();
  out.elements = sim.tissue(0).mesh().tetCount();
  return out;
}

TEST(EffectsTest, ABareSceneRunsTheFreeMotionOnly) {
  const EffectsRun r = run(parse(cubeScene(false, false, false, 0.0)));
  EXPECT_EQ(r.counters.steps, 5);
  EXPECT_EQ(r.counters.rotation_extractions, 0);   // linear material
  EXPECT_EQ(r.counters.damping_evaluations, 0);    // no damping
  EXPECT_EQ(r.counters.collision_queries, 0);      // no instrument
  EXPECT_EQ(r.counters.w_builds, 0);
  EXPECT_EQ(r.counters.solves, 0);
  EXPECT_EQ(r.counters.tangential_rows, 0);
  EXPECT_EQ(r.vtk_frames, 0);             // no output
  // stages(): exactly the tissue's free motion and the note that nothing else runs
  ASSERT_EQ(r.stages.size(), 2u);
  EXPECT_NE(r.stages[0].find("free motion of tissue 'cube'"), std::string::npos);
  EXPECT_NE(r.stages[0].find("linear"), std::string::npos);
  EXPECT_NE(r.stages[0].find("no damping"), std::string::npos);
  EXPECT_NE(r.stages[0].find("no gravity"), std::string::npos);
  EXPECT_EQ(r.stages[0].find("corotational"), std::string::npos);
  EXPECT_NE(r.stages[1].find("no instrument"), std::string::npos);
  for (const char* absent : {"collision detection", "NSGS", "W = H C H^T", "VTK"}) {
    EXPECT_FALSE(anyContains(r.stages, absent)) << absent;
  }
}

TEST(EffectsTest, EveryEffectAScenePutsInRuns) {
  SceneSpec spec = parse(cubeScene(true, true, true, 0.5));
  const auto dir = std::filesystem::temp_directory_path() /
                   ("tactus_effects_vtk_" + std::to_string(::getpid()));
  spec.output.enabled = true;
  spec.output.directory = dir;
  spec.output.every_n_steps = 1;
  const EffectsRun r = run(spec);
  const bool wrote = std::filesystem::exists(dir / "series.pvd");
  std::filesystem::remove_all(dir);
  EXPECT_GT(r.max_contacts, 0);
  EXPECT_GT(r.counters.rotation_extractions, 0);     // corotational
  EXPECT_EQ(r.counters.damping_evaluations, 5);      // damping, once per step
  EXPECT_EQ(r.counters.collision_queries, 5);        // one tissue, once per step
  EXPECT_GT(r.counters.w_builds, 0);
  EXPECT_GT(r.counters.solves, 0);
  EXPECT_GT(r.counters.tangential_rows, 0);          // mu > 0: two tangential rows per contact
  EXPECT_TRUE(r.rows_three_per_contact);
  EXPECT_EQ(r.vtk_frames, 5);
  EXPECT_TRUE(wrote);
  ASSERT_EQ(r.stages.size(), 7u);
  EXPECT_NE(r.stages[0].find("corotational"), std::string::npos);
  EXPECT_NE(r.stages[0].find("Rayleigh damping"), std::string::npos);
  for (const char* present : {"god object", "collision detection", "W = H C H^T",
                              "Coulomb friction mu = 0.5", "constrained motion", "VTK output"}) {
    EXPECT_TRUE(anyContains(r.stages, present)) << present;
  }
  EXPECT_TRUE(anyContains(r.stages, "vertex and face contacts, at the free state"));
}

// A corotational tissue in contact makes one polar decomposition per element and step, the
// element loop's: the warped compliance of the contact steps takes its node rotations from the
// free state's deformation gradients (FemBody::fittedNodeRotations), not from a second
// decomposition. (No output here: the VTK frames' reaction forces evaluate the elastic force.)
TEST(EffectsTest, OnePolarDecompositionPerElementAndStep) {
  const EffectsRun r = run(parse(cubeScene(true, true, true, 0.5)));
  EXPECT_EQ(r.contact_steps, 5);   // the warped compliance updated on every step
  EXPECT_GT(r.counters.w_builds, 0);
  EXPECT_EQ(r.counters.rotation_extractions, 5 * r.elements);
}

// Detection at the start of the step still queries once per step (before the free motion instead
// of after it), finds the contacts, and the printed stages say where and which kinds.
TEST(EffectsTest, StepStartDetectionWithVertexContactsOnly) {
  SceneSpec spec = parse(cubeScene(true, true, true, 0.5));
  spec.solver.contact_detection = ContactDetection::kStepStart;
  spec.instrument.face_contacts = false;
  const EffectsRun r = run(spec);
  EXPECT_GT(r.max_contacts, 0);
  EXPECT_EQ(r.counters.collision_queries, 5);
  EXPECT_GT(r.counters.solves, 0);
  EXPECT_TRUE(anyContains(r.stages, "vertex contacts only, at the start of the step"));
}

TEST(EffectsTest, FrictionlessContactsCarryOneRowEach) {
  const EffectsRun r = run(parse(cubeScene(true, false, true, 0.0)));
  EXPECT_GT(r.max_contacts, 0);
  EXPECT_EQ(r.counters.tangential_rows, 0);
  EXPECT_TRUE(r.rows_equal_contacts);
  EXPECT_EQ(r.counters.damping_evaluations, 0);
  EXPECT_GT(r.counters.solves, 0);
  EXPECT_TRUE(anyContains(r.stages, "NSGS frictionless (1 row per contact)"));
  EXPECT_FALSE(anyContains(r.stages, "Coulomb"));
}

TEST(EffectsTest, LinearMaterialWithAnInstrumentExtractsNoRotation) {
  const EffectsRun r = run(parse(cubeScene(false, true, true, 0.3)));
  EXPECT_GT(r.max_contacts, 0);
  EXPECT_EQ(r.counters.rotation_extractions, 0);
  EXPECT_EQ(r.counters.damping_evaluations, 5);
  EXPECT_GT(r.counters.tangential_rows, 0);
}

// --- sim_server creates no segment without haptics ----------------------------------------------

// Runs sim_server with `args`; returns its exit code and whether /dev/shm/<segment> was created
// meanwhile (inotify IN_CREATE on /dev/shm, so a segment removed before the process exits still
// counts).
struct ServerRun {
  int exit_code = -1;
  bool segment_created = false;
};

ServerRun runServer(const std::vector<std::string>& args, const std::string& segment) {
  ServerRun out;
  const int fd = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
  EXPECT_GE(fd, 0) << "inotify_init1: " << errno;
  if (fd < 0) return out;
  EXPECT_GE(inotify_add_watch(fd, "/dev/shm", IN_CREATE | IN_MOVED_TO), 0);
  const std::string binary = std::string(TACTUS_BINARY_DIR) + "/sim_server/sim_server";
  std::vector<std::string> argv_s = {binary};
  argv_s.insert(argv_s.end(), args.begin(), args.end());
  argv_s.insert(argv_s.end(), {"--segment", segment, "--log-level", "warn"});
  std::vector<char*> argv;
  for (auto& a : argv_s) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = fork();
  if (pid == 0) {
    execv(binary.c_str(), argv.data());
    _exit(127);
  }
  int status = 0;
  waitpid(pid, &status, 0);
  out.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  alignas(inotify_event) char buf[4096];
  for (;;) {
    const ssize_t n = read(fd, buf, sizeof(buf));
    if (n <= 0) break;
    for (ssize_t at = 0; at < n;) {
      const auto* ev = reinterpret_cast<const inotify_event*>(buf + at);
      if (ev->len > 0 && segment == ev->name) out.segment_created = true;
      at += static_cast<ssize_t>(sizeof(inotify_event) + ev->len);
    }
  }
  close(fd);
  return out;
}

TEST(EffectsTest, SimServerWithoutHapticsCreatesNoSegment) {
  const std::string binary = std::string(TACTUS_BINARY_DIR) + "/sim_server/sim_server";
  ASSERT_TRUE(std::filesystem::exists(binary)) << binary << ": build the sim_server target";
  const std::string pid = std::to_string(::getpid());
  // a scene with an instrument but no haptics section
  const auto dir = std::filesystem::temp_directory_path() / ("tactus_effects_" + pid);
  std::filesystem::create_directories(dir);
  const auto no_haptics = dir / "no_haptics.yaml";
  {
    std::string yaml = cubeScene(true, true, true, 0.0);
    const std::string rel = "meshes/cube_low_res.msh";
    yaml.replace(yaml.find(rel), rel.size(), (kData / rel).string());
    std::FILE* f = std::fopen(no_haptics.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs(yaml.c_str(), f);
    std::fclose(f);
  }
  const std::string name = "tactus_effects_" + pid;
  shared::Segment::remove(name);
  // offline, 5 steps
  const ServerRun offline = runServer({no_haptics.string(), "--steps", "5"}, name);
  EXPECT_EQ(offline.exit_code, 0);
  EXPECT_FALSE(offline.segment_created);
  EXPECT_FALSE(shared::Segment::exists(name));
  // paced daemon mode for 50 ms: still no segment, the scene has no haptics
  const ServerRun paced = runServer({no_haptics.string(), "--duration", "0.05"}, name);
  EXPECT_EQ(paced.exit_code, 0);
  EXPECT_FALSE(paced.segment_created);
  EXPECT_FALSE(shared::Segment::exists(name));
  // positive control: a haptic scene in daemon mode does create it (so the watch works)
  const ServerRun haptic =
      runServer({(kData / "scenes" / "press_cube.yaml").string(), "--duration", "0.05"}, name);
  EXPECT_EQ(haptic.exit_code, 0);
  EXPECT_TRUE(haptic.segment_created);
  shared::Segment::remove(name);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace tactus::sim
