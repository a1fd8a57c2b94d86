#pragma once
// Structured tetrahedral meshes for tests and benchmarks: a box of nx x ny x nz hexahedral cells,
// each split into 5 or 6 tetrahedra, conforming across cells and positively oriented
// (det[x1-x0, x2-x0, x3-x0] > 0 for every tetrahedron).

#include <Eigen/Core>

#include "tactus/sim/mesh.h"

namespace tactus::sim {

/// How each hexahedral cell is split.
enum class HexSplit {
  kSix,    ///< Kuhn/Freudenthal split along the cell's main diagonal (6 tets, no parity needed)
  kFive,   ///< one central tet and four corner tets, mirrored on alternate cells (5 tets)
};

/// Box [origin, origin + size_m] meshed with nx * ny * nz cells (each count >= 1).
/// Node (i, j, k) has index i + (nx + 1) * (j + (ny + 1) * k), i along x, j along y, k along z.
/// Throws tactus::Error on a zero count or non-positive size.
TetMesh makeBoxTetMesh(int nx, int ny, int nz, const Eigen::Vector3d& size_m,
                       const Eigen::Vector3d& origin_m = Eigen::Vector3d::Zero(),
                       HexSplit split = HexSplit::kSix);

}  // namespace tactus::sim
