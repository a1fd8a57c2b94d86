// The jitter tool's synthetic mode: the synthetic problem is a valid, solved contact problem, and
// a 0.3 s run of the real haptic loop on it writes records that solve all of its contacts. Also
// the bare-loop baseline. Real-time threads: RUN_SERIAL; no timing thresholds.
#include "jitter_synthetic.h"

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <chrono>
#include <cmath>
#include <thread>

#include "jitter_core.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/rt.h"

namespace tactus::haptic::jitter {
namespace {

TEST(JitterSyntheticProblem, SymmetricSolvedAndMixedGaps) {
  SyntheticProblemOptions o;
  o.rows = 151;  // rounded down to 150
  const SyntheticProblem p = makeSyntheticProblem(o);
  ASSERT_EQ(p.rows, 150);
  ASSERT_EQ(p.contacts, 50);
  const int m = p.rows;
  int penetrating = 0, open = 0;
  for (int i = 0; i < m; ++i) {
    EXPECT_GT(p.W[i * m + i], 0.0);
    for (int j = 0; j < i; ++j) ASSERT_EQ(p.W[i * m + j], p.W[j * m + i]);  // exactly
  }
  for (int c = 0; c < p.contacts; ++c) {
    (p.delta_free[3 * c] < 0.0 ? penetrating : open) += 1;
    EXPECT_GT(p.mu[c], 0.3);
    EXPECT_LT(p.mu[c], 0.7);
  }
  EXPECT_GT(penetrating, 0);
  EXPECT_GT(open, 0);
  // positive definite: a Cholesky factorisation exists
  {
    Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> W(
        p.W.data(), m, m);
    EXPECT_EQ(Eigen::LLT<Eigen::MatrixXd>(W).info(), Eigen::Success);
  }
  // f is a solution of the published problem (natural-map error at the solver's tolerance)
  const shared::ContactProblemView v = shared::denseProblemView(
      p.contacts, m, p.row_offset.data(), p.W.data(), m, p.delta_free.data(), p.mu.data());
  EXPECT_LE(shared::naturalMapError(v, p.f.data()), 1e-8);
  double fn_sum = 0.0;
  for (int c = 0; c < p.contacts; ++c) fn_sum += p.f[3 * c];
  EXPECT_GT(fn_sum, 0.0);
}

TEST(JitterSynthetic, ShortRunSolvesEveryContactEveryTick) {
  SyntheticOptions o;
  o.problem.rows = 150;
  o.rate_hz = 1000.0;
  o.local_model = haptic::LocalModelKind::kFull;   // NSGS every tick (sweeps counted below)
  SyntheticRig rig(o);
  RingFollower follower(rig.segment(), shared::StatsRingReader::Start::kOldest);
  JitterCollector c;
  rig.start();
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  rig.stop();
  follower.drain({&c});
  const JitterReport r = c.report();
  EXPECT_EQ(follower.lost(), 0u);
  ASSERT_GT(r.records, 10u);
  EXPECT_GT(rig.published(), 0u);
  EXPECT_EQ(r.records, rig.loop().counters().ticks.load());
  // every tick had the snapshot (published before the loop started, refreshed at 100 Hz) and
  // solved all of it, except ticks the loop itself flagged stale: on a loaded 2-core machine the
  // publisher thread can be starved past the 50 ms watchdog while the real-time thread holds
  // the other core
  EXPECT_EQ(r.solved + r.stale, r.records);
  EXPECT_GT(r.solved, r.records / 2);
  EXPECT_EQ(r.contacts_p50, 50.0);
  EXPECT_EQ(r.non_finite_residuals, 0u);
  EXPECT_GE(r.sweeps.p50, 1.0);
  EXPECT_TRUE(std::isfinite(r.residual_p50));
}

TEST(JitterSynthetic, EveryRecordCarriesAllContacts) {
  SyntheticOptions o;
  o.problem.rows = 150;
  SyntheticRig rig(o);
  rig.start();
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  rig.stop();
  shared::StatsRingReader reader =
      rig.segment().statsReader(shared::StatsRingReader::Start::kOldest);
  std::vector<shared::StatsRecord> buf(shared::kStatsRingCapacity);
  const std::size_t n = reader.poll(buf.data(), buf.size());
  ASSERT_GT(n, 10u);
  // A record the loop flagged stale (the publisher starved past the watchdog on a loaded 2-core
  // machine, as ShortRunSolvesEveryContactEveryTick explains) carries no problem; every other
  // record carries all 50 contacts, and most records are not stale.
  std::size_t stale = 0;
  for (std::size_t i = 0; i < n; ++i) {
    EXPECT_GE(buf[i].finished_ns, buf[i].woken_ns);
    if ((buf[i].flags & (shared::kStatsNoSnapshot | shared::kStatsSnapshotStale)) != 0) {
      ++stale;
      continue;
    }
    EXPECT_EQ(buf[i].contacts, 50) << "record " << i;
    EXPECT_TRUE(std::isfinite(buf[i].residual)) << "record " << i;
  }
  EXPECT_LT(2 * stale, n);
}

TEST(JitterBareLoop, StopsAfterItsTicksAndRecordsEachLateness) {
  BareLoop bare(500'000, 200);
  std::atomic<bool> stop{false};
  std::thread t([&] {
    shared::setupRealtimeThread(-1, 0, shared::RealtimeConfig::kIgnore, 64);
    bare.run(stop);
  });
  t.join();
  EXPECT_EQ(bare.ticks(), 200u);
  const std::vector<double> late = bare.latenessUs();
  ASSERT_EQ(late.size(), 200u);
  for (double l : late) EXPECT_GE(l, 0.0);
  EXPECT_EQ(bare.periodNs(), 500'000);
}

}  // namespace
}  // namespace tactus::haptic::jitter
