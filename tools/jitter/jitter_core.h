#pragma once
// The jitter tool's building blocks (tactus-jitter, tools/jitter/jitter.cpp), kept in a
// library so the tests can check them on known inputs:
//
//  * Percentiles / summarize(): nearest-rank percentiles (p50, p90, p99, p99.9, max);
//  * JitterCollector: per-tick period error (woken - scheduled), tick duration (finished -
//    woken), solve time and sweeps from StatsRecords, plus overruns and the reader's lost count;
//  * CsvWriter: one row per StatsRecord;
//  * RingFollower: a read-only attachment to a segment's stats ring (the live reader);
//  * BareLoop: the baseline, a PeriodicTimer loop with nothing in the tick, on a prepared
//    real-time thread, whose deadlines can be phase-shifted against the haptic loop's.
//
// None of this runs inside the haptic tick; only BareLoop::run is real-time (allocation-free
// after construction).

#include <array>
#include <atomic>
#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "tactus/shared/messages.h"
#include "tactus/shared/segment.h"
#include "tactus/shared/percentiles.h"
#include "tactus/shared/stats_ring.h"

namespace tactus::haptic::jitter {

// Percentiles of the measured samples: the project's one definition (nearest rank).
using shared::nearestRank;
using shared::Percentiles;
using shared::summarize;

/// Aggregate of a run (all durations in microseconds).
struct JitterReport {
  std::uint64_t records = 0;        ///< records read
  std::uint64_t lost = 0;           ///< records the reader missed (writer lapped it)
  std::uint64_t overruns = 0;       ///< kStatsOverrun flag or tick duration > period
  std::uint64_t overrun_flags = 0;  ///< records with the loop's own kStatsOverrun flag
  std::uint64_t solved = 0;         ///< records with contacts > 0
  /// records flagged kStatsSnapshotStale or kStatsNoSnapshot (no snapshot to solve: the
  /// publisher was late past the watchdog, e.g. starved of CPU)
  std::uint64_t stale = 0;
  std::uint64_t not_converged = 0;  ///< records flagged kStatsSolverNotConverged
  /// the local model each solving tick used (StatsRecord::model): full re-solve, the
  /// linearisation, the linearisation with its active set corrected, a re-solve where neither
  /// held
  std::uint64_t model_full = 0, model_linearized = 0, model_corrected = 0, model_fallback = 0;
  /// fallback re-solves by why the linearisation did not hold (index: StatsFallbackReason)
  std::array<std::uint64_t, shared::kStatsFallbackReasonCount> fallback_by_reason{};
  /// fallback re-solves after at least one corrected solve of the active-set correction
  std::uint64_t correction_gave_up = 0;
  std::uint64_t deadline_missed = 0;  ///< records flagged kStatsDeadlineMissed
  double deadline_us_p50 = 0.0;     ///< the tick's budget (deadline - start), median
  std::uint64_t non_finite_residuals = 0;
  std::int64_t period_ns = 0;  ///< given, or the median scheduled-time step
  double span_s = 0.0;         ///< last woken - first woken
  double rate_hz = 0.0;        ///< (records - 1) / span
  double contacts_p50 = 0.0;
  double residual_p50 = 0.0;
  Percentiles period_error_us;  ///< woken - scheduled
  Percentiles tick_us;          ///< finished - woken
  Percentiles solve_us;         ///< solve_ns (ticks with contacts only)
  Percentiles sweeps;           ///< sweeps (ticks with contacts only)
  Percentiles work_us;          ///< finished - started: the tick's work against its deadline
  Percentiles model_us;         ///< the phase taking the snapshot and solving the model
  Percentiles fallback_us;      ///< solve time of the fallback ticks
};

/// Accumulates StatsRecords (in order, as a reader returns them).
class JitterCollector {
 public:
  /// period_ns > 0: the loop's period; 0: estimated as the median of scheduled_ns steps between
  /// consecutive tick indices.
  explicit JitterCollector(std::int64_t period_ns = 0) : period_ns_(period_ns) {}

  void add(const shared::StatsRecord& record);
  void addLost(std::uint64_t n) { lost_ += n; }
  void setLost(std::uint64_t n) { lost_ = n; }
  std::uint64_t records() const { return static_cast<std::uint64_t>(period_error_us_.size()); }
  /// The loop period in use (given or estimated; 0 before two consecutive ticks).
  std::int64_t periodNs() const;
  JitterReport report() const;
  /// Forgets everything (keeps the given period).
  void clear();

 private:
  std::int64_t period_ns_;
  std::vector<double> period_error_us_, tick_us_, solve_us_, sweeps_, contacts_, residuals_;
  std::vector<std::int64_t> tick_ns_;  ///< for overruns against the (maybe estimated) period
  std::vector<char> flagged_;          ///< kStatsOverrun per record
  std::vector<std::int64_t> steps_ns_;
  std::uint64_t overrun_flags_ = 0;
  std::uint64_t not_converged_ = 0;
  std::uint64_t model_counts_[shared::kStatsModelCount] = {};
  std::array<std::uint64_t, shared::kStatsFallbackReasonCount> fallback_by_reason_{};
  std::uint64_t correction_gave_up_ = 0;
  std::uint64_t deadline_missed_ = 0;
  std::vector<double> work_us_, model_us_, fallback_us_, deadline_us_;
  std::uint64_t stale_ = 0;
  std::uint64_t non_finite_ = 0;
  std::uint64_t lost_ = 0;
  std::int64_t first_woken_ns_ = 0;
  std::int64_t last_woken_ns_ = 0;
  std::optional<shared::StatsRecord> previous_;
};

/// The summary table (fixed width, microseconds). `bare` (optional): the baseline's period error,
/// printed with the ratios project / bare for each percentile.
std::string formatTable(const JitterReport& report, const Percentiles* bare = nullptr,
                        const std::string& bare_note = {});
/// One status line for an interval.
std::string formatLine(double t_s, const JitterReport& interval, std::uint64_t lost_total);

/// CSV with a header and one row per record:
/// tick,scheduled_ns,woken_ns,finished_ns,period_error_ns,tick_ns,solve_ns,sweeps,residual,
/// contacts,force_norm_n,snapshot_seq,flags,model,read_ns,model_ns,output_ns,deadline_ns,prepare_ns
/// (model: StatsModel; deadline_ns relative to the tick's start, 0: none)
class CsvWriter {
 public:
  /// Opens (truncates) `path`; throws tactus::Error when it cannot.
  explicit CsvWriter(const std::string& path);
  ~CsvWriter();
  CsvWriter(const CsvWriter&) = delete;
  CsvWriter& operator=(const CsvWriter&) = delete;
  void write(const shared::StatsRecord& record);
  /// Flushes and closes (throws tactus::Error on a write error); the destructor closes quietly.
  void close();
  static const char* header();
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  std::FILE* file_ = nullptr;
};

/// A reader of a segment's stats ring (read-only attachment, costs the writer nothing).
class RingFollower {
 public:
  /// Opens `name` read-only (throws tactus::SegmentError with the reason).
  explicit RingFollower(const std::string& name, shared::StatsRingReader::Start start =
                                                     shared::StatsRingReader::Start::kNewest);
  /// Attaches to an already opened segment (not owned; must outlive the follower).
  explicit RingFollower(
      const shared::Segment& segment,
      shared::StatsRingReader::Start start = shared::StatsRingReader::Start::kNewest);

  /// Reads every record available now into `collectors` (each gets every record) and `csv`.
  /// Returns the number read.
  std::size_t drain(std::vector<JitterCollector*> collectors, CsvWriter* csv = nullptr);
  /// Records the reader missed so far.
  std::uint64_t lost() const { return reader_.lost(); }
  /// The newest record read (tick index etc.), if any.
  const std::optional<shared::StatsRecord>& newest() const { return newest_; }
  /// The newest record in the ring, read or not (does not move the cursor).
  bool peekNewest(shared::StatsRecord* out) const { return reader_.newest(out); }
  const shared::Segment& segment() const { return *segment_; }
  /// False when the name was removed or now refers to a re-created segment.
  bool stillCurrent() const { return segment_->stillCurrent(); }

 private:
  std::optional<shared::Segment> owned_;
  const shared::Segment* segment_ = nullptr;
  shared::StatsRingReader reader_;
  std::vector<shared::StatsRecord> buffer_;
  std::optional<shared::StatsRecord> newest_;
};

/// The baseline: PeriodicTimer with nothing in the tick (same method as the haptic loop).
class BareLoop {
 public:
  /// Preallocates room for `max_ticks` lateness values.
  BareLoop(std::int64_t period_ns, std::size_t max_ticks);
  /// Runs until `stop` or max_ticks, first deadline = start_ns + period (start_ns = 0: now).
  /// Call on a thread already pinned and prioritised. Real-time: no allocation.
  void run(const std::atomic<bool>& stop, std::int64_t start_ns = 0) noexcept;
  /// Lateness values (woken - scheduled) [us] of the ticks run.
  std::vector<double> latenessUs() const;
  std::size_t ticks() const { return count_; }
  std::int64_t overruns() const { return overruns_; }
  std::int64_t periodNs() const { return period_ns_; }

 private:
  std::int64_t period_ns_;
  std::vector<std::int64_t> late_ns_;
  std::size_t count_ = 0;
  std::int64_t overruns_ = 0;
};

/// The start time that puts a loop's deadlines half a period after `reference_deadline_ns`'s
/// grid (k P + P / 2 past it), with the first deadline at least `lead_ns` after now_ns.
std::int64_t halfPeriodPhase(std::int64_t reference_deadline_ns, std::int64_t period_ns,
                             std::int64_t now_ns, std::int64_t lead_ns = 2'000'000);

/// Writes lateness values as CSV "tick,late_ns" (for the plot's baseline overlay).
void writeBareCsv(const std::string& path, const std::vector<double>& late_us);

}  // namespace tactus::haptic::jitter
