#pragma once
// Frictional contact problem and its nonsmooth Gauss-Seidel (NSGS) solver.
//
// Problem (local frames, Siconos/FCLIB convention):  delta = W f + delta_free.
// Contact i owns rows [row_offset[i], row_offset[i+1]): one row (normal only, mu_i = 0 path)
// or three rows (n, t1, t2). Normal: 0 <= delta_n  _|_  f_n >= 0. Coulomb: ||f_t|| <= mu f_n,
// sliding opposite to the tangential velocity (De Saxce: delta_hat = delta + mu ||delta_t|| n).
//
// W is dense, row-major with leading dimension `ld` (>= rows), so a fixed-capacity buffer (the
// shared segment) can hold it in place. It need not be exactly symmetric. When the view also
// points at W's block-sparse form (`blocks`, see delassus_blocks.h and chooseStorage there), the
// solver reads the blocks instead (W may then be null): same algorithm, same iterates up to
// rounding, a sweep costing the stored blocks instead of all m^2 entries.
//
// Real-time: solveNsgs and naturalMapError never allocate, lock or throw; all scratch memory is
// in NsgsWorkspace, sized once for a capacity (rows, contacts).
//
// Algorithm (solveNsgs). One sweep visits the contacts in order; contact i solves its local
// problem delta_i = W_ii f_i + b_i exactly, with b_i = delta_i - W_ii f_i (the other contacts
// frozen), then delta is updated by W(:, rows_i) * df_i (kColumnUpdate, the default) or b_i is
// gathered from the rows of W (kRowGather). Local problem of a 3-row contact:
//   1. separation: b_n >= 0  ->  f_i = 0 (f = 0 is then a solution: delta_hat = b_hat in K*);
//   2. stick: f = -W_ii^-1 b_i, accepted when f_n > 0 and ||f_t|| <= mu f_n;
//   3. slip: f = f_n (1, mu cos(theta), mu sin(theta)) with delta_n = 0, which fixes
//      f_n(theta) = -b_n / (W_nn + mu W_nt e(theta)); theta solves the scalar equation
//      e(theta) x delta_t(theta) = 0 with e . delta_t < 0 (friction opposite to sliding).
//      Newton on theta from the stick solution's direction (a few iterations, exact to machine
//      precision); if it fails, a 72-point scan of the circle plus bisection on the bracket
//      nearest the start; if that fails too (degenerate W_ii), 100 projected fixed-point
//      iterations f <- P_K(f - rho (W_ii f + b)_hat). The local solve is thus exact, and the
//      outer iteration behaves like Siconos' NSGS with an exact one-contact solver.
// A 3-row contact with mu = 0 and a 1-row contact use the scalar projection
// f_n = max(0, -b_n / W_nn), f_t = 0. Over-relaxation: f_i <- P_K(f_i + sor (f_local - f_i)).

#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

namespace tactus::shared {

class DelassusBlocks;

struct ContactProblemView {
  int contacts = 0;                  ///< nc
  int rows = 0;                      ///< m = row_offset[nc]
  const int* row_offset = nullptr;   ///< nc + 1 entries, row_offset[0] = 0, step 1 or 3
  const double* W = nullptr;         ///< m x m, row-major, leading dimension ld
  int ld = 0;
  const double* delta_free = nullptr;  ///< m (FCLIB's q)
  const double* mu = nullptr;        ///< nc friction coefficients (ignored for 1-row contacts)
  /// W's block form (same contacts, rows and row offsets); when set, read instead of W
  const DelassusBlocks* blocks = nullptr;
};

/// The view of a problem stored densely (W row-major with leading dimension ld), for the types
/// that own one (FclibProblem, the snapshot slots, test problems).
inline ContactProblemView denseProblemView(int contacts, int rows, const int* row_offset,
                                           const double* W, int ld, const double* delta_free,
                                           const double* mu) noexcept {
  ContactProblemView v;
  v.contacts = contacts;
  v.rows = rows;
  v.row_offset = row_offset;
  v.W = W;
  v.ld = ld;
  v.delta_free = delta_free;
  v.mu = mu;
  return v;
}

/// Contacts [c_begin, c_end) of a dense problem as a problem of their own, in place on W's
/// diagonal block (their rows are contiguous): `row_offset_out` (c_end - c_begin + 1 entries)
/// receives their row offsets from the first row. The caller checks the range; the view keeps
/// `problem`'s ld and has no blocks. For a group of contacts W couples to nothing else (a group of
/// coupled bodies, the contacts the devices can reach), solving it is solving its part of the
/// whole problem. No allocation.
inline ContactProblemView contiguousSubproblem(const ContactProblemView& problem, int c_begin,
                                               int c_end, int* row_offset_out) noexcept {
  const int r0 = problem.row_offset[c_begin];
  for (int c = c_begin; c <= c_end; ++c) row_offset_out[c - c_begin] = problem.row_offset[c] - r0;
  return denseProblemView(c_end - c_begin, problem.row_offset[c_end] - r0, row_offset_out,
                          problem.W + static_cast<std::ptrdiff_t>(r0) * problem.ld + r0,
                          problem.ld, problem.delta_free + r0, problem.mu + c_begin);
}

/// How the solver keeps the coupling between contacts (all give the same iterates up to
/// rounding, when W is symmetric for kSymmetricRowUpdate).
/// - kColumnUpdate (default, any W): keeps delta = W f + q current by adding W(:, rows_i) df_i
///   after each contact (strided columns of the row-major W). Error checks are then O(m), and a
///   contact whose force does not change (separated stays separated) costs nothing.
/// - kRowGather (any W): recomputes b_i from the contiguous rows W(rows_i, :) f. Every contact
///   costs 3m multiply-adds, and every error check one more W pass.
/// - kSymmetricRowUpdate: the caller promises W = W^T (the simulation's H C H^T is); as
///   kColumnUpdate but reads the contiguous rows W(rows_i, :) instead of the columns. It also
///   forms delta = W f + q (at the start and to confirm convergence) from the rows of the
///   contacts with a nonzero force only: an entry W(a, b) in the rows of a contact at zero force
///   is read through its twin W(b, a), and a NaN/Inf there gives kNonFinite once either contact's
///   force moves (a NaN cannot pass the simulation's bit-for-bit symmetry check, so a published
///   snapshot never asks for this sweep with one). Wrong results if W is not symmetric.
/// Measured (tests/bench/nsgs_bench.cpp, 150 contacts / 450 rows, 84 in contact, thread CPU time
/// on the loaded 2-core dev VM, streaming W once = 36-40 us): one sweep costs 66-78 us (1.8-2.2
/// W streams) with kColumnUpdate, 87-93 us (2.4-2.5) with kRowGather and 36-41 us (1.0-1.15)
/// with kSymmetricRowUpdate.
enum class NsgsCoupling : std::uint8_t { kColumnUpdate, kRowGather, kSymmetricRowUpdate };

/// Contacts between two looks at the clock for NsgsSettings::deadline_ns (a clock read costs
/// about 20-30 ns, a contact of a 900-row dense problem about 0.2 us).
inline constexpr int kDeadlineCheckContacts = 8;

/// Largest NsgsSettings::anderson_depth.
inline constexpr int kMaxAndersonDepth = 8;
/// Anderson safeguard: error rise over the best that sends the solve back to the best iterate,
/// and how many such returns turn the acceleration off (NsgsSettings::anderson_depth).
inline constexpr double kAndersonRise = 2.0;
inline constexpr int kAndersonStrikes = 3;
/// ... and the acceleration also turns off when the best error has not fallen below
/// kAndersonProgress x itself for kAndersonStallSweeps checked sweeps (a plateau it does not
/// help through).
inline constexpr double kAndersonProgress = 0.99;
inline constexpr int kAndersonStallSweeps = 50;

struct NsgsSettings {
  double tolerance = 1e-6;           ///< on the normalised natural-map error
  int max_sweeps = 500;
  /// Over-relaxation in (0, 2); 1 = plain Gauss-Seidel. Problem dependent: on the bench's
  /// dense FEM-like W, 0.6 needs 46 sweeps against 73 at 1.0; on the rigid FCLIB stacks 1.3 is
  /// best (Box_Stacks 82 contacts: 15 against 22).
  double sor = 1.0;
  /// Relaxation on a cycling or oscillating error. On redundant frictional contacts (a surface
  /// held by both vertex and face contacts, mu = 2) plain Gauss-Seidel can settle into a limit
  /// cycle: measured on a hard-case problem (65 contacts), the error alternates 3.1e-2 / 4.1e-2
  /// for 5000 sweeps at sor 1, while sor 0.7 converges in 39; some mu = 2 sphere piles oscillate
  /// about a plateau (error 3e-4 .. 1.2e-3, period ~20 sweeps) and never converge at sor 1, where
  /// sor 0.7 converges in 1195. sor is multiplied by `stall_sor_factor` (down to `min_sor`; a
  /// solution is a fixed point for any sor, so this only changes the path) when, while the best
  /// error has not fallen below `stall_ratio` times its value at the previous such fall:
  /// - the error oscillates about its best level: 5 peaks (a rise to 1.2x the trough before it,
  ///   then a fall to 1/1.2 of the peak, that trough within 1.5x the best error) within
  ///   2 x `stall_sweeps` sweeps (the mu = 2 drag: at sweep 16; the pile: at sweep ~405); or
  /// - at the end of a window of `stall_sweeps` sweeps without that fall, at least half of the
  ///   window's checks repeat the error 2, 3 or 4 checks before them but not the one just before
  ///   (to 1e-6 relative: a cycle of period 2-4; a flat plateau is not one), or the sweep is past
  ///   3/4 of max_sweeps (the budget is then the nearer limit: the simulation's 500-sweep solves
  ///   on the mu = 2 drag keep their budget-stop residual low so).
  /// Slow convergence, plateaus and transient excursions keep sor: lowering it on any
  /// stagnation cost 4-8x more sweeps on rigid piles, or never reached 1e-9; with 3 peaks in
  /// 50 sweeps the rule also fired on piles that plain Gauss-Seidel solves 1.9x faster than
  /// sor 0.7. Measured (tests/bench/nsgs_rule_bench.cpp, docs/measurements.md, "The relaxation rule"): on 48 problems
  /// (FCLIB, the drag problem, sphere and capsule piles, redundant patches) at 1e-6 and 1e-9 the
  /// rule converges wherever plain or sor 0.7 does, in at most the better one's sweeps; on 40
  /// more (80 runs) it misses 3: plain converging after 3/4 of the budget (the late fallback
  /// then stops it), and plain stalling flat at 1.7e-6 where sor 0.7 converges in 10140.
  /// The windows count sweeps of one call: the haptic loop's 40-sweep ticks can only trigger
  /// the oscillation test (on the drag problem's kind of cycle). stall_sweeps = 0 disables both.
  int stall_sweeps = 50;
  double stall_ratio = 0.9;
  double stall_sor_factor = 0.7;
  double min_sor = 0.2;
  std::int64_t time_budget_ns = 0;   ///< 0: none; else stop after the sweep that crosses it
  /// Absolute deadline on CLOCK_MONOTONIC (shared::monotonicNs()); 0: none. Unlike
  /// time_budget_ns it is checked within sweeps, every kDeadlineCheckContacts contacts, and
  /// before the passes over W outside the sweeps: the entry pass forming W f + q is not started
  /// past it, and the confirmation pass of a converged claim is skipped when the last sweep's
  /// duration no longer fits before it (the solve then returns kTimeBudget with the running
  /// error). A solve stopped inside a sweep returns a consistent iterate: every contact either
  /// updated or not, delta = W f + q kept current. The haptic tick's one deadline.
  std::int64_t deadline_ns = 0;
  int check_every = 1;               ///< compute the error every k sweeps (kRowGather: one W pass)
  /// Anderson acceleration (0: off; at most kMaxAndersonDepth). After each checked sweep the
  /// next iterate is the combination of the last anderson_depth + 1 sweep results whose
  /// fixed-point residuals (sweep output - sweep input) best cancel in the least-squares sense,
  /// not projected (the next sweep's local solves put every contact back on its cone); delta
  /// follows by the same combination of the stored deltas (W is linear), so a step costs
  /// O(depth m), not a W pass. The reported solution is always a sweep's output. Safeguard:
  /// when the error rises above kAndersonRise x the best so far, the solve goes back to the
  /// best iterate and
  /// clears the history; after kAndersonStrikes such returns, or kAndersonStallSweeps checks
  /// without a fall of the best error below kAndersonProgress x itself, it goes on as plain NSGS
  /// from the best iterate, with the relaxation rule above starting afresh (the rule does not
  /// act while the acceleration does).
  /// Measured (docs/measurements.md, "Anderson acceleration"): on the liver grasps (dense W from the FEM
  /// compliance, friction-dominated) depth 8 needs 2-3x fewer sweeps (liver_grasp_23k median
  /// 134 -> 44); on the relaxation rule's problem sets fewer sweeps in 101 of 176 runs (FCLIB
  /// 1.2-2x, capsule piles 5-10x), more than 1.1x in 13 (rigid sphere piles, up to 2.7x) and no
  /// convergence in 2 (a 60-sphere pile): off by default.
  int anderson_depth = 0;
  /// kSymmetricRowUpdate only when W is exactly symmetric (see NsgsCoupling)
  NsgsCoupling coupling = NsgsCoupling::kColumnUpdate;
  /// The caller promises workspace.delta already holds W f + delta_free for the f passed in
  /// (e.g. the previous exit's delta shifted by the change of delta_free, W unchanged): the entry
  /// pass over W is skipped. The haptic loop uses it between ticks on the same snapshot.
  bool delta_is_current = false;
};

/// kConverged: error <= tolerance, the error recomputed from W f + q afresh (not the running
/// delta) when the solve claims it. kMaxSweeps / kTimeBudget: stopped first (f is the last
/// iterate, error its error). kNonFinite: W, q, mu or the warm start holds NaN/Inf, or the
/// iteration produced one; f is zeroed, error = +inf. kEmpty: no contacts, problem larger than
/// the workspace, or an inconsistent view (null pointer, ld < rows, row_offset steps other than
/// 1 or 3, blocks holding another problem's sizes or row offsets); f is left untouched. kIllPosed: some contact's diagonal block cannot be solved by
/// Gauss-Seidel - a diagonal entry of W that NSGS divides by (W_nn; W_tt too when mu > 0) is zero,
/// negative, denormal or below kMinRelativeDiagonal times the largest diagonal entry. Those
/// contacts' forces are held at zero, the others are solved as usual, and error is the real
/// natural-map error of the whole problem (including the held contacts); the status is kIllPosed
/// whatever that error is. Only kConverged means "solved"; every other status is a failure.
enum class NsgsStatus : std::uint8_t {
  kConverged, kMaxSweeps, kTimeBudget, kNonFinite, kEmpty, kIllPosed
};

/// A diagonal entry of W below this fraction of the largest one makes its contact ill-posed.
inline constexpr double kMinRelativeDiagonal = 1e-13;

/// "converged", "max_sweeps", "time_budget", "non_finite", "empty", "ill_posed" (static strings).
std::string_view toString(NsgsStatus status) noexcept;

struct NsgsResult {
  NsgsStatus status = NsgsStatus::kEmpty;
  int sweeps = 0;
  double error = 0.0;                ///< normalised natural-map error at exit
  double sor = 1.0;                  ///< relaxation in use at exit (see NsgsSettings::stall_sweeps)
  int relaxations = 0;               ///< times the stagnation rule lowered sor in this call
  int ill_posed_contacts = 0;        ///< contacts held at zero force (see kIllPosed)
  std::int64_t elapsed_ns = 0;       ///< wall time spent in solveNsgs (CLOCK_MONOTONIC)
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
  std::vector<double> delta;         ///< m: W f + delta_free, kept up to date (valid on exit)
  std::vector<double> scratch;       ///< m: per-row marks (ill-posed contacts)
  /// (3 kMaxAndersonDepth + 6) m: Anderson history (differences of sweep outputs, residuals
  /// and deltas, the newest of each), the running sweep's input and the best iterate with its
  /// delta
  std::vector<double> anderson;
 private:
  int max_rows_ = 0;
  int max_contacts_ = 0;
};

/// Solves in place: `f` (m entries) holds the warm start on entry (zeros for a cold start) and
/// the solution on exit. Never allocates. Problems larger than the workspace return kEmpty.
/// Costs one W pass to form delta = W f + q on entry, then one W pass per sweep. The error is
/// checked after sweeps check_every, 2 check_every, ... and at exit, never before the first
/// sweep (so a warm start that is already a solution costs exactly one sweep). When a check
/// meets the tolerance, delta is formed afresh (one more W pass) and the error re-checked before
/// kConverged is returned. Ill-posed contacts (see kIllPosed) are zeroed in f on entry.
/// On exit workspace.delta holds W f + q for the returned f.
NsgsResult solveNsgs(const ContactProblemView& problem, const NsgsSettings& settings,
                     NsgsWorkspace& workspace, double* f) noexcept;

/// Siconos' fc3d error: sqrt(sum_i ||f_i - P_K(f_i - delta_hat_i)||^2) / max(||q||,||f||,||delta||)
/// (for 1-row contacts: the projection onto R+). Allocation-free; writes delta = W f + q into
/// `delta_out` (m entries) when not null. When the three norms are all zero, the error is not
/// divided (it is then 0). NaN/Inf in the input gives a non-finite error.
double naturalMapError(const ContactProblemView& problem, const double* f,
                       double* delta_out = nullptr) noexcept;

/// Projection onto the Coulomb cone K_mu = {||z_t|| <= mu z_n} (z has 3 entries, in place).
void projectOnCone(double mu, double* z) noexcept;

}  // namespace tactus::shared
