#pragma once
// Private helpers of the fem module (not installed): polar decomposition, boundary nodes and a
// 64-bit FNV-1a hash; the linear solvers are in linear_solver.h.

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <chrono>
#include <cstdint>
#include <vector>

#include "linear_solver.h"
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

/// The nodes not `skip`ped in reverse Cuthill-McKee order over the mesh's node adjacency (each
/// connected part from a node of minimum degree): nodes of one element get nearby positions, so
/// that element loops over data indexed in this order touch nearby memory. Node indices out of
/// range are ignored.
std::vector<int> bandwidthOrder(const TetMesh& mesh, const std::vector<bool>& skip);

/// Sorted unique nodes on the boundary (faces that belong to exactly one tetrahedron).
std::vector<int> boundaryNodes(const TetMesh& mesh);

/// 64-bit FNV-1a over raw bytes, chainable through `seed`.
std::uint64_t fnv1a(const void* data, std::size_t bytes,
                    std::uint64_t seed = 0xcbf29ce484222325ull);

}  // namespace tactus::sim::fem_detail
