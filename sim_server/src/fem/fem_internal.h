#pragma once
// Private helpers of the fem module (not installed): polar decomposition, a thin CHOLMOD wrapper
// with a fixed pattern and reusable workspaces, boundary nodes, and a 64-bit FNV-1a hash.

#include <cholmod.h>

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <cstdint>
#include <vector>

#include "tactus/sim/mesh.h"

namespace tactus::sim::fem_detail {

/// Rotation of the polar decomposition F = R S with det R = +1. Well-conditioned, non-inverted
/// F: scaled Newton iteration (the unique polar factor); otherwise (inverted, flat or
/// ill-conditioned): SVD F = U S V^T with the singular vector of the smallest singular value
/// flipped when det(U V^T) < 0, so R is a proper rotation even for inverted elements.
/// For det F < 0 this is Irving et al.'s reflection-aware ("invertible") polar decomposition:
/// the stretch S = R^T F is symmetric with one negative principal stretch, so the linear
/// corotational strain sym(S) - I compresses that direction past zero and the elastic force
/// pushes the element back out of inversion (tests: polar_test InvertedGradientsPutTheInversion
/// InTheStretch, fem_test Inversion.*). The linear material's restoring stress is bounded, so a
/// large enough load can still hold an element inverted at equilibrium: FemStepStats counts them.
Eigen::Matrix3d polarRotation(const Eigen::Matrix3d& F);

/// Sparse symmetric positive-definite factorisation through the CHOLMOD C API. The matrix is the
/// lower triangle of a compressed column-major Eigen matrix whose pattern never changes:
/// analyze() once, factorize() per step, solve() with workspaces kept between calls.
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
  /// Nonzeros of the factor (for the log/benchmarks).
  std::size_t factorNonzeros() const;

 private:
  cholmod_sparse view(Sparse& lower) const;
  cholmod_common common_;
  cholmod_factor* factor_ = nullptr;
  cholmod_dense* x_ = nullptr;
  cholmod_dense* y_ = nullptr;
  cholmod_dense* e_ = nullptr;
  bool factorized_ = false;
};

/// Sorted unique nodes on the boundary (faces that belong to exactly one tetrahedron).
std::vector<int> boundaryNodes(const TetMesh& mesh);

/// 64-bit FNV-1a over raw bytes, chainable through `seed`.
std::uint64_t fnv1a(const void* data, std::size_t bytes,
                    std::uint64_t seed = 0xcbf29ce484222325ull);

}  // namespace tactus::sim::fem_detail
