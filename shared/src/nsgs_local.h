#pragma once
// NSGS internals shared by the storages of W (dense rows, 3x3 blocks): the per-contact
// Gauss-Seidel step (see nsgs.h, "Algorithm"). Not installed: only shared/src includes it.

#include <cmath>

namespace tactus::shared::detail {

/// sqrt(x^2 + y^2) without std::hypot's cost where the squares cannot overflow or underflow
/// (hypot was a tenth of a haptic tick's time); NaN stays NaN. Differs from hypot by at most
/// one rounding.
inline double planeNorm(double x, double y) noexcept {
  const double s = x * x + y * y;
  if (s > 1e-300 && s < 1e300) return std::sqrt(s);
  return s == 0.0 ? 0.0 : std::hypot(x, y);
}

/// Local 3x3 block (row-major) and free term of one contact.
struct Local3 {
  double a[3][3];
  double b[3];
  double mu;
};

/// Exact solution of one 3-row contact's local problem a f + b (see nsgs.h); f_old is the
/// fallback start.
void solveLocal3(const Local3& p, const double* f_old, double* f) noexcept;

/// One contact's Gauss-Seidel step: from its k (1 or 3) rows' current velocity d = (W f + q)_i,
/// force f and diagonal block a (k x k, row-major), the change df (3 entries, zero past k) of
/// the relaxed local solution f <- P_K(f + sor (f_local - f)); zero when that is not finite.
/// k = 1 and mu <= 0 use the scalar projection; mu < 0 counts as 0.
void contactStep(int k, const double* a, double mu, double sor, const double* d,
                 const double* f, double* df) noexcept;

}  // namespace tactus::shared::detail
