// Nearest-rank percentiles, the one definition every tool and report uses: each figure is a
// value of the sample, p_q the ceil(q n)-th smallest.
#include "tactus/shared/percentiles.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <vector>

namespace tactus::shared {
namespace {

std::vector<double> range(int from, int to) {
  std::vector<double> v;
  for (int i = from; i <= to; ++i) v.push_back(i);
  return v;
}

TEST(Percentiles, NearestRankOnKnownInputs) {
  std::vector<double> v = range(1, 1000);
  std::reverse(v.begin(), v.end());  // summarize sorts
  const Percentiles p = summarize(v);
  EXPECT_EQ(p.count, 1000u);
  EXPECT_EQ(p.p50, 500.0);
  EXPECT_EQ(p.p90, 900.0);
  EXPECT_EQ(p.p99, 990.0);
  EXPECT_EQ(p.p999, 999.0);
  EXPECT_EQ(p.max, 1000.0);
  EXPECT_EQ(p.min, 1.0);
  EXPECT_DOUBLE_EQ(p.mean, 500.5);

  const Percentiles q = summarize(range(1, 10));
  EXPECT_EQ(q.p50, 5.0);
  EXPECT_EQ(q.p90, 9.0);
  EXPECT_EQ(q.p99, 10.0);
  EXPECT_EQ(q.p999, 10.0);
}

TEST(Percentiles, EmptySingleAndOutlier) {
  const Percentiles e = summarize({});
  EXPECT_EQ(e.count, 0u);
  EXPECT_EQ(e.p99, 0.0);
  EXPECT_EQ(e.max, 0.0);
  const Percentiles s = summarize({7.5});
  EXPECT_EQ(s.p50, 7.5);
  EXPECT_EQ(s.p999, 7.5);
  // one outlier in 2000: visible at max only; one in 500: visible at p99.9 as well
  std::vector<double> v(2000, 1.0);
  v[1234] = 100.0;
  Percentiles o = summarize(v);
  EXPECT_EQ(o.p999, 1.0);
  EXPECT_EQ(o.max, 100.0);
  v.assign(500, 1.0);
  v[3] = 100.0;
  o = summarize(v);
  EXPECT_EQ(o.p99, 1.0);
  EXPECT_EQ(o.p999, 100.0);
  const std::vector<double> sorted{1.0, 2.0, 3.0};
  EXPECT_EQ(nearestRank(sorted, 0.0), 1.0);
  EXPECT_EQ(nearestRank(sorted, 1.0), 3.0);
  EXPECT_EQ(nearestRank({}, 0.5), 0.0);
}

// the unsorted entry point sorts a copy and agrees with the summary
TEST(Percentiles, UnsortedPercentileAgreesWithTheSummary) {
  const std::vector<double> v{5.0, 1.0, 4.0, 2.0, 3.0, 9.0, 8.0, 7.0, 6.0, 10.0};
  const Percentiles p = summarize(v);
  EXPECT_EQ(percentile(v, 0.5), p.p50);
  EXPECT_EQ(percentile(v, 0.9), p.p90);
  EXPECT_EQ(percentile(v, 1.0), p.max);
  EXPECT_EQ(percentile(v, 0.0), 1.0);
  EXPECT_EQ(v.front(), 5.0);  // the caller's values are left as they were
}

}  // namespace
}  // namespace tactus::shared
