// NSGS's row update in generic, AVX2 and AVX-512F forms (nsgs_kernels.h). Built with
// -ffp-contract=off (shared/CMakeLists.txt): no kernel may fuse a multiply and an add.
#include "tactus/shared/nsgs_kernels.h"

#include <cstdlib>
#include <cstring>
#include <initializer_list>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define TACTUS_NSGS_X86 1
#include <immintrin.h>
#endif

namespace tactus::shared {
namespace {

using Kernel = void (*)(const double*, std::ptrdiff_t, int, const double*, double*, int) noexcept;

void addRowsGeneric(const double* w0, std::ptrdiff_t ld, int k, const double* df, double* delta,
                    int m) noexcept {
  if (k == 1) {
    for (int j = 0; j < m; ++j) delta[j] += w0[j] * df[0];
    return;
  }
  const double* w1 = w0 + ld;
  const double* w2 = w1 + ld;
  for (int j = 0; j < m; ++j) delta[j] += w0[j] * df[0] + w1[j] * df[1] + w2[j] * df[2];
}

#ifdef TACTUS_NSGS_X86
// The last m % lanes entries, by the generic kernel. Its code is SSE2 (the baseline build), and
// SSE2 instructions run while the upper halves of the vector registers hold data are each
// slowed down (measured here: the AVX-512 kernel 2-3x slower than the generic one on a 150-row
// problem in L2, and the solver's own SSE2 code after it slowed too). The compiler clears the
// upper halves before a return but not before a tail jump into other code, so it is done here.
__attribute__((target("avx2"))) inline void tail(const double* w0, std::ptrdiff_t ld, int k,
                                                 const double* df, double* delta,
                                                 int m) noexcept {
  _mm256_zeroupper();
  addRowsGeneric(w0, ld, k, df, delta, m);
}

__attribute__((target("avx2"))) void addRowsAvx2(const double* w0, std::ptrdiff_t ld, int k,
                                                 const double* df, double* delta,
                                                 int m) noexcept {
  int j = 0;
  const __m256d b0 = _mm256_set1_pd(df[0]);
  if (k == 1) {
    for (; j + 4 <= m; j += 4) {
      const __m256d t = _mm256_mul_pd(_mm256_loadu_pd(w0 + j), b0);
      _mm256_storeu_pd(delta + j, _mm256_add_pd(_mm256_loadu_pd(delta + j), t));
    }
    tail(w0 + j, ld, k, df, delta + j, m - j);
    return;
  }
  const double* w1 = w0 + ld;
  const double* w2 = w1 + ld;
  const __m256d b1 = _mm256_set1_pd(df[1]);
  const __m256d b2 = _mm256_set1_pd(df[2]);
  for (; j + 4 <= m; j += 4) {
    const __m256d t01 = _mm256_add_pd(_mm256_mul_pd(_mm256_loadu_pd(w0 + j), b0),
                                      _mm256_mul_pd(_mm256_loadu_pd(w1 + j), b1));
    const __m256d t = _mm256_add_pd(t01, _mm256_mul_pd(_mm256_loadu_pd(w2 + j), b2));
    _mm256_storeu_pd(delta + j, _mm256_add_pd(_mm256_loadu_pd(delta + j), t));
  }
  tail(w0 + j, ld, k, df, delta + j, m - j);
}

__attribute__((target("avx512f"))) void addRowsAvx512(const double* w0, std::ptrdiff_t ld, int k,
                                                     const double* df, double* delta,
                                                     int m) noexcept {
  int j = 0;
  const __m512d b0 = _mm512_set1_pd(df[0]);
  if (k == 1) {
    for (; j + 8 <= m; j += 8) {
      const __m512d t = _mm512_mul_pd(_mm512_loadu_pd(w0 + j), b0);
      _mm512_storeu_pd(delta + j, _mm512_add_pd(_mm512_loadu_pd(delta + j), t));
    }
    tail(w0 + j, ld, k, df, delta + j, m - j);
    return;
  }
  const double* w1 = w0 + ld;
  const double* w2 = w1 + ld;
  const __m512d b1 = _mm512_set1_pd(df[1]);
  const __m512d b2 = _mm512_set1_pd(df[2]);
  for (; j + 8 <= m; j += 8) {
    const __m512d t01 = _mm512_add_pd(_mm512_mul_pd(_mm512_loadu_pd(w0 + j), b0),
                                      _mm512_mul_pd(_mm512_loadu_pd(w1 + j), b1));
    const __m512d t = _mm512_add_pd(t01, _mm512_mul_pd(_mm512_loadu_pd(w2 + j), b2));
    _mm512_storeu_pd(delta + j, _mm512_add_pd(_mm512_loadu_pd(delta + j), t));
  }
  tail(w0 + j, ld, k, df, delta + j, m - j);
}
#endif

Kernel kernelFor(NsgsKernel kernel) noexcept {
#ifdef TACTUS_NSGS_X86
  if (kernel == NsgsKernel::kAvx512) return &addRowsAvx512;
  if (kernel == NsgsKernel::kAvx2) return &addRowsAvx2;
#endif
  (void)kernel;
  return &addRowsGeneric;
}

}  // namespace

NsgsKernel chooseNsgsKernel(const char* wanted) noexcept {
  NsgsKernel best = NsgsKernel::kGeneric;
  if (nsgsKernelSupported(NsgsKernel::kAvx512)) {
    best = NsgsKernel::kAvx512;
  } else if (nsgsKernelSupported(NsgsKernel::kAvx2)) {
    best = NsgsKernel::kAvx2;
  }
  if (wanted == nullptr) return best;
  for (NsgsKernel k : {NsgsKernel::kGeneric, NsgsKernel::kAvx2, NsgsKernel::kAvx512}) {
    if (std::strcmp(wanted, nsgsKernelName(k)) == 0 && nsgsKernelSupported(k)) return k;
  }
  return best;
}

namespace {

// chosen while the program loads, before any solve
const NsgsKernel g_kernel = chooseNsgsKernel(std::getenv("TACTUS_NSGS_KERNEL"));
const Kernel g_add_rows = kernelFor(g_kernel);

}  // namespace

NsgsKernel nsgsKernel() noexcept { return g_kernel; }

const char* nsgsKernelName(NsgsKernel kernel) noexcept {
  switch (kernel) {
    case NsgsKernel::kAvx2:
      return "avx2";
    case NsgsKernel::kAvx512:
      return "avx512";
    case NsgsKernel::kGeneric:
      break;
  }
  return "generic";
}

bool nsgsKernelSupported(NsgsKernel kernel) noexcept {
#ifdef TACTUS_NSGS_X86
  __builtin_cpu_init();   // needed when called from a static initialiser (g_kernel's)
#endif
  switch (kernel) {
    case NsgsKernel::kGeneric:
      return true;
#ifdef TACTUS_NSGS_X86
    case NsgsKernel::kAvx2:
      return __builtin_cpu_supports("avx2") != 0;
    case NsgsKernel::kAvx512:
      return __builtin_cpu_supports("avx512f") != 0;
#else
    default:
      return false;
#endif
  }
  return false;
}

void addRowsScaled(const double* w0, std::ptrdiff_t ld, int k, const double* df, double* delta,
                   int m) noexcept {
  // (null only if another static initialiser solves before this file's have run)
  const Kernel kernel = g_add_rows != nullptr ? g_add_rows : &addRowsGeneric;
  kernel(w0, ld, k, df, delta, m);
}

void addRowsScaled(NsgsKernel kernel, const double* w0, std::ptrdiff_t ld, int k,
                   const double* df, double* delta, int m) noexcept {
  kernelFor(kernel)(w0, ld, k, df, delta, m);
}

}  // namespace tactus::shared
