// Statistics, CSV, ring follower and bare-loop baseline of the jitter tool.
#include "jitter_core.h"

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>

#include "tactus/haptic/local_model.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/rt.h"

namespace tactus::haptic::jitter {

void JitterCollector::add(const shared::StatsRecord& r) {
  const std::int64_t tick_ns = r.finished_ns - r.woken_ns;
  period_error_us_.push_back(1e-3 * static_cast<double>(r.woken_ns - r.scheduled_ns));
  tick_us_.push_back(1e-3 * static_cast<double>(tick_ns));
  tick_ns_.push_back(tick_ns);
  if (r.contacts > 0) {
    solve_us_.push_back(1e-3 * static_cast<double>(r.solve_ns));
    sweeps_.push_back(static_cast<double>(r.sweeps));
    contacts_.push_back(static_cast<double>(r.contacts));
    if (std::isfinite(r.residual)) {
      residuals_.push_back(r.residual);
    } else {
      ++non_finite_;
    }
    if (r.model >= 0 && r.model < shared::kStatsModelCount) ++model_counts_[r.model];
    if (r.model == shared::kStatsModelFallbackSolve) {
      fallback_us_.push_back(1e-3 * static_cast<double>(r.solve_ns));
      if (r.fallback_reason >= 0 && r.fallback_reason < shared::kStatsFallbackReasonCount) {
        ++fallback_by_reason_[static_cast<std::size_t>(r.fallback_reason)];
      }
      if (r.correction_rounds > 0) ++correction_gave_up_;
    }
    model_us_.push_back(1e-3 * static_cast<double>(r.model_ns));
  }
  if (r.started_ns > 0) work_us_.push_back(1e-3 * static_cast<double>(r.finished_ns - r.started_ns));
  if (r.deadline_ns > 0) deadline_us_.push_back(1e-3 * static_cast<double>(r.deadline_ns - r.started_ns));
  if ((r.flags & shared::kStatsDeadlineMissed) != 0) ++deadline_missed_;
  const bool flagged = (r.flags & shared::kStatsOverrun) != 0;
  flagged_.push_back(flagged ? 1 : 0);
  if (flagged) ++overrun_flags_;
  if ((r.flags & shared::kStatsSolverNotConverged) != 0) ++not_converged_;
  if ((r.flags & (shared::kStatsSnapshotStale | shared::kStatsNoSnapshot)) != 0) ++stale_;
  // the period: scheduled-time steps between consecutive tick indices
  if (previous_ && r.tick == previous_->tick + 1 && r.scheduled_ns > previous_->scheduled_ns) {
    steps_ns_.push_back(r.scheduled_ns - previous_->scheduled_ns);
  }
  if (period_error_us_.size() == 1) first_woken_ns_ = r.woken_ns;
  last_woken_ns_ = r.woken_ns;
  previous_ = r;
}

std::int64_t JitterCollector::periodNs() const {
  if (period_ns_ > 0) return period_ns_;
  if (steps_ns_.empty()) return 0;
  std::vector<std::int64_t> s = steps_ns_;
  std::nth_element(s.begin(), s.begin() + static_cast<std::ptrdiff_t>(s.size() / 2), s.end());
  return s[s.size() / 2];
}

JitterReport JitterCollector::report() const {
  JitterReport rep;
  rep.records = records();
  rep.lost = lost_;
  rep.period_ns = periodNs();
  rep.overrun_flags = overrun_flags_;
  rep.stale = stale_;
  rep.not_converged = not_converged_;
  rep.non_finite_residuals = non_finite_;
  rep.solved = static_cast<std::uint64_t>(solve_us_.size());
  // an overrun: the loop's flag, or a tick longer than the period (known only at the end when
  // it is estimated)
  for (std::size_t k = 0; k < tick_ns_.size(); ++k) {
    if (flagged_[k] != 0 || (rep.period_ns > 0 && tick_ns_[k] > rep.period_ns)) ++rep.overruns;
  }
  if (rep.records > 1 && last_woken_ns_ > first_woken_ns_) {
    rep.span_s = 1e-9 * static_cast<double>(last_woken_ns_ - first_woken_ns_);
    rep.rate_hz = static_cast<double>(rep.records - 1) / rep.span_s;
  }
  rep.period_error_us = summarize(period_error_us_);
  rep.tick_us = summarize(tick_us_);
  rep.solve_us = summarize(solve_us_);
  rep.sweeps = summarize(sweeps_);
  rep.work_us = summarize(work_us_);
  rep.model_us = summarize(model_us_);
  rep.fallback_us = summarize(fallback_us_);
  rep.deadline_us_p50 = summarize(deadline_us_).p50;
  rep.model_full = model_counts_[shared::kStatsModelFull];
  rep.model_linearized = model_counts_[shared::kStatsModelLinearized];
  rep.model_fallback = model_counts_[shared::kStatsModelFallbackSolve];
  rep.model_corrected = model_counts_[shared::kStatsModelCorrected];
  rep.fallback_by_reason = fallback_by_reason_;
  rep.correction_gave_up = correction_gave_up_;
  rep.deadline_missed = deadline_missed_;
  rep.contacts_p50 = summarize(contacts_).p50;
  rep.residual_p50 = summarize(residuals_).p50;
  return rep;
}

void JitterCollector::clear() {
  const std::int64_t period = period_ns_;
  *this = JitterCollector(period);
}

namespace {

std::string row(const char* name, const Percentiles& p, int digits) {
  if (p.count == 0) return fmt::format("{:<22}{:>10}\n", name, "-");
  return fmt::format("{:<22}{:>10.{}f}{:>10.{}f}{:>10.{}f}{:>10.{}f}{:>10.{}f}\n", name, p.p50,
                     digits, p.p90, digits, p.p99, digits, p.p999, digits, p.max, digits);
}

std::string ratio(double a, double b) {
  if (!(b > 0.0)) return fmt::format("{:>10}", "-");
  return fmt::format("{:>9.1f}x", a / b);
}

}  // namespace

std::string formatTable(const JitterReport& r, const Percentiles* bare,
                        const std::string& bare_note) {
  std::string out = fmt::format("{:<22}{:>10}{:>10}{:>10}{:>10}{:>10}\n", "[us]", "p50", "p90",
                                "p99", "p99.9", "max");
  out += row("period error", r.period_error_us, 2);
  out += row("tick duration", r.tick_us, 2);
  out += row("solve time", r.solve_us, 2);
  out += row("sweeps [count]", r.sweeps, 0);
  out += row("tick work (deadline)", r.work_us, 2);
  out += row("model phase", r.model_us, 2);
  if (r.fallback_us.count > 0) out += row("fallback solve", r.fallback_us, 2);
  if (bare != nullptr) {
    out += row("bare loop period err", *bare, 2);
    out += fmt::format(
        "{:<22}{}{}{}{}{}\n", "ratio period err/bare", ratio(r.period_error_us.p50, bare->p50),
        ratio(r.period_error_us.p90, bare->p90), ratio(r.period_error_us.p99, bare->p99),
        ratio(r.period_error_us.p999, bare->p999), ratio(r.period_error_us.max, bare->max));
    if (!bare_note.empty()) out += fmt::format("  bare loop: {}\n", bare_note);
  }
  out += fmt::format(
      "records {} over {:.2f} s ({:.1f} Hz, period {:.1f} us); overruns {} ({:.3f} %, {} flagged "
      "by the loop); lost {}\n",
      r.records, r.span_s, r.rate_hz, 1e-3 * static_cast<double>(r.period_ns), r.overruns,
      r.records > 0 ? 100.0 * static_cast<double>(r.overruns) / static_cast<double>(r.records)
                    : 0.0,
      r.overrun_flags, r.lost);
  if (r.solved > 0) {
    out += fmt::format(
        "ticks with contacts {} (median {:.0f} contacts), residual p50 {:.2e}, "
        "not converged {}, non-finite residuals {}\n",
        r.solved, r.contacts_p50, r.residual_p50, r.not_converged, r.non_finite_residuals);
    const double solved = static_cast<double>(r.solved);
    out += fmt::format(
        "local model: full {} ({:.2f} %), linearized {} ({:.2f} %), corrected {} ({:.2f} %), "
        "fallback re-solve {} ({:.2f} %); converged {:.2f} %; deadline {:.1f} us after the "
        "start, missed {}\n",
        r.model_full, 100.0 * static_cast<double>(r.model_full) / solved, r.model_linearized,
        100.0 * static_cast<double>(r.model_linearized) / solved, r.model_corrected,
        100.0 * static_cast<double>(r.model_corrected) / solved, r.model_fallback,
        100.0 * static_cast<double>(r.model_fallback) / solved,
        100.0 * (solved - static_cast<double>(r.not_converged)) / solved, r.deadline_us_p50,
        r.deadline_missed);
    if (r.model_fallback > 0) {
      out += "fallbacks by reason:";
      for (int k = 0; k < shared::kStatsFallbackReasonCount; ++k) {
        const std::uint64_t n = r.fallback_by_reason[static_cast<std::size_t>(k)];
        if (n > 0) out += fmt::format(" {} {}", toString(static_cast<FallbackReason>(k)), n);
      }
      out += fmt::format("; after the active-set correction gave up {}\n", r.correction_gave_up);
    }
  }
  return out;
}

std::string formatLine(double t_s, const JitterReport& r, std::uint64_t lost_total) {
  return fmt::format(
      "[{:6.1f} s] {:7.1f} Hz | period err p99 {:7.2f} max {:8.2f} us | tick p99 {:8.2f} us | "
      "solve p99 {:8.2f} us | sweeps p50 {:3.0f} | contacts {:4.0f} | overruns {} | lost {}",
      t_s, r.rate_hz, r.period_error_us.p99, r.period_error_us.max, r.tick_us.p99, r.solve_us.p99,
      r.sweeps.p50, r.contacts_p50, r.overruns, lost_total);
}

const char* CsvWriter::header() {
  return "tick,scheduled_ns,woken_ns,finished_ns,period_error_ns,tick_ns,solve_ns,sweeps,residual,"
         "contacts,force_norm_n,snapshot_seq,flags,model,read_ns,model_ns,output_ns,deadline_ns,"
         "prepare_ns,fallback_reason,correction_rounds";
}

CsvWriter::CsvWriter(const std::string& path) : path_(path) {
  file_ = std::fopen(path.c_str(), "w");
  if (file_ == nullptr) {
    throw Error(
        fmt::format("cannot write the CSV file '{}': {} (check the directory exists and "
                    "is writable)",
                    path, std::strerror(errno)));
  }
  std::fprintf(file_, "%s\n", header());
}

CsvWriter::~CsvWriter() {
  if (file_ != nullptr) std::fclose(file_);
}

void CsvWriter::write(const shared::StatsRecord& r) {
  std::fprintf(file_,
               "%llu,%lld,%lld,%lld,%lld,%lld,%lld,%lld,%.6g,%lld,%.6g,%llu,%llu,%lld,%lld,%lld,"
               "%lld,%lld,%lld,%lld,%lld\n",
               static_cast<unsigned long long>(r.tick), static_cast<long long>(r.scheduled_ns),
               static_cast<long long>(r.woken_ns), static_cast<long long>(r.finished_ns),
               static_cast<long long>(r.woken_ns - r.scheduled_ns),
               static_cast<long long>(r.finished_ns - r.woken_ns),
               static_cast<long long>(r.solve_ns), static_cast<long long>(r.sweeps), r.residual,
               static_cast<long long>(r.contacts), r.force_norm_n,
               static_cast<unsigned long long>(r.snapshot_seq),
               static_cast<unsigned long long>(r.flags), static_cast<long long>(r.model),
               static_cast<long long>(r.read_ns), static_cast<long long>(r.model_ns),
               static_cast<long long>(r.output_ns),
               static_cast<long long>(r.deadline_ns > 0 ? r.deadline_ns - r.started_ns : 0),
               static_cast<long long>(r.prepare_ns), static_cast<long long>(r.fallback_reason),
               static_cast<long long>(r.correction_rounds));
}

void CsvWriter::close() {
  if (file_ == nullptr) return;
  const bool bad = std::ferror(file_) != 0;
  const int rc = std::fclose(file_);
  file_ = nullptr;
  if (bad || rc != 0)
    throw Error(fmt::format("error writing the CSV file '{}' (disk full?)", path_));
}

RingFollower::RingFollower(const std::string& name, shared::StatsRingReader::Start start)
    : owned_(shared::Segment::open(name, shared::Access::kReadOnly)),
      segment_(&*owned_),
      reader_(segment_->statsReader(start)),
      buffer_(4096) {}

RingFollower::RingFollower(const shared::Segment& segment, shared::StatsRingReader::Start start)
    : segment_(&segment), reader_(segment.statsReader(start)), buffer_(4096) {}

std::size_t RingFollower::drain(std::vector<JitterCollector*> collectors, CsvWriter* csv) {
  std::size_t total = 0;
  for (std::size_t got; (got = reader_.poll(buffer_.data(), buffer_.size())) > 0;) {
    for (std::size_t i = 0; i < got; ++i) {
      for (JitterCollector* c : collectors) c->add(buffer_[i]);
      if (csv != nullptr) csv->write(buffer_[i]);
    }
    newest_ = buffer_[got - 1];
    total += got;
  }
  return total;
}

BareLoop::BareLoop(std::int64_t period_ns, std::size_t max_ticks)
    : period_ns_(std::max(period_ns, shared::PeriodicTimer::kMinPeriodNs)),
      late_ns_(max_ticks, 0) {}

void BareLoop::run(const std::atomic<bool>& stop, std::int64_t start_ns) noexcept {
  shared::PeriodicTimer timer(period_ns_, shared::PeriodicTimer::kDefaultSpinMarginNs, start_ns);
  count_ = 0;
  // relaxed: a stop request only needs to be seen eventually
  while (count_ < late_ns_.size() && !stop.load(std::memory_order_relaxed)) {
    const shared::TimerTick t = timer.wait();
    late_ns_[count_++] = t.woken_ns - t.scheduled_ns;
  }
  overruns_ = timer.overruns();
}

std::vector<double> BareLoop::latenessUs() const {
  std::vector<double> out(count_);
  for (std::size_t i = 0; i < count_; ++i) out[i] = 1e-3 * static_cast<double>(late_ns_[i]);
  return out;
}

std::int64_t halfPeriodPhase(std::int64_t reference_deadline_ns, std::int64_t period_ns,
                             std::int64_t now_ns, std::int64_t lead_ns) {
  // first deadline = start + P must be >= now + lead and sit at reference + k P + P / 2
  const std::int64_t want_first = now_ns + lead_ns;
  std::int64_t k = (want_first - reference_deadline_ns - period_ns / 2 + period_ns - 1) / period_ns;
  if (k < 0) k = 0;
  const std::int64_t first = reference_deadline_ns + k * period_ns + period_ns / 2;
  return first - period_ns;
}

void writeBareCsv(const std::string& path, const std::vector<double>& late_us) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) throw Error(fmt::format("cannot write '{}': {}", path, std::strerror(errno)));
  std::fprintf(f, "tick,late_ns\n");
  for (std::size_t i = 0; i < late_us.size(); ++i) {
    std::fprintf(f, "%zu,%lld\n", i, static_cast<long long>(std::llround(late_us[i] * 1e3)));
  }
  std::fclose(f);
}

}  // namespace tactus::haptic::jitter
