#pragma once
// Frictional contact problem and its nonsmooth Gauss-Seidel (NSGS) solver.
//
// Problem (local frames, Siconos/FCLIB convention):  delta = W f + delta_free.
// Contact i owns rows [row_offset[i], row_offset[i+1]): one row (normal only, mu_i = 0 path)
// or three rows (n, t1, t2). Normal: 0 <= delta_n  _|_  f_n >= 0. Coulomb: ||f_t|| <= mu f_n,
// sliding opposite to the tangential velocity (De Saxce: delta_hat = delta + mu ||delta_t|| n).
//
// W is dense, row-major with leading dimension `ld` (>= rows), so a fixed-capacity buffer (the
// shared segment) can hold it in place. It need not be exactly symmetric.
//
// Real-time: solveNsgs and naturalMapError never allocate, lock or throw; all scratch memory is
// in NsgsWorkspace, sized once for a capacity (rows, contacts).

#include <cstdint>
#include <vector>

namespace tactus::shared {

struct ContactProblemView {
  int contacts = 0;                  ///< nc
  int rows = 0;                      ///< m = row_offset[nc]
  const int* row_offset = nullptr;   ///< nc + 1 entries, row_offset[0] = 0, step 1 or 3
  const double* W = nullptr;         ///< m x m, row-major, leading dimension ld
  int ld = 0;
  const double* delta_free = nullptr;  ///< m (FCLIB's q)
  const double* mu = nullptr;        ///< nc friction coefficients (ignored for 1-row contacts)
};

struct NsgsSettings {
  double tolerance = 1e-6;           ///< on the normalised natural-map error
  int max_sweeps = 500;
  double sor = 1.0;                  ///< over-relaxation in (0, 2); 1 = plain Gauss-Seidel
  std::int64_t time_budget_ns = 0;   ///< 0: none; else stop after the sweep that crosses it
  int check_every = 1;               ///< compute the error every k sweeps (cost: one W pass)
};

enum class NsgsStatus : std::uint8_t { kConverged, kMaxSweeps, kTimeBudget, kNonFinite, kEmpty };

struct NsgsResult {
  NsgsStatus status = NsgsStatus::kEmpty;
  int sweeps = 0;
  double error = 0.0;                ///< normalised natural-map error at exit
};

/// Preallocated scratch for a capacity; reusable for any problem up to that size.
class NsgsWorkspace {
 public:
  NsgsWorkspace() = default;
  NsgsWorkspace(int max_rows, int max_contacts);
  void reserve(int max_rows, int max_contacts);   ///< allocates (not real-time)
  int maxRows() const;
  int maxContacts() const;
  // (implementation-defined scratch below)
  std::vector<double> delta;         ///< m: W f + delta_free, kept up to date
  std::vector<double> scratch;
 private:
  int max_rows_ = 0;
  int max_contacts_ = 0;
};

/// Solves in place: `f` (m entries) holds the warm start on entry (zeros for a cold start) and
/// the solution on exit. Never allocates. Problems larger than the workspace return kEmpty.
NsgsResult solveNsgs(const ContactProblemView& problem, const NsgsSettings& settings,
                     NsgsWorkspace& workspace, double* f) noexcept;

/// Siconos' fc3d error: sqrt(sum_i ||f_i - P_K(f_i - delta_hat_i)||^2) / max(||q||,||f||,||delta||)
/// (for 1-row contacts: the projection onto R+). Allocation-free; writes delta = W f + q into
/// `delta_out` (m entries) when not null.
double naturalMapError(const ContactProblemView& problem, const double* f,
                       double* delta_out = nullptr) noexcept;

}  // namespace tactus::shared
