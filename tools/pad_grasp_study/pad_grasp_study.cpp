// pad_grasp_study: the flat-pad grasp of a scene (tests/support/pad_grasp.h) over the nominal
// approach and pad_grasp_test's five perturbed ones, with the whole script turned about the
// world's vertical around the jaws' midpoint at the grasp (--yaw-deg), moved along the jaws
// (--deeper-mm) and an optional grip stiffness; or (--grid) the grasp-anywhere grid of
// tests/support/pad_grasp.h (offsets over the lobe's free edge, jaw roll, two grips). One line
// per approach: the held nodes' rise against the tool's, the smallest tet volume ratio in the
// jaws and anywhere, the solver's figures; --csv writes them as a table (scripts/grasp_grid_plot.py
// plots it). The docs/measurements.md ("Grasps") quotes its runs, e.g.
//   build/tools/pad_grasp_study/pad_grasp_study --yaw-deg 65 --grip 0.03 --deeper-mm 4
//   build/tools/pad_grasp_study/pad_grasp_study --scene scenes/liver_grasp_20k.yaml --grid --csv g.csv
#include "tactus/shared/cli.h"
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
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
  namespace cli = tactus::shared::cli;
  cli::App app{"pad_grasp_study: the pad grasp over the nominal and five perturbed approaches, "
               "or over the grasp-anywhere grid"};
  app.footer(
      "Examples:\n"
      "  pad_grasp_study --scene scenes/liver_grasp.yaml --nominal-only\n"
      "  pad_grasp_study --scene scenes/liver_grasp_20k.yaml --grid --end-s 5 --csv grid_20k.csv");
  std::string scene = std::string(TACTUS_SOURCE_DIR) + "/scenes/liver_grasp.yaml";
  double yaw_deg = 0.0, deeper_mm = 0.0, grip = -1.0, roll_deg = 0.0, squeeze = -1.0;
  std::vector<double> offset_mm_arg{0.0, 0.0, 0.0};
  bool nominal_only = false, grid = false, settle_each = false, settle_only = false;
  int grid_skip = 0, grid_count = 0;
  std::string csv_path;
  double end_s = 5.8;
  app.addOption("--scene", scene, "Scene file")->check(cli::existingFile());
  app.addOption("--yaw-deg", yaw_deg, "Turn the script about the world's vertical [deg]")
      ->check(cli::range(-180.0, 180.0));
  app.addOption("--deeper-mm", deeper_mm, "Move the grasp along the jaws, into the tissue [mm]")
      ->check(cli::range(-20.0, 20.0));
  app.addOption("--grip", grip,
                 "Grip stiffness [N m/rad] (default: the scene's); with --grid: run the grid's "
                 "approaches at that grip only")
      ->check(cli::range(0.0, 1.0));
  app.addOption("--squeeze", squeeze,
                 "A closed handle's squeeze beyond the grip's spring [N m] (grasper.grip_squeeze; "
                 "default: the scene's), for every approach")
      ->check(cli::range(0.0, 1.0));
  app.addOption("--roll-deg", roll_deg, "Roll the jaws about their axis after the settling [deg]")
      ->check(cli::range(-90.0, 90.0));
  app.addOption("--offset-mm", offset_mm_arg,
                 "Move the whole script after the settling by x y z in the world frame [mm]")
      ->expected(3)
      ->check(cli::range(-30.0, 30.0));
  app.addFlag("--nominal-only", nominal_only, "Run the nominal approach only");
  app.addFlag("--grid", grid,
               "Run the grasp-anywhere grid (tests/support/pad_grasp.h) instead of the six")
      ->excludes("--nominal-only");
  app.addOption("--grid-skip", grid_skip, "With --grid: skip its first N approaches")
      ->check(cli::range(0, 1000))
      ->needs("--grid");
  app.addOption("--grid-count", grid_count,
                 "With --grid: run at most N approaches (after --grid-skip)")
      ->check(cli::range(1, 1000))
      ->needs("--grid");
  app.addFlag("--settle-each", settle_each,
               "Settle each approach from t = 0 instead of starting all from one settled state");
  app.addFlag("--settle-only", settle_only, "Settle, print what the settling measured and stop")
      ->excludes("--settle-each");
  app.addOption("--csv", csv_path, "Also write one row per approach to this new file");
  app.addOption("--end-s", end_s, "End of the run [s] (the lift ends at 4.5 s)")
      ->check(cli::range(3.5, 8.0));
  TACTUS_CLI_PARSE(app, argc, argv);
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
    if (squeeze >= 0.0) spec.instrument.grip_squeeze_nm = squeeze;
    // the jaws point along the tool's -z: deeper is along it, added to the test's offsets
    const Eigen::Vector3d deeper = (yaw * r0) * Eigen::Vector3d(0, 0, -1e-3 * deeper_mm);
    // the nominal approach, then pad_grasp_test's five; or the grid
    std::vector<ApproachPerturbation> approaches;
    if (grid) {
      approaches = tactus::test_support::gridApproaches();
      if (grip >= 0.0) {   // the grid's approaches at that grip only
        std::erase_if(approaches, [&](const ApproachPerturbation& a) {
          return std::abs(a.grip_k_nmprad - grip) > 1e-12;
        });
        if (approaches.empty()) throw tactus::Error("--grid: no grid approach has that --grip");
      }
      // a part of the list (two processes sharing a grid)
      const auto skip = std::min(approaches.size(), static_cast<std::size_t>(grid_skip));
      approaches.erase(approaches.begin(), approaches.begin() + static_cast<long>(skip));
      if (approaches.empty()) throw tactus::Error("--grid-skip: no approach left");
      if (grid_count > 0 && approaches.size() > static_cast<std::size_t>(grid_count)) {
        approaches.resize(static_cast<std::size_t>(grid_count));
      }
    } else {
      if (!nominal_only) approaches = tactus::test_support::testApproaches();
      approaches.insert(approaches.begin(), ApproachPerturbation{});
    }
    std::ofstream csv;
    if (!csv_path.empty()) {
      if (std::filesystem::exists(csv_path)) throw tactus::Error(csv_path + ": exists (not overwritten)");
      csv.open(csv_path);
      if (!csv) throw tactus::Error(csv_path + ": cannot be written");
      csv << "x_mm,y_mm,z_mm,roll_deg,grip_nmprad,grip_squeeze_nm,rise_pct,held_nodes,"
             "min_jaw_ratio,min_jaw_tet,"
             "min_jaw_t_s,min_jaw_tool_x_mm,min_jaw_tool_y_mm,min_jaw_tool_z_mm,min_any_ratio,"
             "min_any_tet,min_any_t_s,inverted_steps,unconverged_steps,sweeps_median,"
             "normal_force_max_n,load_max_n,rise_pct_at_4_5_s,rise_pct_min_after_4_5_s,opening_closed,"
             "min_contacts_one_jaw_held,max_friction_use_held,max_sliding_fraction_held,run_s\n";
    }
    // every approach from the same settled state (tests/support/pad_grasp.h, SettledStart)
    const tactus::test_support::SettledStart settled =
        settle_each ? tactus::test_support::SettledStart{} : tactus::test_support::settle(spec);
    if (!settle_each) {
      const auto& s = settled.so_far;
      std::printf("settled (1 s, shared by the approaches): smallest tet anywhere %.3f (tet %d at t "
                  "= %.2f s), %d steps with a tet inverted\n",
                  s.min_volume_ratio_anywhere, s.min_volume_tet_anywhere,
                  s.min_volume_ratio_anywhere_t_s, s.inverted_steps);
      std::fflush(stdout);
    }
    if (settle_only) return 0;
    for (ApproachPerturbation a : approaches) {
      a.offset_m += deeper +
                    1e-3 * Eigen::Vector3d(offset_mm_arg[0], offset_mm_arg[1], offset_mm_arg[2]);
      a.roll_deg += roll_deg;
      const Eigen::Vector3d offset_mm = 1e3 * a.offset_m;
      if (a.grip_k_nmprad < 0.0) a.grip_k_nmprad = spec.instrument.grip_k_nmprad;
      const auto start = std::chrono::steady_clock::now();
      const auto r = tactus::test_support::runPadGrasp(spec, a, end_s, settle_each ? nullptr : &settled);
      const double run_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      // the rise at the end of the lift, and the lowest from then on (a slip while held)
      double rise_at_lift_end = 0.0, rise_min_after = 1e9;
      for (const auto& [t, ratio] : r.rise_ratio_trace) {
        if (std::abs(t - 4.5) < 1e-6) rise_at_lift_end = ratio;
        if (t > 4.5 - 1e-6) rise_min_after = std::min(rise_min_after, ratio);
      }
      const double rise = r.held_rise_m / r.tool_rise_m;
      std::printf(
          "offset (%+.0f %+.0f %+.0f) mm roll %+3.0f deg grip %.3f squeeze %.3f: rise %6.1f %% (%d held "
          "nodes; %.1f %% at 4.5 s), smallest tet in the jaws %.3f (tet %d at t = %.2f s, at "
          "(%+.1f %+.1f %+.1f) mm in the tool's frame), anywhere %.3f (tet %d at t = %.2f s, %d "
          "steps inverted), contacts max %d (%d distinct nodes held), unconverged %d, sweeps "
          "median %.0f, normal force max %.2f N, load max %.2f N, %.0f s\n",
          offset_mm.x(), offset_mm.y(), offset_mm.z(), a.roll_deg, a.grip_k_nmprad,
          spec.instrument.grip_squeeze_nm, 100.0 * rise,
          r.held_nodes, 100.0 * rise_at_lift_end, r.min_volume_ratio, r.min_volume_tet,
          r.min_volume_ratio_t_s, 1e3 * r.min_volume_tet_in_tool_m.x(),
          1e3 * r.min_volume_tet_in_tool_m.y(), 1e3 * r.min_volume_tet_in_tool_m.z(),
          r.min_volume_ratio_anywhere, r.min_volume_tet_anywhere, r.min_volume_ratio_anywhere_t_s,
          r.inverted_steps, r.max_contacts, r.max_distinct_nodes_held, r.unconverged_steps,
          tactus::shared::percentile(r.sweeps, 0.5), r.max_total_normal_n, r.max_load_n, run_s);
      std::printf("  jaws closed at %.3f of their opening; held: fewest contacts on one jaw %d, friction "
                  "cone used up to %.2f, contacts sliding up to %.0f %%\n",
                  r.opening_closed, r.min_contacts_one_jaw_held, r.max_friction_use_held,
                  100.0 * r.max_sliding_fraction_held);
      const auto& ph = r.step_s_by_phase;
      std::printf("  steps' time: settle %.1f s, approach %.1f s, close %.1f s, lift %.1f s, hold %.1f s\n",
                  ph[0], ph[1], ph[2], ph[3], ph[4]);
      std::printf("  from the closing, each 0.1 s, t:opening/smallest tet in the jaws/largest normal "
                  "force [N]:");
      for (const auto& x : r.trace) {
        std::printf(" %.1f:%.3f/%.3g/%.3g", x.t_s, x.opening, x.min_jaw_ratio, x.max_normal_n);
      }
      std::printf("\n");
      std::printf("  rise / tool's rise from the lift's start, each 0.1 s:");
      for (const auto& [t, ratio] : r.rise_ratio_trace) std::printf(" %.1f:%.1f", t, 100.0 * ratio);
      std::printf("\n");
      std::fflush(stdout);
      if (csv.is_open()) {
        const Eigen::Vector3d& at = r.min_volume_tet_in_tool_m;
        csv << offset_mm.x() << ',' << offset_mm.y() << ',' << offset_mm.z() << ',' << a.roll_deg
            << ',' << a.grip_k_nmprad << ',' << spec.instrument.grip_squeeze_nm << ','
            << 100.0 * rise << ',' << r.held_nodes << ','
            << r.min_volume_ratio << ',' << r.min_volume_tet << ',' << r.min_volume_ratio_t_s
            << ',' << 1e3 * at.x() << ',' << 1e3 * at.y() << ',' << 1e3 * at.z() << ','
            << r.min_volume_ratio_anywhere << ',' << r.min_volume_tet_anywhere << ','
            << r.min_volume_ratio_anywhere_t_s << ',' << r.inverted_steps << ','
            << r.unconverged_steps << ',' << tactus::shared::percentile(r.sweeps, 0.5) << ','
            << r.max_total_normal_n << ',' << r.max_load_n << ',' << 100.0 * rise_at_lift_end
            << ',' << 100.0 * (rise_min_after < 1e8 ? rise_min_after : 0.0) << ','
            << r.opening_closed << ',' << r.min_contacts_one_jaw_held << ','
            << r.max_friction_use_held << ',' << r.max_sliding_fraction_held << ',' << run_s
            << '\n';
        csv.flush();
        if (!csv) throw tactus::Error(csv_path + ": write failed");
      }
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pad_grasp_study: %s\n", e.what());
    return 1;
  }
  return 0;
}
