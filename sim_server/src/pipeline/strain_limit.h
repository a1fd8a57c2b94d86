#pragma once
// Strain limiting on volume (tissues[i].strain_limit.min_volume_ratio; docs/design.md,
// "Strain limiting"): after the constrained motion, every tetrahedron whose volume fell below
// min_volume_ratio of its rest volume is brought back to it by moving its free nodes along the
// volume's gradient, weighted by their inverse mass (a position projection, Gauss-Seidel over the
// violating tetrahedra), and the nodes' velocities take the same change over the step. Nodes the
// last contact problem's rows touch and fixed nodes do not move, so the contacts keep the
// solved gaps and the projection moves the compression into the tissue behind them.
#include <Eigen/Core>
#include <array>
#include <span>
#include <vector>

#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim {

/// Six times each tet's volume in the mesh's own positions, the rest shape (all positive in a
/// valid mesh).
std::vector<double> restVolumes6(const TetMesh& mesh);

struct StrainLimitScratch {
  std::vector<char> pinned;        ///< per node: fixed, or in a contact row
  std::vector<int> active;         ///< tets below the bound in the current sweep
};

struct StrainLimitResult {
  int limited = 0;       ///< tets found below the bound (first sweep)
  int unresolved = 0;    ///< tets still below the bound after the last sweep
  int sweeps = 0;
};

/// Projects body's positions so that every tet keeps at least min_ratio of its rest volume
/// (rest_volume6 from restVolumes6), moving no node of `rows` (the last problem's tissue rows)
/// nor a fixed node; velocities change by the displacement / h.
StrainLimitResult limitVolumes(FemBody& body, const std::vector<double>& rest_volume6,
                               double min_ratio, double h, std::span<const TissueRow> rows,
                               StrainLimitScratch& scratch);

}  // namespace tactus::sim
