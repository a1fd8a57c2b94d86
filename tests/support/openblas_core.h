#pragma once
// Whether this CPU can run the OpenBLAS kernel family named by OPENBLAS_CORETYPE. OpenBLAS takes
// the name as given and dies with SIGILL at its first call when the CPU lacks the instructions,
// so a test run under a forced kernel checks it first and skips with the reason instead.

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <string>

namespace tactus::test_support {

/// Empty when OPENBLAS_CORETYPE is unset or names a kernel family this CPU runs; otherwise why it
/// cannot (for GTEST_SKIP). Names are OpenBLAS's (case-insensitive); one this check does not
/// know counts as unsupported, since nothing proves it safe.
inline std::string openblasCoreUnsupportedReason() {
  const char* env = std::getenv("OPENBLAS_CORETYPE");
  if (env == nullptr || *env == '\0') return {};
  std::string core(env);
  std::transform(core.begin(), core.end(), core.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
  __builtin_cpu_init();
  struct Need {
    const char* core;
    bool supported;
    const char* feature;
  };
  const Need needs[] = {
      {"skylakex", __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                       __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512dq"),
       "AVX-512 (F, BW, VL, DQ)"},
      {"cooperlake", __builtin_cpu_supports("avx512bf16") != 0, "AVX-512 BF16"},
      {"sapphirerapids", __builtin_cpu_supports("avx512bf16") != 0, "AVX-512 BF16"},
      {"haswell", __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"), "AVX2 and FMA"},
      {"zen", __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"), "AVX2 and FMA"},
      {"sandybridge", __builtin_cpu_supports("avx") != 0, "AVX"},
      {"nehalem", __builtin_cpu_supports("sse4.2") != 0, "SSE4.2"},
      {"penryn", __builtin_cpu_supports("sse4.1") != 0, "SSE4.1"},
      {"core2", __builtin_cpu_supports("ssse3") != 0, "SSSE3"},
      {"prescott", __builtin_cpu_supports("sse3") != 0, "SSE3"},
  };
  for (const Need& n : needs) {
    if (core == n.core) {
      if (n.supported) return {};
      return "OPENBLAS_CORETYPE=" + std::string(env) + " needs " + n.feature +
             ", which this CPU lacks: OpenBLAS would die with SIGILL, so this run is skipped";
    }
  }
  return "OPENBLAS_CORETYPE=" + std::string(env) +
         " is a kernel family this check does not know: skipped rather than risk SIGILL";
#else
  return "OPENBLAS_CORETYPE=" + std::string(env) + " is set on a CPU this check does not know";
#endif
}

}  // namespace tactus::test_support
