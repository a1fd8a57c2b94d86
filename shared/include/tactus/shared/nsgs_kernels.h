#pragma once
// The inner kernel of NSGS's symmetric sweep, in the widest SIMD form this CPU runs.
//
// With an exactly symmetric W (what the simulation publishes), each contact's force change df
// updates the velocities by the contact's own rows:  delta[j] += sum_a W(r + a, j) df[a],
// j < m (nsgs.h; the sweep and the residual `W f + q` both reduce to it). On the grasp's
// problems (480 rows) this loop is most of a haptic tick.
//
// Kernels: generic (the baseline build: SSE2 on x86-64), AVX2 (4 lanes) and AVX-512F (8
// lanes), chosen once when the program loads by what the CPU reports (no check in the tick).
// Every kernel computes each delta[j] with the same operations in the same order
// ((W0 df0 + W1 df1) + W2 df2, then added to delta[j]; no fused multiply-add: the file is
// built with -ffp-contract=off), so they give bit-identical results and the solver's iterates
// do not depend on the machine. TACTUS_NSGS_KERNEL=generic|avx2|avx512 in the environment
// picks one for measurement (an unsupported or unknown name keeps the automatic choice).
//
// Real-time: addRowsScaled never allocates, locks or throws.

#include <cstddef>

namespace tactus::shared {

enum class NsgsKernel { kGeneric, kAvx2, kAvx512 };

/// The kernel the solver uses in this process (chosen at load).
NsgsKernel nsgsKernel() noexcept;
/// "generic", "avx2" or "avx512".
const char* nsgsKernelName(NsgsKernel kernel) noexcept;
/// Whether this CPU runs `kernel` (generic: always).
bool nsgsKernelSupported(NsgsKernel kernel) noexcept;
/// The choice made at load: the widest supported kernel, or `wanted` (a kernel's name, the
/// value of TACTUS_NSGS_KERNEL) when it names a supported one; nullptr: no preference.
NsgsKernel chooseNsgsKernel(const char* wanted) noexcept;

/// delta[j] += w0[j] df[0] (k == 1) or w0[j] df[0] + w0[ld + j] df[1] + w0[2 ld + j] df[2]
/// (k == 3), j < m, with the kernel in use. k must be 1 or 3.
void addRowsScaled(const double* w0, std::ptrdiff_t ld, int k, const double* df, double* delta,
                   int m) noexcept;
/// The same with a given kernel (tests, benchmarks); it must be supported.
void addRowsScaled(NsgsKernel kernel, const double* w0, std::ptrdiff_t ld, int k,
                   const double* df, double* delta, int m) noexcept;

}  // namespace tactus::shared
