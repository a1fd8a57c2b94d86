#include "linear_solver.h"

#include "fem_internal.h"

#include <pthread.h>
#include <signal.h>

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

}  // namespace

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
  spdlog::debug("CHOLMOD analysis: n {} nnz(A) {} nnz(L) {:.0f} flops {:.3g} ordering {} {}", lower.rows(),
                lower.nonZeros(), common_.lnz, common_.fl,
                common_.method[common_.selected].ordering,
                factor_->is_super ? "supernodal" : "simplicial");
}

bool CholmodSolver::factorize(Sparse& lower) {
  cholmod_sparse a = view(lower);
  const int ok = cholmod_factorize(&a, factor_, &common_);
  factorized_ = ok && common_.status == CHOLMOD_OK && factor_->minor == factor_->n;
  return factorized_;
}

void CholmodSolver::solve(const double* b, double* x, int ncols) {
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
  cholmod_solve2(CHOLMOD_A, factor_, &bd, nullptr, &x_, nullptr, &y_, &e_, &common_);
  if (!x_) throw NumericalError("CHOLMOD solve failed (out of memory?)");
  std::memcpy(x, x_->x, sizeof(double) * n * bd.ncol);
}

std::size_t CholmodSolver::factorNonzeros() const {
  if (!factor_) return 0;
  if (factor_->is_super) {
    // supernodal: count the stored values
    return factor_->xsize;
  }
  return factor_->nzmax;
}

// ---- factor reuse ----

ReuseSolveResult ReusedFactorSolver::solve(CholmodSolver& factor, Sparse& a,
                                           const Eigen::VectorXd& b, Eigen::VectorXd& x,
                                           const Eigen::Matrix3d* block_rotation) {
  ReuseSolveResult out;
  if (age_steps_ >= 0) ++age_steps_;
  bool refresh = age_steps_ < 0 || !factor.factorized() ||
                 (policy_.refactor_every_steps > 0 && age_steps_ >= policy_.refactor_every_steps) ||
                 2 * last_iterations_ > policy_.refactor_iterations;
  if (!refresh) {
    const std::int64_t t0 = shared::monotonicNs();
    const CgResult cg = conjugateGradient(
        a, b, x, policy_.tolerance, policy_.refactor_iterations, cg_,
        [&](const Eigen::VectorXd& r, Eigen::VectorXd& z) {
          if (!block_rotation) {
            factor.solve(r.data(), z.data(), 1);
            return;
          }
          // z = T A_f^-1 T^T r
          const Eigen::Index blocks = r.size() / 3;
          warp_.resize(r.size());
          for (Eigen::Index k = 0; k < blocks; ++k)
            warp_.segment<3>(3 * k).noalias() = block_rotation[k].transpose() * r.segment<3>(3 * k);
          factor.solve(warp_.data(), warp_.data(), 1);
          for (Eigen::Index k = 0; k < blocks; ++k)
            z.segment<3>(3 * k).noalias() = block_rotation[k] * warp_.segment<3>(3 * k);
        });
    out.solve_s = shared::secondsSinceNs(t0);
    out.cg_iterations = cg.iterations;
    out.residual = cg.residual;
    last_iterations_ = cg.iterations;
    refresh = !cg.converged;
  }
  if (refresh) {
    const std::int64_t t1 = shared::monotonicNs();
    if (!factor.analyzed()) factor.analyze(a);
    const bool factored = factor.factorize(a);
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
