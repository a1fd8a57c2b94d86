// pad_grasp_study: the flat-pad grasp of a scene (tests/support/pad_grasp.h) over the nominal
// approach and pad_grasp_test's five perturbed ones, with the whole script turned about the
// world's vertical around the jaws' midpoint at the grasp (--yaw-deg), moved along the jaws
// (--deeper-mm) and an optional grip stiffness. One line per approach: the held nodes' rise
// against the tool's, the smallest tet volume ratio in the jaws, the solver's figures. The
// docs/measurements.md ("Grasps") quotes its runs, e.g.
//   build/tools/pad_grasp_study/pad_grasp_study --yaw-deg 65 --grip 0.03 --deeper-mm 4
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "support/pad_grasp.h"
#include "tactus/shared/error.h"
#include "tactus/shared/percentiles.h"
#include "tactus/sim/scene.h"

using tactus::test_support::ApproachPerturbation;

int main(int argc, char** argv) {
  CLI::App app{"pad_grasp_study: the pad grasp over the nominal and five perturbed approaches"};
  app.footer(
      "Example:\n"
      "  pad_grasp_study --scene scenes/liver_grasp.yaml --nominal-only");
  std::string scene = std::string(TACTUS_SOURCE_DIR) + "/scenes/liver_grasp.yaml";
  double yaw_deg = 0.0, deeper_mm = 0.0, grip = -1.0;
  std::vector<double> offset_mm_arg{0.0, 0.0, 0.0};
  bool nominal_only = false;
  app.add_option("--scene", scene, "Scene file")->check(CLI::ExistingFile);
  app.add_option("--yaw-deg", yaw_deg, "Turn the script about the world's vertical [deg]")
      ->check(CLI::Range(-180.0, 180.0));
  app.add_option("--deeper-mm", deeper_mm, "Move the grasp along the jaws, into the tissue [mm]")
      ->check(CLI::Range(-20.0, 20.0));
  app.add_option("--grip", grip, "Grip stiffness [N m/rad] (default: the scene's)")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--offset-mm", offset_mm_arg,
                 "Move the whole script after the settling by x y z in the world frame [mm]")
      ->expected(3)
      ->check(CLI::Range(-30.0, 30.0));
  app.add_flag("--nominal-only", nominal_only, "Run the nominal approach only");
  CLI11_PARSE(app, argc, argv);
  try {
    tactus::sim::SceneSpec spec = tactus::sim::loadScene(scene);
    auto& keys = spec.instrument.trajectory;
    // the grasp: the key at which the approach ends (t = 2 s in the grasp scenes)
    const auto grasp = std::find_if(keys.begin(), keys.end(),
                                    [](const auto& k) { return std::abs(k.t_s - 2.0) < 1e-9; });
    if (grasp == keys.end()) throw tactus::Error(scene + ": no trajectory key at t = 2 s");
    const Eigen::Matrix3d r0 = grasp->pose.orientation.toRotationMatrix();
    const Eigen::Vector3d centre = grasp->pose.position_m + r0 * Eigen::Vector3d(0, 0, -0.01);
    const Eigen::Quaterniond yaw(Eigen::AngleAxisd(yaw_deg * M_PI / 180.0, Eigen::Vector3d::UnitZ()));
    auto turn = [&](tactus::sim::PoseSpec& p) {
      p.position_m = centre + yaw * (p.position_m - centre);
      p.orientation = (yaw * p.orientation).normalized();
    };
    for (auto& k : keys) turn(k.pose);
    turn(spec.instrument.initial_pose);
    if (grip >= 0.0) spec.instrument.grip_k_nmprad = grip;
    // the jaws point along the tool's -z: deeper is along it, added to the test's offsets
    const Eigen::Vector3d deeper = (yaw * r0) * Eigen::Vector3d(0, 0, -1e-3 * deeper_mm);
    // the nominal approach, then pad_grasp_test's five
    std::vector<ApproachPerturbation> approaches;
    if (!nominal_only) approaches = tactus::test_support::testApproaches();
    approaches.insert(approaches.begin(), ApproachPerturbation{});
    for (ApproachPerturbation a : approaches) {
      const Eigen::Vector3d offset_mm = 1e3 * a.offset_m;
      a.offset_m += deeper +
                    1e-3 * Eigen::Vector3d(offset_mm_arg[0], offset_mm_arg[1], offset_mm_arg[2]);
      const auto r = tactus::test_support::runPadGrasp(spec, a);
      std::printf(
          "offset (%+.0f %+.0f %+.0f) mm roll %+3.0f deg: rise %6.1f %% (%d held nodes), smallest "
          "tet %.3f (tet %d at t = %.2f s), contacts max %d (%d distinct nodes held), unconverged "
          "%d, sweeps median %.0f, normal force max %.2f N, load max %.2f N\n",
          offset_mm.x(), offset_mm.y(), offset_mm.z(), a.roll_deg,
          100.0 * r.held_rise_m / r.tool_rise_m, r.held_nodes, r.min_volume_ratio,
          r.min_volume_tet, r.min_volume_ratio_t_s, r.max_contacts, r.max_distinct_nodes_held,
          r.unconverged_steps, tactus::shared::percentile(r.sweeps, 0.5),
          r.max_total_normal_n, r.max_load_n);
      std::fflush(stdout);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pad_grasp_study: %s\n", e.what());
    return 1;
  }
  return 0;
}
