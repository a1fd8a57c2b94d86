#pragma once
// Strain limiting on volume (tissues[i].strain_limit.min_volume_ratio; docs/design.md,
// "Strain limiting"): after the constrained motion, every tetrahedron whose volume fell below
// min_volume_ratio of its rest volume is brought back to it by moving its free nodes along the
// volume's gradient, weighted by their inverse mass (a position projection, Gauss-Seidel over the
// violating tetrahedra), and the nodes' velocities take the same change over the step. Nodes the
// last contact problem's rows touch move only after 10 sweeps, fixed nodes never, so the contacts
// keep the solved gaps where the tissue behind them can take the compression; a node of a contact
// with friction then moves along that contact's normal only, so that the limiter opens or closes
// its gap but never slides it over the pad (its tangential motion is the friction solve's).
// Where the sweeps cannot untangle what the correction inverted (a contact node pushed through
// several layers of tets), the tets left below go back to the step's start, where every tet kept
// its bound, with the ring of tets around them that this would leave below: no tet ends a pass
// below the bound.
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
  std::vector<int> active;         ///< tets found below the bound in any sweep of the call
  std::vector<int> below;          ///< tets below the bound after the last sweep
  std::vector<char> listed;        ///< per tet: in active
  std::vector<int> node_tet_offset, node_tet;   ///< node -> its tets (CSR), built once
  std::vector<int> moved;          ///< per node: the last sweep that moved it
  std::vector<int> moved_nodes;    ///< the nodes the current sweep moved
  std::vector<int> checked;        ///< per tet: the last sweep that measured it
  std::vector<char> rolled;        ///< per node: moved back to the valid state
  std::vector<int> contact_nodes;  ///< the nodes of the call's rows, each once
  /// per node of contact_nodes: the unit normal along which a node of a frictional contact may
  /// move (zero: any direction); the other entries are not read
  std::vector<Eigen::Vector3d> slide_normal;
};

/// Builds the scratch's node -> tets map of `body` and writes the storage of its per-node and
/// per-tet buffers now, so that the first step that limits a tet takes no fresh page (the
/// Simulation calls it at set-up). What limitVolumes computes is unchanged.
void prepareStrainLimit(const FemBody& body, StrainLimitScratch& scratch);

struct StrainLimitResult {
  int limited = 0;       ///< tets found below the bound (first sweep)
  int unresolved = 0;    ///< tets still below the bound after the last sweep
  int sweeps = 0;
  int rolled_back = 0;   ///< nodes moved back to the valid state (none when the sweeps lift every tet)
};

/// Projects body's positions so that every tet keeps at least min_ratio of its rest volume
/// (rest_volume6 from restVolumes6), moving a node of `rows` (the last problem's tissue rows)
/// only after 10 sweeps and never a fixed node; velocities change by the displacement / h.
/// row_offset (contacts + 1 entries) groups the rows by contact, its first row the normal: a
/// contact with friction rows (three) lets its nodes move along its normal only (a node in
/// several such contacts: along their mean normal, signs aligned). With
/// q_valid (positions where every tet keeps the bound: the step's start) the nodes of the tets
/// the sweeps leave below go back to it, ring by ring until none is below (StrainLimitResult::
/// rolled_back); without it they stay below (StrainLimitResult::unresolved).
StrainLimitResult limitVolumes(FemBody& body, const std::vector<double>& rest_volume6,
                               double min_ratio, double h, std::span<const TissueRow> rows,
                               std::span<const int> row_offset, StrainLimitScratch& scratch,
                               const Eigen::VectorXd* q_valid = nullptr);

}  // namespace tactus::sim
