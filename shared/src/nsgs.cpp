#include "tactus/shared/nsgs.h"

#include <algorithm>
#include <cmath>
#include <ctime>
#include <limits>
#include <numbers>

namespace tactus::shared {
namespace {

std::int64_t nowNs() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// Local 3x3 block (row-major) and free term of one contact.
struct Local3 {
  double a[3][3];
  double b[3];
  double mu;
};

// Slip residual at angle theta: f = fn (1, mu c, mu s), delta_n = 0.
struct SlipEval {
  bool valid = false;  // denominator > 0 (f_n > 0)
  double fn = 0.0;
  double g = 0.0;      // e x delta_t (zero at a slip solution)
  double h = 0.0;      // e . delta_t (negative at a slip solution)
  double dg = 0.0;     // d g / d theta
};

SlipEval evalSlip(const Local3& p, double theta) noexcept {
  SlipEval r;
  const double c = std::cos(theta);
  const double s = std::sin(theta);
  const double mu = p.mu;
  const double den = p.a[0][0] + mu * (p.a[0][1] * c + p.a[0][2] * s);
  if (!(den > 0.0)) return r;
  r.valid = true;
  const double fn = -p.b[0] / den;
  const double dden = mu * (-p.a[0][1] * s + p.a[0][2] * c);
  const double dfn = -fn * dden / den;
  // delta_t = fn (a_tn + mu a_tt e) + b_t
  const double k1 = p.a[1][0] + mu * (p.a[1][1] * c + p.a[1][2] * s);
  const double k2 = p.a[2][0] + mu * (p.a[2][1] * c + p.a[2][2] * s);
  const double d1 = fn * k1 + p.b[1];
  const double d2 = fn * k2 + p.b[2];
  const double dd1 = dfn * k1 + fn * mu * (-p.a[1][1] * s + p.a[1][2] * c);
  const double dd2 = dfn * k2 + fn * mu * (-p.a[2][1] * s + p.a[2][2] * c);
  r.fn = fn;
  r.g = c * d2 - s * d1;
  r.h = c * d1 + s * d2;
  r.dg = (c * dd2 - s * dd1) - r.h;
  return r;
}

void setSlip(const Local3& p, double theta, double fn, double* f) noexcept {
  f[0] = fn;
  f[1] = p.mu * fn * std::cos(theta);
  f[2] = p.mu * fn * std::sin(theta);
}

// Bisection on [lo, hi] where g changes sign; true with the root's force in f when valid.
bool bisectSlip(const Local3& p, double lo, double hi, double g_lo, double h_tol,
                double* f) noexcept {
  for (int it = 0; it < 100 && hi - lo > 1e-15; ++it) {
    const double mid = 0.5 * (lo + hi);
    const SlipEval e = evalSlip(p, mid);
    if (!e.valid) return false;
    if ((e.g < 0.0) == (g_lo < 0.0)) {
      lo = mid;
      g_lo = e.g;
    } else {
      hi = mid;
    }
  }
  const double theta = 0.5 * (lo + hi);
  const SlipEval e = evalSlip(p, theta);
  if (!e.valid || e.h > h_tol || !std::isfinite(e.fn)) return false;
  setSlip(p, theta, e.fn, f);
  return true;
}

// Degenerate block: projected fixed point f <- P_K(f - rho (a f + b)_hat), from f_old.
void slipFallback(const Local3& p, const double* f_old, double* f) noexcept {
  const auto& a = p.a;
  const double mu = p.mu;
  double rho = 0.0;
  for (int k = 0; k < 3; ++k) rho = std::max(rho, a[k][k]);
  rho = rho > 0.0 ? 1.0 / rho : 1.0;
  double z[3] = {f_old[0], f_old[1], f_old[2]};
  projectOnCone(mu, z);
  for (int it = 0; it < 100; ++it) {
    double d[3];
    for (int k = 0; k < 3; ++k) d[k] = a[k][0] * z[0] + a[k][1] * z[1] + a[k][2] * z[2] + p.b[k];
    d[0] += mu * std::hypot(d[1], d[2]);
    for (int k = 0; k < 3; ++k) z[k] -= rho * d[k];
    projectOnCone(mu, z);
  }
  f[0] = z[0];
  f[1] = z[1];
  f[2] = z[2];
}

// x . y with four independent partial sums (a single chain is add-latency bound).
inline double dot(const double* x, const double* y, int n) noexcept {
  double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
  int k = 0;
  for (; k + 4 <= n; k += 4) {
    s0 += x[k] * y[k];
    s1 += x[k + 1] * y[k + 1];
    s2 += x[k + 2] * y[k + 2];
    s3 += x[k + 3] * y[k + 3];
  }
  for (; k < n; ++k) s0 += x[k] * y[k];
  return (s0 + s1) + (s2 + s3);
}

// (x0 . y, x1 . y, x2 . y) in one pass over y, two partial sums per row.
inline void dot3(const double* x0, const double* x1, const double* x2, const double* y, int n,
                 double* out) noexcept {
  double a0 = 0.0, a1 = 0.0, b0 = 0.0, b1 = 0.0, c0 = 0.0, c1 = 0.0;
  int k = 0;
  for (; k + 2 <= n; k += 2) {
    a0 += x0[k] * y[k];
    b0 += x1[k] * y[k];
    c0 += x2[k] * y[k];
    a1 += x0[k + 1] * y[k + 1];
    b1 += x1[k + 1] * y[k + 1];
    c1 += x2[k + 1] * y[k + 1];
  }
  if (k < n) {
    a0 += x0[k] * y[k];
    b0 += x1[k] * y[k];
    c0 += x2[k] * y[k];
  }
  out[0] = a0 + a1;
  out[1] = b0 + b1;
  out[2] = c0 + c1;
}

// Exact solution of one 3-row contact's local problem (see nsgs.h); f_old is the fallback start.
void solveLocal3(const Local3& p, const double* f_old, double* f) noexcept {
  const double mu = p.mu;
  // separation
  if (!(p.b[0] < 0.0)) {
    f[0] = f[1] = f[2] = 0.0;
    return;
  }
  // frictionless three-row contact: scalar normal projection
  if (!(mu > 0.0)) {
    f[0] = p.a[0][0] > 0.0 ? -p.b[0] / p.a[0][0] : 0.0;
    f[1] = f[2] = 0.0;
    return;
  }
  const auto& a = p.a;
  const double scale_b = std::abs(p.b[0]) + std::abs(p.b[1]) + std::abs(p.b[2]);
  // stick trial: a f = -b by cofactors
  const double c00 = a[1][1] * a[2][2] - a[1][2] * a[2][1];
  const double c01 = a[1][2] * a[2][0] - a[1][0] * a[2][2];
  const double c02 = a[1][0] * a[2][1] - a[1][1] * a[2][0];
  const double det = a[0][0] * c00 + a[0][1] * c01 + a[0][2] * c02;
  double amax = 0.0;
  for (const auto& row : a) {
    for (double v : row) amax = std::max(amax, std::abs(v));
  }
  double theta0 = std::atan2(-p.b[2], -p.b[1]);
  if (std::abs(det) > 1e-13 * amax * amax * amax) {
    const double inv = -1.0 / det;
    const double x0 = inv * (c00 * p.b[0] + (a[0][2] * a[2][1] - a[0][1] * a[2][2]) * p.b[1] +
                             (a[0][1] * a[1][2] - a[0][2] * a[1][1]) * p.b[2]);
    const double x1 = inv * (c01 * p.b[0] + (a[0][0] * a[2][2] - a[0][2] * a[2][0]) * p.b[1] +
                             (a[0][2] * a[1][0] - a[0][0] * a[1][2]) * p.b[2]);
    const double x2 = inv * (c02 * p.b[0] + (a[0][1] * a[2][0] - a[0][0] * a[2][1]) * p.b[1] +
                             (a[0][0] * a[1][1] - a[0][1] * a[1][0]) * p.b[2]);
    const double xt = std::hypot(x1, x2);
    if (x0 > 0.0 && xt <= mu * x0 * (1.0 + 1e-12)) {
      f[0] = x0;
      f[1] = x1;
      f[2] = x2;
      return;
    }
    if (xt > 0.0) theta0 = std::atan2(x2, x1);
  } else if (std::hypot(f_old[1], f_old[2]) > 0.0) {
    theta0 = std::atan2(f_old[2], f_old[1]);
  }
  // slip: Newton on theta
  const double g_tol = 1e-14 * (scale_b + 1e-300);
  const double h_tol = 1e-10 * scale_b;
  double theta = theta0;
  for (int it = 0; it < 12; ++it) {
    const SlipEval e = evalSlip(p, theta);
    if (!e.valid || !(std::abs(e.dg) > 0.0)) break;
    const double step = e.g / e.dg;
    if (std::abs(e.g) <= g_tol || std::abs(step) < 1e-13) {
      if (e.h <= h_tol && std::isfinite(e.fn)) {
        setSlip(p, theta, e.fn, f);
        return;
      }
      break;
    }
    theta -= std::clamp(step, -0.5, 0.5);
  }
  // slip: scan for sign changes of g over the angles where f_n > 0, keep the valid root nearest
  // theta0. den(theta) = a_nn + mu r cos(theta - alpha) > 0 is the whole circle or one arc; on
  // an arc, samples cluster near its ends, where f_n -> inf and roots can hide.
  constexpr int kScan = 72;
  const double r_nt = mu * std::hypot(a[0][1], a[0][2]);
  double lo = theta0 - std::numbers::pi;
  double span = 2.0 * std::numbers::pi;
  bool arc = false;
  if (a[0][0] <= r_nt) {
    if (!(r_nt > 0.0)) return slipFallback(p, f_old, f);
    const double alpha = std::atan2(a[0][2], a[0][1]);
    const double beta = std::acos(std::clamp(-a[0][0] / r_nt, -1.0, 1.0));
    lo = alpha - beta;
    span = 2.0 * beta;
    arc = true;
  }
  auto sample = [&](int k) {
    if (!arc) return lo + span * k / kScan;
    // Chebyshev-like clustering; the ends themselves (f_n infinite) are nudged inside
    const double t = std::clamp(static_cast<double>(k) / kScan, 1e-5, 1.0 - 1e-5);
    return lo + span * 0.5 * (1.0 - std::cos(std::numbers::pi * t));
  };
  double best_dist = 1e300;
  double th_prev = sample(0);
  SlipEval e_prev = evalSlip(p, th_prev);
  for (int k = 1; k <= kScan; ++k) {
    const double th = sample(k);
    const SlipEval e = evalSlip(p, th);
    double root[3];
    if (e.valid && e_prev.valid && (e.g < 0.0) != (e_prev.g < 0.0) &&
        (e.h < 0.0 || e_prev.h < 0.0) && bisectSlip(p, th_prev, th, e_prev.g, h_tol, root)) {
      const double th_root = std::atan2(root[2], root[1]);
      const double dist = std::abs(std::remainder(th_root - theta0, 2.0 * std::numbers::pi));
      if (dist < best_dist) {
        best_dist = dist;
        f[0] = root[0];
        f[1] = root[1];
        f[2] = root[2];
      }
    }
    th_prev = th;
    e_prev = e;
  }
  if (best_dist < 1e300) return;
  slipFallback(p, f_old, f);
}

// delta = W f + q (row pass); returns ||delta||^2.
double computeDelta(const ContactProblemView& p, const double* f, double* delta) noexcept {
  const int m = p.rows;
  double nrm2 = 0.0;
  for (int j = 0; j < m; ++j) {
    delta[j] = dot(p.W + static_cast<std::ptrdiff_t>(j) * p.ld, f, m) + p.delta_free[j];
    nrm2 += delta[j] * delta[j];
  }
  return nrm2;
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
    const double dhat_n = di[0] + mu * std::hypot(di[1], di[2]);
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
  if (p.contacts <= 0 || p.rows <= 0 || f == nullptr || p.W == nullptr ||
      p.delta_free == nullptr || p.row_offset == nullptr || p.ld < p.rows) {
    return false;
  }
  if (p.contacts > ws.maxContacts() || p.rows > ws.maxRows()) return false;
  if (p.row_offset[0] != 0 || p.row_offset[p.contacts] != p.rows) return false;
  bool any3 = false;
  for (int i = 0; i < p.contacts; ++i) {
    const int k = p.row_offset[i + 1] - p.row_offset[i];
    if (k != 1 && k != 3) return false;
    any3 = any3 || k == 3;
  }
  return !any3 || p.mu != nullptr;
}

// Loads contact i's 3x3 block of W.
void loadBlock(const ContactProblemView& p, int r, Local3& loc) noexcept {
  for (int k = 0; k < 3; ++k) {
    const double* w = p.W + static_cast<std::ptrdiff_t>(r + k) * p.ld + r;
    loc.a[k][0] = w[0];
    loc.a[k][1] = w[1];
    loc.a[k][2] = w[2];
  }
}

// Marks in `mark` (per row, 1.0 on a contact's first row) the contacts whose diagonal entries
// Gauss-Seidel divides by are not usable (see NsgsStatus::kIllPosed); returns their number.
int markIllPosed(const ContactProblemView& p, double* mark) noexcept {
  const int m = p.rows;
  double max_diag = 0.0;
  for (int j = 0; j < m; ++j) {
    const double d = p.W[static_cast<std::ptrdiff_t>(j) * p.ld + j];
    if (d > max_diag) max_diag = d;   // NaN never compares greater
  }
  const double floor = kMinRelativeDiagonal * max_diag;
  int count = 0;
  for (int i = 0; i < p.contacts; ++i) {
    const int r = p.row_offset[i];
    const int k = p.row_offset[i + 1] - r;
    const int used = (k == 3 && p.mu[i] > 0.0) ? 3 : 1;
    bool bad = false;
    for (int a = 0; a < used; ++a) {
      const double d = p.W[static_cast<std::ptrdiff_t>(r + a) * p.ld + r + a];
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
  const double zt = std::hypot(z[1], z[2]);
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
  max_rows_ = max_rows;
  max_contacts_ = max_contacts;
}

int NsgsWorkspace::maxRows() const { return max_rows_; }
int NsgsWorkspace::maxContacts() const { return max_contacts_; }

double naturalMapError(const ContactProblemView& problem, const double* f,
                       double* delta_out) noexcept {
  const int m = problem.rows;
  double q2 = 0.0;
  for (int j = 0; j < m; ++j) q2 += problem.delta_free[j] * problem.delta_free[j];
  // without an output buffer, accumulate the residual row block by row block
  if (delta_out != nullptr) {
    computeDelta(problem, f, delta_out);
    return normalisedError(errorParts(problem, f, delta_out), q2);
  }
  ErrorParts total;
  for (int i = 0; i < problem.contacts; ++i) {
    const int r = problem.row_offset[i];
    const int k = problem.row_offset[i + 1] - r;
    double d[3] = {0.0, 0.0, 0.0};
    for (int a = 0; a < k; ++a) {
      const double* w = problem.W + static_cast<std::ptrdiff_t>(r + a) * problem.ld;
      d[a] = dot(w, f, m) + problem.delta_free[r + a];
    }
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

// Stagnation rule (see NsgsSettings::stall_sweeps): a check "repeats" when its error equals one
// of the last kCyclePeriods errors to kCycleRelTol; a window is a limit cycle when at least half
// of its checks repeat. Slow convergence and plateaus drift, so they never qualify.
constexpr int kCyclePeriods = 4;
constexpr double kCycleRelTol = 1e-6;

NsgsResult solveNsgs(const ContactProblemView& problem, const NsgsSettings& settings,
                     NsgsWorkspace& workspace, double* f) noexcept {
  NsgsResult result;
  const std::int64_t t0 = nowNs();
  if (!viewUsable(problem, workspace, f)) return result;
  const ContactProblemView& p = problem;
  const int nc = p.contacts;
  const int m = p.rows;
  const std::ptrdiff_t ld = p.ld;
  double* delta = workspace.delta.data();
  double sor = settings.sor;
  const int check_every = std::max(settings.check_every, 1);
  const int max_sweeps = std::max(settings.max_sweeps, 1);
  const bool row_gather = settings.coupling == NsgsCoupling::kRowGather;
  const bool symmetric = settings.coupling == NsgsCoupling::kSymmetricRowUpdate;

  auto fail = [&](NsgsStatus status) {
    for (int j = 0; j < m; ++j) f[j] = 0.0;
    for (int j = 0; j < m; ++j) delta[j] = p.delta_free[j];
    result.status = status;
    result.error = std::numeric_limits<double>::infinity();
    result.elapsed_ns = nowNs() - t0;
    return result;
  };

  // inputs: mu finite, delta = W f + q finite (NaN/Inf anywhere in W, q or f shows up here)
  double q2 = 0.0;
  for (int j = 0; j < m; ++j) q2 += p.delta_free[j] * p.delta_free[j];
  for (int i = 0; i < nc; ++i) {
    if (p.row_offset[i + 1] - p.row_offset[i] == 3 && !std::isfinite(p.mu[i])) {
      return fail(NsgsStatus::kNonFinite);
    }
  }
  // contacts NSGS cannot solve: held at zero force (then delta must be formed afresh)
  double* ill = workspace.scratch.data();
  result.ill_posed_contacts = markIllPosed(p, ill);
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
  double delta2 = 0.0;
  if (delta_current) {
    for (int j = 0; j < m; ++j) delta2 += delta[j] * delta[j];
  } else {
    delta2 = computeDelta(p, f, delta);
  }
  if (!std::isfinite(delta2) || !std::isfinite(q2)) {
    return fail(NsgsStatus::kNonFinite);
  }

  // stagnation watch (see NsgsSettings::stall_sweeps)
  double best_error = std::numeric_limits<double>::infinity();
  double window_best = best_error;   // best error when the current window opened
  // errors of the last kCyclePeriods checks (ring, newest at recent[(checks_done - 1) % K])
  double recent[kCyclePeriods];
  for (double& e : recent) e = best_error;
  int checks_done = 0;
  int window_start = 0;
  int window_repeats = 0;            // checks in the window whose error repeats a recent one
  result.sor = sor;
  Local3 loc{};
  for (int sweep = 1; sweep <= max_sweeps; ++sweep) {
    for (int i = 0; i < nc; ++i) {
      const int r = p.row_offset[i];
      const int k = p.row_offset[i + 1] - r;
      double* fi = f + r;
      if (ill[r] != 0.0) continue;   // ill-posed: held at zero
      // current local velocity of contact i
      double di[3];
      if (row_gather) {
        const double* w = p.W + r * ld;
        if (k == 1) {
          di[0] = dot(w, f, m);
        } else {
          dot3(w, w + ld, w + 2 * ld, f, m, di);
        }
        for (int a = 0; a < k; ++a) di[a] += p.delta_free[r + a];
      } else {
        for (int a = 0; a < k; ++a) di[a] = delta[r + a];
      }
      double df[3] = {0.0, 0.0, 0.0};
      if (k == 1) {
        const double w = p.W[r * ld + r];
        const double b = di[0] - w * fi[0];
        const double fl = w > 0.0 ? std::max(0.0, -b / w) : (b >= 0.0 ? 0.0 : fi[0]);
        const double fnew = std::max(0.0, fi[0] + sor * (fl - fi[0]));
        if (std::isfinite(fnew)) df[0] = fnew - fi[0];
      } else {
        loadBlock(p, r, loc);
        loc.mu = std::max(p.mu[i], 0.0);
        for (int a = 0; a < 3; ++a) {
          loc.b[a] = di[a] - (loc.a[a][0] * fi[0] + loc.a[a][1] * fi[1] + loc.a[a][2] * fi[2]);
        }
        double fl[3];
        solveLocal3(loc, fi, fl);
        double fnew[3] = {fl[0], fl[1], fl[2]};
        if (sor != 1.0) {
          for (int a = 0; a < 3; ++a) fnew[a] = fi[a] + sor * (fl[a] - fi[a]);
          projectOnCone(loc.mu, fnew);
        }
        if (std::isfinite(fnew[0]) && std::isfinite(fnew[1]) && std::isfinite(fnew[2])) {
          for (int a = 0; a < 3; ++a) df[a] = fnew[a] - fi[a];
        }
      }
      if (df[0] == 0.0 && df[1] == 0.0 && df[2] == 0.0) continue;
      for (int a = 0; a < k; ++a) fi[a] += df[a];
      if (row_gather) continue;
      if (symmetric) {
        // delta += W(rows_i, :)^T df_i (contiguous rows; equal to the columns when W = W^T)
        const double* w0 = p.W + r * ld;
        if (k == 1) {
          for (int j = 0; j < m; ++j) delta[j] += w0[j] * df[0];
        } else {
          const double* w1 = w0 + ld;
          const double* w2 = w1 + ld;
          for (int j = 0; j < m; ++j) delta[j] += w0[j] * df[0] + w1[j] * df[1] + w2[j] * df[2];
        }
        continue;
      }
      // delta += W(:, rows_i) df_i (strided columns of the row-major W)
      const double* w = p.W + r;
      if (k == 1) {
        for (int j = 0; j < m; ++j) delta[j] += w[j * ld] * df[0];
      } else {
        for (int j = 0; j < m; ++j) {
          const double* wj = w + j * ld;
          delta[j] += wj[0] * df[0] + wj[1] * df[1] + wj[2] * df[2];
        }
      }
    }
    result.sweeps = sweep;
    const bool over_budget =
        settings.time_budget_ns > 0 && nowNs() - t0 >= settings.time_budget_ns;
    const bool last = sweep == max_sweeps || over_budget;
    if (sweep % check_every != 0 && !last) continue;
    if (row_gather) computeDelta(p, f, delta);
    result.error = normalisedError(errorParts(p, f, delta), q2);
    if (!std::isfinite(result.error)) return fail(NsgsStatus::kNonFinite);
    if (result.error <= settings.tolerance && !row_gather) {
      // claim checked against delta = W f + q formed afresh (the running delta accumulates
      // rounding, worst when f is large)
      computeDelta(p, f, delta);
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
    bool repeats = false;
    for (const double e : recent) {
      repeats = repeats || std::abs(result.error - e) <= kCycleRelTol * result.error;
    }
    if (repeats) ++window_repeats;
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

}  // namespace tactus::shared
