// The BLAS routines CHOLMOD calls, serialised by one process-wide lock (see linear_solver.h,
// blasCallsSerialised). Debian's serial OpenBLAS keeps one work buffer per process: a background
// factorisation and a solve on the step's thread that called it at once overwrote each other's
// panels (found by helgrind; wrong factors). These definitions in the program take precedence
// over the library's for CHOLMOD's references; each takes the lock and calls the library's own.
#include <dlfcn.h>

#include <atomic>
#include <cstdint>
#include <mutex>

#include "linear_solver.h"
#include "tactus/shared/clock.h"
#include "tactus/sim/fem.h"

namespace tactus::sim::fem_detail {
namespace {

std::mutex& blasMutex() {
  static std::mutex m;
  return m;
}

std::atomic<long> g_contended{0};
std::atomic<std::int64_t> g_waited_ns{0};

// Holds the lock for one call; counts the calls that found it taken and how long they waited.
class BlasCall {
 public:
  BlasCall() {
    if (!blasMutex().try_lock()) {
      const std::int64_t t0 = shared::monotonicNs();
      blasMutex().lock();
      g_contended.fetch_add(1, std::memory_order_relaxed);
      g_waited_ns.fetch_add(shared::monotonicNs() - t0, std::memory_order_relaxed);
    }
  }
  ~BlasCall() { blasMutex().unlock(); }
  BlasCall(const BlasCall&) = delete;
  BlasCall& operator=(const BlasCall&) = delete;
};

template <class Fn>
Fn next(const char* name) {
  return reinterpret_cast<Fn>(dlsym(RTLD_NEXT, name));
}

}  // namespace

}  // namespace tactus::sim::fem_detail

namespace tactus::sim {

BlasLockFigures blasLockFigures() {
  return {fem_detail::g_contended.load(std::memory_order_relaxed),
          1e-9 * static_cast<double>(fem_detail::g_waited_ns.load(std::memory_order_relaxed))};
}

}  // namespace tactus::sim

using tactus::sim::fem_detail::BlasCall;
using tactus::sim::fem_detail::next;

// The real-valued routines of CHOLMOD's supernodal factorisation and solve, with CHOLMOD's own
// argument lists (the Fortran character lengths are not passed).
extern "C" {

void dgemm_(const char* ta, const char* tb, const int* m, const int* n, const int* k,
            const double* alpha, const double* a, const int* lda, const double* b, const int* ldb,
            const double* beta, double* c, const int* ldc) {
  using Fn = void (*)(const char*, const char*, const int*, const int*, const int*, const double*,
                      const double*, const int*, const double*, const int*, const double*, double*,
                      const int*);
  static const Fn fn = next<Fn>("dgemm_");
  const BlasCall lock;
  fn(ta, tb, m, n, k, alpha, a, lda, b, ldb, beta, c, ldc);
}

void dgemv_(const char* t, const int* m, const int* n, const double* alpha, const double* a,
            const int* lda, const double* x, const int* incx, const double* beta, double* y,
            const int* incy) {
  using Fn = void (*)(const char*, const int*, const int*, const double*, const double*,
                      const int*, const double*, const int*, const double*, double*, const int*);
  static const Fn fn = next<Fn>("dgemv_");
  const BlasCall lock;
  fn(t, m, n, alpha, a, lda, x, incx, beta, y, incy);
}

void dsyrk_(const char* uplo, const char* t, const int* n, const int* k, const double* alpha,
            const double* a, const int* lda, const double* beta, double* c, const int* ldc) {
  using Fn = void (*)(const char*, const char*, const int*, const int*, const double*,
                      const double*, const int*, const double*, double*, const int*);
  static const Fn fn = next<Fn>("dsyrk_");
  const BlasCall lock;
  fn(uplo, t, n, k, alpha, a, lda, beta, c, ldc);
}

void dtrsm_(const char* side, const char* uplo, const char* t, const char* diag, const int* m,
            const int* n, const double* alpha, const double* a, const int* lda, double* b,
            const int* ldb) {
  using Fn = void (*)(const char*, const char*, const char*, const char*, const int*, const int*,
                      const double*, const double*, const int*, double*, const int*);
  static const Fn fn = next<Fn>("dtrsm_");
  const BlasCall lock;
  fn(side, uplo, t, diag, m, n, alpha, a, lda, b, ldb);
}

void dtrsv_(const char* uplo, const char* t, const char* diag, const int* n, const double* a,
            const int* lda, double* x, const int* incx) {
  using Fn = void (*)(const char*, const char*, const char*, const int*, const double*,
                      const int*, double*, const int*);
  static const Fn fn = next<Fn>("dtrsv_");
  const BlasCall lock;
  fn(uplo, t, diag, n, a, lda, x, incx);
}

void dpotrf_(const char* uplo, const int* n, double* a, const int* lda, int* info) {
  using Fn = void (*)(const char*, const int*, double*, const int*, int*);
  static const Fn fn = next<Fn>("dpotrf_");
  const BlasCall lock;
  fn(uplo, n, a, lda, info);
}

}  // extern "C"

namespace tactus::sim::fem_detail {

bool blasCallsSerialised() {
  // CHOLMOD reaches these definitions only when the program's own take precedence over the
  // library's (a static link into the executable); otherwise background factorisation is off
  return dlsym(RTLD_DEFAULT, "dgemm_") == reinterpret_cast<void*>(&dgemm_) &&
         dlsym(RTLD_NEXT, "dgemm_") != nullptr;
}

}  // namespace tactus::sim::fem_detail
