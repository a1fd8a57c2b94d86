// sim_server: runs a scene. Offline (--steps N) as fast as possible with a per-stage timing
// table at the end, or as a daemon paced to real time that publishes the contact problem to the
// haptic process through the shared segment (when the scene enables haptics).
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <optional>

#include "tactus/sim/runner.h"
#include "tactus/shared/error.h"

namespace {
std::atomic<bool> g_stop{false};
void onSignal(int) { g_stop.store(true); }
}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Tactus simulation server: FEM tissue, contact and friction, god-object instrument"};
  tactus::sim::RunOptions opt;
  std::string log_level = "info";
  app.add_option("scene", opt.scene_path, "Scene file (YAML)")->required()->check(CLI::ExistingFile);
  app.add_option("--steps", opt.steps, "Run N steps offline as fast as possible, then exit");
  app.add_option("--duration", opt.duration_s, "Stop after this simulated time [s] (0: run until SIGINT/SIGTERM)");
  app.add_option("--output", opt.output_dir, "Write a VTK series (.vtu + .pvd) into DIR");
  app.add_option("--output-every", opt.output_every, "Write every N steps (with --output)");
  app.add_option("--segment", opt.segment, "Shared-memory segment name (haptics)");
  app.add_flag("--no-haptics", opt.no_haptics, "Do not publish to a segment even if enabled");
  app.add_flag("--status", opt.status, "Log a status line every second (daemon mode)");
  app.add_option("--stats-json", opt.stats_json, "Write per-stage statistics as JSON to FILE");
  app.add_option("--export-trajectory", opt.export_trajectory,
                 "Write the scene's scripted instrument trajectory as a device CSV and exit");
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}));
  CLI11_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::from_str(log_level));
  spdlog::set_pattern("[%H:%M:%S.%e] [sim] [%^%l%$] %v");

  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
  try {
    return tactus::sim::runSimulation(opt, g_stop);
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 1;
  }
}
