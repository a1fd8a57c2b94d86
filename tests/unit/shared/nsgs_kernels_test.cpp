// NSGS's SIMD row kernels (nsgs_kernels.h): every kernel this CPU runs gives the generic
// kernel's bits, for 1- and 3-row contacts, every tail length and unaligned rows.
#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "tactus/shared/nsgs_kernels.h"

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <cpuid.h>
#include <immintrin.h>
#define TACTUS_TEST_XINUSE 1
#endif

namespace tactus::shared {
namespace {

constexpr NsgsKernel kAll[] = {NsgsKernel::kGeneric, NsgsKernel::kAvx2, NsgsKernel::kAvx512};

// One test per kernel, so a kernel this CPU lacks shows as a skipped test (with the reason)
// instead of passing without having run.
class NsgsKernelTest : public ::testing::TestWithParam<NsgsKernel> {
 protected:
  void SetUp() override {
    if (!nsgsKernelSupported(GetParam())) {
      GTEST_SKIP() << "this CPU cannot run the " << nsgsKernelName(GetParam())
                   << " kernel (instruction set absent): not tested here";
    }
  }
};

TEST_P(NsgsKernelTest, MatchesTheGenericBits) {
  const NsgsKernel kernel = GetParam();
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int compared = 0;
  for (int k : {1, 3}) {
    for (int m = 0; m <= 41; ++m) {
      for (int offset = 0; offset < 2; ++offset) {   // rows and delta off a 16-byte boundary
        const std::ptrdiff_t ld = m + 5;
        std::vector<double> w(static_cast<std::size_t>(3 * ld + offset));
        for (double& x : w) x = u(rng) * 1e-3;
        const double df[3] = {u(rng), u(rng) * 1e3, u(rng) * 1e-4};
        std::vector<double> start(static_cast<std::size_t>(m + offset));
        for (double& x : start) x = u(rng);
        std::vector<double> want = start, got = start;
        addRowsScaled(NsgsKernel::kGeneric, w.data() + offset, ld, k, df, want.data() + offset, m);
        addRowsScaled(kernel, w.data() + offset, ld, k, df, got.data() + offset, m);
        ASSERT_EQ(std::memcmp(want.data(), got.data(), want.size() * sizeof(double)), 0)
            << nsgsKernelName(kernel) << " k " << k << " m " << m << " offset " << offset;
        ++compared;
      }
    }
  }
  EXPECT_EQ(compared, 2 * 42 * 2);
}

#ifdef TACTUS_TEST_XINUSE
// XINUSE (xgetbv with ecx = 1) where the CPU reports it: bit 2 set while the upper halves of
// the ymm registers hold data, bit 6 the same for zmm0-15; 0 where it cannot be read.
__attribute__((target("xsave"))) unsigned long long upperStateInUse() {
  unsigned a = 0, b = 0, c = 0, d = 0;
  if (__get_cpuid_count(0xD, 1, &a, &b, &c, &d) == 0 || (a & 0x4u) == 0) return 0;
  return _xgetbv(1) & ((1ULL << 2) | (1ULL << 6));
}
#endif

// A SIMD kernel hands its tail to the generic (SSE2) kernel and returns to SSE2 code: it must
// leave the upper halves of the vector registers clear, or every SSE2 instruction after it is
// slowed (measured: the AVX-512 kernel 2-3x slower than the generic one on a 150-row problem).
TEST_P(NsgsKernelTest, ReturnsWithTheUpperRegisterHalvesClear) {
#ifdef TACTUS_TEST_XINUSE
  const NsgsKernel kernel = GetParam();
  if (kernel == NsgsKernel::kGeneric) GTEST_SKIP() << "the generic kernel uses no wide registers";
  std::vector<double> w(3 * 45, 1e-3), delta(45, 0.0);
  const double df[3] = {1.0, 2.0, 3.0};
  for (int k : {1, 3}) {
    for (int m : {40, 41, 45}) {   // no tail, tails of 1 and 5 (AVX-512) entries
      addRowsScaled(kernel, w.data(), 45, k, df, delta.data(), m);
      EXPECT_EQ(upperStateInUse(), 0u) << nsgsKernelName(kernel) << " k " << k << " m " << m;
    }
  }
#else
  GTEST_SKIP() << "x86-64 only";
#endif
}

INSTANTIATE_TEST_SUITE_P(Kernels, NsgsKernelTest, ::testing::ValuesIn(kAll),
                         [](const ::testing::TestParamInfo<NsgsKernel>& info) {
                           return std::string(nsgsKernelName(info.param));
                         });

TEST(NsgsKernels, TheGenericKernelAddsTheScaledRows) {
  const double w[3 * 4] = {1, 2, 3, 0, 10, 20, 30, 0, 100, 200, 300, 0};   // ld 4, m 3
  const double df[3] = {1.0, 0.5, -0.25};
  double delta[3] = {1, 1, 1};
  addRowsScaled(NsgsKernel::kGeneric, w, 4, 3, df, delta, 3);
  EXPECT_DOUBLE_EQ(delta[0], 1 + 1 + 5 - 25);
  EXPECT_DOUBLE_EQ(delta[1], 1 + 2 + 10 - 50);
  EXPECT_DOUBLE_EQ(delta[2], 1 + 3 + 15 - 75);
  double one[3] = {0, 0, 0};
  addRowsScaled(NsgsKernel::kGeneric, w, 4, 1, df, one, 3);
  EXPECT_DOUBLE_EQ(one[2], 3.0);
}

TEST(NsgsKernels, TheChoiceIsTheWidestSupportedUnlessANamedOneIsSupported) {
  const NsgsKernel best = chooseNsgsKernel(nullptr);
  EXPECT_TRUE(nsgsKernelSupported(best));
  if (best == NsgsKernel::kGeneric) {
    EXPECT_FALSE(nsgsKernelSupported(NsgsKernel::kAvx2));
  }
  if (best == NsgsKernel::kAvx2) {
    EXPECT_FALSE(nsgsKernelSupported(NsgsKernel::kAvx512));
  }
  EXPECT_EQ(chooseNsgsKernel("generic"), NsgsKernel::kGeneric);
  EXPECT_EQ(chooseNsgsKernel("sse9"), best);
  EXPECT_EQ(chooseNsgsKernel(""), best);
  for (NsgsKernel kernel : kAll) {
    EXPECT_EQ(chooseNsgsKernel(nsgsKernelName(kernel)),
              nsgsKernelSupported(kernel) ? kernel : best);
  }
  // without TACTUS_NSGS_KERNEL in the test's environment the process uses the widest
  if (std::getenv("TACTUS_NSGS_KERNEL") == nullptr) {
    EXPECT_EQ(nsgsKernel(), best);
  }
}

}  // namespace
}  // namespace tactus::shared
