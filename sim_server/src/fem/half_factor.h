// A supernodal Cholesky factor's values in half precision, for PCG's preconditioner solves
// (CholmodSolver::setHalfPrecisionPreconditioner, PreconditionerPrecision::kHalf).
#pragma once

#include <cholmod.h>

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tactus::sim::fem_detail {

/// The values of a supernodal factor L = L1 D (D = diag(L), L1 unit lower triangular) kept as
/// L1's strictly lower entries in IEEE half precision (binary16, 11 significant bits) and D^-2 in
/// float, packed column by column without the diagonal blocks' unused upper triangles:
/// liver_23k's factor takes 5.4 MB instead of the float copy's 12.9 MB, and the forward and
/// backward sweeps of a preconditioner solve, which read the whole factor and are bound by
/// memory, read that much less (docs/design.md, "Free motion"). Scaling the columns by their
/// diagonal keeps every stored entry near 1 in size, inside half's range.
///
/// The sweeps accumulate in float. Their order of operations is fixed: products and
/// differences are never fused, and a dot product sums in 16 lanes (entry i in lane i mod 16,
/// the lanes then added pairwise), so the AVX-512F, the F16C/AVX2 and the generic (any CPU)
/// kernels give the same bits. The kernel is chosen once per process from the CPU
/// (halfSweepKernelName); TACTUS_HALF_SWEEP_KERNEL=generic|f16c|avx512 picks one the CPU has.
class HalfFactor {
 public:
  /// Converts the numeric supernodal factor `f` (double values). False when an entry of L1 is
  /// not finite or beyond half's range (65504): the values are then unusable and the caller
  /// keeps its float copy (CholmodSolver holds whether they are current). Allocates only when
  /// the factor's pattern grew.
  bool assign(const cholmod_factor& f);
  /// x = P^T L^-T L^-1 P b for one right-hand side of length n (x may alias b), `f` the factor
  /// assign() converted (its pattern and permutation). No allocation after prepare().
  void solve(const cholmod_factor& f, const double* b, double* x);
  /// Sizes and writes the solve's workspaces for `f`.
  void prepare(const cholmod_factor& f);
  /// Reads one value per page; see CholmodSolver::touchPages.
  float touchPages() const;
  void swap(HalfFactor& other) noexcept;

 private:
  std::vector<std::uint16_t> l1_;   // per supernode, per column j: L1's rows below j
  std::vector<float> d_inv2_;       // 1 / L_jj^2 in the factor's order
  std::size_t most_rows_ = 0;       // the most rows of a supernode
  std::vector<float> y_, t_;        // the permuted right-hand side, a supernode's gathered rows
};

/// The name of the kernel HalfFactor::solve uses in this process ("avx512", "f16c", "generic").
const char* halfSweepKernelName();
/// The sweeps here are faster than the float copy's: a vector kernel (F16C or AVX-512F) runs,
/// or TACTUS_HALF_SWEEP_KERNEL named the one that runs. The generic kernel converts each entry
/// in integer code, about 1.5x slower than the float sweeps on liver_23k
/// (preconditioner_bench): FemBody then keeps the float copy instead.
bool halfSweepsPayOff();
/// Runs the sweeps with the named kernel if the CPU has it (for the tests that compare them);
/// false otherwise.
bool setHalfSweepKernel(const char* name);

/// IEEE binary16 from float, rounded to nearest even, with the magnitudes below half's smallest
/// normal (2^-14, 6.1e-5) stored as +0 (entries that small of a unit-diagonal factor change no
/// PCG iteration, and without subnormals halfToFloat needs no branch); false when |v| rounds
/// beyond 65504 or v is not finite.
bool floatToHalf(float v, std::uint16_t& out);
/// The float a binary16 normal or zero holds (exact); not for subnormals, infinities or NaNs,
/// which floatToHalf never makes.
float halfToFloat(std::uint16_t h);

}  // namespace tactus::sim::fem_detail
