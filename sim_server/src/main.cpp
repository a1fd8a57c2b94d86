// sim_server: runs a scene. Offline (--steps N) as fast as possible with a per-stage timing
// table at the end, or as a daemon paced to real time that publishes the contact problem to the
// haptic process through the shared segment (when the scene enables haptics).
#include "tactus/shared/cli.h"
#include <new>
#include <spdlog/spdlog.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <optional>

#include "tactus/sim/runner.h"
#include "tactus/sim/scene.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/shared/messages.h"

namespace {
// the one stop flag: loading, C0 precomputation and file reads poll it too
std::atomic<bool>& g_stop = tactus::shared::stopFlag();
volatile std::sig_atomic_t g_signal = 0;
void onSignal(int signo) {
  g_signal = signo;
  g_stop.store(true);
}
}  // namespace

int main(int argc, char** argv) {
  namespace cli = tactus::shared::cli;
  cli::App app{"Tactus simulation server: FEM tissue, contact and friction, god-object instrument"};
  app.footer(
      "Examples:\n"
      "  sim_server scenes/liver_grasp.yaml   (scripts/start.sh starts it with haptic_server)\n"
      "  sim_server scenes/liver_grasp.yaml --steps 800 --record-snapshots grasp.snap");
  tactus::sim::RunOptions opt;
  std::string log_level = "info";
  app.addOption("scene", opt.scene_path, "Scene file (YAML)")
      ->required()
      ->check(cli::existingFile());
  app.addOption("--steps", opt.steps, "Run N >= 1 steps offline as fast as possible, then exit")
      ->check(cli::range(1L, 1'000'000'000L));
  app.addOption("--duration", opt.duration_s,
                 "Stop after this simulated time [s]; 0 (the default): run until SIGINT, SIGTERM "
                 "or SIGHUP")
      ->check(cli::finiteRange(0.0, 1e7, "s"));
  app.addOption("--output", opt.output_dir, "Write a VTK series (.vtu + .pvd) into DIR");
  app.addOption("--output-every", opt.output_every, "Write every N steps (with --output)");
  app.addOption("--segment", opt.segment, "Shared-memory segment name (haptics)");
  app.addFlag("--no-haptics", opt.no_haptics, "Do not publish to a segment even if enabled");
  app.addFlag("--status", opt.status, "Log a status line every second (daemon mode)");
  app.addOption("--stats-json", opt.stats_json, "Write per-stage statistics as JSON to FILE");
  app.addOption("--export-trajectory", opt.export_trajectory,
                 "Write the scene's scripted instrument trajectory as a device CSV and exit");
  app.addOption("--export-instrument", opt.export_instrument,
                 "Whose trajectory --export-trajectory writes (0-based instrument index)")
      ->check(cli::range(0, tactus::shared::kMaxInstruments - 1));
  bool print_instrument_count = false;
  app.addFlag("--print-instrument-count", print_instrument_count,
               "Print the scene's number of instruments (devices haptic_server serves) and exit");
  bool print_haptic_options = false;
  app.addFlag("--print-haptic-options", print_haptic_options,
               "Print haptic_server's options for the scene's haptics section (workspace "
               "mapping), one per line, and exit");
  app.addOption("--record-snapshots", opt.record_snapshots,
                 "Record every step's contact snapshot (simulated time stamps) to a new FILE, "
                 "written at the end of the run, for tactus-jitter --replay FILE (offline with "
                 "--steps, or as a daemon)");
  app.addOption("--record-snapshots-max-mb", opt.record_snapshots_max_mb,
                 "Stop recording snapshots (the run goes on) before the file passes this size "
                 "[MiB]; 2048 is what tactus-jitter --replay reads")
      ->check(cli::range(1, tactus::sim::kMaxRecordingMiB))->captureDefault();
  app.addOption("--record-snapshots-from-step", opt.record_snapshots_from_step,
                 "Record the snapshots from this step on (1: every step), e.g. a long run's "
                 "hold without the approach before it")
      ->check(cli::range(1L, 1L << 40))->captureDefault();
  app.addFlag("--overwrite", opt.overwrite,
               "Replace existing --stats-json / --export-trajectory / --record-snapshots files "
               "and an earlier "
               "run's VTK series in the --output folder");
  app.addOption("--log-level", log_level, "trace, debug, info, warn, error")
      ->check(cli::isMember({"trace", "debug", "info", "warn", "error"}));
  TACTUS_CLI_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::from_str(log_level));
  spdlog::set_pattern("[%H:%M:%S.%e] [sim] [%^%l%$] %v");

  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
  std::signal(SIGHUP, onSignal);  // the terminal closed: stop cleanly (removes the segment)
  try {
    if (print_instrument_count) {
      std::printf("%d\n", tactus::sim::instrumentCount(tactus::sim::loadScene(opt.scene_path)));
      return 0;
    }
    if (print_haptic_options) {
      const tactus::sim::SceneSpec spec = tactus::sim::loadScene(opt.scene_path);
      for (const std::string& o : tactus::sim::hapticServerOptions(spec.haptics)) {
        std::printf("%s\n", o.c_str());
      }
      return 0;
    }
    return tactus::sim::runSimulation(opt, g_stop);
  } catch (const tactus::Cancelled& e) {
    spdlog::error("{}; exiting", e.what());
    return 128 + (g_signal != 0 ? static_cast<int>(g_signal) : SIGTERM);
  } catch (const std::bad_alloc&) {
    spdlog::error("out of memory: the scene needs more memory than this machine can give (a "
                  "large mesh's compliance block C0, a large max_contacts); see the memory "
                  "figures logged above, use a coarser mesh, compliance.c0_precision: float, or "
                  "compliance.model: exact");
    return 1;
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 1;
  }
}
