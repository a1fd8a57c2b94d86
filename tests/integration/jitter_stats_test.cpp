// The jitter tool's statistics, CSV writer and attach mode (a test writer fills a real segment's
// stats ring with known records; the follower must report exact percentiles and losses).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <numeric>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "jitter_core.h"
#include "tactus/shared/error.h"
#include "tactus/shared/segment.h"

namespace tactus::haptic::jitter {
namespace {

shared::StatsRecord record(std::uint64_t tick, std::int64_t period_ns, std::int64_t late_ns,
                           std::int64_t duration_ns, std::int64_t contacts = 0) {
  shared::StatsRecord r;
  r.tick = tick;
  r.scheduled_ns = 1'000'000'000 + static_cast<std::int64_t>(tick) * period_ns;
  r.woken_ns = r.scheduled_ns + late_ns;
  r.finished_ns = r.woken_ns + duration_ns;
  r.contacts = contacts;
  r.solve_ns = duration_ns / 2;
  r.sweeps = contacts > 0 ? static_cast<std::int64_t>(tick % 7) : 0;
  r.residual = contacts > 0 ? 1e-7 : 0.0;
  r.snapshot_seq = tick / 10;
  return r;
}

TEST(JitterCollector, PeriodOverrunsAndSolvedTicks) {
  JitterCollector c;  // period estimated
  for (std::uint64_t i = 0; i < 100; ++i) {
    // late i us, duration 100 us, except ticks 10 and 20 which last longer than the period
    const std::int64_t duration = (i == 10 || i == 20) ? 1'500'000 : 100'000;
    shared::StatsRecord r =
        record(i, 1'000'000, static_cast<std::int64_t>(i) * 1000, duration, i < 50 ? 5 : 0);
    if (i == 30) r.flags |= shared::kStatsOverrun;
    if (i == 40) r.flags |= shared::kStatsSolverNotConverged;
    c.add(r);
  }
  c.addLost(3);
  const JitterReport rep = c.report();
  EXPECT_EQ(rep.records, 100u);
  EXPECT_EQ(rep.lost, 3u);
  EXPECT_EQ(rep.period_ns, 1'000'000);
  EXPECT_EQ(rep.overruns, 3u);
  EXPECT_EQ(rep.overrun_flags, 1u);
  EXPECT_EQ(rep.not_converged, 1u);
  EXPECT_EQ(rep.solved, 50u);
  EXPECT_EQ(rep.period_error_us.p50, 49.0);
  EXPECT_EQ(rep.period_error_us.p90, 89.0);
  EXPECT_EQ(rep.period_error_us.p99, 98.0);
  EXPECT_EQ(rep.period_error_us.max, 99.0);
  EXPECT_EQ(rep.tick_us.p50, 100.0);
  EXPECT_EQ(rep.tick_us.max, 1500.0);
  EXPECT_EQ(rep.solve_us.count, 50u);
  EXPECT_EQ(rep.sweeps.max, 6.0);
  EXPECT_EQ(rep.contacts_p50, 5.0);
  EXPECT_NEAR(rep.rate_hz, 99.0 / (99 * 1e-3 + 99e-6), 1e-6);

  // a given period overrides the estimate: with 2 ms no duration counts, only the flag
  JitterCollector given(2'000'000);
  for (std::uint64_t i = 0; i < 100; ++i) {
    shared::StatsRecord r = record(i, 1'000'000, 0, (i == 10) ? 1'500'000 : 100'000);
    if (i == 30) r.flags |= shared::kStatsOverrun;
    given.add(r);
  }
  EXPECT_EQ(given.report().overruns, 1u);
  given.clear();
  EXPECT_EQ(given.records(), 0u);
  EXPECT_EQ(given.periodNs(), 2'000'000);
}

TEST(JitterCollector, CountsEachModelAndWhyTheLinearisationFellBack) {
  JitterCollector c(1'000'000);
  const auto add = [&](std::int64_t model, std::int64_t reason, std::int64_t rounds) {
    shared::StatsRecord r = record(c.records(), 1'000'000, 0, 100'000, 4);
    r.model = model;
    r.fallback_reason = reason;
    r.correction_rounds = rounds;
    c.add(r);
  };
  for (int i = 0; i < 5; ++i) add(shared::kStatsModelLinearized, shared::kStatsFallbackNone, 0);
  add(shared::kStatsModelCorrected, shared::kStatsFallbackContactLifts, 2);
  add(shared::kStatsModelFallbackSolve, shared::kStatsFallbackSlipTurns, 6);
  add(shared::kStatsModelFallbackSolve, shared::kStatsFallbackSlipTurns, 6);
  add(shared::kStatsModelFallbackSolve, shared::kStatsFallbackOutOfRange, 0);
  add(shared::kStatsModelFallbackSolve, 99, 0);   // a value this build does not know
  add(shared::kStatsModelFull, shared::kStatsFallbackNone, 0);
  const JitterReport rep = c.report();
  EXPECT_EQ(rep.model_linearized, 5u);
  EXPECT_EQ(rep.model_corrected, 1u);
  EXPECT_EQ(rep.model_fallback, 4u);
  EXPECT_EQ(rep.model_full, 1u);
  EXPECT_EQ(rep.fallback_by_reason[shared::kStatsFallbackSlipTurns], 2u);
  EXPECT_EQ(rep.fallback_by_reason[shared::kStatsFallbackOutOfRange], 1u);
  EXPECT_EQ(rep.fallback_by_reason[shared::kStatsFallbackContactLifts], 0u);  // corrected
  EXPECT_EQ(rep.correction_gave_up, 2u);
  const std::string table = formatTable(rep);
  EXPECT_NE(table.find("fallbacks by reason: out_of_range 1 slip_turns 2; after the active-set "
                       "correction gave up 2"),
            std::string::npos)
      << table;
}

TEST(JitterCollector, PeriodEstimateIgnoresSkippedTicks) {
  JitterCollector c;
  std::uint64_t tick = 0;
  for (int i = 0; i < 20; ++i) {
    c.add(record(tick, 500'000, 0, 10'000));
    tick += (i % 5 == 4) ? 3 : 1;  // missing records (lost) every fifth: not period steps
  }
  EXPECT_EQ(c.periodNs(), 500'000);
}

TEST(JitterCsv, OneRowPerRecordWithDerivedColumns) {
  const std::string path = ::testing::TempDir() + "/jitter_csv_test.csv";
  {
    CsvWriter w(path);
    shared::StatsRecord a = record(7, 1'000'000, 1234, 56'789, 3);
    a.force_norm_n = 1.5;
    a.flags = shared::kStatsOverrun | shared::kStatsForceClamped;
    a.model = shared::kStatsModelFallbackSolve;
    a.fallback_reason = shared::kStatsFallbackSlipTurns;
    a.correction_rounds = 6;
    w.write(a);
    w.write(record(8, 1'000'000, 0, 1, 0));
    w.close();
  }
  std::ifstream in(path);
  std::string header, l1, l2, extra;
  std::getline(in, header);
  std::getline(in, l1);
  std::getline(in, l2);
  EXPECT_FALSE(std::getline(in, extra));
  EXPECT_EQ(header, CsvWriter::header());
  // (read_ns, model_ns, output_ns, deadline_ns, prepare_ns: zero in these records)
  EXPECT_EQ(l1, "7,1007000000,1007001234,1007058023,1234,56789,28394,0,1e-07,3,1.5,0,17,"
                "3,0,0,0,0,0,6,6");
  EXPECT_EQ(l2, "8,1008000000,1008000000,1008000001,0,1,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0");
  std::remove(path.c_str());
  EXPECT_THROW({ CsvWriter bad("/nonexistent-dir/x.csv"); }, tactus::Error);
}

class JitterAttach : public ::testing::Test {
 protected:
  void SetUp() override {
    name_ = "tactus-jitter-test-" + std::to_string(::getpid());
    segment_.emplace(shared::Segment::create(name_, shared::SegmentCapacity::forContacts(2)));
  }
  void TearDown() override { segment_.reset(); }
  std::string name_;
  std::optional<shared::Segment> segment_;
};

TEST_F(JitterAttach, ExactPercentilesFromALiveRing) {
  shared::StatsRingWriter writer = segment_->statsWriter();
  RingFollower follower(name_);  // read-only attachment by name, as the tool does
  EXPECT_EQ(follower.segment().access(), shared::Access::kReadOnly);
  JitterCollector c(1'000'000);
  EXPECT_EQ(follower.drain({&c}), 0u);
  // record i: i us late, 2 i us long, 4 contacts
  for (std::uint64_t i = 1; i <= 1000; ++i) {
    writer.push(record(i, 1'000'000, static_cast<std::int64_t>(i) * 1000,
                       2 * static_cast<std::int64_t>(i) * 1000, 4));
  }
  EXPECT_EQ(follower.drain({&c}), 1000u);
  const JitterReport r = c.report();
  EXPECT_EQ(r.records, 1000u);
  EXPECT_EQ(follower.lost(), 0u);
  EXPECT_EQ(r.period_error_us.p50, 500.0);
  EXPECT_EQ(r.period_error_us.p90, 900.0);
  EXPECT_EQ(r.period_error_us.p99, 990.0);
  EXPECT_EQ(r.period_error_us.p999, 999.0);
  EXPECT_EQ(r.period_error_us.max, 1000.0);
  EXPECT_EQ(r.tick_us.p99, 1980.0);
  EXPECT_EQ(r.solve_us.p50, 500.0);
  // ticks 501..1000 last longer than the 1 ms period
  EXPECT_EQ(r.overruns, 500u);
  ASSERT_TRUE(follower.newest().has_value());
  EXPECT_EQ(follower.newest()->tick, 1000u);
}

TEST_F(JitterAttach, LappedReaderCountsExactlyTheLostRecords) {
  shared::StatsRingWriter writer = segment_->statsWriter();
  RingFollower follower(name_);
  JitterCollector c(1'000'000);
  const std::uint64_t cap = segment_->header().stats_capacity;
  ASSERT_EQ(cap, shared::kStatsRingCapacity);
  const std::uint64_t n = cap + 500;
  // record i is i ns late; the reader sleeps through n records: the oldest 500 are gone
  for (std::uint64_t i = 0; i < n; ++i)
    writer.push(record(i, 1'000'000, static_cast<std::int64_t>(i), 10));
  EXPECT_EQ(follower.drain({&c}), cap);
  EXPECT_EQ(follower.lost(), 500u);
  c.setLost(follower.lost());
  const JitterReport r = c.report();
  EXPECT_EQ(r.lost, 500u);
  EXPECT_EQ(r.records, cap);
  // the records read are 500 .. n-1 (ns), i.e. 0.5 .. 8.691 us
  EXPECT_DOUBLE_EQ(r.period_error_us.max, 1e-3 * static_cast<double>(n - 1));
  EXPECT_DOUBLE_EQ(r.period_error_us.p50, 1e-3 * static_cast<double>(500 + cap / 2 - 1));
  // a second lap after catching up: again exactly what was skipped
  for (std::uint64_t i = n; i < n + 2 * cap; ++i) writer.push(record(i, 1'000'000, 0, 10));
  EXPECT_EQ(follower.drain({&c}), cap);
  EXPECT_EQ(follower.lost(), 500u + cap);
}

TEST_F(JitterAttach, CsvFromTheRingHasOneRowPerRecord) {
  shared::StatsRingWriter writer = segment_->statsWriter();
  RingFollower follower(*segment_, shared::StatsRingReader::Start::kOldest);
  for (std::uint64_t i = 0; i < 25; ++i) writer.push(record(i, 1'000'000, 0, 10));
  const std::string path = ::testing::TempDir() + "/jitter_ring_test.csv";
  JitterCollector c;
  {
    CsvWriter w(path);
    EXPECT_EQ(follower.drain({&c}, &w), 25u);
    w.close();
  }
  std::ifstream in(path);
  int lines = 0;
  for (std::string l; std::getline(in, l);) ++lines;
  EXPECT_EQ(lines, 26);
  std::remove(path.c_str());
}

TEST(JitterPhase, HalfPeriodAfterTheReferenceGrid) {
  const std::int64_t p = 1'000'000;
  const std::int64_t ref = 5'000'000'000;
  const std::int64_t now = ref + 3'700'000;
  const std::int64_t start = halfPeriodPhase(ref, p, now, 2'000'000);
  const std::int64_t first = start + p;
  EXPECT_GE(first, now + 2'000'000);
  EXPECT_LT(first, now + 2'000'000 + p);
  EXPECT_EQ((first - ref) % p, p / 2);
}

}  // namespace
}  // namespace tactus::haptic::jitter
