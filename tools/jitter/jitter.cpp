// tactus-jitter: timing of the haptic tick. Attach mode follows a running haptic_server's stats
// ring read-only; synthetic mode runs the real haptic loop in-process on synthetic snapshots, and
// replay mode (--replay FILE) on the snapshots a run recorded, published at their recorded times.
// Prints a line per second and a percentile table at the end; optional CSV, plot and a bare-loop
// baseline (same core, priority, timer method and period) for ratios.
//
// The baseline on a 2-core machine. The haptic loop owns one core; the other carries the
// simulation, the OS and this tool. A bare loop on the other core would measure a different,
// busier core; one on the haptic core competes with the loop it measures. So by default the bare
// loop runs on the haptic core, at the same SCHED_FIFO priority, during the measurement, with
// its deadlines placed half a period after the haptic loop's (read from the ring): both see the
// same core, the same moment and the same host noise, and while the haptic tick lasts less than
// half a period minus the 80 us spin margin neither delays the other (at equal FIFO priority
// neither preempts; the bare loop adds one 80 us spin per period to the core). When ticks are
// longer (e.g. 900-row problems) the bare loop's wake-ups queue behind them and its figures are
// inflated: use --baseline-mode after (synthetic only), which runs the bare loop alone on the
// same core for as many ticks once the haptic loop has stopped (same core, different moment).
#include "tactus/shared/cli.h"
#include <fmt/format.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>
#include <thread>

#include "jitter_core.h"
#include "jitter_replay.h"
#include "jitter_synthetic.h"
#include "tactus/shared/haptic_limits.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/nsgs_kernels.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/rt.h"
#include "tactus/shared/snapshot_file.h"

#ifndef TACTUS_SOURCE_DIR
#define TACTUS_SOURCE_DIR "."
#endif

namespace {

using namespace tactus;
using namespace tactus::haptic::jitter;

std::atomic<bool> g_stop{false};
void onSignal(int) { g_stop.store(true); }

struct Options {
  std::string segment = "tactus";
  double duration_s = 10.0;
  std::string csv;
  std::string plot;
  bool baseline = false;
  std::string baseline_mode = "interleaved";
  int synthetic_rows = 0;
  std::string replay;
  bool loop_replay = false;
  bool bounce_replay = false;
  double rate_hz = 1000.0;
  double sim_rate_hz = 100.0;
  int core = -1;
  int priority = 80;
  int sweeps = 50;
  int anderson_depth = 0;
  double snapshot_blend_ms = 0.0;
  std::string local_model = "automatic";
  bool full_fallback = false;
  bool no_correction = false;
  bool offline = false;
  double offline_latency_ms = 10.0;
  bool offline_device_leads = false;
  double budget_fraction = 0.4;
  double period_us = 0.0;
  std::string reader = "live";
  double wait_s = 10.0;
  unsigned seed = 1;
  bool quiet = false;
};

// The baseline thread: real-time set-up on the haptic core, then the bare loop.
struct Baseline {
  std::unique_ptr<BareLoop> bare;
  std::thread thread;
  std::atomic<bool> stop{false};
  std::string rt_summary;
  void start(int core, int priority, std::int64_t period_ns, std::size_t max_ticks,
             std::int64_t start_ns) {
    bare = std::make_unique<BareLoop>(period_ns, max_ticks);
    thread = std::thread([this, core, priority, start_ns] {
      rt_summary = shared::setupRealtimeThread(core, priority, shared::RealtimeConfig::kIgnore);
      bare->run(stop, start_ns);
      shared::setNormalPriority();
    });
  }
  void finish() {
    stop.store(true);
    if (thread.joinable()) thread.join();
  }
};

std::optional<shared::Segment> waitForSegment(const std::string& name, double wait_s) {
  const std::int64_t t0 = shared::monotonicNs();
  bool said = false;
  for (;;) {
    shared::TryOpenResult r = shared::Segment::tryOpen(name, shared::Access::kReadOnly);
    if (r.ok()) return std::move(r.segment);
    if (r.status == shared::OpenStatus::kMismatch || r.status == shared::OpenStatus::kError) {
      throw SegmentError(r.message);
    }
    if (g_stop.load() || shared::monotonicNs() - t0 > shared::secondsToNs(wait_s)) {
      throw SegmentError(
          fmt::format("segment '{}' not found after {:.0f} s ({}); start the daemons first "
                      "(scripts/start.sh) or use --synthetic ROWS",
                      name, wait_s, r.message));
    }
    if (!said) {
      std::printf("waiting for segment '%s'...\n", name.c_str());
      std::fflush(stdout);
      said = true;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
}

// The loop period: given (synthetic, --period-us) or estimated from the records read so far.
std::int64_t knownPeriodNs(const JitterCollector& c, std::int64_t given) {
  return given > 0 ? given : c.periodNs();
}

std::string plotScript() {
  if (const char* env = std::getenv("TACTUS_JITTER_PLOT")) return env;
  return std::string(TACTUS_SOURCE_DIR) + "/scripts/jitter_plot.py";
}

int run(const Options& o) {
  const bool replay = !o.replay.empty();
  if (replay && o.synthetic_rows > 0) throw Error("--replay and --synthetic exclude each other");
  if (!replay && (o.loop_replay || o.bounce_replay)) {
    throw Error("--loop and --bounce need --replay FILE");
  }
  if (o.offline_device_leads && !o.offline) throw Error("--offline-device-leads needs --offline");
  // synthetic or replay: the haptic loop runs in-process
  const bool synthetic = o.synthetic_rows > 0 || replay;
  const int core = o.core >= 0 ? o.core : shared::availableCpuCount() - 1;
  if (!synthetic && o.reader == "none") {
    throw Error("--reader none needs --synthetic or --replay (attach mode is the reader)");
  }
  if (!synthetic && o.baseline && o.baseline_mode == "after") {
    throw Error(
        "--baseline-mode after needs --synthetic or --replay: in attach mode the daemon keeps "
        "its core busy, so the bare loop is interleaved half a period after its ticks");
  }

  // the measured loop: a running daemon's segment, or the in-process synthetic rig
  std::unique_ptr<SyntheticRig> rig;
  std::unique_ptr<ReplayRig> replay_rig;
  std::optional<shared::Segment> attached;
  std::int64_t period_ns = o.period_us > 0.0 ? static_cast<std::int64_t>(o.period_us * 1e3) : 0;
  if (replay && o.offline) {
    const std::vector<shared::RecordedSnapshot> snaps = shared::readSnapshotFile(o.replay);
    OfflineReplayOptions oo;
    oo.rate_hz = o.rate_hz;
    oo.latency_ms = o.offline_latency_ms;
    oo.device_leads = o.offline_device_leads;
    oo.settings.kind = *haptic::parseLocalModelKind(o.local_model);
    oo.settings.max_sweeps = o.sweeps;
    oo.settings.anderson_depth = o.anderson_depth;
    oo.settings.reduced_fallback = !o.full_fallback;
    oo.settings.active_set_correction = !o.no_correction;
    const OfflineReplayReport r = replayOffline(snaps, oo);
    const double n = static_cast<double>(std::max<std::uint64_t>(r.ticks, 1));
    std::printf("offline replay of %s: %zu snapshots, %.0f Hz, snapshots adopted %.1f ms after "
                "their time; local model %s\n",
                o.replay.c_str(), snaps.size(), o.rate_hz, o.offline_latency_ms,
                o.local_model.c_str());
    std::printf("ticks %llu: linearized %.2f %%, corrected %.2f %%, fallback %.2f %%, full %.2f %%; converged %.2f %% "
                "(reference not converged: %llu)\n",
                static_cast<unsigned long long>(r.ticks), 100.0 * r.linearized / n,
                100.0 * r.corrected / n,
                100.0 * r.fallbacks / n, 100.0 * r.full / n, 100.0 * r.converged / n,
                static_cast<unsigned long long>(r.reference_not_converged));
    std::printf("fallback reasons:");
    for (std::size_t k = 1; k < r.fallback_reasons.size(); ++k) {
      if (r.fallback_reasons[k] == 0) continue;
      std::printf(" %s %llu",
                  std::string(haptic::toString(static_cast<haptic::FallbackReason>(k))).c_str(),
                  static_cast<unsigned long long>(r.fallback_reasons[k]));
    }
    const Percentiles e = summarize(r.force_error);
    const Percentiles su = summarize(r.solve_us);
    const Percentiles pm = summarize(r.prepare_ms);
    std::printf("\nheld force (median |F| of the full problem) %.4f N; |F_model - F_full| / held: "
                "p50 %.4f %%, p99 %.4f %%, max %.4f %%\n",
                r.held_force_n, 100.0 * e.p50, 100.0 * e.p99, 100.0 * e.max);
    std::printf("model solve (offline) p50 %.1f us, p99 %.1f us, max %.1f us; preparation p50 "
                "%.2f ms, p99 %.2f ms, max %.2f ms\n",
                su.p50, su.p99, su.max, pm.p50, pm.p99, pm.max);
    return 0;
  }
  if (replay) {
    std::vector<shared::RecordedSnapshot> snaps = shared::readSnapshotFile(o.replay);
    ReplayOptions ro;
    ro.loop = o.loop_replay || o.bounce_replay;
    ro.bounce = o.bounce_replay;
    ro.rate_hz = o.rate_hz;
    ro.core = core;
    ro.priority = o.priority;
    ro.max_sweeps = o.sweeps;
    ro.anderson_depth = o.anderson_depth;
    ro.snapshot_blend_ms = o.snapshot_blend_ms;
    ro.local_model = *haptic::parseLocalModelKind(o.local_model);
    ro.reduced_fallback = !o.full_fallback;
    ro.active_set_correction = !o.no_correction;
    ro.solve_budget_fraction = o.budget_fraction;
    replay_rig = std::make_unique<ReplayRig>(std::move(snaps), ro);
    period_ns = replay_rig->periodNs();
    std::printf(
        "replay: %zu snapshots from %s (%.2f s per pass%s), up to %d rows (%d contacts), "
        "%d device(s); "
        "loop %.0f Hz on core %d, SCHED_FIFO %d, %d sweeps max, deadline %.0f us, local model "
        "%s (%s%s fallback); reader: %s; NSGS kernel %s\n",
        replay_rig->snapshotCount(), o.replay.c_str(), 1e-9 * static_cast<double>(replay_rig->passNs()),
        o.bounce_replay ? ", back and forth" : o.loop_replay ? ", looping" : "",
        replay_rig->maxRows(), replay_rig->maxContacts(),
        replay_rig->devices(),
        o.rate_hz, core, o.priority, o.sweeps,
        o.budget_fraction * 1e-3 * static_cast<double>(period_ns), o.local_model.c_str(),
        o.no_correction ? "" : "active-set correction, ", o.full_fallback ? "full" : "reduced",
        o.reader.c_str(),
        shared::nsgsKernelName(shared::nsgsKernel()));
    if (!ro.loop && shared::secondsToNs(o.duration_s) > replay_rig->passNs()) {
      std::printf(
          "note: the recording is shorter than --duration: after it the snapshot goes stale "
          "and forces fade (--loop replays it again)\n");
    }
  } else if (synthetic) {
    SyntheticOptions so;
    so.problem.rows = o.synthetic_rows;
    so.problem.seed = o.seed;
    so.rate_hz = o.rate_hz;
    so.sim_rate_hz = o.sim_rate_hz;
    so.core = core;
    so.priority = o.priority;
    so.max_sweeps = o.sweeps;
    so.anderson_depth = o.anderson_depth;
    so.snapshot_blend_ms = o.snapshot_blend_ms;
    so.local_model = *haptic::parseLocalModelKind(o.local_model);
    so.reduced_fallback = !o.full_fallback;
    so.active_set_correction = !o.no_correction;
    so.solve_budget_fraction = o.budget_fraction;
    rig = std::make_unique<SyntheticRig>(so);
    period_ns = rig->periodNs();
    const auto& p = rig->problem();
    std::printf(
        "synthetic: %d rows (%d contacts), cold solve %d sweeps, error %.2e; "
        "loop %.0f Hz on core %d, SCHED_FIFO %d, %d sweeps max, budget %.0f us; "
        "snapshots at %.0f Hz; reader: %s; NSGS kernel %s\n",
        p.rows, p.contacts, p.solve_sweeps, p.solve_error, o.rate_hz, core, o.priority, o.sweeps,
        o.budget_fraction * 1e-3 * static_cast<double>(period_ns), o.sim_rate_hz, o.reader.c_str(),
        shared::nsgsKernelName(shared::nsgsKernel()));
  } else {
    attached = waitForSegment(o.segment, o.wait_s);
    std::printf("attached read-only to '%s' (generation %llu)\n", o.segment.c_str(),
                static_cast<unsigned long long>(attached->generation()));
  }
  const shared::Segment& seg =
      replay_rig ? replay_rig->segment() : (rig ? rig->segment() : *attached);
  // synthetic: read everything from the first tick; attach: from now on
  RingFollower follower(seg, synthetic ? shared::StatsRingReader::Start::kOldest
                                       : shared::StatsRingReader::Start::kNewest);
  JitterCollector total(period_ns);
  JitterCollector interval(period_ns);
  std::unique_ptr<CsvWriter> csv;
  std::string csv_path = o.csv;
  bool temp_csv = false;
  if (csv_path.empty() && !o.plot.empty()) {
    csv_path = fmt::format("/tmp/tactus-jitter-{}.csv", static_cast<long>(::getpid()));
    temp_csv = true;
  }
  if (!csv_path.empty()) csv = std::make_unique<CsvWriter>(csv_path);

  if (rig) {
    rig->start();
    if (!rig->rtSummary().empty()) {
      std::printf("real-time set-up incomplete: %s\n", rig->rtSummary().c_str());
    }
  }
  if (replay_rig) {
    replay_rig->start();
    if (!replay_rig->rtSummary().empty()) {
      std::printf("real-time set-up incomplete: %s\n", replay_rig->rtSummary().c_str());
    }
  }

  Baseline baseline;
  bool baseline_started = false;
  const bool interleaved = o.baseline && o.baseline_mode == "interleaved";
  const std::int64_t t0 = shared::monotonicNs();
  const std::int64_t end = t0 + shared::secondsToNs(o.duration_s);
  std::int64_t last_line = t0;
  const bool busy = o.reader == "busy";
  const bool live = o.reader != "none";
  while (!g_stop.load() && shared::monotonicNs() < end) {
    if (busy) {
      shared::cpuRelax();
    } else {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    // the baseline starts once the haptic loop's deadline grid is known
    shared::StatsRecord newest;
    if (interleaved && !baseline_started && knownPeriodNs(total, period_ns) > 0 &&
        follower.peekNewest(&newest)) {
      const std::int64_t p = knownPeriodNs(total, period_ns);
      const double left_s = 1e-9 * static_cast<double>(end - shared::monotonicNs());
      baseline.start(core, o.priority, p,
                     static_cast<std::size_t>(std::max(1.0, left_s * 1e9 / p + 16.0)),
                     halfPeriodPhase(newest.scheduled_ns, p, shared::monotonicNs()));
      baseline_started = true;
    }
    if (!live) continue;
    follower.drain({&total, &interval}, csv.get());
    if (!synthetic && !follower.stillCurrent()) {
      std::printf(
          "the segment was removed or re-created: stopping (the table covers the old "
          "one)\n");
      break;
    }
    const std::int64_t now = shared::monotonicNs();
    if (now - last_line >= shared::kNsPerS) {
      interval.setLost(follower.lost());
      if (!o.quiet) {
        std::printf("%s\n", formatLine(1e-9 * static_cast<double>(now - t0), interval.report(),
                                       follower.lost())
                                .c_str());
        std::fflush(stdout);
      }
      interval.clear();
      last_line = now;
    }
  }
  if (baseline_started) baseline.finish();
  if (rig) rig->stop();
  if (replay_rig) replay_rig->stop();
  follower.drain({&total}, csv.get());
  total.setLost(follower.lost());
  const JitterReport report = total.report();

  // "after": the bare loop alone on the (now idle) haptic core for as many ticks
  if (o.baseline && o.baseline_mode == "after") {
    baseline.start(core, o.priority, period_ns, std::max<std::size_t>(report.records, 1), 0);
    baseline_started = true;
    baseline.thread.join();  // it stops by itself after that many ticks
  }

  std::string title;
  if (replay_rig) {
    title = fmt::format("replay of {} ({} snapshots, up to {} rows), {:.0f} Hz, core {}, priority {}",
                        o.replay, replay_rig->snapshotCount(), replay_rig->maxRows(), o.rate_hz,
                        core, o.priority);
  } else if (rig) {
    title = fmt::format("synthetic {} rows ({} contacts), {:.0f} Hz, core {}, priority {}",
                        rig->problem().rows, rig->problem().contacts, o.rate_hz, core, o.priority);
  } else {
    title = fmt::format("segment '{}'", o.segment);
  }
  std::printf("\n%s\n", title.c_str());
  Percentiles bare;
  std::string bare_note;
  if (baseline_started) {
    bare = summarize(baseline.bare->latenessUs());
    bare_note = fmt::format(
        "{} ticks, {} overruns, {} on core {}, SCHED_FIFO {}, same PeriodicTimer and period{}",
        baseline.bare->ticks(), baseline.bare->overruns(),
        interleaved ? "interleaved half a period after the haptic ticks" : "after the measurement",
        core, o.priority,
        baseline.rt_summary.empty()
            ? ""
            : " (real-time set-up incomplete: " + baseline.rt_summary + ")");
  }
  std::printf("%s", formatTable(report, baseline_started ? &bare : nullptr, bare_note).c_str());

  if (csv) csv->close();
  if (!o.plot.empty()) {
    std::string bare_csv;
    if (baseline_started) {
      bare_csv = fmt::format("/tmp/tactus-jitter-bare-{}.csv", static_cast<long>(::getpid()));
      writeBareCsv(bare_csv, baseline.bare->latenessUs());
    }
    const std::string cmd =
        fmt::format("/usr/bin/python3 '{}' '{}' '{}' --title '{}'{}", plotScript(), csv_path,
                    o.plot, title, bare_csv.empty() ? "" : " --baseline '" + bare_csv + "'");
    const int rc = std::system(cmd.c_str());
    if (!bare_csv.empty()) std::filesystem::remove(bare_csv);
    if (rc != 0) {
      std::fprintf(stderr, "plot failed (%s); Debian: apt-get install python3-matplotlib\n",
                   cmd.c_str());
    } else {
      std::printf("plot written to %s\n", o.plot.c_str());
    }
  }
  if (temp_csv) std::filesystem::remove(csv_path);
  if (!o.csv.empty()) std::printf("CSV written to %s\n", o.csv.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  namespace cli = tactus::shared::cli;
  cli::App app{
      "tactus-jitter: haptic tick timing (period error, tick duration, solve time, sweeps) from "
      "a running haptic_server's stats ring (attach, read-only) or an in-process synthetic run"};
  app.footer(
      "Examples:\n"
      "  tactus-jitter --segment tactus --duration 10 --baseline --plot jitter.png\n"
      "  tactus-jitter --synthetic 450 --duration 10 --baseline\n"
      "  tactus-jitter --synthetic 900 --baseline --baseline-mode after\n"
      "  tactus-jitter --replay grasp.snap --loop --duration 10 --baseline   (sim_server "
      "--record-snapshots)\n"
      "  tactus-jitter --synthetic 450 --duration 7 --reader none   (vs --reader live / busy)");
  Options o;
  app.addOption("--segment", o.segment, "Segment to attach to (attach mode)")
      ->captureDefault();
  app.addOption("--duration", o.duration_s, "Seconds to measure")->captureDefault();
  app.addOption("--csv", o.csv, "Write one row per tick record to FILE");
  app.addOption("--plot", o.plot,
                 "Write a PNG (period-error histogram, log scale, and time series) via "
                 "scripts/jitter_plot.py and /usr/bin/python3 (python3-matplotlib)");
  app.addFlag("--baseline", o.baseline,
               "Also run a bare timer loop on the haptic core (same priority, PeriodicTimer and "
               "period) and print the ratios");
  app.addOption("--baseline-mode", o.baseline_mode,
                 "interleaved: during the measurement, deadlines half a period after the haptic "
                 "loop's; after: once the synthetic loop has stopped")
      ->check(cli::isMember({"interleaved", "after"}))
      ->captureDefault();
  app.addOption("--synthetic", o.synthetic_rows,
                 "Synthetic mode: run the haptic loop in-process on snapshots of ROWS rows "
                 "(150, 450, 900 typical)")
      ->check(cli::range(3, 3000));
  app.addOption("--replay", o.replay,
                 "Replay mode: run the haptic loop in-process on the snapshots recorded in FILE "
                 "(sim_server SCENE --steps N --record-snapshots FILE), published at their recorded times")
      ->check(cli::existingFile());
  app.addFlag("--loop", o.loop_replay,
               "Replay: start the recording over after its end (the device jumps back to the "
               "first snapshot's pose)");
  app.addFlag("--bounce", o.bounce_replay,
               "Replay: loop by playing the recording backwards from its end, then forwards "
               "again (the device moves only by recorded steps; implies --loop)");
  app.addOption("--rate", o.rate_hz, "Synthetic/replay: haptic loop rate [Hz]")
      ->check(cli::range(50.0, 4000.0))
      ->captureDefault();
  app.addOption("--sim-rate", o.sim_rate_hz, "Synthetic: snapshot rate [Hz]")
      ->check(cli::range(1.0, 1000.0))
      ->captureDefault();
  app.addOption("--core", o.core,
                 "CPU of the haptic loop (synthetic) and of the baseline (-1: the last CPU, as "
                 "haptic_server)")
      ->captureDefault();
  app.addOption("--priority", o.priority, "SCHED_FIFO priority (0: do not ask)")
      ->check(cli::range(0, 99))
      ->captureDefault();
  app.addOption("--anderson-depth", o.anderson_depth,
                 "Synthetic/replay: NSGS Anderson acceleration depth per tick (0: off)")
      ->check(cli::range(0, shared::kMaxAndersonDepth));
  app.addOption("--snapshot-blend-ms", o.snapshot_blend_ms,
                 "Synthetic/replay: blend each new snapshot's force in over this time [ms] "
                 "(haptic_server --snapshot-blend-ms; 0: off)")
      ->check(cli::finiteRange(0.0, shared::HapticLimits::kMaxSnapshotBlendMs, "ms"));
  app.addOption("--local-model", o.local_model,
                 "Synthetic/replay: the local model (haptic_server --local-model)")
      ->check(cli::isMember({"full", "linearized", "automatic"}))
      ->captureDefault();
  app.addFlag("--full-fallback", o.full_fallback,
               "Synthetic/replay: where the linearisation does not hold, re-solve every reached "
               "contact instead of the reduced problem (local_model.h)");
  app.addFlag("--no-correction", o.no_correction,
               "Synthetic/replay: where the linearisation does not hold, fall back at once "
               "instead of first correcting its active set (local_model.h)");
  app.addFlag("--offline", o.offline,
               "Replay: no real-time loop; tick the recording's timeline and compare the local "
               "model's force with the full problem solved to 1e-9 at the same poses");
  app.addOption("--offline-latency-ms", o.offline_latency_ms,
                 "Offline replay: time from a snapshot to the tick adopting it [ms]")
      ->check(cli::range(0.0, 1000.0))
      ->captureDefault();
  app.addFlag("--offline-device-leads", o.offline_device_leads,
               "Offline replay: the device follows the newest published snapshot's pose, as in "
               "the loop, while the model adopts each snapshot --offline-latency-ms later");
  app.addOption("--budget-fraction", o.budget_fraction,
                 "Synthetic/replay: the tick's deadline as a fraction of the period "
                 "(haptic_server uses 0.4)")
      ->check(cli::range(0.01, 0.9))
      ->captureDefault();
  app.addOption("--sweeps", o.sweeps, "Synthetic/replay: NSGS sweeps per tick")
      ->check(cli::range(1, 10000))
      ->captureDefault();
  app.addOption("--period-us", o.period_us,
                 "Attach: the loop period (default: estimated from the records)");
  app.addOption("--reader", o.reader,
                 "live: poll the ring every 100 ms; busy: poll it continuously; none: read it "
                 "only at the end (synthetic, <= 8192 records)")
      ->check(cli::isMember({"live", "busy", "none"}))
      ->captureDefault();
  app.addOption("--wait", o.wait_s, "Attach: seconds to wait for the segment")
      ->captureDefault();
  app.addOption("--seed", o.seed, "Synthetic: problem seed")->captureDefault();
  app.addFlag("--quiet", o.quiet, "No per-second lines");
  TACTUS_CLI_PARSE(app, argc, argv);
  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tactus-jitter: %s\n", e.what());
    return 1;
  }
}
