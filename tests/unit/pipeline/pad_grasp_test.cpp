// The flat-pad grasp of scenes/liver_grasp.yaml: the jaws close on the right lobe
// with a finite grip, lift it 2 cm and hold it. Asserted on the nominal approach and on five
// perturbed ones (grasp point moved by up to 3 mm, jaw roll by up to 15 deg):
//  * the held nodes (in contact when the jaws have closed) rise at least 90 % of the tool's lift;
//  * no tet at a node in contact falls below 0.3 of its rest volume (the grip does not crush);
//  * every contact step's NSGS reaches its tolerance, median sweeps <= 50;
//  * the total normal force stays within a bound of what the hold needs (the contact force the
//    tool carries against gravity);
//  * no tissue point carries two contacts from one jaw (a vertex pinched between both pads has
//    one contact per jaw).
// ctest runs the nominal grasp once more per OpenBLAS kernel (tests/CMakeLists.txt,
// OPENBLAS_CORETYPE).
//
// The perturbed approaches hold since the scene's approach turned 60 deg toward the lobe's mass
// (docs/design.md, "The grasp scenes"): measured rises 95-100 %, the closest 92.2 % (3 mm higher, rolled
// -15 deg). Along the jaws' axis of the earlier approach the lobe's weight rolled it off the
// 5.5 mm pads in four of the five.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <ostream>
#include <string>

#include "../../support/openblas_core.h"
#include "../../support/pad_grasp.h"

namespace tactus::sim {
namespace {

using test_support::ApproachPerturbation;
using test_support::PadGraspResult;

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

SceneSpec scene(const char* file) {
  SceneSpec spec = loadScene(std::string(TACTUS_SOURCE_DIR) + "/scenes/" + file);
  for (auto& t : spec.tissues) t.compliance_cache_dir.clear();
  return spec;
}

// liver_grasp_20k.yaml -> liver_grasp_20k
std::string sceneStem(const char* file) {
  std::string name = file;
  name.resize(name.find('.'));
  return name;
}

// The 20k and 23k grasps start from their scene's state after the settling (t = 1 s). Under
// ctest, a setup test per scene (PadGraspSettleTest below, as pad_grasp_settle_<scene>; the
// fixtures of tests/CMakeLists.txt) settles once and writes it to
// $TACTUS_PAD_GRASP_SETTLED_DIR/<scene>.settled, and every test of the scene reads it; without
// the variable (the executable run by hand) each test settles itself. Either start gives the
// same figures to the bit (SettledStartGivesTheSameGraspAsSettlingEach: a settled start is the
// settling run's own state; the file holds its bytes and what the settling measured).
std::filesystem::path settledFile(const std::string& scene_stem) {
  const char* dir = std::getenv("TACTUS_PAD_GRASP_SETTLED_DIR");
  if (dir == nullptr || *dir == '\0') return {};
  return std::filesystem::path(dir) / (scene_stem + ".settled");
}

test_support::SettledStart settledStart(const SceneSpec& spec, const std::string& scene_stem) {
  const std::filesystem::path file = settledFile(scene_stem);
  if (file.empty()) return test_support::settle(spec);
  test_support::SettledStart start;
  std::string why;
  std::error_code ec;
  // a file older than this executable was written by another build: refused, not settled again
  // (the setup test did not run, or failed)
  const auto exe = std::filesystem::last_write_time("/proc/self/exe", ec);
  if (!ec && std::filesystem::exists(file) && std::filesystem::last_write_time(file) < exe) {
    why = file.string() + ": older than this executable";
  } else if (test_support::readSettledStart(file, start, why)) {
    return start;
  }
  ADD_FAILURE() << why << "; ctest's setup test pad_grasp_settle_" << scene_stem
                << " writes it (run without TACTUS_PAD_GRASP_SETTLED_DIR, the test settles itself)";
  return test_support::settle(spec);
}

void printResult(const PadGraspResult& r) {
  std::printf("held nodes %d: rise %.2f mm of the tool's %.2f mm (%.1f %%); min tet volume ratio "
              "%.3f (node patches %.3f); contacts max %d (%d distinct jaw-points, %d held by both jaws, %d distinct "
              "nodes); while held max %d contacts on %d distinct nodes; %d contact steps, "
              "%d unconverged, sweeps median %.0f max %.0f; total normal force max %.3f N, "
              "load max %.3f N; geometric penetration max %.3f mm median %.4f mm\n",
              r.held_nodes, 1e3 * r.held_rise_m, 1e3 * r.tool_rise_m,
              100.0 * r.held_rise_m / r.tool_rise_m, r.min_volume_ratio, r.min_patch_volume_ratio,
              r.max_contacts,
              r.max_distinct_points, r.max_points_held_by_both_jaws, r.max_distinct_nodes,
              r.max_contacts_held, r.max_distinct_nodes_held, r.contact_steps, r.unconverged_steps,
              median(r.sweeps), r.sweeps.empty() ? 0.0 : *std::max_element(r.sweeps.begin(), r.sweeps.end()),
              r.max_total_normal_n, r.max_load_n, 1e3 * r.max_geometric_penetration_m,
              1e3 * median(r.geometric_penetration_m));
}

void expectHeldAndWellPosed(const PadGraspResult& r) {
  printResult(r);
  EXPECT_GT(r.tool_rise_m, 0.018);
  EXPECT_GT(r.held_nodes, 2);
  EXPECT_GE(r.held_rise_m, 0.9 * r.tool_rise_m);
  EXPECT_GE(r.min_volume_ratio, 0.3);
  EXPECT_EQ(r.unconverged_steps, 0);
  EXPECT_LE(median(r.sweeps), 50.0);
  EXPECT_EQ(r.max_distinct_points, r.max_contacts);
  // the grip squeezes: the normal force exceeds the load it carries, but not without bound
  EXPECT_GT(r.max_total_normal_n, r.max_load_n);
  EXPECT_LT(r.max_total_normal_n, 30.0 * r.max_load_n);
}

// ctest runs these tests once more per forced OpenBLAS kernel (tests/CMakeLists.txt): a kernel
// this CPU cannot run skips the whole run with the reason.
class OpenblasCoreEnvironment : public ::testing::Environment {
 public:
  void SetUp() override {
    const std::string reason = test_support::openblasCoreUnsupportedReason();
    if (!reason.empty()) GTEST_SKIP() << reason;
  }
};
const ::testing::Environment* const kOpenblasCoreEnvironment =
    ::testing::AddGlobalTestEnvironment(new OpenblasCoreEnvironment);

TEST(PadGraspTest, NominalApproachHoldsTheLobe) {
  expectHeldAndWellPosed(test_support::runPadGrasp(scene("liver_grasp.yaml"), {}));
}

// The scene's Anderson acceleration (solver.nsgs_anderson_depth: 5) on the grasp's own problems:
// the same grasp with plain NSGS needs at least 1.5x the median sweeps (measured 35 against 16)
// and stops at its 300-sweep cap on some steps; the lobe rises the same.
TEST(PadGraspTest, AndersonAccelerationCutsTheSweepsOfTheGrasp) {
  SceneSpec plain_spec = scene("liver_grasp.yaml");
  ASSERT_EQ(plain_spec.solver.nsgs_anderson_depth, 5);
  const PadGraspResult fast = test_support::runPadGrasp(plain_spec, {});
  plain_spec.solver.nsgs_anderson_depth = 0;
  const PadGraspResult plain = test_support::runPadGrasp(plain_spec, {});
  printResult(plain);
  EXPECT_EQ(fast.unconverged_steps, 0);
  EXPECT_GE(median(plain.sweeps), 1.5 * median(fast.sweeps));
  EXPECT_NEAR(fast.held_rise_m, plain.held_rise_m, 0.05 * plain.tool_rise_m);
}

class PerturbedPadGraspTest : public ::testing::TestWithParam<ApproachPerturbation> {};

TEST_P(PerturbedPadGraspTest, HoldsTheLobe) {
  expectHeldAndWellPosed(test_support::runPadGrasp(scene("liver_grasp.yaml"), GetParam()));
}

// e.g. x0_yp3_z0_roll0: the offset in mm and the roll in deg, p/m for the sign; with a grip,
// _grip15 for 0.015 N m/rad
std::string approachName(const ApproachPerturbation& a) {
  std::string name;
  auto part = [&name](const char* axis, double v) {
    const long n = std::lround(v);
    if (!name.empty()) name += '_';
    name += axis;
    name += n > 0 ? "p" : n < 0 ? "m" : "";
    name += std::to_string(std::abs(n));
  };
  part("x", 1e3 * a.offset_m.x());
  part("y", 1e3 * a.offset_m.y());
  part("z", 1e3 * a.offset_m.z());
  part("roll", a.roll_deg);
  if (a.grip_k_nmprad >= 0.0) name += "_grip" + std::to_string(std::lround(1e3 * a.grip_k_nmprad));
  return name;
}

INSTANTIATE_TEST_SUITE_P(
    Approaches, PerturbedPadGraspTest, ::testing::ValuesIn(test_support::testApproaches()),
    [](const ::testing::TestParamInfo<ApproachPerturbation>& info) {
      return approachName(info.param);
    });

// pad_grasp_study starts every approach from one state saved after the settling (SettledStart):
// an approach that changes the script after 1 s and the grip gives the same figures, to the bit,
// as one that settles itself. Through the closing and into the lift (3.2 s).
TEST(PadGraspTest, SettledStartGivesTheSameGraspAsSettlingEach) {
  const SceneSpec spec = scene("liver_grasp.yaml");
  const ApproachPerturbation a{Eigen::Vector3d(0.002, -0.002, 0.0), 10.0, 0.02};
  const test_support::SettledStart settled = test_support::settle(spec);
  const PadGraspResult from_settled = test_support::runPadGrasp(spec, a, 3.2, &settled);
  const PadGraspResult settling = test_support::runPadGrasp(spec, a, 3.2);
  printResult(from_settled);
  EXPECT_GT(settling.held_nodes, 2);
  EXPECT_GT(settling.contact_steps, 50);
  EXPECT_EQ(from_settled.held_nodes, settling.held_nodes);
  EXPECT_EQ(from_settled.contact_steps, settling.contact_steps);
  EXPECT_EQ(from_settled.held_rise_m, settling.held_rise_m);
  EXPECT_EQ(from_settled.tool_rise_m, settling.tool_rise_m);
  EXPECT_EQ(from_settled.min_volume_ratio, settling.min_volume_ratio);
  EXPECT_EQ(from_settled.min_volume_ratio_anywhere, settling.min_volume_ratio_anywhere);
  EXPECT_EQ(from_settled.max_total_normal_n, settling.max_total_normal_n);
  EXPECT_EQ(from_settled.sweeps, settling.sweeps);
}

// liver_grasp_23k (SOFA's liver_23k with its caps peeled and its tets improved by TetGen: 7144
// nodes, 28931 tets; its compliance is 1.6 GB, built once in about 40 s into
// .cache/compliance-23k-repaired; the run takes 1-3 min). The nominal list: the lobe
// rises with the tool, no tet in the jaws falls below 0.3 of its rest volume (0.327 measured),
// every contact step's NSGS reaches its tolerance with median sweeps <= 50 (48), the forces stay
// within the liver2 bound, no tissue point has two contacts from one jaw, and while the lobe is
// lifted and held the pads touch 150 distinct tissue nodes or more (the paper's count on
// distinct features). The crush bound holds at this grasp point, not 1 mm around it (docs/measurements.md,
// "Grasps"): the perturbed approaches are liver2's test.
TEST(PadGrasp23kTest, NominalApproachLiftsTheLobeAndConverges) {
  SceneSpec spec = loadScene(std::string(TACTUS_SOURCE_DIR) + "/scenes/liver_grasp_23k.yaml");
  const test_support::SettledStart settled = settledStart(spec, "liver_grasp_23k");
  const PadGraspResult r = test_support::runPadGrasp(spec, {}, 5.8, &settled);
  printResult(r);
  EXPECT_GT(r.tool_rise_m, 0.018);
  EXPECT_GT(r.held_nodes, 2);
  EXPECT_GE(r.held_rise_m, 0.9 * r.tool_rise_m);
  EXPECT_EQ(r.unconverged_steps, 0);
  EXPECT_LE(median(r.sweeps), 50.0);   // with Anderson acceleration (137 without)
  EXPECT_EQ(r.max_distinct_points, r.max_contacts);
  EXPECT_GT(r.max_total_normal_n, r.max_load_n);
  EXPECT_LT(r.max_total_normal_n, 30.0 * r.max_load_n);
  EXPECT_GE(r.max_distinct_nodes_held, 150);
  EXPECT_GT(r.min_patch_volume_ratio, 0.0);
  EXPECT_GE(r.min_volume_ratio, 0.3);
}

// On SOFA's liver_23k mesh as it is, slivers (quality 0.004) invert under gravity alone, so the
// smallest tet volume in the jaws is no crush measure there (docs/design.md, "The grasp
// scenes"). liver_grasp_20k (liver2.obj's surface remeshed without slivers, 19595 tets, its
// compliance 0.45 GB in .cache/compliance-20k; about 20 s), grasped at liver_grasp_23k's point,
// meets the nominal list: the lobe rises with the tool (101.7 % measured), no tet in the jaws
// falls below 0.3 of its rest volume (0.500), every contact step converges with median sweeps
// <= 50 (26), the forces stay within the liver2 bound and no tissue point has two contacts from
// one jaw. Its pads touch about 125 distinct tissue nodes (1.7 mm surface elements): the 150-node
// count is liver_grasp_23k's (above).
TEST(PadGrasp20kTest, NominalApproachHoldsTheLobe) {
  SceneSpec spec = loadScene(std::string(TACTUS_SOURCE_DIR) + "/scenes/liver_grasp_20k.yaml");
  const test_support::SettledStart settled = settledStart(spec, "liver_grasp_20k");
  expectHeldAndWellPosed(test_support::runPadGrasp(spec, {}, 5.8, &settled));
}

// The settling of the 20k and 23k scenes (to t = 1 s, the instrument away from the lobe), which
// their grasps start from (settledStart above): no tet inverts anywhere (the grid's third
// criterion, for the steps before its approaches start). Under ctest (pad_grasp_settle_<scene>)
// it writes the settled start for the scene's tests.
class PadGraspSettleTest : public ::testing::TestWithParam<const char*> {};

TEST_P(PadGraspSettleTest, SettlesWithoutInvertingATet) {
  const SceneSpec spec = loadScene(std::string(TACTUS_SOURCE_DIR) + "/scenes/" + GetParam());
  const test_support::SettledStart settled = test_support::settle(spec);
  const PadGraspResult& r = settled.so_far;
  std::printf("settled: smallest tet anywhere %.3f (tet %d at t = %.2f s), %d steps with a tet "
              "inverted, %d contact steps; state %zu bytes\n",
              r.min_volume_ratio_anywhere, r.min_volume_tet_anywhere,
              r.min_volume_ratio_anywhere_t_s, r.inverted_steps, r.contact_steps,
              settled.state.size());
  EXPECT_GT(r.min_volume_ratio_anywhere, 0.0);
  EXPECT_EQ(r.inverted_steps, 0);
  const std::filesystem::path file = settledFile(sceneStem(GetParam()));
  if (!file.empty()) {
    std::filesystem::create_directories(file.parent_path());
    std::string why;
    ASSERT_TRUE(test_support::writeSettledStart(file, settled, why)) << why;
  }
}

INSTANTIATE_TEST_SUITE_P(Settle, PadGraspSettleTest,
                         ::testing::Values("liver_grasp_20k.yaml", "liver_grasp_23k.yaml"),
                         [](const ::testing::TestParamInfo<const char*>& info) {
                           return sceneStem(info.param);
                         });

// The grasp anywhere (tests/support/pad_grasp.h, gridApproaches): approaches of the grid on
// liver_grasp_20k and liver_grasp_23k, the grasp point up to 5 mm off along the jaws and along
// the lobe's edge, the jaws rolled up to 20 deg, at the scenes' grip and at twice it. Each must
// lift the held nodes at least 90 % of the tool's rise, keep every tet in the jaws at 0.3 of its
// rest volume or more and invert no tet anywhere. The run ends at 5.0 s, 0.5 s into the hold, as
// pad_grasp_study --grid's (the nominal tests hold to 5.8 s): in the 11 grid approaches run to
// 5.8 s every verdict at 5.0 s was the verdict at 5.8 s; a slip shows as the lift ends (4.4-4.7 s)
// or earlier. Not shorter: a liver_grasp_23k corner reached its smallest tet in the jaws (0.258)
// at 4.86 s.
//
// Enabled (HoldsWithoutCrushOrInversion/<mesh>_<part>): six of the grid's approaches per mesh
// that meet the three criteria in docs/measurements.md's grid (with strain limiting), besides
// the nominal one the tests above run; each part runs its two or three one after the other from
// the mesh's settled state (its 100 settling steps run once per ctest run, settledStart above;
// SettledStartGivesTheSameGraspAsSettlingEach shows that this gives the same figures to the
// bit), and ctest runs the parts side by side. Disabled (DISABLED_Failing): approaches that
// fail, each with what failed. Run them with
// --gtest_also_run_disabled_tests --gtest_filter='*Failing*'; move an approach to the enabled
// list when it passes.
constexpr double kGridTestEndS = 5.0;

void expectHeldWithoutCrushOrInversion(const PadGraspResult& r) {
  printResult(r);
  std::printf("smallest tet anywhere %.3f (tet %d at t = %.2f s), %d steps with a tet inverted\n",
              r.min_volume_ratio_anywhere, r.min_volume_tet_anywhere,
              r.min_volume_ratio_anywhere_t_s, r.inverted_steps);
  EXPECT_GT(r.tool_rise_m, 0.018);
  EXPECT_GT(r.held_nodes, 2);
  EXPECT_GE(r.held_rise_m, 0.9 * r.tool_rise_m);
  EXPECT_GE(r.min_volume_ratio, 0.3);
  EXPECT_GT(r.min_volume_ratio_anywhere, 0.0);
  EXPECT_EQ(r.inverted_steps, 0);
}

ApproachPerturbation gridApproach(double x_mm, double y_mm, double roll_deg, double grip) {
  return {Eigen::Vector3d(1e-3 * x_mm, 1e-3 * y_mm, 0.0), roll_deg, grip};
}

struct GridMesh {
  const char* scene;
  const char* part;   ///< the test's name after the mesh's ("" : none)
  std::vector<ApproachPerturbation> approaches;
};

void PrintTo(const GridMesh& m, std::ostream* os) { *os << m.scene << ' ' << m.part; }

std::vector<GridMesh> passingGridApproaches() {
  // with strain limiting (measured 2026-11-29, docs/measurements.md; liver_grasp_20k at
  // liver_grasp_23k's grasp point with face contacts): six per mesh besides the nominal ones, in
  // parts of two or three so that ctest can run them side by side. liver_grasp_20k's: the four
  // corners of the offset plane, rolled both ways, both grips, and the axial rolls
  const double light = test_support::kGridGripsNmprad[0], firm = test_support::kGridGripsNmprad[1];
  return {{"liver_grasp_20k.yaml", "a",
           {gridApproach(-5, 5, -20, light), gridApproach(5, 5, -20, light),
            gridApproach(0, 0, 20, light)}},
          {"liver_grasp_20k.yaml", "b",
           {gridApproach(-5, -5, 20, firm), gridApproach(5, -5, 20, firm),
            gridApproach(0, 0, -20, firm)}},
          {"liver_grasp_23k.yaml", "a", {gridApproach(5, 5, 20, light), gridApproach(5, 5, 20, firm)}},
          {"liver_grasp_23k.yaml", "b", {gridApproach(5, -5, 20, light), gridApproach(0, 0, 0, firm)}},
          {"liver_grasp_23k.yaml", "c", {gridApproach(0, -5, 0, firm), gridApproach(0, 0, 20, firm)}}};
}

class PadGraspGridTest : public ::testing::TestWithParam<GridMesh> {};

TEST_P(PadGraspGridTest, HoldsWithoutCrushOrInversion) {
  const SceneSpec spec =
      loadScene(std::string(TACTUS_SOURCE_DIR) + "/scenes/" + GetParam().scene);
  const test_support::SettledStart settled = settledStart(spec, sceneStem(GetParam().scene));
  for (const ApproachPerturbation& a : GetParam().approaches) {
    SCOPED_TRACE(approachName(a));
    std::printf("%s %s\n", GetParam().scene, approachName(a).c_str());
    expectHeldWithoutCrushOrInversion(
        test_support::runPadGrasp(spec, a, kGridTestEndS, &settled));
  }
}

INSTANTIATE_TEST_SUITE_P(Grid, PadGraspGridTest, ::testing::ValuesIn(passingGridApproaches()),
                         [](const ::testing::TestParamInfo<GridMesh>& info) {
                           const std::string part = info.param.part;
                           return sceneStem(info.param.scene) + (part.empty() ? "" : "_" + part);
                         });

struct FailingGridCase {
  const char* scene;
  ApproachPerturbation approach;
  const char* reason;   ///< what failed in docs/measurements.md's grid
};

void PrintTo(const FailingGridCase& c, std::ostream* os) {
  *os << c.scene << ' ' << approachName(c.approach) << ": " << c.reason;
}

std::vector<FailingGridCase> failingGridApproaches() {
  // both scenes as shipped (docs/measurements.md, "The grasp anywhere", 2026-11-30). Every other
  // approach of both grids meets all three; the same (+5, -5) mm rolled -20 deg slips on both
  // meshes (at both grips on liver_grasp_20k, at the light one on liver_grasp_23k). Not enabled
  // though they pass: liver_grasp_23k's (-5, -5) mm rolled -20 deg (92.0-93.2 % as shipped,
  // 86.3-94.6 % across the preconditioner's precision: its rise follows the rounding)
  const double light = test_support::kGridGripsNmprad[0], firm = test_support::kGridGripsNmprad[1];
  return {
      {"liver_grasp_20k.yaml", gridApproach(5, -5, -20, light), "slips (rise 71 %)"},
      {"liver_grasp_20k.yaml", gridApproach(5, -5, -20, firm), "slips (rise 86.5 %)"},
      {"liver_grasp_23k.yaml", gridApproach(5, -5, -20, light), "slips (rise 87.9 %)"},
  };
}

class FailingPadGraspGridTest : public ::testing::TestWithParam<FailingGridCase> {};

TEST_P(FailingPadGraspGridTest, HoldsWithoutCrushOrInversion) {
  const SceneSpec spec =
      loadScene(std::string(TACTUS_SOURCE_DIR) + "/scenes/" + GetParam().scene);
  std::printf("failed in the grid: %s\n", GetParam().reason);
  expectHeldWithoutCrushOrInversion(
      test_support::runPadGrasp(spec, GetParam().approach, kGridTestEndS));
}

INSTANTIATE_TEST_SUITE_P(
    DISABLED_Failing, FailingPadGraspGridTest, ::testing::ValuesIn(failingGridApproaches()),
    [](const ::testing::TestParamInfo<FailingGridCase>& info) {
      // e.g. liver_grasp_20k_xm5_ym5_z0_rollm20_grip15
      return sceneStem(info.param.scene) + '_' + approachName(info.param.approach);
    });

}  // namespace
}  // namespace tactus::sim
