#include "linear_solver.h"

#include "fem_internal.h"

#include <dlfcn.h>
#include <pthread.h>
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>

#include <spdlog/spdlog.h>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"

namespace tactus::sim::fem_detail {

// ---- CHOLMOD ----

namespace {

// METIS, which cholmod_analyze calls for its orderings, replaces the SIGTERM handler while it
// runs (GKlib's gk_sigtrap) and swallows a SIGTERM that arrives then: a stop request sent during
// the analysis of a large mesh was lost (FilesTest.SigtermDuringC0PrecomputationExitsWithAMessage
// failed so). The stop signals are blocked in this thread around the analysis; one that arrives
// stays pending and reaches the process's own handler when they are unblocked.
class StopSignalsBlocked {
 public:
  StopSignalsBlocked() {
    sigset_t stop;
    sigemptyset(&stop);
    sigaddset(&stop, SIGINT);
    sigaddset(&stop, SIGTERM);
    sigaddset(&stop, SIGHUP);
    blocked_ = pthread_sigmask(SIG_BLOCK, &stop, &previous_) == 0;
  }
  ~StopSignalsBlocked() {
    if (blocked_) pthread_sigmask(SIG_SETMASK, &previous_, nullptr);
  }
  StopSignalsBlocked(const StopSignalsBlocked&) = delete;
  StopSignalsBlocked& operator=(const StopSignalsBlocked&) = delete;

 private:
  sigset_t previous_{};
  bool blocked_ = false;
};

std::atomic<long> g_blas_contended{0};
std::atomic<std::int64_t> g_blas_waited_ns{0};

// Holds cholmodBlasMutex() for one CHOLMOD call; counts the calls that found it taken and their
// wait.
class CholmodBlasCall {
 public:
  CholmodBlasCall() : lock_(cholmodBlasMutex(), std::try_to_lock) {
    if (lock_.owns_lock()) return;
    const std::int64_t t0 = shared::monotonicNs();
    lock_.lock();
    g_blas_contended.fetch_add(1, std::memory_order_relaxed);
    g_blas_waited_ns.fetch_add(shared::monotonicNs() - t0, std::memory_order_relaxed);
  }

 private:
  std::unique_lock<std::mutex> lock_;
};

}  // namespace

std::mutex& cholmodBlasMutex() {
  static std::mutex m;
  return m;
}

CholmodSolver::CholmodSolver() {
  limitNumericThreads();
  cholmod_start(&common_);
  // analyze() tries AMD, METIS and CHOLMOD's nested dissection and keeps the sparsest factor
  // (liver_23k: 2.95 M nonzeros instead of AMD's 3.13 M, whose result also depends on the input
  // order); the analysis runs once per matrix pattern
  common_.nmethods = 4;
  common_.print = 0;
  common_.error_handler = nullptr;
}

CholmodSolver::~CholmodSolver() {
  if (factor_) cholmod_free_factor(&factor_, &common_);
  if (symbolic_) cholmod_free_factor(&symbolic_, &common_);
  if (x_) cholmod_free_dense(&x_, &common_);
  if (y_) cholmod_free_dense(&y_, &common_);
  if (e_) cholmod_free_dense(&e_, &common_);
  cholmod_finish(&common_);
}

cholmod_sparse CholmodSolver::view(Sparse& lower) const {
  cholmod_sparse s{};
  s.nrow = static_cast<std::size_t>(lower.rows());
  s.ncol = static_cast<std::size_t>(lower.cols());
  s.nzmax = static_cast<std::size_t>(lower.nonZeros());
  s.p = lower.outerIndexPtr();
  s.i = lower.innerIndexPtr();
  s.nz = nullptr;
  s.x = lower.valuePtr();
  s.z = nullptr;
  s.stype = -1;  // lower triangle holds the symmetric matrix
  s.itype = CHOLMOD_INT;
  s.xtype = CHOLMOD_REAL;
  s.dtype = CHOLMOD_DOUBLE;
  s.sorted = 1;
  s.packed = 1;
  return s;
}

void CholmodSolver::analyze(Sparse& lower) {
  if (!lower.isCompressed()) lower.makeCompressed();
  if (factor_) cholmod_free_factor(&factor_, &common_);
  if (symbolic_) cholmod_free_factor(&symbolic_, &common_);
  single_current_ = false;
  half_current_ = false;
  ++generation_;
  cholmod_sparse a = view(lower);
  {
    const StopSignalsBlocked stop_signals_pending;
    factor_ = cholmod_analyze(&a, &common_);
  }
  factorized_ = false;
  if (!factor_ || common_.status < CHOLMOD_OK) {
    throw NumericalError("CHOLMOD symbolic analysis failed (status " +
                         std::to_string(common_.status) + ") for a system of " +
                         std::to_string(lower.rows()) + " unknowns");
  }
  if (factor_->is_super) {
    symbolic_ = cholmod_copy_factor(factor_, &common_);
    if (!symbolic_) throw NumericalError("CHOLMOD: copying a factor failed (out of memory?)");
  }
  spdlog::debug("CHOLMOD analysis: n {} nnz(A) {} nnz(L) {:.0f} flops {:.3g} ordering {} {}", lower.rows(),
                lower.nonZeros(), common_.lnz, common_.fl,
                common_.method[common_.selected].ordering,
                factor_->is_super ? "supernodal" : "simplicial");
}

bool CholmodSolver::factorize(Sparse& lower) {
  ++generation_;
  if (!factor_->is_super && symbolic_ != nullptr) {
    // a simplicial conversion of an earlier factor: start again from the supernodal analysis
    cholmod_free_factor(&factor_, &common_);
    factorized_ = false;
    factor_ = cholmod_copy_factor(symbolic_, &common_);
    if (!factor_) throw NumericalError("CHOLMOD: copying a factor failed (out of memory?)");
  }
  cholmod_sparse a = view(lower);
  int ok = 0;
  if (factor_->is_super) {
    const CholmodBlasCall blas;
    ok = cholmod_factorize(&a, factor_, &common_);
  } else {
    ok = cholmod_factorize(&a, factor_, &common_);
  }
  factorized_ = ok && common_.status == CHOLMOD_OK && factor_->minor == factor_->n;
  single_current_ = false;
  half_current_ = false;
  syncPreconditionerCopies();
  return factorized_;
}

void CholmodSolver::setBlasFreeSolves(bool on) {
  blas_free_solves_ = on;
  syncPreconditionerCopies();
}

void CholmodSolver::setSinglePrecisionPreconditioner(bool on) {
  single_precision_ = on;
  if (on) half_precision_ = false;
  if (!on) single_x_ = {};
  syncPreconditionerCopies();
}

void CholmodSolver::setHalfPrecisionPreconditioner(bool on) {
  half_precision_ = on;
  if (on) single_precision_ = false;
  syncPreconditionerCopies();
}

void CholmodSolver::syncPreconditionerCopies() {
  const bool copies = blas_free_solves_ && factorized_;
  if (!(half_precision_ && copies)) {
    half_current_ = false;
  } else if (!half_current_) {
    half_current_ = factor_->is_super && half_.assign(*factor_);
  }
  // the float copy: asked for, or in place of a half copy that could not be made
  const bool want_single = single_precision_ || (half_precision_ && !half_current_);
  if (!(want_single && copies))
    single_current_ = false;
  else if (!single_current_)
    makeSinglePrecisionCopy();
}

void CholmodSolver::makeSinglePrecisionCopy() {
  single_current_ = false;
  if (factor_ == nullptr || !factor_->is_super) return;
  const auto* lx = static_cast<const double*>(factor_->x);
  single_x_.resize(factor_->xsize);
  for (std::size_t k = 0; k < factor_->xsize; ++k) single_x_[k] = static_cast<float>(lx[k]);
  single_current_ = true;
}

namespace {

// One sweep pair of CholmodSolver::supernodalSolveWithoutBlas over the permuted right-hand sides
// `y` (n x ncols, or a vector: Eigen's matrix-vector kernels for one column), `e` its scratch,
// with the factor's values `lx` (f.x, or its float copy: then y and e are float too). With
// skip_zero the forward sweep passes over the supernodes whose part of y is all zero when it
// reaches them (CholmodSolver::setSkipZeroSupernodes); returns how many it skipped.
template <class Scalar, class Y, class E>
long supernodalSweeps(const cholmod_factor& f, const Scalar* lx, Y& y, E& e, bool skip_zero) {
  long skipped = 0;
  const int* super = static_cast<const int*>(f.super);
  const int* pi = static_cast<const int*>(f.pi);
  const int* px = static_cast<const int*>(f.px);
  const int* ls = static_cast<const int*>(f.s);
  const auto nsuper = static_cast<Eigen::Index>(f.nsuper);
  const Eigen::Index ncols = y.cols();
  using Block = Eigen::Map<const Eigen::Matrix<Scalar, Eigen::Dynamic, Eigen::Dynamic>, 0,
                           Eigen::OuterStride<>>;
  for (Eigen::Index s = 0; s < nsuper; ++s) {   // L y = P b
    const int k1 = super[s], nscol = super[s + 1] - k1;
    const int psi = pi[s], nsrow = pi[s + 1] - psi, nsrow2 = nsrow - nscol;
    const Block l(lx + px[s], nsrow, nscol, Eigen::OuterStride<>(nsrow));
    auto y1 = y.middleRows(k1, nscol);
    // a part of y still zero has nothing to solve or pass on (see skipZeroSupernodes)
    if (skip_zero && (y1.array() == Scalar(0)).all()) {
      ++skipped;
      continue;
    }
    l.topRows(nscol).template triangularView<Eigen::Lower>().solveInPlace(y1);
    if (nsrow2 == 0) continue;
    auto e2 = e.topRows(nsrow2);
    e2.noalias() = l.bottomRows(nsrow2) * y1;
    const int* rows = ls + psi + nscol;
    for (Eigen::Index c = 0; c < ncols; ++c)
      for (int i = 0; i < nsrow2; ++i) y(rows[i], c) -= e2(i, c);
  }
  for (Eigen::Index s = nsuper - 1; s >= 0; --s) {   // L^T z = y
    const int k1 = super[s], nscol = super[s + 1] - k1;
    const int psi = pi[s], nsrow = pi[s + 1] - psi, nsrow2 = nsrow - nscol;
    const Block l(lx + px[s], nsrow, nscol, Eigen::OuterStride<>(nsrow));
    auto y1 = y.middleRows(k1, nscol);
    if (nsrow2 > 0) {
      auto e2 = e.topRows(nsrow2);
      const int* rows = ls + psi + nscol;
      for (Eigen::Index c = 0; c < ncols; ++c)
        for (int i = 0; i < nsrow2; ++i) e2(i, c) = y(rows[i], c);
      y1.noalias() -= l.bottomRows(nsrow2).transpose() * e2;
    }
    l.topRows(nscol).template triangularView<Eigen::Lower>().transpose().solveInPlace(y1);
  }
  return skipped;
}

// x = P^T L^-T L^-1 P b for the columns of `y` (n x ncols, or a vector): b gathered into y in
// the factor's order (converted to Scalar), supernodalSweeps, y scattered back into x.
template <class Scalar, class Y, class E>
long permutedSweeps(const cholmod_factor& f, const Scalar* lx, Y& y, E& e, const double* b,
                    double* x, bool skip_zero) {
  const auto n = static_cast<Eigen::Index>(f.n);
  const int* perm = static_cast<const int*>(f.Perm);
  bool negative_zero = false;   // (skipping keeps the full sweep's bits only without one)
  for (Eigen::Index c = 0; c < y.cols(); ++c)
    for (Eigen::Index k = 0; k < n; ++k) {
      const auto v = static_cast<Scalar>(b[c * n + (perm ? perm[k] : k)]);
      negative_zero = negative_zero || (v == Scalar(0) && std::signbit(v));
      y(k, c) = v;
    }
  const long skipped = supernodalSweeps(f, lx, y, e, skip_zero && !negative_zero);
  for (Eigen::Index c = 0; c < y.cols(); ++c)
    for (Eigen::Index k = 0; k < n; ++k)
      x[c * n + (perm ? perm[k] : k)] = static_cast<double>(y(k, c));
  return skipped;
}

}  // namespace

void CholmodSolver::supernodalSolveWithoutBlas(const double* b, double* x, int ncols) {
  // cholmod_super_lsolve's and cholmod_super_ltsolve's sweeps, their dtrsv/dgemv (dtrsm/dgemm)
  // by Eigen's kernels
  const cholmod_factor& f = *factor_;
  const auto n = static_cast<Eigen::Index>(f.n);
  const auto esize = static_cast<Eigen::Index>(f.maxesize);
  const auto* lx = static_cast<const double*>(f.x);
  own_y_.resize(n, ncols);
  own_e_.resize(esize, ncols);
  if (ncols == 1) {   // Eigen's matrix-vector kernels for one column
    Eigen::Map<Eigen::VectorXd> y(own_y_.data(), n), e(own_e_.data(), esize);
    skipped_supernodes_ = permutedSweeps(f, lx, y, e, b, x, skip_zero_supernodes_);
    return;
  }
  skipped_supernodes_ = permutedSweeps(f, lx, own_y_, own_e_, b, x, skip_zero_supernodes_);
}

void CholmodSolver::prepareSolveWorkspaces() {
  if (factor_ == nullptr || !factor_->is_super) return;
  const auto n = static_cast<Eigen::Index>(factor_->n);
  const auto esize = static_cast<Eigen::Index>(factor_->maxesize);
  own_y_.setZero(n, 1);
  own_e_.setZero(esize, 1);
  if (single_current_) {
    single_y_.setZero(n);
    single_e_.setZero(esize);
  }
  if (half_current_) half_.prepare(*factor_);
}

void CholmodSolver::solvePreconditioner(const double* b, double* x) {
  if (half_current_ && blas_free_solves_) {
    half_.solve(*factor_, b, x);
    skipped_supernodes_ = 0;
    return;
  }
  if (!single_current_ || !blas_free_solves_) {
    solve(b, x, 1);
    return;
  }
  // supernodalSolveWithoutBlas's permutation and sweeps, in float
  const cholmod_factor& f = *factor_;
  single_y_.resize(static_cast<Eigen::Index>(f.n));
  single_e_.resize(static_cast<Eigen::Index>(f.maxesize));
  skipped_supernodes_ = permutedSweeps(f, static_cast<const float*>(single_x_.data()), single_y_,
                                       single_e_, b, x, skip_zero_supernodes_);
}

void CholmodSolver::solve(const double* b, double* x, int ncols) {
  if (factor_->is_super && blas_free_solves_) {
    supernodalSolveWithoutBlas(b, x, ncols);
    return;
  }
  solveWithBlas(b, x, ncols);
}

void CholmodSolver::solveWithBlas(const double* b, double* x, int ncols) {
  const auto n = factor_->n;
  cholmod_dense bd{};
  bd.nrow = n;
  bd.ncol = static_cast<std::size_t>(ncols);
  bd.nzmax = n * bd.ncol;
  bd.d = n;
  bd.x = const_cast<double*>(b);
  bd.z = nullptr;
  bd.xtype = CHOLMOD_REAL;
  bd.dtype = CHOLMOD_DOUBLE;
  if (factor_->is_super) {
    const CholmodBlasCall blas;
    cholmod_solve2(CHOLMOD_A, factor_, &bd, nullptr, &x_, nullptr, &y_, &e_, &common_);
  } else {
    cholmod_solve2(CHOLMOD_A, factor_, &bd, nullptr, &x_, nullptr, &y_, &e_, &common_);
  }
  if (!x_) throw NumericalError("CHOLMOD solve failed (out of memory?)");
  std::memcpy(x, x_->x, sizeof(double) * n * bd.ncol);
}

void CholmodSolver::analyzeLike(const CholmodSolver& other) {
  if (factor_) cholmod_free_factor(&factor_, &common_);
  if (symbolic_) cholmod_free_factor(&symbolic_, &common_);
  factorized_ = false;
  single_current_ = false;
  half_current_ = false;
  ++generation_;
  factor_ = cholmod_copy_factor(other.symbolic_ ? other.symbolic_ : other.factor_, &common_);
  if (!factor_) throw NumericalError("CHOLMOD: copying a factor failed (out of memory?)");
  if (other.symbolic_) {
    symbolic_ = cholmod_copy_factor(other.symbolic_, &common_);
    if (!symbolic_) throw NumericalError("CHOLMOD: copying a factor failed (out of memory?)");
  }
}

void CholmodSolver::swapFactor(CholmodSolver& other) noexcept {
  std::swap(factor_, other.factor_);
  std::swap(factorized_, other.factorized_);
  // the float copies go with their factors (each side's setting stays its own)
  single_x_.swap(other.single_x_);
  std::swap(single_current_, other.single_current_);
  half_.swap(other.half_);
  std::swap(half_current_, other.half_current_);
  ++generation_;
  ++other.generation_;
}

double CholmodSolver::touchPages() const {
  if (!factor_ || !factorized_ || factor_->x == nullptr) return 0.0;
  // one value a page: a page is 4096 bytes or more, so every page of the arrays is read
  const std::size_t count = factor_->is_super ? factor_->xsize : factor_->nzmax;
  const auto* x = static_cast<const double*>(factor_->x);
  double sum = 0.0;
  for (std::size_t i = 0; i < count; i += 4096 / sizeof(double)) sum += x[i];
  if (count > 0) sum += x[count - 1];
  if (single_current_) {
    for (std::size_t i = 0; i < single_x_.size(); i += 4096 / sizeof(float)) sum += single_x_[i];
  }
  if (half_current_) sum += static_cast<double>(half_.touchPages());
  return sum;
}

std::size_t CholmodSolver::factorNonzeros() const {
  if (!factor_) return 0;
  if (factor_->is_super) {
    // supernodal: count the stored values
    return factor_->xsize;
  }
  return factor_->nzmax;
}

// ---- background factorisation ----

namespace {
// OpenMP keeps its limits per thread: a new thread starts from the environment's, and CHOLMOD's
// supernodal factorisation then opened parallel regions whose threads called the serial
// OpenBLAS at once (wrong factors). The worker takes the process's limit (no nested team, one
// thread) for itself.
void limitOpenMpInThisThread() {
  using SetInt = void (*)(int);
  if (auto* fn = reinterpret_cast<SetInt>(dlsym(RTLD_DEFAULT, "omp_set_max_active_levels"))) fn(0);
  if (auto* fn = reinterpret_cast<SetInt>(dlsym(RTLD_DEFAULT, "omp_set_num_threads"))) fn(1);
}
}  // namespace

BackgroundFactoriser::~BackgroundFactoriser() {
  if (!worker_.joinable()) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  worker_.join();
}

void BackgroundFactoriser::start(const Sparse& a, const CholmodSolver& like) {
  if (!solver_) {
    solver_ = std::make_unique<CholmodSolver>();
    solver_->analyzeLike(like);
    // the factor handed over is solved without BLAS
    solver_->setBlasFreeSolves(true);
    // the float copy of the preconditioner made here, after the worker's factorisation
    solver_->setSinglePrecisionPreconditioner(like.singlePrecisionPreconditioner());
    solver_->setHalfPrecisionPreconditioner(like.halfPrecisionPreconditioner());
    copy_ = a;   // pattern and values; later jobs copy the values only
  } else {
    std::copy(a.valuePtr(), a.valuePtr() + a.nonZeros(), copy_.valuePtr());
  }
  if (!worker_.joinable()) {
    const StopSignalsBlocked stop_signals_blocked;   // the new thread inherits the mask
    worker_ = std::thread([this] { run(); });
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    pending_ = true;
    done_ = false;
  }
  busy_ = true;
  wake_.notify_all();
}

bool BackgroundFactoriser::finished() {
  std::lock_guard<std::mutex> lock(mutex_);
  return done_;
}

bool BackgroundFactoriser::collect(CholmodSolver& factor, double& waited_s,
                                   double& factorisation_s) {
  const std::int64_t t0 = shared::monotonicNs();
  std::unique_lock<std::mutex> lock(mutex_);
  wake_.wait(lock, [this] { return done_; });
  waited_s = shared::secondsSinceNs(t0);
  factorisation_s = factorisation_s_;
  busy_ = false;
  if (!ok_) return false;
  factor.swapFactor(*solver_);
  return true;
}

void BackgroundFactoriser::discard() {
  std::unique_lock<std::mutex> lock(mutex_);
  wake_.wait(lock, [this] { return done_; });
  busy_ = false;
}

void BackgroundFactoriser::run() {
  limitOpenMpInThisThread();
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    wake_.wait(lock, [this] { return stop_ || pending_; });
    if (stop_) return;
    pending_ = false;
    lock.unlock();
    const std::int64_t t0 = shared::monotonicNs();
    const bool ok = solver_->factorize(copy_);
    const double seconds = shared::secondsSinceNs(t0);
    lock.lock();
    ok_ = ok;
    factorisation_s_ = seconds;
    done_ = true;
    wake_.notify_all();
  }
}

// ---- factor reuse ----

bool ReusedFactorSolver::adoptDue(CholmodSolver& factor, double& waited_s,
                                  double& factorisation_s, bool after_contact) {
  waited_s = 0.0;
  factorisation_s = 0.0;
  if (background_ == nullptr || !background_->busy()) return false;
  ++job_steps_;
  const int lag = policy_.background_lag_steps;
  const int free_lag = policy_.background_free_lag_steps > 0 ? policy_.background_free_lag_steps
                                                               : policy_.background_lag_steps;
  // a step after contact counts 1 / lag of the way, one without 1 / free_lag (in units of
  // 1 / (lag x free_lag)); with free_lag == lag every step counts alike. Held at the due
  // count once reached (a job not ready in the when-ready mode is looked at again each step).
  job_units_ = std::min(job_units_ + (after_contact ? free_lag : lag), lag * free_lag);
  if (job_units_ < lag * free_lag) return false;
  if (policy_.background_when_ready && !background_->finished()) {
    // not ready: this step goes on with the factor it has; the next one looks again
    ++not_ready_steps_;
    return false;
  }
  if (job_stale_) {
    // a newer factor was made since the job started: drop it (at the same step as it would
    // have been taken, so that what runs when does not depend on the worker's speed)
    const std::int64_t t0 = shared::monotonicNs();
    background_->discard();
    waited_s = shared::secondsSinceNs(t0);
    return false;
  }
  if (!background_->collect(factor, waited_s, factorisation_s)) return false;
  // the factor is job_steps_ steps old; solve() counts this step
  age_steps_ = job_steps_ - 1;
  last_iterations_ = 0;
  ++refreshes_;
  return true;
}

// ---- the local correction ----

void ReusedFactorSolver::indexBlocks(const Sparse& a) {
  if (indexed_nonzeros_ == a.nonZeros()) return;
  const int nodes = static_cast<int>(a.cols() / 3);
  blocks_.clear();
  diagonal_block_.assign(static_cast<std::size_t>(nodes), -1);
  // the blocks of each column node, in the order their rows first appear
  std::vector<int> last_of_row(static_cast<std::size_t>(nodes), -1);
  for (int col_node = 0; col_node < nodes; ++col_node) {
    const auto first = static_cast<int>(blocks_.size());
    for (int c = 3 * col_node; c < 3 * col_node + 3; ++c) {
      for (auto p = a.outerIndexPtr()[c]; p < a.outerIndexPtr()[c + 1]; ++p) {
        const int row = a.innerIndexPtr()[p];
        const int row_node = row / 3;
        int& k = last_of_row[static_cast<std::size_t>(row_node)];
        if (k < first) {
          k = static_cast<int>(blocks_.size());
          NodeBlock nb;
          nb.row = row_node;
          nb.col = col_node;
          nb.pos.fill(-1);
          blocks_.push_back(nb);
        }
        blocks_[static_cast<std::size_t>(k)].pos[static_cast<std::size_t>(3 * (row % 3) + c % 3)] =
            static_cast<int>(p);
      }
    }
  }
  // per node, the blocks of its block row (stored as (row, col) or as (col, row))
  node_block_begin_.assign(static_cast<std::size_t>(nodes) + 1, 0);
  for (std::size_t k = 0; k < blocks_.size(); ++k) {
    const NodeBlock& nb = blocks_[k];
    ++node_block_begin_[static_cast<std::size_t>(nb.row) + 1];
    if (nb.row != nb.col) ++node_block_begin_[static_cast<std::size_t>(nb.col) + 1];
    else diagonal_block_[static_cast<std::size_t>(nb.row)] = static_cast<int>(k);
  }
  for (int i = 0; i < nodes; ++i) node_block_begin_[i + 1] += node_block_begin_[i];
  node_block_index_.assign(static_cast<std::size_t>(node_block_begin_.back()), 0);
  std::vector<int> fill(node_block_begin_.begin(), node_block_begin_.end() - 1);
  for (std::size_t k = 0; k < blocks_.size(); ++k) {
    const NodeBlock& nb = blocks_[k];
    node_block_index_[static_cast<std::size_t>(fill[nb.row]++)] = static_cast<int>(k);
    if (nb.row != nb.col) node_block_index_[static_cast<std::size_t>(fill[nb.col]++)] = static_cast<int>(k);
  }
  local_index_.assign(static_cast<std::size_t>(nodes), -1);
  indexed_nonzeros_ = a.nonZeros();
}

Eigen::Matrix3d ReusedFactorSolver::blockValues(const NodeBlock& b, const double* values) const {
  Eigen::Matrix3d m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      int p = b.pos[static_cast<std::size_t>(3 * r + c)];
      if (p < 0 && b.row == b.col) p = b.pos[static_cast<std::size_t>(3 * c + r)];   // symmetric
      m(r, c) = p < 0 ? 0.0 : values[p];
    }
  return m;
}

int ReusedFactorSolver::selectLocalNodes(const Sparse& a, const double* factor_a_values,
                                         const Eigen::Matrix3d* block_rotation) {
  for (const int i : local_nodes_) local_index_[static_cast<std::size_t>(i)] = -1;
  local_nodes_.clear();
  const double threshold = policy_.local_correction_threshold;
  if (threshold <= 0.0 || factor_a_values == nullptr || block_rotation == nullptr ||
      a.cols() % 3 != 0)
    return 0;
  indexBlocks(a);
  candidates_.clear();
  const int nodes = static_cast<int>(a.cols() / 3);
  const double threshold2 = threshold * threshold;
  for (int i = 0; i < nodes; ++i) {
    const int k = diagonal_block_[static_cast<std::size_t>(i)];
    if (k < 0) continue;
    const NodeBlock& nb = blocks_[static_cast<std::size_t>(k)];
    const Eigen::Matrix3d now = blockValues(nb, a.valuePtr());
    const Eigen::Matrix3d warped =
        block_rotation[i] * blockValues(nb, factor_a_values) * block_rotation[i].transpose();
    const double misfit2 = (now - warped).squaredNorm();
    const double scale2 = now.squaredNorm();
    if (misfit2 > threshold2 * scale2) candidates_.push_back({misfit2 / scale2, i});
  }
  const auto cap = static_cast<std::size_t>(std::max(policy_.local_correction_max_nodes, 0));
  if (candidates_.size() > cap) {
    // the furthest off (ties to the lower node: the same nodes on every run)
    std::nth_element(candidates_.begin(), candidates_.begin() + static_cast<std::ptrdiff_t>(cap),
                     candidates_.end(), [](const auto& l, const auto& r) {
                       return l.first > r.first || (l.first == r.first && l.second < r.second);
                     });
    candidates_.resize(cap);
  }
  for (const auto& c : candidates_) local_nodes_.push_back(c.second);
  std::sort(local_nodes_.begin(), local_nodes_.end());
  const auto m = static_cast<Eigen::Index>(3 * local_nodes_.size());
  if (m == 0) return 0;
  for (std::size_t j = 0; j < local_nodes_.size(); ++j)
    local_index_[static_cast<std::size_t>(local_nodes_[j])] = static_cast<int>(j);
  // A_LL (dense, lower part filled; LLT reads the lower triangle)
  const auto capacity = static_cast<Eigen::Index>(3 * cap);
  if (local_a_.rows() != capacity) {
    local_a_.setZero(capacity, capacity);
    local_u_.setZero(capacity);
  }
  auto block = local_a_.topLeftCorner(m, m);
  block.setZero();
  for (const int i : local_nodes_) {
    const auto li = 3 * local_index_[static_cast<std::size_t>(i)];
    for (int q = node_block_begin_[i]; q < node_block_begin_[i + 1]; ++q) {
      const NodeBlock& nb = blocks_[static_cast<std::size_t>(node_block_index_[q])];
      if (nb.row != i) continue;   // each block once: from its row node
      const int lj = local_index_[static_cast<std::size_t>(nb.col)];
      if (lj < 0) continue;
      block.block<3, 3>(li, 3 * lj) = blockValues(nb, a.valuePtr());
    }
  }
  Eigen::Ref<Eigen::MatrixXd> factor_in_place(block);
  const Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(factor_in_place);
  if (llt.info() != Eigen::Success) {
    for (const int i : local_nodes_) local_index_[static_cast<std::size_t>(i)] = -1;
    local_nodes_.clear();
    return 0;
  }
  return static_cast<int>(local_nodes_.size());
}

void ReusedFactorSolver::localResidual(const Sparse& a, const Eigen::VectorXd& r,
                                       const Eigen::VectorXd& y) {
  for (std::size_t j = 0; j < local_nodes_.size(); ++j) {
    const int i = local_nodes_[j];
    Eigen::Vector3d u = r.segment<3>(3 * i);
    for (int q = node_block_begin_[i]; q < node_block_begin_[i + 1]; ++q) {
      const NodeBlock& nb = blocks_[static_cast<std::size_t>(node_block_index_[q])];
      const Eigen::Matrix3d m = blockValues(nb, a.valuePtr());
      if (nb.row == i) u.noalias() -= m * y.segment<3>(3 * nb.col);
      else u.noalias() -= m.transpose() * y.segment<3>(3 * nb.row);
    }
    local_u_.segment<3>(3 * static_cast<Eigen::Index>(j)) = u;
  }
}

void ReusedFactorSolver::addLocalSolution(Eigen::VectorXd& x) {
  const auto m = static_cast<Eigen::Index>(3 * local_nodes_.size());
  const auto lower = local_a_.topLeftCorner(m, m).triangularView<Eigen::Lower>();
  auto u = local_u_.head(m);
  lower.solveInPlace(u);
  lower.adjoint().solveInPlace(u);
  for (std::size_t j = 0; j < local_nodes_.size(); ++j)
    x.segment<3>(3 * local_nodes_[j]) += u.segment<3>(3 * static_cast<Eigen::Index>(j));
}

ReuseSolveResult ReusedFactorSolver::solve(CholmodSolver& factor, Sparse& a,
                                           const Eigen::VectorXd& b, Eigen::VectorXd& x,
                                           const Eigen::Matrix3d* block_rotation,
                                           const double* factor_a_values) {
  ReuseSolveResult out;
  const bool prepared = prepared_ && factor.factorized();
  prepared_ = false;
  if (age_steps_ >= 0) ++age_steps_;
  const bool missing = age_steps_ < 0 || !factor.factorized();
  const bool due =
      (policy_.refactor_every_steps > 0 && age_steps_ >= policy_.refactor_every_steps) ||
      2 * last_iterations_ > policy_.refactor_iterations;
  const bool background = background_ != nullptr && policy_.background_lag_steps > 0;
  bool refresh = missing || (due && !background);
  auto startBackground = [&] {
    if (background_->busy()) return;
    background_->start(a, factor);
    job_steps_ = 0;
    job_units_ = 0;
    job_stale_ = false;
    out.background_started = true;
  };
  if (!refresh && background && due) startBackground();
  if (!refresh) {
    const std::int64_t t0 = shared::monotonicNs();
    const int bound = background ? 3 * policy_.refactor_iterations : policy_.refactor_iterations;
    out.local_nodes = selectLocalNodes(a, factor_a_values, block_rotation);
    if (out.local_nodes > 0) {
      // the start with Z^T (b - A x0) = 0
      localResidual(a, b, x);
      addLocalSolution(x);
    }
    const CgResult cg = conjugateGradient(
        a, b, x, policy_.tolerance, bound, cg_,
        [&](const Eigen::VectorXd& r, Eigen::VectorXd& z) {
          if (!block_rotation) {
            factor.solvePreconditioner(r.data(), z.data());
            return;
          }
          // z = T A_f^-1 T^T r
          const Eigen::Index blocks = r.size() / 3;
          warp_.resize(r.size());
          for (Eigen::Index k = 0; k < blocks; ++k)
            warp_.segment<3>(3 * k).noalias() = block_rotation[k].transpose() * r.segment<3>(3 * k);
          factor.solvePreconditioner(warp_.data(), warp_.data());
          for (Eigen::Index k = 0; k < blocks; ++k)
            z.segment<3>(3 * k).noalias() = block_rotation[k] * warp_.segment<3>(3 * k);
          if (out.local_nodes > 0) {
            // z += Z A_LL^-1 Z^T (r - A z)
            localResidual(a, r, z);
            addLocalSolution(z);
          }
        });
    out.solve_s = shared::secondsSinceNs(t0);
    out.cg_iterations = cg.iterations;
    out.residual = cg.residual;
    last_iterations_ = cg.iterations;
    refresh = !cg.converged;
    if (background && cg.iterations > policy_.refactor_iterations) startBackground();
  }
  if (refresh) {
    job_stale_ = true;   // this factor is newer than a running job's
    const std::int64_t t1 = shared::monotonicNs();
    // a prepared factor holds this A already (notePreparedFactor): only the direct solve
    out.prepared = prepared && missing;
    bool factored = true;
    if (!out.prepared) {
      if (!factor.analyzed()) factor.analyze(a);
      factored = factor.factorize(a);
    }
    out.factorisation_s = shared::secondsSinceNs(t1);
    if (!factored) {
      age_steps_ = -1;
      return out;
    }
    const std::int64_t t2 = shared::monotonicNs();
    factor.solve(b.data(), x.data(), 1);
    out.solve_s += shared::secondsSinceNs(t2);
    out.refreshed = true;
    out.residual = 0.0;
    age_steps_ = 0;
    last_iterations_ = 0;
    ++refreshes_;
  }
  out.ok = x.allFinite();
  return out;
}

}  // namespace tactus::sim::fem_detail

namespace tactus::sim {

BlasLockFigures blasLockFigures() {
  return {fem_detail::g_blas_contended.load(std::memory_order_relaxed),
          1e-9 * static_cast<double>(fem_detail::g_blas_waited_ns.load(std::memory_order_relaxed))};
}

std::unique_lock<std::mutex> lockCholmodBlas() {
  return std::unique_lock<std::mutex>(fem_detail::cholmodBlasMutex());
}

}  // namespace tactus::sim
