// HalfFactor: the packed half-precision factor and its sweeps in generic, F16C and AVX-512F
// forms. Built with -ffp-contract=off (sim_server/CMakeLists.txt): no kernel may fuse a
// multiply and an add, so that all three give the same bits.
#include "half_factor.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <utility>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define TACTUS_HALF_X86 1
#include <immintrin.h>
#endif

namespace tactus::sim::fem_detail {

namespace {

// floatToHalf, inlined into HalfFactor::assign
__attribute__((always_inline)) inline bool encodeHalf(float v, std::uint16_t& out) {
  std::uint32_t x = 0;
  std::memcpy(&x, &v, sizeof x);
  const auto sign = static_cast<std::uint16_t>((x >> 16) & 0x8000u);
  const std::uint32_t ax = x & 0x7fffffffu;
  if (ax >= 0x477ff000u) return false;   // rounds to 65520 or beyond (or inf, NaN)
  if (ax < 0x38800000u) {
    // below half's smallest normal, 2^-14: +0 (no subnormals, so that halfToFloat is a shift)
    out = 0;
    return true;
  }
  std::uint32_t m = ax - (112u << 23);         // exponent rebased
  m += 0x0fffu + ((m >> 13) & 1u);             // round to nearest even at bit 13
  out = static_cast<std::uint16_t>(sign | (m >> 13));
  return true;
}

// halfToFloat, inlined into every kernel
__attribute__((always_inline)) inline float decodeHalf(std::uint16_t h) {
  // exponent and mantissa moved to float's places, the exponent rebased (bias 15 to 127)
  const std::uint32_t magnitude = static_cast<std::uint32_t>(h & 0x7fffu) << 13;
  const std::uint32_t bits = (magnitude != 0 ? magnitude + (112u << 23) : 0u) |
                             (static_cast<std::uint32_t>(h & 0x8000u) << 16);
  float out = 0.0f;
  std::memcpy(&out, &bits, sizeof out);
  return out;
}

}  // namespace

bool floatToHalf(float v, std::uint16_t& out) { return encodeHalf(v, out); }

float halfToFloat(std::uint16_t h) { return decodeHalf(h); }

namespace {

// Stored after the last column: the vector kernels read whole blocks of 8 or 16 entries, a
// column's last block past its end (the lanes past it are multiplied by zeros, or not stored).
constexpr std::size_t kPadding = 16;

struct Sweep {
  const int* super;
  const int* pi;
  const int* rows;
  long nsuper;
  const std::uint16_t* l1;
  const float* d_inv2;
  float* y;
  float* t;
};

// A supernode's entries in l1: column j holds its nsrow - 1 - j rows below the diagonal
inline std::size_t blockEntries(long nscol, long nsrow) {
  return static_cast<std::size_t>(nscol * nsrow - nscol * (nscol + 1) / 2);
}

// Column j of a supernode whose entries start at `block`: its first entry is row j + 1
inline const std::uint16_t* column(const std::uint16_t* block, long j, long nsrow) {
  return block + static_cast<std::size_t>(j * (nsrow - 1) - j * (j - 1) / 2);
}

// The 16 lanes added pairwise: (l, l + 8), then (l, l + 4), (l, l + 2), (l, l + 1)
inline float reduce16(float* acc) {
  for (int w = 8; w >= 1; w /= 2)
    for (int q = 0; q < w; ++q) acc[q] = acc[q] + acc[q + w];
  return acc[0];
}

// Every kernel below works on a block of C (1-4) columns of a supernode at once, over the rows
// below the block: AXPY t[i] = t[i] - l0[i] w0 - l1[i] w1 - ... (in that order: the bits of
// one column after the other), DOT out[a] = the 16-lane dot product of la with t (entry i in
// lane i mod 16, the lanes past n adding zeros, then reduce16).

// ---- generic: any CPU ----
template <int C>
inline void axpyGeneric(const std::uint16_t* const* l, const float* w, float* t, long n) {
  for (long i = 0; i < n; ++i) {
    float v = t[i];
    for (int a = 0; a < C; ++a) v = v - decodeHalf(l[a][i]) * w[a];
    t[i] = v;
  }
}

template <int C>
inline void dotGeneric(const std::uint16_t* const* l, const float* t, long n, float* out) {
  for (int a = 0; a < C; ++a) {
    float acc[16] = {};
    long i = 0;
    for (; i + 16 <= n; i += 16)
      for (int q = 0; q < 16; ++q) acc[q] = acc[q] + decodeHalf(l[a][i + q]) * t[i + q];
    if (i < n)
      for (int q = 0; q < 16; ++q)
        acc[q] = acc[q] + (i + q < n ? decodeHalf(l[a][i + q]) * t[i + q] : 0.0f);
    out[a] = reduce16(acc);
  }
}

// The sweeps, written once for each kernel: TARGET the function attribute, AXPY and DOT the
// kernels (templates on C). A block's own triangle (its columns' rows inside the block) is
// solved entry by entry, the same code for every kernel.
#define TACTUS_HALF_SWEEPS(NAME, TARGET, AXPY, DOT)                                         \
  TARGET void NAME(const Sweep& s, long n) {                                                \
    const std::uint16_t* block = s.l1;                                                      \
    for (long k = 0; k < s.nsuper; ++k) { /* L1 w = P b */                                  \
      const long k1 = s.super[k], nscol = s.super[k + 1] - k1;                              \
      const long psi = s.pi[k], nsrow = s.pi[k + 1] - psi;                                  \
      const int* rows = s.rows + psi;                                                       \
      for (long i = 0; i < nscol; ++i) s.t[i] = s.y[k1 + i];                                \
      for (long i = nscol; i < nsrow; ++i) s.t[i] = s.y[rows[i]];                           \
      for (long j0 = 0; j0 < nscol; j0 += 4) {                                              \
        const int c = static_cast<int>(nscol - j0 < 4 ? nscol - j0 : 4);                    \
        const std::uint16_t* l[4] = {};                                                     \
        float w[4] = {};                                                                    \
        for (int a = 0; a < c; ++a) {                                                       \
          l[a] = column(block, j0 + a, nsrow);                                              \
          w[a] = s.t[j0 + a];                                                               \
          for (int r = a + 1; r < c; ++r)                                                   \
            s.t[j0 + r] = s.t[j0 + r] - decodeHalf(l[a][r - a - 1]) * w[a];                \
          l[a] += c - a - 1;                                                                \
        }                                                                                   \
        float* below = s.t + j0 + c;                                                        \
        const long m = nsrow - j0 - c;                                                      \
        switch (c) {                                                                        \
          case 4: AXPY<4>(l, w, below, m); break;                                           \
          case 3: AXPY<3>(l, w, below, m); break;                                           \
          case 2: AXPY<2>(l, w, below, m); break;                                           \
          default: AXPY<1>(l, w, below, m); break;                                          \
        }                                                                                   \
      }                                                                                     \
      block += blockEntries(nscol, nsrow);                                                  \
      for (long i = 0; i < nscol; ++i) s.y[k1 + i] = s.t[i];                                \
      for (long i = nscol; i < nsrow; ++i) s.y[rows[i]] = s.t[i];                           \
    }                                                                                       \
    for (long i = 0; i < n; ++i) s.y[i] = s.y[i] * s.d_inv2[i]; /* D^-2 */                  \
    for (long k = s.nsuper - 1; k >= 0; --k) { /* L1^T x = D^-2 w */                        \
      const long k1 = s.super[k], nscol = s.super[k + 1] - k1;                              \
      const long psi = s.pi[k], nsrow = s.pi[k + 1] - psi;                                  \
      const int* rows = s.rows + psi;                                                       \
      block -= blockEntries(nscol, nsrow);                                                  \
      for (long i = 0; i < nscol; ++i) s.t[i] = s.y[k1 + i];                                \
      for (long i = nscol; i < nsrow; ++i) s.t[i] = s.y[rows[i]];                           \
      for (long j0 = (nscol - 1) / 4 * 4; j0 >= 0; j0 -= 4) {                               \
        const int c = static_cast<int>(nscol - j0 < 4 ? nscol - j0 : 4);                    \
        const std::uint16_t* l[4] = {};                                                     \
        for (int a = 0; a < c; ++a) l[a] = column(block, j0 + a, nsrow) + (c - a - 1);      \
        float v[4] = {};                                                                    \
        const float* below = s.t + j0 + c;                                                  \
        const long m = nsrow - j0 - c;                                                      \
        switch (c) {                                                                        \
          case 4: DOT<4>(l, below, m, v); break;                                            \
          case 3: DOT<3>(l, below, m, v); break;                                            \
          case 2: DOT<2>(l, below, m, v); break;                                            \
          default: DOT<1>(l, below, m, v); break;                                           \
        }                                                                                   \
        for (int a = c - 1; a >= 0; --a) {                                                  \
          const std::uint16_t* la = column(block, j0 + a, nsrow);                           \
          float sum = v[a];                                                                 \
          for (int r = c - 1; r > a; --r)                                                   \
            sum = sum + decodeHalf(la[r - a - 1]) * s.t[j0 + r];                           \
          s.t[j0 + a] = s.t[j0 + a] - sum;                                                  \
        }                                                                                   \
      }                                                                                     \
      for (long i = 0; i < nscol; ++i) s.y[k1 + i] = s.t[i];                                \
    }                                                                                       \
  }

TACTUS_HALF_SWEEPS(sweepsGeneric, , axpyGeneric, dotGeneric)

#ifdef TACTUS_HALF_X86
// ---- F16C with AVX: the 16 lanes as two 8-lane halves ----
#define TACTUS_F16C __attribute__((target("avx,f16c")))

// the first min(max(remaining, 0), 8) lanes set (AVX has no integer compare)
TACTUS_F16C inline __m256i maskF16c(long remaining) {
  static const int kLanes[16] = {-1, -1, -1, -1, -1, -1, -1, -1, 0, 0, 0, 0, 0, 0, 0, 0};
  const long set = remaining < 0 ? 0 : (remaining > 8 ? 8 : remaining);
  return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(kLanes + 8 - set));
}

TACTUS_F16C inline __m256 loadHalf8(const std::uint16_t* l) {
  return _mm256_cvtph_ps(_mm_loadu_si128(reinterpret_cast<const __m128i*>(l)));
}

template <int C>
TACTUS_F16C inline void axpyF16c(const std::uint16_t* const* l, const float* w, float* t,
                                 long n) {
  __m256 wv[C];
  for (int a = 0; a < C; ++a) wv[a] = _mm256_set1_ps(w[a]);
  long i = 0;
  for (; i + 8 <= n; i += 8) {
    __m256 v = _mm256_loadu_ps(t + i);
    for (int a = 0; a < C; ++a) v = _mm256_sub_ps(v, _mm256_mul_ps(loadHalf8(l[a] + i), wv[a]));
    _mm256_storeu_ps(t + i, v);
  }
  if (i < n) {
    const __m256i m = maskF16c(n - i);
    __m256 v = _mm256_maskload_ps(t + i, m);
    for (int a = 0; a < C; ++a) v = _mm256_sub_ps(v, _mm256_mul_ps(loadHalf8(l[a] + i), wv[a]));
    _mm256_maskstore_ps(t + i, m, v);
  }
}

// The 16 lanes of a dot product, held as two 8-lane halves (lanes 0-7, 8-15), added pairwise as
// reduce16 does; AVX only, so that the F16C and the AVX-512F kernels both inline it
__attribute__((target("avx"))) inline float reduceHalves(__m256 lo, __m256 hi) {
  const __m256 s8 = _mm256_add_ps(lo, hi);
  const __m128 s4 = _mm_add_ps(_mm256_castps256_ps128(s8), _mm256_extractf128_ps(s8, 1));
  const __m128 s2 = _mm_add_ps(s4, _mm_movehl_ps(s4, s4));
  return _mm_cvtss_f32(_mm_add_ss(s2, _mm_shuffle_ps(s2, s2, 1)));
}

template <int C>
TACTUS_F16C inline void dotF16c(const std::uint16_t* const* l, const float* t, long n,
                                float* out) {
  __m256 lo[C], hi[C];
  for (int a = 0; a < C; ++a) lo[a] = hi[a] = _mm256_setzero_ps();
  long i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m256 t0 = _mm256_loadu_ps(t + i), t1 = _mm256_loadu_ps(t + i + 8);
    for (int a = 0; a < C; ++a) {
      lo[a] = _mm256_add_ps(lo[a], _mm256_mul_ps(loadHalf8(l[a] + i), t0));
      hi[a] = _mm256_add_ps(hi[a], _mm256_mul_ps(loadHalf8(l[a] + i + 8), t1));
    }
  }
  if (i < n) {
    // the lanes past n: finite entries (the next column's, the padding) times +0
    const __m256 t0 = _mm256_maskload_ps(t + i, maskF16c(n - i));
    const __m256 t1 = _mm256_maskload_ps(t + i + 8, maskF16c(n - i - 8));
    for (int a = 0; a < C; ++a) {
      lo[a] = _mm256_add_ps(lo[a], _mm256_mul_ps(loadHalf8(l[a] + i), t0));
      hi[a] = _mm256_add_ps(hi[a], _mm256_mul_ps(loadHalf8(l[a] + i + 8), t1));
    }
  }
  for (int a = 0; a < C; ++a) out[a] = reduceHalves(lo[a], hi[a]);
}

TACTUS_HALF_SWEEPS(sweepsF16cBody, TACTUS_F16C, axpyF16c, dotF16c)
TACTUS_F16C void sweepsF16c(const Sweep& s, long n) {
  sweepsF16cBody(s, n);
  _mm256_zeroupper();
}

// ---- AVX-512F: the 16 lanes in one register ----
#define TACTUS_AVX512 __attribute__((target("avx512f")))

// (the zero-masked forms with every lane set: GCC 12 warns, falsely, that the plain ones' own
// placeholder may be used uninitialised)
TACTUS_AVX512 inline __m512 loadHalf16(const std::uint16_t* l) {
  return _mm512_maskz_cvtph_ps(0xffff, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(l)));
}

template <int C>
TACTUS_AVX512 inline void axpyAvx512(const std::uint16_t* const* l, const float* w, float* t,
                                     long n) {
  __m512 wv[C];
  for (int a = 0; a < C; ++a) wv[a] = _mm512_set1_ps(w[a]);
  long i = 0;
  for (; i + 16 <= n; i += 16) {
    __m512 v = _mm512_loadu_ps(t + i);
    for (int a = 0; a < C; ++a) v = _mm512_sub_ps(v, _mm512_mul_ps(loadHalf16(l[a] + i), wv[a]));
    _mm512_storeu_ps(t + i, v);
  }
  if (i < n) {
    const auto m = static_cast<__mmask16>((1u << (n - i)) - 1u);
    __m512 v = _mm512_maskz_loadu_ps(m, t + i);
    for (int a = 0; a < C; ++a) v = _mm512_sub_ps(v, _mm512_mul_ps(loadHalf16(l[a] + i), wv[a]));
    _mm512_mask_storeu_ps(t + i, m, v);
  }
}

template <int C>
TACTUS_AVX512 inline void dotAvx512(const std::uint16_t* const* l, const float* t, long n,
                                    float* out) {
  __m512 acc[C];
  for (int a = 0; a < C; ++a) acc[a] = _mm512_setzero_ps();
  long i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m512 tv = _mm512_loadu_ps(t + i);
    for (int a = 0; a < C; ++a)
      acc[a] = _mm512_add_ps(acc[a], _mm512_mul_ps(loadHalf16(l[a] + i), tv));
  }
  if (i < n) {
    const auto m = static_cast<__mmask16>((1u << (n - i)) - 1u);
    const __m512 tv = _mm512_maskz_loadu_ps(m, t + i);
    for (int a = 0; a < C; ++a)
      acc[a] = _mm512_add_ps(acc[a], _mm512_mul_ps(loadHalf16(l[a] + i), tv));
  }
  for (int a = 0; a < C; ++a) {
    const __m256 lo =
        _mm256_castpd_ps(_mm512_maskz_extractf64x4_pd(0xff, _mm512_castps_pd(acc[a]), 0));
    const __m256 hi =
        _mm256_castpd_ps(_mm512_maskz_extractf64x4_pd(0xff, _mm512_castps_pd(acc[a]), 1));
    out[a] = reduceHalves(lo, hi);
  }
}

TACTUS_HALF_SWEEPS(sweepsAvx512Body, TACTUS_AVX512, axpyAvx512, dotAvx512)
TACTUS_AVX512 void sweepsAvx512(const Sweep& s, long n) {
  sweepsAvx512Body(s, n);
  _mm256_zeroupper();
}
#endif

using SweepKernel = void (*)(const Sweep&, long);

struct Kernel {
  SweepKernel fn = &sweepsGeneric;
  const char* name = "generic";
  bool named = false;   // TACTUS_HALF_SWEEP_KERNEL chose it
};

bool pick(Kernel& k, const char* name) {
  if (std::strcmp(name, "generic") == 0) {
    k = Kernel{&sweepsGeneric, "generic"};
    return true;
  }
#ifdef TACTUS_HALF_X86
  __builtin_cpu_init();
  if (std::strcmp(name, "f16c") == 0 && __builtin_cpu_supports("avx") &&
      __builtin_cpu_supports("f16c")) {
    k = Kernel{&sweepsF16c, "f16c"};
    return true;
  }
  if (std::strcmp(name, "avx512") == 0 && __builtin_cpu_supports("avx512f")) {
    k = Kernel{&sweepsAvx512, "avx512"};
    return true;
  }
#endif
  return false;
}

Kernel& chosen() {
  static Kernel k = [] {
    Kernel out;
    const char* env = std::getenv("TACTUS_HALF_SWEEP_KERNEL");
    if (env != nullptr && pick(out, env)) {
      out.named = true;
      return out;
    }
    if (!pick(out, "avx512") && !pick(out, "f16c")) pick(out, "generic");
    return out;
  }();
  return k;
}

}  // namespace

const char* halfSweepKernelName() { return chosen().name; }

bool setHalfSweepKernel(const char* name) {
  Kernel& k = chosen();
  const bool named = k.named;
  if (!pick(k, name)) return false;
  k.named = named;
  return true;
}

bool halfSweepsPayOff() {
  const Kernel& k = chosen();
  return k.named || std::strcmp(k.name, "generic") != 0;
}

bool HalfFactor::assign(const cholmod_factor& f) {
  if (!f.is_super || f.xtype != CHOLMOD_REAL || f.x == nullptr) return false;
  const int* super = static_cast<const int*>(f.super);
  const int* pi = static_cast<const int*>(f.pi);
  const int* px = static_cast<const int*>(f.px);
  const auto* lx = static_cast<const double*>(f.x);
  const auto nsuper = static_cast<long>(f.nsuper);
  std::size_t entries = 0;
  most_rows_ = 0;
  for (long k = 0; k < nsuper; ++k) {
    entries += blockEntries(super[k + 1] - super[k], pi[k + 1] - pi[k]);
    most_rows_ = std::max(most_rows_, static_cast<std::size_t>(pi[k + 1] - pi[k]));
  }
  l1_.resize(entries + kPadding);
  d_inv2_.resize(f.n);
  std::uint16_t* out = l1_.data();
  for (long k = 0; k < nsuper; ++k) {
    const long k1 = super[k], nscol = super[k + 1] - k1, nsrow = pi[k + 1] - pi[k];
    const double* block = lx + px[k];
    for (long j = 0; j < nscol; ++j) {
      const double* column = block + j * nsrow;
      const double d = column[j];
      if (!(d > 0.0) || !std::isfinite(d)) return false;
      d_inv2_[static_cast<std::size_t>(k1 + j)] = static_cast<float>(1.0 / (d * d));
      for (long i = j + 1; i < nsrow; ++i)
        if (!encodeHalf(static_cast<float>(column[i] / d), *out++)) return false;
    }
  }
  std::fill(l1_.end() - kPadding, l1_.end(), std::uint16_t{0});
  return true;
}

void HalfFactor::prepare(const cholmod_factor& f) {
  y_.assign(f.n, 0.0f);
  t_.assign(most_rows_, 0.0f);
}

void HalfFactor::solve(const cholmod_factor& f, const double* b, double* x) {
  const auto n = static_cast<long>(f.n);
  const int* perm = static_cast<const int*>(f.Perm);
  if (y_.size() != static_cast<std::size_t>(n) || t_.size() < most_rows_) prepare(f);
  for (long k = 0; k < n; ++k) y_[static_cast<std::size_t>(k)] = static_cast<float>(b[perm ? perm[k] : k]);
  const Sweep s{static_cast<const int*>(f.super), static_cast<const int*>(f.pi),
                static_cast<const int*>(f.s), static_cast<long>(f.nsuper), l1_.data(),
                d_inv2_.data(), y_.data(), t_.data()};
  chosen().fn(s, n);
  for (long k = 0; k < n; ++k) x[perm ? perm[k] : k] = static_cast<double>(y_[static_cast<std::size_t>(k)]);
}

float HalfFactor::touchPages() const {
  float sum = 0.0f;
  for (std::size_t i = 0; i < l1_.size(); i += 4096 / sizeof(std::uint16_t)) sum += static_cast<float>(l1_[i]);
  for (std::size_t i = 0; i < d_inv2_.size(); i += 4096 / sizeof(float)) sum += d_inv2_[i];
  return sum;
}

void HalfFactor::swap(HalfFactor& other) noexcept {
  l1_.swap(other.l1_);
  d_inv2_.swap(other.d_inv2_);
  std::swap(most_rows_, other.most_rows_);
}

}  // namespace tactus::sim::fem_detail
