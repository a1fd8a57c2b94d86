#pragma once
// Percentiles and summaries of measured samples, one definition for every tool and report
// (tactus-bench, tactus-jitter, tactus-monitor, the viewer's status, sim_server --stats-json).
//
// Nearest rank: the q-percentile of n values is the ceil(q n)-th smallest (1-based, clamped to
// [1, n]), so every reported figure is a value that occurred (a p99 of a tick time is a tick
// that happened, never an interpolation between two). Not for the real-time path: these sort.

#include <cstddef>
#include <span>
#include <vector>

namespace tactus::shared {

/// Summary of a sample; count = 0: everything zero.
struct Percentiles {
  std::size_t count = 0;
  double min = 0.0;
  double p50 = 0.0;
  double p90 = 0.0;
  double p99 = 0.0;
  double p999 = 0.0;
  double max = 0.0;
  double mean = 0.0;
};

/// Nearest-rank percentile of ascending `sorted` values, q in [0, 1] (q = 0 gives the minimum,
/// q = 1 the maximum); 0 for an empty sample.
double nearestRank(std::span<const double> sorted, double q);

/// Nearest-rank percentile of unsorted values (sorts a copy).
double percentile(std::vector<double> values, double q);

/// The summary of unsorted values (taken by value: sorted in place).
Percentiles summarize(std::vector<double> values);

}  // namespace tactus::shared
