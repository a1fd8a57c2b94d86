// tactus-accuracy: the study's plans (quick and full), its run cache, the output files and the
// command line (what is measured and how: study.h).
#include "tactus/shared/cli.h"
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <map>
#include <memory>
#include <sstream>

#include "study.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"

namespace tactus::study {
namespace {

struct SimPlan {
  std::string main_mesh = "liver2";
  std::vector<std::string> meshes;
  double duration_s = 8.0;
  std::vector<sim::ComplianceKind> compliances;
  std::vector<double> tolerances;          // warped, sweep cap = reference's
  std::vector<int> budgets;                // warped, tolerance 1e-12 (the budget binds)
  std::vector<double> time_steps_s;        // besides the scene's
};

class RunCache {
 public:
  RunCache(const Options& o, double duration_s) : o_(o), duration_s_(duration_s) {}
  const SimRun& get(const sim::SceneSpec& base, const SimConfig& cfg, double duration_s = 0.0,
                    bool probe_w = false) {
    auto it = runs_.find(cfg.key());
    if (it != runs_.end()) return *it->second;
    fmt::print("  run {:<10} h {:>5.1f} ms  {:<9}  tol {:.0e}  sweeps {:>5} ... ", cfg.mesh,
               1e3 * cfg.h_s, complianceName(cfg.compliance), cfg.tol, cfg.sweeps);
    std::fflush(stdout);
    auto run = std::make_unique<SimRun>(
        runSim(o_, base, cfg, duration_s > 0.0 ? duration_s : duration_s_, probe_w));
    fmt::print("{:.1f} s (set-up {:.1f} s), step median {:.2f} ms\n", run->wall_s, run->setup_s,
               1e3 * median(run->step_s));
    std::fflush(stdout);
    const SimRun& ref = *run;
    runs_.emplace(cfg.key(), std::move(run));
    return ref;
  }

 private:
  const Options& o_;
  double duration_s_;
  std::map<std::string, std::unique_ptr<SimRun>> runs_;
};

// The haptic study's device motions: a slow press of `press_m` over press_s, a tremor of
// o.tremor_mm at o.tremor_hz over tremor_s, a 2 mm tap in 60 ms.
std::vector<DeviceMotion> hapticMotions(const Options& o, double press_s, double press_m,
                                        double tremor_s) {
  DeviceMotion press, tremor, tap;
  press.name = "slow_press";
  press.motion_s = press_s;
  press.amplitude_m = press_m;
  tremor.name = "tremor";
  tremor.motion_s = tremor_s;
  tremor.amplitude_m = 1e-3 * o.tremor_mm;
  tremor.freq_hz = o.tremor_hz;
  tremor.dir = Eigen::Vector3d(0.5, 0.3, 0.8).normalized();
  tap.name = "fast_tap";
  tap.motion_s = 0.06;
  tap.amplitude_m = 2e-3;
  tap.tail_s = 0.1;
  return {press, tremor, tap};
}

std::string tolLabel(double tol) { return fmt::format("{:.0e}", tol); }

int run(Options& o) {
  const std::int64_t t_all = shared::monotonicNs();
  const bool quick = o.mode == "quick";
  SimPlan sp;
  HapticPlan hp;
  if (quick) {
    // under 2 minutes: the coarse liver, a short span, one point per axis
    sp.main_mesh = "liver";
    sp.meshes = {"liver"};
    sp.duration_s = 3.5;
    sp.compliances = {sim::ComplianceKind::kExact, sim::ComplianceKind::kWarped,
                      sim::ComplianceKind::kRest, sim::ComplianceKind::kUncoupled};
    sp.tolerances = {1e-3};
    sp.budgets = {10};
    sp.time_steps_s = {0.02};
    hp.mesh = "liver";
    hp.rates = {{1000.0, 0.01}, {1000.0, 0.02}, {500.0, 0.01}};
    hp.motions = hapticMotions(o, 0.4, 2e-3, 0.25);
  } else {
    sp.main_mesh = "liver2";
    sp.meshes = {"liver", "liver2"};
    if (o.with_23k) sp.meshes.push_back("liver_23k");
    sp.duration_s = 8.0;
    sp.compliances = {sim::ComplianceKind::kExact, sim::ComplianceKind::kWarped,
                      sim::ComplianceKind::kRest, sim::ComplianceKind::kUncoupled};
    sp.tolerances = {1e-2, 1e-3, 1e-4, 1e-6, 1e-8};
    sp.budgets = {3, 10, 30, 100};
    sp.time_steps_s = {0.0025, 0.005, 0.02};
    hp.mesh = "liver2";
    hp.rates = {{1000.0, 0.01}, {1000.0, 0.04}, {1000.0, 0.02}, {1000.0, 0.005},
                {500.0, 0.01},  {2000.0, 0.01}, {4000.0, 0.01}};
    hp.motions = hapticMotions(o, 1.0, 3e-3, 0.5);
    hp.exact_snapshot_pairs = static_cast<int>(hp.rates.size());
  }
  if (o.duration_s > 0.0) sp.duration_s = o.duration_s;
  hp.budgets = {1, 3, 10, 0};
  hp.t0_s = o.haptic_t0_s > 0.0 ? o.haptic_t0_s : 3.0;
  fs::create_directories(o.out);
  fs::create_directories(o.cache_dir);

  // ---- part 1: the simulation step
  std::map<std::string, sim::SceneSpec> bases;
  for (const std::string& m : sp.meshes) bases[m] = meshScene(o, m);
  const sim::SceneSpec& main_base = bases.at(sp.main_mesh);
  const double scene_tol = main_base.solver.nsgs_tolerance;
  const int scene_sweeps = main_base.solver.nsgs_max_sweeps;
  if (o.part == "all" || o.part == "sim") {
    fmt::print("part 1: simulation step ({} s of the script per run)\n", sp.duration_s);
    RunCache cache(o, sp.duration_s);
    std::vector<SimRow> rows;
    const double h_main = main_base.time_step_s;
    const SimRun* main_ref = nullptr;
    std::vector<const SimRun*> w_probes;
    for (const std::string& m : sp.meshes) {
      const sim::SceneSpec& base = bases.at(m);
      // liver_23k (opt-in): ~0.4 s per step here, so a shorter span and no second exact run
      const bool big = m == "liver_23k";
      const double dur = big ? o.duration_23k_s : 0.0;
      const SimRun& ref = cache.get(base, {m, h_main, sim::ComplianceKind::kExact, o.ref_tolerance,
                                           o.ref_sweeps}, dur, true);
      w_probes.push_back(&ref);
      if (m == sp.main_mesh) main_ref = &ref;
      rows.push_back({"compliance", "reference", &ref, &ref});
      for (const sim::ComplianceKind k : sp.compliances) {
        if (big && k == sim::ComplianceKind::kExact) continue;
        const SimRun& r = cache.get(base, {m, h_main, k, scene_tol, scene_sweeps}, dur);
        rows.push_back({"compliance", complianceName(k), &r, &ref});
      }
    }
    for (const double tol : sp.tolerances) {
      const SimRun& r = cache.get(main_base, {sp.main_mesh, h_main, sim::ComplianceKind::kWarped,
                                              tol, o.ref_sweeps});
      rows.push_back({"tolerance", "tol " + tolLabel(tol), &r, main_ref});
    }
    for (const int b : sp.budgets) {
      const SimRun& r = cache.get(main_base, {sp.main_mesh, h_main, sim::ComplianceKind::kWarped,
                                              1e-12, b});
      rows.push_back({"sweeps", fmt::format("{} sweeps", b), &r, main_ref});
    }
    {
      std::vector<double> hs = sp.time_steps_s;
      hs.push_back(h_main);
      std::sort(hs.begin(), hs.end());
      hs.erase(std::unique(hs.begin(), hs.end()), hs.end());
      const SimRun& ref = cache.get(main_base, {sp.main_mesh, hs.front(),
                                                sim::ComplianceKind::kExact, o.ref_tolerance,
                                                o.ref_sweeps});
      for (const double h : hs) {
        const SimRun& ex = cache.get(main_base, {sp.main_mesh, h, sim::ComplianceKind::kExact,
                                                 o.ref_tolerance, o.ref_sweeps});
        rows.push_back({"time_step", &ex == &ref ? "reference" : fmt::format("exact h {} ms",
                                                                             1e3 * h),
                        &ex, &ref});
        const SimRun& wa = cache.get(main_base, {sp.main_mesh, h, sim::ComplianceKind::kWarped,
                                                 scene_tol, scene_sweeps});
        rows.push_back({"time_step", fmt::format("warped h {} ms", 1e3 * h), &wa, &ref});
      }
    }
    writeOutput(o, "sim_accuracy.csv", simCsv(rows, o.early_until_s));
    {
      std::ostringstream w;
      w << "mesh,tets,compliance,samples,w_rel_err_median,w_rel_err_max\n";
      for (const SimRun* r : w_probes) {
        for (const auto& [name, v] : r->w_error) {
          w << r->cfg.mesh << ',' << r->tets << ',' << name << ',' << v.size() << ','
            << fmtG(median(v)) << ',' << fmtG(v.empty() ? 0.0 : *std::max_element(v.begin(),
                                                                                   v.end()))
            << '\n';
        }
      }
      writeOutput(o, "w_accuracy.csv", w.str());
    }
    {
      std::string ts = "series,t_s,fx_n,fy_n,fz_n\n";
      for (const SimRow& r : rows) {
        if (r.study != "compliance" || r.run->cfg.mesh != sp.main_mesh) continue;
        appendSeries(ts, r.label, r.run->t, r.run->force);
      }
      writeOutput(o, "sim_timeseries.csv", ts);
    }
  }
  if (o.part == "all" || o.part == "states") {
    // compliance models on the same states of one exact trajectory
    const std::int64_t t_s = shared::monotonicNs();
    const StateComparison sc =
        compareStates(o, main_base, sp.main_mesh, sp.duration_s, quick ? 5 : 1);
    writeOutput(o, "w_states.csv", statesCsv(sc));
    fmt::print("  compliance models on {} states of the exact run ({} skipped: rows differ) in "
               "{:.1f} s\n", sc.rows.size(), sc.skipped, shared::secondsSinceNs(t_s));
  }
  const double part1_s = shared::secondsSinceNs(t_all);

  // ---- part 2: the haptic loop
  const bool run_haptic = o.part == "all" || o.part == "haptic";
  if (run_haptic) {
    fmt::print("part 2: haptic loop ({} mesh, window from {} s; R1, R2 and the methods)\n",
               hp.mesh, hp.t0_s);
  }
  const std::int64_t t_h = shared::monotonicNs();
  ReplayCheck replay;
  const std::vector<HapticCase> cases =
      run_haptic ? runHaptic(o, hp, replay) : std::vector<HapticCase>{};
  if (!cases.empty()) writeOutput(o, "haptic_accuracy.csv", hapticCsv(cases, hp.mesh));
  {
    // the force against time of every motion at the first (rate, step) pair, both snapshot Ws
    std::string ts = "motion,snapshot_w,series,t_s,fx_n,fy_n,fz_n\n";
    for (const HapticCase& c : cases) {
      if (c.rate_hz != hp.rates.front().first || c.sim_h_s != hp.rates.front().second) continue;
      std::istringstream lines(hapticSeries(c, hp.t0_s));
      for (std::string line; std::getline(lines, line);) {
        ts += c.motion + ',' + c.snapshot_w + ',' + line + '\n';
      }
    }
    if (!cases.empty()) writeOutput(o, "haptic_timeseries.csv", ts);
  }
  const double part2_s = shared::secondsSinceNs(t_h);

  // ---- meta
  {
    std::ostringstream meta;
    const std::time_t now = std::time(nullptr);
    char date[64];
    std::strftime(date, sizeof date, "%Y-%m-%d %H:%M", std::localtime(&now));
    meta << "key,value\n"
         << "date," << date << '\n'
         << "mode," << o.mode << '\n'
         << "machine," << "loaded 2-core VM (shared with other builds; timings are indicative)\n"
         << "sim_duration_s," << sp.duration_s << '\n'
         << "sim_main_mesh," << sp.main_mesh << '\n'
         << "early_until_s," << o.early_until_s << '\n'
         << "reference_tolerance," << o.ref_tolerance << '\n'
         << "reference_max_sweeps," << o.ref_sweeps << '\n'
         << "scene_tolerance," << scene_tol << '\n'
         << "scene_max_sweeps," << scene_sweeps << '\n'
         << "haptic_mesh," << hp.mesh << '\n'
         << "haptic_t0_s," << hp.t0_s << '\n'
         << "haptic_rate_hz," << hp.rates.front().first << '\n'
         << "haptic_sim_hz," << 1.0 / hp.rates.front().second << '\n'
         << "replay_steps," << replay.steps << '\n'
         << "replay_max_rel_diff," << fmtG(replay.max_rel_diff) << '\n'
         << "replay_max_force_n," << fmtG(replay.max_force_n) << '\n'
         << "haptic_latency_steps," << o.latency_steps << '\n'
         << "haptic_tolerance," << bases.begin()->second.haptics.nsgs_tolerance << '\n'
         << "tremor_mm," << o.tremor_mm << '\n'
         << "coherence_bound," << o.coherence_bound << '\n'
         << "tremor_hz," << o.tremor_hz << '\n'
         << "with_23k," << (o.with_23k ? 1 : 0) << '\n'
         << "duration_23k_s," << o.duration_23k_s << '\n'
         << "part1_s," << fmtG(part1_s) << '\n'
         << "part2_s," << fmtG(part2_s) << '\n'
         << "total_s," << fmtG(shared::secondsSinceNs(t_all)) << '\n';
    writeOutput(o, "meta.csv", meta.str());
  }
  fmt::print("done in {:.0f} s (simulation step {:.0f} s, haptic {:.0f} s); CSV in {}\n",
             shared::secondsSinceNs(t_all), part1_s, part2_s, o.out.string());
  return 0;
}

}  // namespace
}  // namespace tactus::study

int main(int argc, char** argv) {
  namespace cli = tactus::shared::cli;
  cli::App app{"tactus-accuracy: accuracy against time of the contact pipeline (compliance "
               "model, NSGS tolerance and sweeps, time step, mesh) and of the haptic local model "
               "(rate, sweeps per tick), each against a reference computed in the same run. "
               "Writes sim_accuracy.csv, haptic_accuracy.csv, *_timeseries.csv and meta.csv."};
  app.footer(
      "Example:\n"
      "  tactus-accuracy --out accuracy --quick");
  using tactus::study::Options;
  Options o;
  bool quick = false;
  std::string root;
#ifdef TACTUS_SOURCE_DIR
  root = TACTUS_SOURCE_DIR;
#endif
  std::string out, cache;
  app.addOption("--out", out, "Output directory for the CSV files")->required();
  app.addFlag("--overwrite", o.overwrite,
               "Replace the CSV files an earlier run left in --out (refused otherwise)");
  app.addFlag("--quick", quick, "Quick mode (< 2 min): coarse liver, short spans, few points");
  app.addOption("--part", o.part,
                 "What to run: all, sim (the simulation step study), states (compliance models on "
                 "the same states), haptic (the haptic loop); the report covers what exists")
      ->check(cli::isMember({"all", "sim", "states", "haptic"}))
      ->captureDefault();
  app.addFlag("--with-23k", o.with_23k,
               "Add liver_23k to the mesh study (precomputes a 1.6 GB warped compliance; slow)");
  app.addOption("--root", root, "Repository root (scenes/ is read from it)")
      ->captureDefault();
  app.addOption("--cache-dir", cache,
                 "Compliance cache directory (default: <root>/.cache/accuracy)");
  app.addOption("--duration", o.duration_s, "Seconds of the script per simulation run "
                                             "(default: 8 full, 3.5 quick)");
  app.addOption("--duration-23k", o.duration_23k_s,
                 "Seconds of the script per liver_23k run (--with-23k)")
      ->captureDefault();
  app.addOption("--early-until", o.early_until_s,
                 "End of the second force-error window [s] (the grasp and the start of the lift, "
                 "before the exact reference's grasp slips)")
      ->captureDefault();
  app.addOption("--ref-tolerance", o.ref_tolerance, "NSGS tolerance of the references")
      ->captureDefault();
  app.addOption("--ref-sweeps", o.ref_sweeps, "NSGS sweep cap of the references")
      ->captureDefault();
  app.addOption("--haptic-t0", o.haptic_t0_s, "Start of the haptic window on the script [s] "
                                               "(default 3: the jaws on the lobe)");
  app.addOption("--coherence-bound", o.coherence_bound,
                 "exact_below_coherence of the bounded warped model in the state comparison")
      ->captureDefault()
      ->check(cli::range(0.0, 1.0));
  app.addOption("--latency-steps", o.latency_steps,
                 "Simulation periods between a step's device sample and its snapshot's use")
      ->captureDefault()
      ->check(cli::range(0, 10));
  app.addOption("--tremor-mm", o.tremor_mm, "Amplitude of the tremor motion [mm]")
      ->captureDefault();
  app.addOption("--tremor-hz", o.tremor_hz, "Frequency of the tremor motion [Hz]")
      ->captureDefault();
  app.addOption("--log-level", o.log_level, "spdlog level")
      ->check(cli::isMember({"trace", "debug", "info", "warn", "error"}))
      ->captureDefault();
  TACTUS_CLI_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::from_str(o.log_level));
  o.mode = quick ? "quick" : "full";
  o.out = out;
  o.root = root;
  o.cache_dir = cache.empty() ? o.root / ".cache/accuracy" : std::filesystem::path(cache);
  try {
    return tactus::study::run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tactus-accuracy: %s\n", e.what());
    return 1;
  }
}