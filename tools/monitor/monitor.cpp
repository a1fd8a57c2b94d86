// tactus-monitor: attaches read-only to a running segment and prints one status line per
// interval (simulation rate, haptic rate, contacts, rendered force, haptic tick p99). Used by
// scripts/start.sh; costs the haptic loop nothing (it only reads the stats ring). Waits at most
// --wait seconds for the segment to (re)appear, then gives up with a message; SIGINT, SIGTERM
// and SIGHUP stop it within 50 ms.
#include "tactus/shared/cli.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <thread>
#include <vector>

#include "tactus/shared/clock.h"
#include "tactus/shared/percentiles.h"
#include "tactus/shared/segment.h"

namespace {
std::atomic<bool> g_stop{false};
void onSignal(int) { g_stop.store(true); }

// Sleeps `s` seconds in short slices, returning early on a stop signal.
void sleepInterruptibly(double s) {
  using Clock = std::chrono::steady_clock;
  const Clock::time_point end =
      Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
  while (!g_stop.load()) {
    const Clock::duration left = end - Clock::now();
    if (left <= Clock::duration::zero()) return;
    std::this_thread::sleep_for(std::min<Clock::duration>(left, std::chrono::milliseconds(50)));
  }
}

}  // namespace

int main(int argc, char** argv) {
  using namespace tactus::shared;
  namespace cli = tactus::shared::cli;
  cli::App app{"Tactus status monitor: one line per interval from a running segment"};
  app.footer(
      "Example:\n"
      "  tactus-monitor --segment tactus --interval 1   (beside scripts/start.sh)");
  std::string name = "tactus";
  double interval_s = 1.0;
  double duration_s = 0.0;
  double wait_s = 60.0;
  app.addOption("--segment", name, "Segment name")
      ->captureDefault()
      ->check(cli::Validator(
          [](std::string& text) -> std::string {
            try {
              Segment::validateName(text);
            } catch (const std::exception& e) {
              return e.what();
            }
            return {};
          },
          "NAME"));
  app.addOption("--interval", interval_s, "Seconds between lines")
      ->captureDefault()
      ->check(cli::finiteRange(0.05, 3600.0, "s"));
  app.addOption("--duration", duration_s,
                 "Stop after S seconds; 0 (the default): run until SIGINT, SIGTERM or SIGHUP")
      ->check(cli::finiteRange(0.0, 1e7, "s"));
  app.addOption("--wait", wait_s,
                 "Give up (exit 1) when no segment has been found for S seconds")
      ->captureDefault()
      ->check(cli::finiteRange(0.1, 1e7, "s"));
  TACTUS_CLI_PARSE(app, argc, argv);
  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
  std::signal(SIGHUP, onSignal);

  std::optional<Segment> seg;
  StatsRingReader reader;  // detached (default) until the segment is open
  std::vector<StatsRecord> buf(8192);
  std::vector<double> ticks_us, period_err_us;
  const std::int64_t t0 = monotonicNs();
  std::int64_t last = t0;
  std::uint64_t last_snapshot = 0;
  std::int64_t absent_since = t0;  // when the segment was last seen (or the start)
  while (!g_stop.load()) {
    sleepInterruptibly(interval_s);
    if (g_stop.load()) break;
    const std::int64_t now = monotonicNs();
    if (duration_s > 0.0 && now - t0 > static_cast<std::int64_t>(duration_s * 1e9)) break;
    if (seg && !seg->stillCurrent()) {
      reader = StatsRingReader{};
      seg.reset();
      absent_since = now;
    }
    if (!seg) {
      TryOpenResult r = Segment::tryOpen(name, Access::kReadOnly);
      if (!r.ok()) {
        if (now - absent_since > static_cast<std::int64_t>(wait_s * 1e9)) {
          std::fprintf(stderr, "tactus-monitor: giving up after %.1f s without the segment "
                       "(--wait): %s\n", wait_s, r.message.c_str());
          return 1;
        }
        std::printf("[status] waiting for segment '%s'\n", name.c_str());
        std::fflush(stdout);
        continue;
      }
      seg.emplace(std::move(*r.segment));
      reader = seg->statsReader(StatsRingReader::Start::kNewest);
      last = now;
      last_snapshot = 0;
      continue;
    }
    ticks_us.clear();
    period_err_us.clear();
    std::size_t count = 0;
    StatsRecord newest{};
    for (std::size_t got; (got = reader.poll(buf.data(), buf.size())) > 0;) {
      for (std::size_t i = 0; i < got; ++i) {
        const StatsRecord& r = buf[i];
        ticks_us.push_back(1e-3 * static_cast<double>(r.finished_ns - r.woken_ns));
        period_err_us.push_back(1e-3 * static_cast<double>(r.woken_ns - r.scheduled_ns));
      }
      count += got;
      newest = buf[got - 1];
    }
    const double dt = 1e-9 * static_cast<double>(now - last);
    last = now;
    const std::int64_t sim_age_ms = (now - seg->heartbeatNs(Side::kSim)) / 1'000'000;
    if (count == 0) {
      std::printf("[status] sim heartbeat %lld ms ago | haptic: no ticks\n",
                  static_cast<long long>(sim_age_ms));
    } else {
      const double sim_hz =
          last_snapshot > 0 ? static_cast<double>(newest.snapshot_seq - last_snapshot) / dt : 0.0;
      last_snapshot = newest.snapshot_seq;
      // one force per device ("force 0.611 N", or "forces 0.611 0.402 N" for two devices)
      char forces[96];   // "forces" + at most kMaxInstruments " %6.3f" + " N": fits
      if (newest.devices > 1) {
        int at = std::snprintf(forces, sizeof(forces), "forces");
        const std::int64_t n = std::min<std::int64_t>(newest.devices, kMaxInstruments);
        for (std::int64_t i = 0; i < n; ++i) {
          at += std::snprintf(forces + at, sizeof(forces) - static_cast<std::size_t>(at), " %6.3f",
                              newest.device_force_norm_n[static_cast<std::size_t>(i)]);
        }
        std::snprintf(forces + at, sizeof(forces) - static_cast<std::size_t>(at), " N");
      } else {
        std::snprintf(forces, sizeof(forces), "force %6.3f N", newest.force_norm_n);
      }
      std::printf("[status] sim %6.1f Hz | haptic %7.1f Hz | contacts %3lld | %s | "
                  "tick p99 %7.1f us | wake p99 %7.1f us%s\n",
                  sim_hz, static_cast<double>(count) / dt, static_cast<long long>(newest.contacts),
                  forces, percentile(ticks_us, 0.99), percentile(period_err_us, 0.99),
                  (newest.flags & kStatsSnapshotStale) ? " | STALE" : "");
    }
    std::fflush(stdout);
  }
  return 0;
}
