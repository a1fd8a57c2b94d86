// NSGS relaxation rule against plain (sor 1) and fixed-relaxed (sor 0.7, 0.5) Gauss-Seidel on
// the problem set of tests/support/nsgs_rule_set.h: sweeps to 1e-6 and 1e-9 (20000 at most).
// Run: build/tests/bench/nsgs_rule_bench --table   (docs/measurements.md's table)
//      build/tests/bench/nsgs_rule_bench --holdout (other seeds and sizes, not in the tests)
//      build/tests/bench/nsgs_rule_bench --trace NAME SOR TOL  (error after every sweep, rule off)
//      build/tests/bench/nsgs_rule_bench --anderson (Anderson acceleration against the rule alone)
// The Google Benchmark part ("Small") only feeds the ctest smoke run.

#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "../support/nsgs_rule_set.h"
#include "tactus/shared/nsgs.h"

namespace {

using tactus::shared::NsgsResult;
using tactus::shared::NsgsSettings;
using tactus::shared::NsgsStatus;
using tactus::shared::NsgsWorkspace;

NsgsResult run(const tactus::test::DenseProblem& p, const NsgsSettings& s) {
  NsgsWorkspace ws(p.rows(), p.contacts());
  std::vector<double> f(p.rows(), 0.0);
  return tactus::shared::solveNsgs(p.view(), s, ws, f.data());
}

NsgsSettings settings(double tol, double sor, bool rule) {
  NsgsSettings s;
  s.tolerance = tol;
  s.max_sweeps = 20000;
  s.sor = sor;
  if (!rule) s.stall_sweeps = 0;
  return s;
}

int sweeps(const NsgsResult& r) { return r.status == NsgsStatus::kConverged ? r.sweeps : -1; }

// Problems outside the tested set (other seeds and sizes), to check the rule is not fitted to it.
std::vector<tactus::test::NamedProblem> holdout() {
  using namespace tactus::test;
  std::vector<NamedProblem> set;
  for (unsigned seed = 6; seed <= 20; ++seed) {
    set.push_back({"spheres20_mu2_s" + std::to_string(seed), spherePile(20, seed, 2.0)});
  }
  for (unsigned seed = 6; seed <= 10; ++seed) {
    set.push_back({"spheres40_mu0.8_s" + std::to_string(seed), spherePile(40, seed, 0.8)});
    set.push_back({"spheres60c6_mu1_s" + std::to_string(seed), spherePile(60, seed, 1.0, 6)});
  }
  for (unsigned seed = 4; seed <= 8; ++seed) {
    set.push_back({"capsules6x4_mu2_s" + std::to_string(seed), capsulePile(6, 4, seed, 2.0)});
    set.push_back({"patch4x6_mu2_s" + std::to_string(seed), redundantPatch(4, 6, seed, 2.0)});
    set.push_back({"patch6x4_mu1_s" + std::to_string(seed), redundantPatch(6, 4, seed, 1.0)});
  }
  return set;
}

void table(bool hold_out) {
  const auto set = hold_out ? holdout() : tactus::test::nsgsRuleSet(TACTUS_TEST_DATA_DIR);
  std::printf("%-44s %5s %6s %6s %6s %6s %6s  %s\n", "problem", "tol", "plain", "sor0.7",
              "sor0.5", "rule", "ratio", "relaxations/sor");
  int misses = 0;
  for (const double tol : {1e-6, 1e-9}) {
    for (const auto& [name, p] : set) {
      const int plain = sweeps(run(p, settings(tol, 1.0, false)));
      const int r07 = sweeps(run(p, settings(tol, 0.7, false)));
      const int r05 = sweeps(run(p, settings(tol, 0.5, false)));
      const NsgsResult rule = run(p, settings(tol, 1.0, true));
      const int nr = sweeps(rule);
      int best = -1;
      for (const int n : {plain, r07}) {
        if (n > 0 && (best < 0 || n < best)) best = n;
      }
      const bool miss = best > 0 && (nr < 0 || nr > 1.1 * best + 10);
      misses += miss ? 1 : 0;
      char ratio[16] = "-";
      if (best > 0 && nr > 0) std::snprintf(ratio, sizeof ratio, "%.2f", double(nr) / best);
      std::printf("%-44s %5.0e %6d %6d %6d %6d %6s  %d/%.3g%s\n", name.c_str(), tol, plain, r07,
                  r05, nr, ratio, rule.relaxations, rule.sor, miss ? "  MISS" : "");
      std::fflush(stdout);
    }
  }
  std::printf("misses (rule > 1.1 x min(plain, sor 0.7) + 10, or not converged): %d\n", misses);
}

// Anderson acceleration (NsgsSettings::anderson_depth 5 and 8, the rule on) against NSGS with
// the rule alone, on the rule set and the hold-out set.
void andersonTable() {
  auto set = tactus::test::nsgsRuleSet(TACTUS_TEST_DATA_DIR);
  for (auto& named : holdout()) set.push_back(std::move(named));
  std::printf("%-44s %5s %6s %6s %6s\n", "problem", "tol", "rule", "aa5", "aa8");
  int fewer = 0, more = 0, lost = 0, runs = 0;
  for (const double tol : {1e-6, 1e-9}) {
    for (const auto& [name, p] : set) {
      int n[3];
      for (int v = 0; v < 3; ++v) {
        NsgsSettings s = settings(tol, 1.0, true);
        s.anderson_depth = v == 0 ? 0 : v == 1 ? 5 : 8;
        n[v] = sweeps(run(p, s));
      }
      ++runs;
      if (n[0] > 0 && n[2] < 0) ++lost;
      if (n[0] > 0 && n[2] > 0 && n[2] < n[0]) ++fewer;
      if (n[0] > 0 && n[2] > 1.1 * n[0]) ++more;
      std::printf("%-44s %5.0e %6d %6d %6d\n", name.c_str(), tol, n[0], n[1], n[2]);
      std::fflush(stdout);
    }
  }
  std::printf("depth 8 against the rule alone over %d runs: fewer sweeps %d, more than 1.1x %d, "
              "not converged where the rule alone converges %d\n", runs, fewer, more, lost);
}

void trace(const char* want, double sor, double tol) {
  auto set = tactus::test::nsgsRuleSet(TACTUS_TEST_DATA_DIR);
  for (auto& named : holdout()) set.push_back(std::move(named));
  for (const auto& [name, p] : set) {
    if (name != want) continue;
    NsgsWorkspace ws(p.rows(), p.contacts());
    std::vector<double> f(p.rows(), 0.0);
    NsgsSettings s = settings(tol, sor, false);
    s.max_sweeps = 1;
    for (int k = 1; k <= 20000; ++k) {
      const NsgsResult r = tactus::shared::solveNsgs(p.view(), s, ws, f.data());
      std::printf("%d %.10e\n", k, r.error);
      if (r.status == NsgsStatus::kConverged) break;
      s.delta_is_current = true;
    }
  }
}

void BM_RuleSmall(benchmark::State& state) {
  const auto p = tactus::test::spherePile(9, 1, 0.8);
  for (auto _ : state) benchmark::DoNotOptimize(run(p, settings(1e-6, 1.0, true)).sweeps);
}
BENCHMARK(BM_RuleSmall);

}  // namespace

int main(int argc, char** argv) {
  const bool hold_out = argc >= 2 && std::strcmp(argv[1], "--holdout") == 0;
  if (hold_out || (argc >= 2 && std::strcmp(argv[1], "--table") == 0)) {
    table(hold_out);
    return 0;
  }
  if (argc >= 2 && std::strcmp(argv[1], "--anderson") == 0) {
    andersonTable();
    return 0;
  }
  if (argc >= 5 && std::strcmp(argv[1], "--trace") == 0) {
    trace(argv[2], std::atof(argv[3]), std::atof(argv[4]));
    return 0;
  }
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
