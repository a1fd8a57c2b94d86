// Nearest-rank percentiles (percentiles.h).
#include "tactus/shared/percentiles.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace tactus::shared {

double nearestRank(std::span<const double> sorted, double q) {
  if (sorted.empty()) return 0.0;
  const auto n = static_cast<double>(sorted.size());
  // rank = ceil(q n) in [1, n]; the slack keeps 0.9 * 10 = 9 from rounding up to 10
  const double rank = std::clamp(std::ceil(q * n - 1e-9), 1.0, n);
  return sorted[static_cast<std::size_t>(rank) - 1];
}

double percentile(std::vector<double> values, double q) {
  std::sort(values.begin(), values.end());
  return nearestRank(values, q);
}

Percentiles summarize(std::vector<double> values) {
  Percentiles p;
  p.count = values.size();
  if (values.empty()) return p;
  std::sort(values.begin(), values.end());
  p.min = values.front();
  p.p50 = nearestRank(values, 0.50);
  p.p90 = nearestRank(values, 0.90);
  p.p99 = nearestRank(values, 0.99);
  p.p999 = nearestRank(values, 0.999);
  p.max = values.back();
  p.mean = std::accumulate(values.begin(), values.end(), 0.0) / static_cast<double>(values.size());
  return p;
}

}  // namespace tactus::shared
