#pragma once
// Anderson acceleration of the NSGS sweeps (NsgsSettings::anderson_depth, nsgs.h): the history
// of the last sweeps and the mixing step, over storage the workspace preallocates
// (NsgsWorkspace::anderson). Not installed: only shared/src includes it.
//
// Per checked sweep k: x_k is the sweep's input, g_k its output, r_k = g_k - x_k its residual.
// With the differences of the last n + 1 <= depth + 1 of them (dR_u = r_{u+1} - r_u, dG_u
// likewise), gamma = argmin || r_k - dR gamma || (normal equations on dR's Gram matrix, kept up
// to date one row per sweep; Gaussian elimination on the stack) and x_{k+1} = g_k - dG gamma,
// left unprojected (the next sweep's local solves put every contact back on its cone, whatever
// its force was; projecting here cost W's rows for every moved contact, about a sweep). delta =
// W x + q follows by the same combination of the stored delta differences: O(depth m) per
// sweep. Ill-posed contacts stay at zero: they are zero in every sweep output, so in every
// difference. Safeguard: see NsgsSettings::anderson_depth.

#include <algorithm>
#include <cstddef>
#include <limits>

#include "nsgs_storage.h"   // detail::dot
#include "tactus/shared/nsgs.h"

namespace tactus::shared::detail {

class Anderson {
 public:
  /// `storage`: NsgsWorkspace::anderson ((3 kMaxAndersonDepth + 6) m doubles).
  Anderson(int depth, int m, double* storage) noexcept
      : depth_(std::clamp(depth, 0, kMaxAndersonDepth)), m_(m), on_(depth_ > 0) {
    const std::ptrdiff_t md = static_cast<std::ptrdiff_t>(m);
    d_g_ = storage;                      // depth differences of sweep outputs
    d_r_ = d_g_ + depth_ * md;           // ... of residuals
    d_delta_ = d_r_ + depth_ * md;       // ... of deltas
    g_ = d_delta_ + depth_ * md;         // the newest sweep output, residual and delta
    r_ = g_ + md;
    delta_ = r_ + md;
    x_ = delta_ + md;                    // the running sweep's input
    best_f_ = x_ + md;
    best_delta_ = best_f_ + md;
  }

  bool on() const noexcept { return on_; }

  /// Before a sweep: keeps its input.
  void keepInput(const double* f) noexcept {
    if (on_) std::copy(f, f + m_, x_);
  }

  /// After a checked sweep that did not converge, with its error, output f and delta = W f + q:
  /// f and delta become the next sweep's input, either mixed or, when the extrapolation went
  /// astray, the best iterate. Returns false when the acceleration has just turned off (f and
  /// delta are then the best iterate, for plain sweeps).
  bool step(double error, double* f, double* delta) noexcept {
    if (error < kAndersonProgress * best_) {
      best_ = error;
      since_progress_ = 0;
      std::copy(f, f + m_, best_f_);
      std::copy(delta, delta + m_, best_delta_);
    } else if (++since_progress_ > kAndersonStallSweeps) {
      // no progress for a while: plain sweeps from the best iterate
      backToBest(f, delta);
      on_ = false;
      return false;
    } else if (error > kAndersonRise * best_) {
      backToBest(f, delta);
      have_newest_ = false;
      differences_ = 0;
      next_slot_ = 0;   // the valid slots are 0 .. differences_ - 1 until the ring is full
      on_ = ++strikes_ < kAndersonStrikes;
      return on_;
    }
    store(f, delta);
    mix(f, delta);
    return true;
  }

 private:
  void backToBest(double* f, double* delta) const noexcept {
    std::copy(best_f_, best_f_ + m_, f);
    std::copy(best_delta_, best_delta_ + m_, delta);
  }

  double* row(double* base, int slot) const noexcept {
    return base + static_cast<std::ptrdiff_t>(slot) * m_;
  }

  // Records the sweep's output; with a previous one, their difference goes into the oldest slot
  // and its Gram row (residual differences' dot products) is updated: O(depth m).
  void store(const double* f, const double* delta) noexcept {
    if (have_newest_) {
      const int s = next_slot_;
      double* dg = row(d_g_, s);
      double* dr = row(d_r_, s);
      double* dd = row(d_delta_, s);
      for (int j = 0; j < m_; ++j) {
        const double r = f[j] - x_[j];
        dg[j] = f[j] - g_[j];
        dr[j] = r - r_[j];
        dd[j] = delta[j] - delta_[j];
      }
      next_slot_ = (next_slot_ + 1) % depth_;
      differences_ = std::min(differences_ + 1, depth_);
      for (int t = 0; t < differences_; ++t) {
        const double* dt = row(d_r_, t);
        const double sum = dot(dr, dt, m_);
        gram_[s * kMaxAndersonDepth + t] = gram_[t * kMaxAndersonDepth + s] = sum;
      }
    }
    for (int j = 0; j < m_; ++j) {
      g_[j] = f[j];
      r_[j] = f[j] - x_[j];
      delta_[j] = delta[j];
    }
    have_newest_ = true;
  }

  // gamma = argmin || r - dR gamma ||, then f = g - dG gamma (delta likewise).
  void mix(double* f, double* delta) const noexcept {
    const int n = differences_;
    if (n < 1) return;
    double a[kMaxAndersonDepth * kMaxAndersonDepth];
    double gamma[kMaxAndersonDepth];
    double trace = 0.0;
    for (int u = 0; u < n; ++u) {
      const double* du = row(d_r_, u);
      gamma[u] = dot(du, r_, m_);
      for (int v = 0; v < n; ++v) a[u * n + v] = gram_[u * kMaxAndersonDepth + v];
      trace += a[u * n + u];
    }
    for (int u = 0; u < n; ++u) a[u * n + u] += 1e-10 * trace + std::numeric_limits<double>::min();
    for (int u = 0; u < n; ++u) {   // elimination without pivoting (symmetric positive definite)
      if (!(a[u * n + u] > 0.0)) return;
      for (int v = u + 1; v < n; ++v) {
        const double factor = a[v * n + u] / a[u * n + u];
        for (int c = u; c < n; ++c) a[v * n + c] -= factor * a[u * n + c];
        gamma[v] -= factor * gamma[u];
      }
    }
    for (int u = n - 1; u >= 0; --u) {
      double sum = gamma[u];
      for (int v = u + 1; v < n; ++v) sum -= a[u * n + v] * gamma[v];
      gamma[u] = sum / a[u * n + u];
    }
    for (int u = 0; u < n; ++u) {
      const double* dg = row(d_g_, u);
      const double* dd = row(d_delta_, u);
      for (int j = 0; j < m_; ++j) {
        f[j] -= gamma[u] * dg[j];
        delta[j] -= gamma[u] * dd[j];
      }
    }
  }

  int depth_;
  int m_;
  bool on_;
  bool have_newest_ = false;
  int differences_ = 0;     // valid difference slots (0..depth)
  int next_slot_ = 0;       // the slot the next difference replaces
  int strikes_ = 0;
  int since_progress_ = 0;  // checked sweeps since the best error last fell by kAndersonProgress
  double best_ = std::numeric_limits<double>::infinity();
  double gram_[kMaxAndersonDepth * kMaxAndersonDepth] = {};
  double* d_g_;
  double* d_r_;
  double* d_delta_;
  double* g_;
  double* r_;
  double* delta_;
  double* x_;
  double* best_f_;
  double* best_delta_;
};

}  // namespace tactus::shared::detail
