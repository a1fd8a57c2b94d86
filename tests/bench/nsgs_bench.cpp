// NSGS cost on a realistic dense problem: 150 contacts (450 rows) on a compliant surface patch.
// Figures: the cost of one sweep against the time to stream W once (counter sweep_per_stream),
// for both coupling schemes; cold solves against warm-started ones along a haptic-like sequence
// of slowly moving free velocities (counter sweeps = mean sweeps per solve). "Small" variants
// (10 contacts) feed the ctest smoke run.
//
// Times in the counters are thread CPU time (the 2-core machine is shared).
// Run: build/tests/bench/nsgs_bench  (or --benchmark_filter=450rows).

#include <benchmark/benchmark.h>

#include <algorithm>
#include <ctime>
#include <limits>
#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include "tactus/shared/delassus_blocks.h"
#include "tactus/shared/nsgs.h"

#include "../support/sphere_pile.h"

namespace {

using tactus::shared::ContactProblemView;
using tactus::shared::DelassusBlocks;
using tactus::shared::NsgsCoupling;
using tactus::shared::NsgsResult;
using tactus::shared::NsgsSettings;
using tactus::shared::NsgsStatus;
using tactus::shared::NsgsWorkspace;

// Contacts spread over a 1 x 1 patch of a soft surface pressed by a round indenter that also
// drags sideways. W = R^T (C (x) S) R: C_ij = exp(-|p_i - p_j| / l) + c0 delta_ij (a positive
// definite surface-compliance kernel), S a 3x3 SPD normal/tangent compliance with a little
// coupling, R per-contact rotations of the tangent plane. So W is dense and SPD, as the
// condensed FEM compliance H C H^T of a tissue is.
struct SurfaceProblem : tactus::test::DenseProblem {
  int nc = 0;
  std::vector<double> q0, dq;

  // cutoff_radius: contacts farther apart than this are not coupled (W's block fill falls with
  // it: about pi r^2 of the blocks are non-zero); infinite by default (every block non-zero).
  explicit SurfaceProblem(int contacts, unsigned seed = 1,
                          double cutoff_radius = std::numeric_limits<double>::infinity())
      : nc(contacts) {
    const int m = 3 * nc;
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u01(0.0, 1.0);
    std::vector<double> px(nc), py(nc), phi(nc);
    for (int i = 0; i < nc; ++i) {
      px[i] = u01(rng);
      py[i] = u01(rng);
      phi[i] = 2.0 * std::numbers::pi * u01(rng);
    }
    const double s[3][3] = {{1.0, 0.1, 0.0}, {0.1, 0.6, 0.0}, {0.0, 0.0, 0.6}};
    W.assign(static_cast<std::size_t>(m) * m, 0.0);
    for (int i = 0; i < nc; ++i) {
      for (int j = 0; j < nc; ++j) {
        const double r = std::hypot(px[i] - px[j], py[i] - py[j]);
        if (r > cutoff_radius) continue;
        const double c = std::exp(-r / 0.15) + (i == j ? 0.5 : 0.0);
        // R_i^T S R_j with R = rotation of (t1, t2) by phi about n
        double ri[3][3] = {{1, 0, 0}, {0, std::cos(phi[i]), -std::sin(phi[i])},
                           {0, std::sin(phi[i]), std::cos(phi[i])}};
        double rj[3][3] = {{1, 0, 0}, {0, std::cos(phi[j]), -std::sin(phi[j])},
                           {0, std::sin(phi[j]), std::cos(phi[j])}};
        for (int a = 0; a < 3; ++a) {
          for (int b = 0; b < 3; ++b) {
            double v = 0.0;
            for (int k = 0; k < 3; ++k) {
              for (int l = 0; l < 3; ++l) v += ri[k][a] * s[k][l] * rj[l][b];
            }
            W[static_cast<std::size_t>(3 * i + a) * m + 3 * j + b] = c * v;
          }
        }
      }
    }
    // indenter at the centre: approaching inside radius 0.55, separating outside; drag along x
    q0.resize(m);
    dq.resize(m);
    for (int i = 0; i < nc; ++i) {
      const double d2 = (px[i] - 0.5) * (px[i] - 0.5) + (py[i] - 0.5) * (py[i] - 0.5);
      q0[3 * i] = -(1.0 - d2 / 0.3);
      q0[3 * i + 1] = 0.4 * std::cos(phi[i]);   // drag (1, 0) in the rotated tangent frame
      q0[3 * i + 2] = -0.4 * std::sin(phi[i]);
      dq[3 * i] = -1.0;                          // the indenter pushes a little deeper
      dq[3 * i + 1] = 0.2 * std::sin(phi[i]);
      dq[3 * i + 2] = 0.2 * std::cos(phi[i]);
    }
    q = q0;
    mu.assign(nc, 0.3);
    row_offset.resize(nc + 1);
    for (int i = 0; i <= nc; ++i) row_offset[i] = 3 * i;
  }

  // Free velocity at haptic tick k (1 ms): a slow oscillation of the indenter.
  void setTick(int k) {
    const double a = 0.02 * std::sin(2.0 * std::numbers::pi * k / 500.0);
    for (std::size_t j = 0; j < q.size(); ++j) q[j] = q0[j] + a * dq[j];
  }
};

// Sum of all entries of W with four partial sums (bandwidth-bound, not add-latency bound).
double sumW(const SurfaceProblem& p) {
  const double* w = p.W.data();
  const std::size_t n = p.W.size();
  double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
  for (std::size_t k = 0; k + 4 <= n; k += 4) {
    s0 += w[k];
    s1 += w[k + 1];
    s2 += w[k + 2];
    s3 += w[k + 3];
  }
  return (s0 + s1) + (s2 + s3);
}

// Thread CPU time in ns (the machine is shared: wall time would count other processes' turns).
double cpuNs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) * 1e9 + static_cast<double>(ts.tv_nsec);
}

// Best-of CPU time (ns) to stream W once (sum of all entries).
double streamNs(const SurfaceProblem& p) {
  double best = 1e30;
  for (int rep = 0; rep < 50; ++rep) {
    const double t0 = cpuNs();
    benchmark::DoNotOptimize(sumW(p));
    best = std::min(best, cpuNs() - t0);
  }
  return best;
}

void BM_StreamW(benchmark::State& state, int contacts) {
  const SurfaceProblem p(contacts);
  for (auto _ : state) {
    benchmark::DoNotOptimize(sumW(p));
  }
  state.SetBytesProcessed(state.iterations() * static_cast<std::int64_t>(p.W.size() * 8));
}

// 20 sweeps from a mid-solve state (contacts active and changing), no error checks in between.
void BM_NsgsSweep(benchmark::State& state, int contacts, NsgsCoupling coupling) {
  SurfaceProblem p(contacts);
  NsgsWorkspace ws(p.rows(), p.nc);
  std::vector<double> f0(p.rows(), 0.0), f(p.rows());
  NsgsSettings s;
  s.max_sweeps = 3;
  s.tolerance = 0.0;
  tactus::shared::solveNsgs(p.view(), s, ws, f0.data());
  constexpr int kSweeps = 20;
  s.max_sweeps = kSweeps;
  s.check_every = 1000;
  s.coupling = coupling;
  double total_ns = 0.0;
  for (auto _ : state) {
    std::copy(f0.begin(), f0.end(), f.begin());
    const double t0 = cpuNs();
    const NsgsResult r = tactus::shared::solveNsgs(p.view(), s, ws, f.data());
    total_ns += cpuNs() - t0;
    benchmark::DoNotOptimize(r);
  }
  // includes 1/20 of the entry pass (delta = W f + q) and the final error check
  const double sweep_ns = total_ns / (static_cast<double>(state.iterations()) * kSweeps);
  const double stream_ns = streamNs(p);
  int active = 0;
  for (int i = 0; i < p.nc; ++i) active += f[3 * i] > 0.0;
  state.counters["sweep_us"] = sweep_ns * 1e-3;
  state.counters["stream_us"] = stream_ns * 1e-3;
  state.counters["sweep_per_stream"] = sweep_ns / stream_ns;
  state.counters["active_contacts"] = active;
}

// Haptic-like sequence: the free velocity moves every tick; cold (f = 0) or warm (previous f).
void BM_NsgsSequence(benchmark::State& state, int contacts, bool warm) {
  SurfaceProblem p(contacts);
  NsgsWorkspace ws(p.rows(), p.nc);
  std::vector<double> f(p.rows(), 0.0);
  NsgsSettings s;
  s.tolerance = 1e-6;
  s.max_sweeps = 1000;
  long sweeps = 0, solves = 0, failures = 0;
  int tick = 0;
  for (auto _ : state) {
    p.setTick(tick++);
    if (!warm) std::fill(f.begin(), f.end(), 0.0);
    const NsgsResult r = tactus::shared::solveNsgs(p.view(), s, ws, f.data());
    sweeps += r.sweeps;
    ++solves;
    failures += r.status != NsgsStatus::kConverged;
  }
  state.counters["sweeps"] = static_cast<double>(sweeps) / std::max(solves, 1L);
  state.counters["not_converged"] = static_cast<double>(failures);
}

// CPU time per sweep (ns) of 20 sweeps from a mid-solve state, no error checks in between.
double sweepNs(const ContactProblemView& v, NsgsCoupling coupling, int reps) {
  NsgsWorkspace ws(v.rows, v.contacts);
  std::vector<double> f0(v.rows, 0.0), f(v.rows);
  NsgsSettings s;
  s.max_sweeps = 3;
  s.tolerance = 0.0;
  tactus::shared::solveNsgs(v, s, ws, f0.data());
  constexpr int kSweeps = 20;
  s.max_sweeps = kSweeps;
  s.check_every = 1000;
  s.coupling = coupling;
  std::vector<double> times;
  for (int rep = 0; rep < reps; ++rep) {
    std::copy(f0.begin(), f0.end(), f.begin());
    const double t0 = cpuNs();
    benchmark::DoNotOptimize(tactus::shared::solveNsgs(v, s, ws, f.data()));
    times.push_back((cpuNs() - t0) / kSweeps);
  }
  std::sort(times.begin(), times.end());
  return times[times.size() / 2];
}

// Dense against block storage on the same problem, whose block fill the cutoff radius sets
// (range(0) = radius in thousandths; 450 rows): the crossover fill behind kBlockSparseMaxFill.
// Counters: fill, dense_us (symmetric row update, the dense path's fastest), blocks_us (same
// coupling on the blocks), blocks_column_us, ratio = blocks_us / dense_us, convert_us (one
// conversion of the dense W to blocks), choose_us (chooseStorage: converts, or stops once the
// fill passes kBlockSparseMaxFill), chosen_blocks. Best-of CPU times.
void BM_NsgsStorage(benchmark::State& state, int contacts) {
  const SurfaceProblem p(contacts, 1, 1e-3 * static_cast<double>(state.range(0)));
  const ContactProblemView dense = p.view();
  DelassusBlocks blocks(p.rows(), p.nc, 1.0);
  double convert_ns = 1e30;
  for (int rep = 0; rep < 20; ++rep) {
    const double t0 = cpuNs();
    blocks.assign(dense, 1.0);
    convert_ns = std::min(convert_ns, cpuNs() - t0);
  }
  // the automatic choice (kBlockSparseMaxFill): converts, or gives up early on a fuller W
  DelassusBlocks chosen(p.rows(), p.nc);
  double choose_ns = 1e30;
  for (int rep = 0; rep < 20; ++rep) {
    const double t0 = cpuNs();
    benchmark::DoNotOptimize(tactus::shared::chooseStorage(dense, chosen));
    choose_ns = std::min(choose_ns, cpuNs() - t0);
  }
  ContactProblemView sparse = dense;
  sparse.blocks = &blocks;
  double dense_ns = 0, blocks_ns = 0, column_ns = 0;
  for (auto _ : state) {
    dense_ns = sweepNs(dense, NsgsCoupling::kSymmetricRowUpdate, 15);
    blocks_ns = sweepNs(sparse, NsgsCoupling::kSymmetricRowUpdate, 15);
    column_ns = sweepNs(sparse, NsgsCoupling::kColumnUpdate, 15);
  }
  state.counters["fill"] = blocks.fill();
  state.counters["dense_us"] = dense_ns * 1e-3;
  state.counters["blocks_us"] = blocks_ns * 1e-3;
  state.counters["blocks_column_us"] = column_ns * 1e-3;
  state.counters["ratio"] = blocks_ns / dense_ns;
  state.counters["convert_us"] = convert_ns * 1e-3;
  state.counters["choose_us"] = choose_ns * 1e-3;
  state.counters["chosen_blocks"] = chosen.holds();
}

// A multi-body problem (rigid sphere pile, tests/support/sphere_pile.h; range(0) spheres):
// sweep time on each storage, and which one chooseStorage picks.
void BM_NsgsPile(benchmark::State& state) {
  const tactus::test::DenseProblem p =
      tactus::test::spherePile(static_cast<int>(state.range(0)), 1, 0.3);
  const ContactProblemView dense = p.view();
  DelassusBlocks blocks(p.rows(), p.contacts());
  const ContactProblemView chosen = tactus::shared::chooseStorage(dense, blocks);
  double dense_ns = 0, blocks_ns = 0;
  for (auto _ : state) {
    dense_ns = sweepNs(dense, NsgsCoupling::kSymmetricRowUpdate, 5);
    blocks_ns = sweepNs(chosen, NsgsCoupling::kSymmetricRowUpdate, 15);
  }
  state.counters["contacts"] = p.contacts();
  state.counters["fill"] = blocks.fill();
  state.counters["chosen_blocks"] = chosen.blocks != nullptr;
  state.counters["dense_us"] = dense_ns * 1e-3;
  state.counters["chosen_us"] = blocks_ns * 1e-3;
}

}  // namespace

BENCHMARK_CAPTURE(BM_NsgsStorage, 450rows, 150)
    ->Arg(100)->Arg(150)->Arg(200)->Arg(300)->Arg(400)->Arg(500)->Arg(700)->Arg(2000)
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_NsgsStorage, Small, 10)->Arg(300)->Iterations(1);
BENCHMARK(BM_NsgsPile)->Arg(60)->Arg(90)->Arg(150)->Iterations(1)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_StreamW, 450rows, 150);
BENCHMARK_CAPTURE(BM_NsgsSweep, 450rows_column, 150, NsgsCoupling::kColumnUpdate);
BENCHMARK_CAPTURE(BM_NsgsSweep, 450rows_row, 150, NsgsCoupling::kRowGather);
BENCHMARK_CAPTURE(BM_NsgsSweep, 450rows_symmetric, 150, NsgsCoupling::kSymmetricRowUpdate);
BENCHMARK_CAPTURE(BM_NsgsSequence, 450rows_cold, 150, false)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_NsgsSequence, 450rows_warm, 150, true)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_NsgsSweep, Small_column, 10, NsgsCoupling::kColumnUpdate);
BENCHMARK_CAPTURE(BM_NsgsSweep, Small_row, 10, NsgsCoupling::kRowGather);
BENCHMARK_CAPTURE(BM_NsgsSweep, Small_symmetric, 10, NsgsCoupling::kSymmetricRowUpdate);
BENCHMARK_CAPTURE(BM_NsgsSequence, Small_cold, 10, false);
BENCHMARK_CAPTURE(BM_NsgsSequence, Small_warm, 10, true);

BENCHMARK_MAIN();
