// The exact one-contact local solve of NSGS and the Gauss-Seidel step built on it (see nsgs.h);
// shared by every storage of W (nsgs.cpp drives the sweeps).
#include "nsgs_local.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "tactus/shared/nsgs.h"

namespace tactus::shared::detail {
namespace {

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
    d[0] += mu * planeNorm(d[1], d[2]);
    for (int k = 0; k < 3; ++k) z[k] -= rho * d[k];
    projectOnCone(mu, z);
  }
  f[0] = z[0];
  f[1] = z[1];
  f[2] = z[2];
}

}  // namespace

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
  // the slip search's start angle, computed only once the stick trial has failed: the stick
  // trial's direction, else the old force's, else opposite the free tangential velocity
  const auto awayFromSliding = [&] { return std::atan2(-p.b[2], -p.b[1]); };
  double theta0;
  if (std::abs(det) > 1e-13 * amax * amax * amax) {
    const double inv = -1.0 / det;
    const double x0 = inv * (c00 * p.b[0] + (a[0][2] * a[2][1] - a[0][1] * a[2][2]) * p.b[1] +
                             (a[0][1] * a[1][2] - a[0][2] * a[1][1]) * p.b[2]);
    const double x1 = inv * (c01 * p.b[0] + (a[0][0] * a[2][2] - a[0][2] * a[2][0]) * p.b[1] +
                             (a[0][2] * a[1][0] - a[0][0] * a[1][2]) * p.b[2]);
    const double x2 = inv * (c02 * p.b[0] + (a[0][1] * a[2][0] - a[0][0] * a[2][1]) * p.b[1] +
                             (a[0][0] * a[1][1] - a[0][1] * a[1][0]) * p.b[2]);
    const double xt = planeNorm(x1, x2);
    if (x0 > 0.0 && xt <= mu * x0 * (1.0 + 1e-12)) {
      f[0] = x0;
      f[1] = x1;
      f[2] = x2;
      return;
    }
    theta0 = xt > 0.0 ? std::atan2(x2, x1) : awayFromSliding();
  } else {
    theta0 = planeNorm(f_old[1], f_old[2]) > 0.0 ? std::atan2(f_old[2], f_old[1])
                                                 : awayFromSliding();
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
  const double r_nt = mu * planeNorm(a[0][1], a[0][2]);
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

void contactStep(int k, const double* a, double mu, double sor, const double* d,
                 const double* f, double* df) noexcept {
  df[0] = df[1] = df[2] = 0.0;
  if (k == 1) {
    const double w = a[0];
    const double b = d[0] - w * f[0];
    const double fl = w > 0.0 ? std::max(0.0, -b / w) : (b >= 0.0 ? 0.0 : f[0]);
    const double fnew = std::max(0.0, f[0] + sor * (fl - f[0]));
    if (std::isfinite(fnew)) df[0] = fnew - f[0];
    return;
  }
  Local3 loc;
  loc.mu = std::max(mu, 0.0);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) loc.a[r][c] = a[3 * r + c];
    loc.b[r] = d[r] - (a[3 * r] * f[0] + a[3 * r + 1] * f[1] + a[3 * r + 2] * f[2]);
  }
  double fl[3];
  solveLocal3(loc, f, fl);
  double fnew[3] = {fl[0], fl[1], fl[2]};
  if (sor != 1.0) {
    for (int r = 0; r < 3; ++r) fnew[r] = f[r] + sor * (fl[r] - f[r]);
    projectOnCone(loc.mu, fnew);
  }
  if (std::isfinite(fnew[0]) && std::isfinite(fnew[1]) && std::isfinite(fnew[2])) {
    for (int r = 0; r < 3; ++r) df[r] = fnew[r] - f[r];
  }
}

}  // namespace tactus::shared::detail
