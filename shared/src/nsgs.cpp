#include "tactus/shared/nsgs.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <ctime>
#include <limits>

#include "nsgs_anderson.h"
#include "nsgs_local.h"
#include "nsgs_storage.h"
#include "tactus/shared/nsgs_clock.h"

namespace tactus::shared {
namespace {

using detail::BlockW;
using detail::DenseW;

// The solve's clock (nsgs_clock.h): CLOCK_MONOTONIC unless a test has set a scripted one.
std::atomic<NsgsClockFn> g_test_clock{nullptr};
std::atomic<void*> g_test_clock_context{nullptr};

std::int64_t nowNs() noexcept {
  if (const NsgsClockFn clock = g_test_clock.load(std::memory_order_relaxed)) {
    return clock(g_test_clock_context.load(std::memory_order_relaxed));
  }
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// Unnormalised squared natural-map residual and ||f||^2, ||delta||^2 given delta.
struct ErrorParts {
  double res2 = 0.0;
  double f2 = 0.0;
  double d2 = 0.0;
};

ErrorParts errorParts(const ContactProblemView& p, const double* f, const double* delta) noexcept {
  ErrorParts e;
  for (int i = 0; i < p.contacts; ++i) {
    const int r = p.row_offset[i];
    if (p.row_offset[i + 1] - r == 1) {
      const double z = std::max(0.0, f[r] - delta[r]);
      e.res2 += (f[r] - z) * (f[r] - z);
      e.f2 += f[r] * f[r];
      e.d2 += delta[r] * delta[r];
      continue;
    }
    const double mu = p.mu[i];
    const double* fi = f + r;
    const double* di = delta + r;
    const double dhat_n = di[0] + mu * detail::planeNorm(di[1], di[2]);
    double z[3] = {fi[0] - dhat_n, fi[1] - di[1], fi[2] - di[2]};
    projectOnCone(mu, z);
    for (int k = 0; k < 3; ++k) {
      e.res2 += (fi[k] - z[k]) * (fi[k] - z[k]);
      e.f2 += fi[k] * fi[k];
      e.d2 += di[k] * di[k];
    }
  }
  return e;
}

double normalisedError(const ErrorParts& e, double q2) noexcept {
  const double norm = std::sqrt(std::max({q2, e.f2, e.d2}));
  const double err = std::sqrt(e.res2);
  return norm > 0.0 ? err / norm : err;
}

// Structural checks of the view (kEmpty when they fail).
bool viewUsable(const ContactProblemView& p, const NsgsWorkspace& ws, const double* f) noexcept {
  if (p.contacts <= 0 || p.rows <= 0 || f == nullptr || p.delta_free == nullptr ||
      p.row_offset == nullptr) {
    return false;
  }
  if (p.blocks == nullptr && (p.W == nullptr || p.ld < p.rows)) return false;
  if (p.contacts > ws.maxContacts() || p.rows > ws.maxRows()) return false;
  if (p.row_offset[0] != 0 || p.row_offset[p.contacts] != p.rows) return false;
  bool any3 = false;
  for (int i = 0; i < p.contacts; ++i) {
    const int k = p.row_offset[i + 1] - p.row_offset[i];
    if (k != 1 && k != 3) return false;
    any3 = any3 || k == 3;
  }
  if (p.blocks != nullptr) {   // the blocks must hold this problem's partition
    if (p.blocks->contacts() != p.contacts || p.blocks->rows() != p.rows) return false;
    const int* ro = p.blocks->rowOffset();
    for (int i = 0; i <= p.contacts; ++i) {
      if (ro[i] != p.row_offset[i]) return false;
    }
  }
  return !any3 || p.mu != nullptr;
}

// Marks in `mark` (per row, 1.0 on a contact's first row) the contacts whose diagonal entries
// Gauss-Seidel divides by are not usable (see NsgsStatus::kIllPosed); returns their number.
template <class Storage>
int markIllPosed(const ContactProblemView& p, const Storage& w, double* mark) noexcept {
  double max_diag = 0.0;
  double buf[9];
  for (int i = 0; i < p.contacts; ++i) {
    const int r = p.row_offset[i];
    const int k = p.row_offset[i + 1] - r;
    const double* a = w.diagonalBlock(i, r, k, buf);
    for (int c = 0; c < k; ++c) {
      if (a[c * k + c] > max_diag) max_diag = a[c * k + c];   // NaN never compares greater
    }
  }
  const double floor = kMinRelativeDiagonal * max_diag;
  int count = 0;
  for (int i = 0; i < p.contacts; ++i) {
    const int r = p.row_offset[i];
    const int k = p.row_offset[i + 1] - r;
    const int used = (k == 3 && p.mu[i] > 0.0) ? 3 : 1;
    const double* diag = w.diagonalBlock(i, r, k, buf);
    bool bad = false;
    for (int a = 0; a < used; ++a) {
      const double d = diag[a * k + a];
      if (!(std::isnormal(d) && d > 0.0 && d >= floor)) bad = true;
    }
    for (int a = 0; a < k; ++a) mark[r + a] = 0.0;
    mark[r] = bad ? 1.0 : 0.0;
    count += bad ? 1 : 0;
  }
  return count;
}

}  // namespace

std::string_view toString(NsgsStatus status) noexcept {
  switch (status) {
    case NsgsStatus::kConverged: return "converged";
    case NsgsStatus::kMaxSweeps: return "max_sweeps";
    case NsgsStatus::kTimeBudget: return "time_budget";
    case NsgsStatus::kNonFinite: return "non_finite";
    case NsgsStatus::kEmpty: return "empty";
    case NsgsStatus::kIllPosed: return "ill_posed";
  }
  return "unknown";
}

void projectOnCone(double mu, double* z) noexcept {
  const double zt = detail::planeNorm(z[1], z[2]);
  if (zt <= mu * z[0]) return;
  if (mu * zt <= -z[0]) {
    z[0] = z[1] = z[2] = 0.0;
    return;
  }
  const double fn = (z[0] + mu * zt) / (1.0 + mu * mu);
  const double s = mu * fn / zt;
  z[0] = fn;
  z[1] *= s;
  z[2] *= s;
}

NsgsWorkspace::NsgsWorkspace(int max_rows, int max_contacts) { reserve(max_rows, max_contacts); }

void NsgsWorkspace::reserve(int max_rows, int max_contacts) {
  max_rows = std::max(max_rows, 0);
  max_contacts = std::max(max_contacts, 0);
  delta.assign(static_cast<std::size_t>(max_rows), 0.0);
  scratch.assign(static_cast<std::size_t>(max_rows), 0.0);
  anderson.assign(static_cast<std::size_t>(max_rows) * (3 * kMaxAndersonDepth + 6), 0.0);
  max_rows_ = max_rows;
  max_contacts_ = max_contacts;
}

int NsgsWorkspace::maxRows() const { return max_rows_; }
int NsgsWorkspace::maxContacts() const { return max_contacts_; }

namespace {

template <class Storage>
double naturalMapErrorWith(const ContactProblemView& problem, const Storage& w, const double* f,
                           double* delta_out) noexcept {
  const int m = problem.rows;
  double q2 = 0.0;
  for (int j = 0; j < m; ++j) q2 += problem.delta_free[j] * problem.delta_free[j];
  // without an output buffer, accumulate the residual row block by row block
  if (delta_out != nullptr) {
    w.computeDelta(f, delta_out);
    return normalisedError(errorParts(problem, f, delta_out), q2);
  }
  ErrorParts total;
  for (int i = 0; i < problem.contacts; ++i) {
    const int r = problem.row_offset[i];
    const int k = problem.row_offset[i + 1] - r;
    double d[3] = {0.0, 0.0, 0.0};
    w.gatherRows(i, r, k, f, d);
    for (int a = 0; a < k; ++a) d[a] += problem.delta_free[r + a];
    // one-contact view of the same formula
    const int offs[2] = {0, k};
    ContactProblemView one;
    one.contacts = 1;
    one.rows = k;
    one.row_offset = offs;
    one.mu = problem.mu != nullptr ? problem.mu + i : nullptr;
    const ErrorParts e = errorParts(one, f + r, d);
    total.res2 += e.res2;
    total.f2 += e.f2;
    total.d2 += e.d2;
  }
  return normalisedError(total, q2);
}

}  // namespace

double naturalMapError(const ContactProblemView& problem, const double* f,
                       double* delta_out) noexcept {
  if (problem.blocks != nullptr) {
    return naturalMapErrorWith(problem, BlockW(problem, *problem.blocks), f, delta_out);
  }
  return naturalMapErrorWith(problem, DenseW(problem), f, delta_out);
}

// Limit-cycle rule (see NsgsSettings::stall_sweeps): a check "repeats" when its error equals the
// error 2 to kCyclePeriods checks before it to kCycleRelTol but not the one just before (a flat
// plateau is not a cycle); a window is a limit cycle when at least half of its checks repeat.
constexpr int kCyclePeriods = 4;
constexpr double kCycleRelTol = 1e-6;
// Oscillation rule (see NsgsSettings::stall_sweeps): a peak is a rise of the error to
// kSwingRatio times the trough before it followed by a fall to 1 / kSwingRatio of the peak; it
// counts when that trough lies within kTroughToBest of the best error (an oscillation about the
// best level, not a transient excursion). kPeaksToRelax counted peaks within kPeakSpan x
// stall_sweeps sweeps, while the best error has not fallen below stall_ratio times its value at
// the previous such fall, lower sor at once. Chosen on plain Gauss-Seidel traces of the bench's
// piles (tests/bench/nsgs_rule_bench.cpp --trace): 3 peaks in 50 sweeps, or troughs within 2x,
// also fire on piles plain Gauss-Seidel solves faster than the relaxed one.
constexpr double kSwingRatio = 1.2;
constexpr double kTroughToBest = 1.5;
constexpr int kPeaksToRelax = 5;
constexpr int kPeakSpan = 2;

namespace {

// The sweeps of solveNsgs on one storage of W (see nsgs_storage.h).
template <class Storage>
NsgsResult solveWith(const ContactProblemView& p, const Storage& w, const NsgsSettings& settings,
                     NsgsWorkspace& workspace, double* f, std::int64_t t0) noexcept {
  NsgsResult result;
  const int nc = p.contacts;
  const int m = p.rows;
  double* delta = workspace.delta.data();
  double sor = settings.sor;
  const int check_every = std::max(settings.check_every, 1);
  const int max_sweeps = std::max(settings.max_sweeps, 1);
  const bool row_gather = settings.coupling == NsgsCoupling::kRowGather;
  const bool symmetric = settings.coupling == NsgsCoupling::kSymmetricRowUpdate;

  // delta = W f + q afresh; by rows when W is symmetric (see computeDeltaSymmetric)
  auto formDelta = [&]() {
    return symmetric ? detail::computeDeltaSymmetric(p, w, f, delta) : w.computeDelta(f, delta);
  };
  auto fail = [&](NsgsStatus status) {
    for (int j = 0; j < m; ++j) f[j] = 0.0;
    for (int j = 0; j < m; ++j) delta[j] = p.delta_free[j];
    result.status = status;
    result.error = std::numeric_limits<double>::infinity();
    result.elapsed_ns = nowNs() - t0;
    return result;
  };

  // inputs: mu finite, delta = W f + q finite (NaN/Inf anywhere in W, q or f shows up here;
  // with the symmetric sweep, see NsgsCoupling)
  double q2 = 0.0;
  for (int j = 0; j < m; ++j) q2 += p.delta_free[j] * p.delta_free[j];
  for (int i = 0; i < nc; ++i) {
    if (p.row_offset[i + 1] - p.row_offset[i] == 3 && !std::isfinite(p.mu[i])) {
      return fail(NsgsStatus::kNonFinite);
    }
  }
  // contacts NSGS cannot solve: held at zero force (then delta must be formed afresh)
  double* ill = workspace.scratch.data();
  result.ill_posed_contacts = markIllPosed(p, w, ill);
  bool delta_current = settings.delta_is_current;
  if (result.ill_posed_contacts > 0) {
    for (int i = 0; i < nc; ++i) {
      const int r = p.row_offset[i];
      if (ill[r] == 0.0) continue;
      for (int j = r; j < p.row_offset[i + 1]; ++j) {
        if (f[j] != 0.0) delta_current = false;
        f[j] = 0.0;
      }
    }
  }
  const std::int64_t deadline = settings.deadline_ns;
  auto pastDeadline = [&]() { return deadline > 0 && nowNs() >= deadline; };
  auto stopAtDeadline = [&](double error) {
    result.status = NsgsStatus::kTimeBudget;
    result.error = error;
    result.sor = sor;
    result.elapsed_ns = nowNs() - t0;
    return result;
  };
  double delta2 = 0.0;
  if (!delta_current && pastDeadline()) {
    return stopAtDeadline(std::numeric_limits<double>::infinity());
  }
  if (delta_current) {
    for (int j = 0; j < m; ++j) delta2 += delta[j] * delta[j];
  } else {
    delta2 = formDelta();
  }
  if (!std::isfinite(delta2) || !std::isfinite(q2)) {
    return fail(NsgsStatus::kNonFinite);
  }

  // relaxation rule (see NsgsSettings::stall_sweeps and kPeaksToRelax)
  constexpr double kInf = std::numeric_limits<double>::infinity();
  double best_error = kInf;
  double window_best;                // best error when the current window opened
  // errors of the last kCyclePeriods checks (ring, newest at recent[(checks_done - 1) % K])
  double recent[kCyclePeriods];
  int checks_done;
  int window_start;
  int window_repeats;                // checks in the window whose error repeats a recent one
  double progress_best;              // best error when it last fell below stall_ratio x this
  bool rising;                       // looking for a peak (else for a trough)
  double swing_high;                 // highest error since the last trough
  double swing_low;                  // lowest error since the last peak
  double trough;                     // the trough the current rise started from
  int peak_sweep[kPeaksToRelax];     // sweeps of the last counted peaks (ring)
  int peaks;                         // counted peaks since progress_best was set
  // the rule's state with nothing observed yet, from `sweep` on (best_error is kept)
  auto restartRule = [&](int sweep) {
    window_best = progress_best = swing_low = trough = kInf;
    for (double& e : recent) e = kInf;
    checks_done = 0;
    window_start = sweep;
    window_repeats = 0;
    rising = true;
    swing_high = 0.0;
    peaks = 0;
  };
  restartRule(0);
  result.sor = sor;
  double block[9];   // a contact's diagonal block (dense storage)
  // Anderson acceleration (NsgsSettings::anderson_depth; not with kRowGather, which keeps no
  // running delta)
  detail::Anderson anderson(row_gather ? 0 : settings.anderson_depth, m,
                            workspace.anderson.data());
  std::int64_t sweep_start = nowNs();
  std::int64_t last_sweep_ns = 0;
  std::int64_t last_anderson_ns = 0;   // duration of the last Anderson step
  bool checked = false;                // result.error holds a check's error
  for (int sweep = 1; sweep <= max_sweeps; ++sweep) {
    anderson.keepInput(f);
    bool stopped_inside = false;
    int visited = 0;
    for (int i = 0; i < nc; ++i) {
      // a look at the clock before every block of contacts, the sweep's first included
      if (deadline > 0 && i % kDeadlineCheckContacts == 0 && pastDeadline()) {
        stopped_inside = true;
        break;
      }
      ++visited;
      const int r = p.row_offset[i];
      const int k = p.row_offset[i + 1] - r;
      double* fi = f + r;
      if (ill[r] != 0.0) continue;   // ill-posed: held at zero
      // current local velocity of contact i
      double di[3];
      if (row_gather) {
        w.gatherRows(i, r, k, f, di);
        for (int a = 0; a < k; ++a) di[a] += p.delta_free[r + a];
      } else {
        for (int a = 0; a < k; ++a) di[a] = delta[r + a];
      }
      double df[3];
      detail::contactStep(k, w.diagonalBlock(i, r, k, block), k == 3 ? p.mu[i] : 0.0, sor, di,
                          fi, df);
      if (df[0] == 0.0 && df[1] == 0.0 && df[2] == 0.0) continue;
      for (int a = 0; a < k; ++a) fi[a] += df[a];
      if (row_gather) continue;
      if (symmetric) {
        w.addRowsTransposed(i, r, k, df, delta);   // equal to the columns when W = W^T
      } else {
        w.addColumns(i, r, k, df, delta);
      }
    }
    // a sweep stopped before its first contact is not counted
    result.sweeps = stopped_inside && visited == 0 ? sweep - 1 : sweep;
    const std::int64_t sweep_end = nowNs();
    last_sweep_ns = sweep_end - sweep_start;
    sweep_start = sweep_end;
    const bool over_deadline = stopped_inside || (deadline > 0 && sweep_end >= deadline);
    const bool over_budget =
        over_deadline || (settings.time_budget_ns > 0 && sweep_end - t0 >= settings.time_budget_ns);
    const bool last = sweep == max_sweeps || over_budget;
    if (sweep % check_every != 0 && !last) continue;
    if (row_gather) {
      // the check's W pass is not started once the deadline has been seen passed: the error
      // stays the last check's (+inf before any) and W f + q is not formed
      if (over_deadline) return stopAtDeadline(checked ? result.error : kInf);
      w.computeDelta(f, delta);
    }
    checked = true;
    result.error = normalisedError(errorParts(p, f, delta), q2);
    if (!std::isfinite(result.error)) return fail(NsgsStatus::kNonFinite);
    if (result.error <= settings.tolerance && !row_gather) {
      // no time left for the confirmation pass (about one sweep): not claimed
      if (deadline > 0 && nowNs() + last_sweep_ns >= deadline) {
        return stopAtDeadline(result.error);
      }
      // claim checked against delta = W f + q formed afresh (the running delta accumulates
      // rounding, worst when f is large)
      formDelta();
      result.error = normalisedError(errorParts(p, f, delta), q2);
      if (!std::isfinite(result.error)) return fail(NsgsStatus::kNonFinite);
    }
    if (result.error <= settings.tolerance) {
      result.status = NsgsStatus::kConverged;
      break;
    }
    if (last) {
      result.status = over_budget ? NsgsStatus::kTimeBudget : NsgsStatus::kMaxSweeps;
      break;
    }
    best_error = std::min(best_error, result.error);
    if (anderson.on()) {
      // The step (O(depth m), not interruptible: f and delta move together) only when it fits
      // before the deadline. Its cost is affine in the history's length, so at most about twice
      // the last step's; a sweep bounds it too while the history is short. When it does not fit,
      // the next sweep starts from this one's output (plain, stopped at its blocks' checks).
      const std::int64_t step_start = deadline > 0 ? nowNs() : 0;
      if (deadline > 0 &&
          step_start + std::max(2 * last_anderson_ns, last_sweep_ns) >= deadline) {
        continue;
      }
      // the rule watches plain sweeps only; once the acceleration turns off it starts afresh
      if (!anderson.step(result.error, f, delta)) restartRule(sweep);
      if (deadline > 0) {
        sweep_start = nowNs();
        last_anderson_ns = sweep_start - step_start;
      }
      continue;
    }
    bool repeats = false;   // at a lag of 2..kCyclePeriods checks but not at a lag of 1
    for (int back = 1; back <= kCyclePeriods; ++back) {
      const double e = recent[(checks_done - back + kCyclePeriods) % kCyclePeriods];
      const bool same = std::abs(result.error - e) <= kCycleRelTol * result.error;
      if (back == 1 && same) break;
      repeats = repeats || same;
    }
    if (repeats) ++window_repeats;
    if (best_error < settings.stall_ratio * progress_best) {
      progress_best = best_error;
      rising = true;
      swing_high = swing_low = trough = result.error;
      peaks = 0;
    } else if (rising) {
      swing_high = std::max(swing_high, result.error);
      if (result.error * kSwingRatio < swing_high) {
        if (trough <= kTroughToBest * best_error) peak_sweep[peaks++ % kPeaksToRelax] = sweep;
        rising = false;
        swing_low = result.error;
      }
    } else {
      swing_low = std::min(swing_low, result.error);
      if (result.error > kSwingRatio * swing_low) {
        rising = true;
        swing_high = result.error;
        trough = swing_low;
      }
    }
    // the oldest of the last kPeaksToRelax peaks is peak_sweep[peaks % kPeaksToRelax]
    if (settings.stall_sweeps > 0 && peaks >= kPeaksToRelax &&
        sweep - peak_sweep[peaks % kPeaksToRelax] <= kPeakSpan * settings.stall_sweeps &&
        sor > settings.min_sor) {
      sor = std::max(settings.min_sor, sor * settings.stall_sor_factor);
      ++result.relaxations;
      progress_best = best_error;
      rising = true;
      swing_high = swing_low = trough = result.error;
      peaks = 0;
    }
    recent[checks_done % kCyclePeriods] = result.error;
    ++checks_done;
    if (settings.stall_sweeps > 0 && sweep - window_start >= settings.stall_sweeps) {
      const int checks = (sweep - window_start) / check_every;
      const bool stalled = best_error > settings.stall_ratio * window_best;
      const bool oscillating = 2 * window_repeats >= checks;
      // past 3/4 of the sweep budget, any stagnation counts (the budget is the harder limit)
      const bool late =
          4 * static_cast<std::int64_t>(sweep) > 3 * static_cast<std::int64_t>(max_sweeps);
      if (stalled && (oscillating || late) && sor > settings.min_sor) {
        sor = std::max(settings.min_sor, sor * settings.stall_sor_factor);
        ++result.relaxations;
      }
      window_start = sweep;
      window_best = best_error;
      window_repeats = 0;
    }
  }
  if (result.ill_posed_contacts > 0) result.status = NsgsStatus::kIllPosed;
  result.sor = sor;
  result.elapsed_ns = nowNs() - t0;
  return result;
}

}  // namespace

void setNsgsClockForTesting(NsgsClockFn clock, void* context) noexcept {
  g_test_clock_context.store(context, std::memory_order_relaxed);
  g_test_clock.store(clock, std::memory_order_relaxed);
}

NsgsResult solveNsgs(const ContactProblemView& problem, const NsgsSettings& settings,
                     NsgsWorkspace& workspace, double* f) noexcept {
  const std::int64_t t0 = nowNs();
  if (!viewUsable(problem, workspace, f)) return NsgsResult{};
  if (problem.blocks != nullptr) {
    return solveWith(problem, BlockW(problem, *problem.blocks), settings, workspace, f, t0);
  }
  return solveWith(problem, DenseW(problem), settings, workspace, f, t0);
}

}  // namespace tactus::shared
