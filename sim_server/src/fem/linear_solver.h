#pragma once
// Private linear solvers of the fem module (not installed): the CHOLMOD wrapper, a preconditioned
// conjugate gradient over the lower triangle of a symmetric matrix, and the factor-reuse
// strategy (LinearSolverKind::kCholmodReuse; fem.h, docs/design.md, "Free motion", Solvers).

#include <cholmod.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <condition_variable>
#include <cstddef>
#include <array>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "half_factor.h"
#include "tactus/sim/state_archive.h"

namespace tactus::sim::fem_detail {

/// The process-wide lock of the CHOLMOD calls that use BLAS: supernodal numeric factorisation
/// and supernodal solves (cholmod_super_numeric and cholmod_super_solve are the only parts of
/// CHOLMOD that reference BLAS). CholmodSolver takes it around those calls and nothing else; the
/// figures are public (blasLockFigures in fem.h). Why: the serial OpenBLAS that Debian installs
/// keeps one work buffer per process without a lock, so two threads in BLAS at once overwrite
/// each other's panels (wrong factors, found by helgrind with a background factorisation).
std::mutex& cholmodBlasMutex();

/// Sparse symmetric positive-definite factorisation through the CHOLMOD C API. The matrix is the
/// lower triangle of a compressed column-major Eigen matrix whose pattern never changes:
/// analyze() once, factorize() per step, solve() with workspaces kept between calls.
///
/// CHOLMOD chooses a supernodal factor for the large meshes (dense blocks, BLAS) and a simplicial
/// one for the small. A supernodal factorisation or solve holds cholmodBlasMutex(). With
/// setBlasFreeSolves(true) solve() keeps the supernodal factor and runs CHOLMOD's supernodal
/// sweeps itself (cholmod_super_lsolve's and cholmod_super_ltsolve's order, their dense
/// triangular solves and matrix-vector products by Eigen's kernels): no BLAS and no lock, the
/// same bits whatever another thread does, and one right-hand side as fast as CHOLMOD's BLAS
/// solve (liver_grasp_23k: docs/measurements.md, "The background refresh as the default"). The
/// solvers a step's thread uses while a background factorisation runs are set so, whether the
/// worker's factor is taken a fixed number of steps later or when ready
/// (FactorReusePolicy::background_when_ready): no solve of the step waits for the worker. (A
/// simplicial factor's solves make no BLAS call either way.)
class CholmodSolver {
 public:
  using Sparse = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;
  CholmodSolver();
  ~CholmodSolver();
  CholmodSolver(const CholmodSolver&) = delete;
  CholmodSolver& operator=(const CholmodSolver&) = delete;

  /// Symbolic analysis (fill-reducing ordering). Throws NumericalError on failure.
  void analyze(Sparse& lower);
  /// Numeric factorisation; false when the matrix is not positive definite.
  bool factorize(Sparse& lower);
  bool analyzed() const { return factor_ != nullptr; }
  bool factorized() const { return factorized_; }
  /// x = A^-1 b for `ncols` column-major right-hand sides of length n (x may alias b).
  void solve(const double* b, double* x, int ncols);
  /// solve() for many right-hand sides at once (the rest compliance C0's precomputation): on a
  /// supernodal factor CHOLMOD's own solve, whose dense blocks BLAS multiplies with the CPU's
  /// widest vectors (OpenBLAS picks its kernels when it starts), also with setBlasFreeSolves on;
  /// it holds cholmodBlasMutex() for the call, so it waits for a background factorisation
  /// running in another thread. The bits follow the CPU's BLAS kernels, as those of a solver
  /// without setBlasFreeSolves do.
  void solveWithBlas(const double* b, double* x, int ncols);
  /// Nonzeros of the factor (for the log/benchmarks).
  std::size_t factorNonzeros() const;
  /// The symbolic analysis of `other` (analyzed) taken over by copying it: no second ordering,
  /// and both then factorise matrices of the same pattern alike.
  void analyzeLike(const CholmodSolver& other);
  /// Exchanges the factors (and whether each holds a numeric one, and their float copies) with
  /// `other`.
  void swapFactor(CholmodSolver& other) noexcept;
  /// See the class comment; turning it on converts a supernodal numeric factor held now.
  void setBlasFreeSolves(bool on);
  bool blasFreeSolves() const { return blas_free_solves_; }
  /// Single-precision preconditioner solves (with setBlasFreeSolves; the factor-reuse strategy's
  /// PCG): factorize() also keeps a float copy of the supernodal factor's values (made by the
  /// thread that factorises: the background worker's, so a step never pays the conversion;
  /// swapFactor hands it over with the factor), and solvePreconditioner() runs the same sweeps
  /// on it in float (Eigen's generic float kernels, which accumulate in float). The sweeps read
  /// half the bytes: liver_23k's factor 12.9 MB instead of 25.8 (docs/measurements.md, "The
  /// simulation step at organ scale"). The result differs from the double solve by about
  /// 1e-7 relative (the factor's own rounding to float dominates; a double accumulation over the
  /// float values would not change that); PCG's residual, products and convergence test stay in
  /// double, so only the preconditioner is less exact, far less than the reused factor's lag
  /// makes it anyway. solve() (direct solves, compliance) stays in double. Deterministic: the
  /// copy is a rounding of the values, the same bits on every run. Turning it on converts a
  /// supernodal numeric factor held now (with setBlasFreeSolves on).
  void setSinglePrecisionPreconditioner(bool on);
  bool singlePrecisionPreconditioner() const { return single_precision_; }
  /// Half-precision preconditioner solves (with setBlasFreeSolves): factorize() also keeps the
  /// factor as a HalfFactor (half_factor.h: L D^-1 in binary16 and D^-2, packed; 5.4 MB on
  /// liver_23k against the float copy's 12.9 MB), made by the thread that factorises and
  /// handed over by swapFactor like the float copy, and solvePreconditioner() sweeps it. When
  /// an entry does not fit in half's range the float copy is made instead. Exclusive with
  /// setSinglePrecisionPreconditioner (the last one set wins).
  void setHalfPrecisionPreconditioner(bool on);
  bool halfPrecisionPreconditioner() const { return half_precision_; }
  /// The factor's half-precision copy is held: solvePreconditioner() uses it.
  bool holdsHalfPrecisionCopy() const { return half_current_; }
  /// The factor's float copy is held (setSinglePrecisionPreconditioner, a supernodal factor
  /// solved without BLAS): solvePreconditioner() uses it.
  bool holdsSinglePrecisionCopy() const { return single_current_; }
  /// x ~= A^-1 b for one right-hand side of length n (x may alias b): the float sweeps when the
  /// float copy is held, solve() otherwise.
  void solvePreconditioner(const double* b, double* x);
  /// The forward sweep of the solves without BLAS (setBlasFreeSolves; solvePreconditioner too)
  /// passes over a supernode whose part of the permuted right-hand side is still all zero when
  /// the sweep reaches it: on by default. The bits are those of the full sweep: such a part
  /// stays +0 through the triangular solve (+0 divided by the positive diagonal, minus +-0
  /// products), and what it would pass on, -(L_below y1), is a sum of +-0 that changes no entry
  /// it meets (a non-zero x stays x; +0 - (+-0) is +0, and from a right-hand side without -0
  /// the sweep never makes one: x - x is +0; a right-hand side holding a -0, after its rounding
  /// to float for the float sweeps, is swept in full). What it saves: the contact correction's
  /// right-hand side lies on the ~200 nodes the contact rows touch (liver_grasp_23k: 21000
  /// DOFs), so the forward sweep reads only the supernodes on their paths to the root of the
  /// elimination tree instead of the whole rest factor (docs/design.md, "The correction's
  /// forward sweep over the touched supernodes only"). Off: every supernode (for comparison).
  void setSkipZeroSupernodes(bool on) { skip_zero_supernodes_ = on; }
  /// Supernodes the last solve without BLAS skipped in its forward sweep.
  long skippedSupernodes() const { return skipped_supernodes_; }
  /// The numeric factor is supernodal (its solves use BLAS and take the lock).
  bool supernodal() const { return factor_ != nullptr && factor_->is_super; }
  /// Changes whenever the factor held may change (analyze, analyzeLike, factorize, swapFactor):
  /// a caller that kept the value knows the factor is still the one it computed when it is the
  /// same.
  std::uint64_t generation() const { return generation_; }
  /// Reads one value per 4 KiB page of the numeric factor (and of its float copy) and returns
  /// their sum (nothing when there is none). A factor kept for a later solve (the rest factor of
  /// the contact correction, unused until the first contact) has its pages touched so, at a few
  /// hundredths of a millisecond a call when they are resident: on the VM this project measures
  /// on, a page not read for some time costs about 10 us at its next read (the first contact
  /// step's rest solve took 50-60 ms instead of 4-5 in half the runs of liver_grasp_23k;
  /// docs/measurements.md, "The simulation step at organ scale"), and a call once a step keeps
  /// that cost off the step that needs the factor. Leaves the factor and every result alone.
  double touchPages() const;
  /// Sizes and writes the workspaces of the solves without BLAS (double, and float when the
  /// single-precision copy is current) for one right-hand side, so that the first solve takes
  /// no fresh page. The factor and every result are left alone. Nothing without a supernodal
  /// factor.
  void prepareSolveWorkspaces();

 private:
  cholmod_sparse view(Sparse& lower) const;
  /// setBlasFreeSolves: solve() on the supernodal factor by Eigen's dense kernels
  void supernodalSolveWithoutBlas(const double* b, double* x, int ncols);
  /// singlePrecisionPreconditioner: the float copy of the current supernodal factor's values
  void makeSinglePrecisionCopy();
  /// The half and float copies made or dropped to match the settings and the factor held now
  /// (the float one also in place of a half copy that could not be made).
  void syncPreconditionerCopies();
  cholmod_common common_;
  cholmod_factor* factor_ = nullptr;
  cholmod_factor* symbolic_ = nullptr;   // the supernodal analysis (null when simplicial)
  cholmod_dense* x_ = nullptr;
  cholmod_dense* y_ = nullptr;
  cholmod_dense* e_ = nullptr;
  Eigen::MatrixXd own_y_, own_e_;   // supernodalSolveWithoutBlas's workspaces
  std::vector<float> single_x_;     // the float copy of factor_->x (single_current_)
  HalfFactor half_;                 // the half-precision copy (half_current_)
  Eigen::VectorXf single_y_, single_e_;   // solvePreconditioner's float workspaces
  bool factorized_ = false;
  bool single_precision_ = false;
  bool single_current_ = false;     // single_x_ holds factor_'s current values
  bool half_precision_ = false;
  bool half_current_ = false;       // half_ holds factor_'s current values
  bool blas_free_solves_ = false;
  bool skip_zero_supernodes_ = true;
  long skipped_supernodes_ = 0;
  std::uint64_t generation_ = 0;
};

/// Work vectors of conjugateGradient, kept between calls (no allocation once sized).
struct CgBuffers {
  Eigen::VectorXd r, z, p, ap;
};

struct CgResult {
  int iterations = 0;
  double residual = 0.0;  ///< final ||b - A x|| / ||b||
  bool converged = false; ///< residual <= tolerance and x finite
};

/// Preconditioned conjugate gradient on A x = b, A symmetric positive definite given by its lower
/// triangle. x holds the warm start on entry (a non-finite start residual restarts from 0) and
/// the last iterate on exit. `precond(r, z)` sets z = P^-1 r. Stops when ||b - A x|| / ||b|| <=
/// tolerance or after max_iterations; b = 0 gives x = 0.
template <class Precond>
CgResult conjugateGradient(const CholmodSolver::Sparse& lower, const Eigen::VectorXd& b,
                           Eigen::VectorXd& x, double tolerance, int max_iterations,
                           CgBuffers& w, Precond&& precond) {
  CgResult out;
  const auto a = lower.selfadjointView<Eigen::Lower>();
  const double b_norm = b.norm();
  if (b_norm == 0.0) {
    x.setZero(b.size());
    out.converged = true;
    return out;
  }
  w.r = b;
  w.r.noalias() -= a * x;
  double res = w.r.norm() / b_norm;
  if (!(res < 1e300)) {
    x.setZero(b.size());
    w.r = b;
    res = 1.0;
  }
  int it = 0;
  if (res > tolerance) {
    w.z.resize(b.size());
    precond(w.r, w.z);
    w.p = w.z;
    double rz = w.r.dot(w.z);
    while (it < max_iterations) {
      w.ap.noalias() = a * w.p;
      const double pap = w.p.dot(w.ap);
      if (!(pap > 0.0)) break;
      const double step = rz / pap;
      x.noalias() += step * w.p;
      w.r.noalias() -= step * w.ap;
      ++it;
      res = w.r.norm() / b_norm;
      if (res <= tolerance) break;
      precond(w.r, w.z);
      const double rz_new = w.r.dot(w.z);
      w.p = w.z + (rz_new / rz) * w.p;
      rz = rz_new;
    }
  }
  out.iterations = it;
  out.residual = res;
  out.converged = res <= tolerance && x.allFinite();
  return out;
}

/// A worker thread that factorises a copy of a system matrix while its caller goes on (the
/// factor-reuse strategy's background refresh). One job at a time: start() copies the matrix's
/// values and returns; collect() waits for the job if it still runs and hands its factor over.
/// The thread starts with the first job and is joined by the destructor; the stop signals are
/// blocked in it (they reach the process's other threads), and OpenMP is limited in it as in the
/// process. Its CHOLMOD state is its own; its factorisation holds cholmodBlasMutex() (several
/// bodies' workers and the step's own factorisations never run BLAS at once), and its solver is
/// set to solve without BLAS (CholmodSolver::setBlasFreeSolves), so the factor handed over is
/// solved without BLAS; when the caller's solver keeps a float copy for its preconditioner
/// solves (CholmodSolver::setSinglePrecisionPreconditioner), the worker makes it after its
/// factorisation and hands it over with the factor. The caller's solver must be set so too: then nothing on the step's
/// thread runs BLAS while the worker does, except a factorisation there, which waits for the
/// worker's. The worker runs at the process's priority: a lower one would make such a
/// factorisation wait longer whenever the machine is busy.
class BackgroundFactoriser {
 public:
  using Sparse = CholmodSolver::Sparse;
  BackgroundFactoriser() = default;
  ~BackgroundFactoriser();
  BackgroundFactoriser(const BackgroundFactoriser&) = delete;
  BackgroundFactoriser& operator=(const BackgroundFactoriser&) = delete;
  /// Starts factorising a copy of `a`, whose pattern `like` (analyzed) was analysed for.
  /// Requires !busy().
  void start(const Sparse& a, const CholmodSolver& like);
  /// A job was started and not collected.
  bool busy() const { return busy_; }
  /// The started job has finished (its result can be collected without waiting).
  bool finished();
  /// Waits for the started job; when its factorisation succeeded, swaps its factor into
  /// `factor` and returns true. `waited_s`: how long this call waited; `factorisation_s`: the
  /// job's own time.
  bool collect(CholmodSolver& factor, double& waited_s, double& factorisation_s);
  /// Waits for the started job and drops its result.
  void discard();

 private:
  void run();
  std::thread worker_;
  std::mutex mutex_;
  std::condition_variable wake_;
  Sparse copy_;
  std::unique_ptr<CholmodSolver> solver_;
  bool busy_ = false;       // caller's side: started, not collected
  bool pending_ = false;    // guarded: the worker has a job to take
  bool done_ = false;       // guarded: the job finished
  bool ok_ = false;         // guarded: and succeeded
  bool stop_ = false;       // guarded
  double factorisation_s_ = 0.0;
};

/// When the factor-reuse strategy refreshes its factorisation.
struct FactorReusePolicy {
  double tolerance = 1e-8;        ///< PCG relative residual
  int refactor_iterations = 8;    ///< PCG iteration bound (see ReusedFactorSolver)
  int refactor_every_steps = 0;   ///< also refresh when the factor is this many steps old (0: never)
  /// > 0: refresh in the background (see ReusedFactorSolver), the new factor taking over this
  /// many steps after the step whose matrix it factorises; 0: refresh synchronously
  int background_lag_steps = 0;
  /// background mode: the new factor takes over at the first step at least background_lag_steps
  /// after its start at which the worker has finished, and no step ever waits for the worker
  /// (the steps at which the factor changes then depend on the worker's speed); false: exactly
  /// background_lag_steps steps after, waiting for the worker if it has not finished
  bool background_when_ready = false;
  /// background mode, lagged: the lag over steps without contact (see
  /// ReusedFactorSolver::adoptDue); 0: background_lag_steps
  int background_free_lag_steps = 0;
  /// > 0: PCG corrects the preconditioner exactly at the nodes where it is furthest from the
  /// current A (see ReusedFactorSolver::solve): a node whose diagonal block of A differs from
  /// the warped factor's, T A_f T^T, by more than this fraction (Frobenius norms) joins the
  /// local block; 0: no local correction
  double local_correction_threshold = 0.0;
  /// at most this many nodes in the local block (those furthest off when more qualify)
  int local_correction_max_nodes = 96;
};

/// Figures of one ReusedFactorSolver::solve.
struct ReuseSolveResult {
  bool ok = false;               ///< false: the factorisation failed or x is not finite
  bool refreshed = false;        ///< the current A was factorised in this solve
  int cg_iterations = 0;         ///< PCG iterations (those of a failed attempt included)
  double residual = 0.0;         ///< final relative residual (0 after a direct solve)
  double factorisation_s = 0.0;
  double solve_s = 0.0;
  /// background mode: this solve started factorising its A on the worker thread
  bool background_started = false;
  /// the refresh used the factor prepared before the step (notePreparedFactor): a direct solve,
  /// no factorisation in this solve
  bool prepared = false;
  /// nodes in the PCG's local correction (0: none)
  int local_nodes = 0;
};

/// A dv = b with the CHOLMOD factorisation of a recent system matrix A_f as the preconditioner of
/// a warm-started PCG. The factor is refreshed (CHOLMOD factorises the current A and solves
/// directly, synchronously) when
///  * there is none yet, or it is `refactor_every_steps` steps old (when that is > 0);
///  * the previous step's PCG needed more than refactor_iterations / 2 iterations (the matrix is
///    drifting away from A_f: refresh before the bound is hit);
///  * PCG does not reach the tolerance within refactor_iterations iterations (the step then pays
///    those iterations plus a factorisation and a direct solve; its result is exact).
/// So every solve meets the tolerance: a direct solve with a fresh factor, or a PCG that
/// converged. The factor is the caller's (shared with the exact compliance path): whoever
/// refactorises it at the current A calls noteFactorised().
///
/// Background mode (background_lag_steps = L > 0, a worker set with setBackground): the schedule
/// and the drift (all reasons but a missing factor) start factorising the current A on the
/// worker instead (when it is idle) and the step goes on with PCG on the old factor; L steps later, adoptDue() at the start of that step
/// takes the new factor (waiting for the worker only if it has not finished: counted by the
/// caller). A PCG that misses refactor_iterations goes on to 3 x refactor_iterations (and starts
/// a background factorisation); only one that misses those too refreshes synchronously. The
/// factor changes at steps fixed by the iteration counts, not by the worker's speed: the results
/// do not depend on timing. With background_when_ready the factor instead takes over at the
/// first step, L or more steps after the start, at which the worker has finished: adoptDue()
/// never waits (a job not finished yet is looked at again at the next step, the step going on
/// with PCG on the factor it has), so refactorisation is off the step's critical path, at the
/// price of results that depend on the worker's timing (each still meets the tolerance).
/// PCG's preconditioner solves are the factor's solvePreconditioner() (single precision when
/// the factor is set so); its direct solves after a refresh are solve() (double).
///
/// Local correction (local_correction_threshold > 0, with A_f's values given to solve()): the
/// warp follows rotations that one rotation per node represents; where the elements around a
/// node deform unlike it (the tets crushed between a grasper's jaws, a released lobe's fold) the
/// warped factor is wrong at a handful of nodes, and PCG spent most of its iterations there
/// (liver_grasp_23k: 11-22 iterations with a factor one step old). Before PCG the nodes whose
/// diagonal block of A is furthest from T A_f T^T form a local block A_LL, factorised densely
/// (Z: the unit vectors of its unknowns). The start is corrected so that Z^T r0 = 0
/// (x0 += Z A_LL^-1 Z^T r0), and each preconditioner solve y = T A_f^-1 T^T r is followed by
/// z = y + Z A_LL^-1 Z^T (r - A y): the deflated PCG in its "adapted" form (A-DEF2), which keeps
/// Z^T r = 0 at every iteration, so that plain PCG's recurrences apply. Which nodes form the
/// block follows from A, A_f and the rotations alone: reproducible bit for bit.
class ReusedFactorSolver {
 public:
  using Sparse = CholmodSolver::Sparse;
  explicit ReusedFactorSolver(const FactorReusePolicy& policy) : policy_(policy) {}
  /// The worker of background mode (the caller's; it outlives this solver's use).
  void setBackground(BackgroundFactoriser* worker) { background_ = worker; }
  /// Background mode, at the start of each step before solve(): when the worker's job is
  /// background_lag_steps steps old, swaps its factor into `factor` (waiting for it if it still
  /// runs; `waited_s`) and returns true: the factor is then that of the matrix of the step that
  /// started the job. A job made stale by a newer factor is dropped at that step instead.
  /// With background_when_ready: the same when the job has finished, nothing (no wait) when it
  /// has not (counted by notReadySteps()).
  /// `after_contact`: the previous step's contact correction solved with the body. With
  /// background_free_lag_steps > 0 the steps since the job's start are weighed: each counts
  /// background_free_lag_steps units after a step in contact, background_lag_steps units after
  /// one without, and the job is due when they reach background_lag_steps x
  /// background_free_lag_steps (the lag's steps in contact, or the free lag's without; a mix in
  /// between). Without, every step counts one and the job is due after background_lag_steps.
  bool adoptDue(CholmodSolver& factor, double& waited_s, double& factorisation_s,
                bool after_contact = false);
  /// background_when_ready: steps at which a job was due and had not finished (each went on with
  /// the factor it had instead of waiting).
  long notReadySteps() const { return not_ready_steps_; }
  /// x holds the warm start (the previous step's solution) on entry, the solution on exit.
  /// `block_rotation` (null: none) warps the preconditioner to T A_f^-1 T^T with T block
  /// diagonal, one 3x3 rotation per 3 consecutive unknowns (size / 3 of them): the rotation of
  /// each node since the factor's step, so that the factor follows the tissue's rotations.
  /// `factor_a_values` (null: none): the values of A_f, the matrix the factor was computed
  /// from, in A's pattern; with block_rotation and local_correction_threshold > 0 they enable
  /// the local correction.
  ReuseSolveResult solve(CholmodSolver& factor, Sparse& a, const Eigen::VectorXd& b,
                         Eigen::VectorXd& x, const Eigen::Matrix3d* block_rotation = nullptr,
                         const double* factor_a_values = nullptr);
  /// The factor was computed from the current A outside solve() (it is 0 steps old).
  void noteFactorised() {
    age_steps_ = 0;
    last_iterations_ = 0;
    job_stale_ = true;
  }
  /// For the next solve() only: the factor holds its A already (factorised before the step,
  /// e.g. at set-up from the same state, and checked by the caller to be that A's to the bit).
  /// When that solve refreshes (no factor of record yet) it solves directly with it instead of
  /// factorising: the same factor and the same bits as the factorisation would give, without
  /// the step paying for it.
  void notePreparedFactor() { prepared_ = true; }
  /// The factor no longer holds a step's A (e.g. a static solve factorised K): refresh next time.
  void forget() {
    age_steps_ = -1;
    job_stale_ = true;
  }
  /// Sizes and writes the PCG's work vectors and the warp's for `n` unknowns (set-up: the first
  /// PCG then takes no fresh page). Every value is written by solve() before it is read.
  void prepareBuffers(Eigen::Index n) {
    for (Eigen::VectorXd* v : {&cg_.r, &cg_.z, &cg_.p, &cg_.ap, &warp_}) v->setZero(n);
  }
  /// Steps since the factor was computed (-1: none yet).
  int ageSteps() const { return age_steps_; }
  long refreshes() const { return refreshes_; }
  /// The factor's age and the last PCG's iterations (what decides the next refresh) are state,
  /// and in background mode whether a job is in flight, its age and whether it is stale: a job
  /// is a factor being computed on another thread from an earlier step's A, whose values the
  /// caller keeps in its state; after loading, jobToRestart() says that the caller must start it
  /// again from them (restartJob), so that a restored run takes the same factor at the same
  /// step as the run that saved it. refreshes_ counts, cg_ and warp_ are scratch.
  void transferState(StateArchive& ar) {
    ar("age_steps", age_steps_);
    ar("last_iterations", last_iterations_);
    bool job = background_ != nullptr && background_->busy();
    ar("background_job", job);
    ar("background_job_steps", job_steps_);
    ar("background_job_units", job_units_);
    ar("background_job_stale", job_stale_);
    if (!ar.loading()) return;
    if (background_ != nullptr && background_->busy()) background_->discard();
    restart_job_ = job && background_ != nullptr;
  }
  /// After transferState loaded a state with a job in flight: true (once).
  bool jobToRestart() {
    const bool r = restart_job_;
    restart_job_ = false;
    return r;
  }
  /// Starts the loaded job again on the worker: `a` holds the values of the job's A, `like` is
  /// the analysed factor of record. The job keeps its loaded age.
  void restartJob(const Sparse& a, const CholmodSolver& like) { background_->start(a, like); }

 private:
  FactorReusePolicy policy_;
  CgBuffers cg_;
  Eigen::VectorXd warp_;
  int age_steps_ = -1;
  int last_iterations_ = 0;
  long refreshes_ = 0;
  long not_ready_steps_ = 0;
  BackgroundFactoriser* background_ = nullptr;
  int job_steps_ = 0;        // steps since the worker's job started (while it is busy)
  int job_units_ = 0;        // and their weights (adoptDue)
  bool job_stale_ = false;   // a newer factor than the job's was made since it started
  bool restart_job_ = false; // a loaded state had a job in flight (jobToRestart)
  bool prepared_ = false;    // notePreparedFactor (consumed by the next solve)

  // ---- the local correction (scratch, rebuilt each solve from A, A_f and the rotations) ----
  // The 3x3 block of A at (row node, column node), row >= col: the positions of its nine
  // values in A's value array (-1: not stored, the diagonal block's upper part).
  struct NodeBlock {
    int row = 0, col = 0;
    std::array<int, 9> pos{};
  };
  void indexBlocks(const Sparse& a);
  Eigen::Matrix3d blockValues(const NodeBlock& b, const double* values) const;
  int selectLocalNodes(const Sparse& a, const double* factor_a_values,
                       const Eigen::Matrix3d* block_rotation);
  // local_u_ = (r - A y) at the local nodes' unknowns
  void localResidual(const Sparse& a, const Eigen::VectorXd& r, const Eigen::VectorXd& y);
  // x += Z A_LL^-1 local_u_
  void addLocalSolution(Eigen::VectorXd& x);
  std::vector<NodeBlock> blocks_;
  std::vector<int> diagonal_block_;                      // per node: its diagonal block
  std::vector<int> node_block_begin_, node_block_index_; // per node: the blocks in its row
  Eigen::Index indexed_nonzeros_ = -1;
  std::vector<std::pair<double, int>> candidates_;       // (misfit, node)
  std::vector<int> local_nodes_;                         // ascending
  std::vector<int> local_index_;                         // per node: its place in local_nodes_, -1
  // A_LL, then its Cholesky factor in the lower triangle: the top left 3 x local nodes square
  // of a matrix sized once for the most nodes (and local_u_ its head), so that a block of
  // another size than the last takes no allocation
  Eigen::MatrixXd local_a_;
  Eigen::VectorXd local_u_;
};

}  // namespace tactus::sim::fem_detail
