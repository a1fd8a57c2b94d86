#pragma once
// Loads on a tissue (scene tissues[i].loads; scenes/README.md "Loads"; docs/design.md "Loads"):
//  * force: a total force F spread evenly over the region's N nodes (F / N each);
//  * pressure: p on every boundary triangle whose three nodes are in the region, at the
//    positions of the start of the step (a follower load): each of its nodes gets -p A N / 3
//    (A its area, N its outward normal; p > 0 pushes into the tissue);
//  * displacement: the region's nodes are Dirichlet nodes moved along a path of offsets from
//    their rest positions (linear between keys): before the free motion their velocity is set to
//    (x(t + h) - x) / h, so the implicit Euler step sees them where they will be, and after it
//    their positions are set to x(t + h).
// Force and pressure ramp linearly from 0 over `ramp` seconds, evaluated at the end of the step
// (t + h, implicit Euler).

#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

#include "tactus/sim/fem.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {

/// One load as the model holds it: its spec and what its region selected.
struct TissueLoad {
  LoadSpec spec;
  std::vector<int> nodes;                        ///< the region's nodes
  std::vector<std::array<int, 3>> triangles;     ///< pressure: outward boundary triangles
};

/// The tissue's loads on its placed mesh. Throws SceneError naming a load whose region selects
/// no node (or, for a pressure, no boundary triangle).
std::vector<TissueLoad> buildTissueLoads(const TetMesh& mesh, const TissueSpec& tissue,
                                         const std::string& fallback_where);

/// The nodes the displacement loads move (they are Dirichlet nodes).
std::vector<int> prescribedNodes(const std::vector<TissueLoad>& loads);

/// A path's offset at t_s.
Eigen::Vector3d pathOffset(const std::vector<DisplacementKey>& path, double t_s);

/// Before the free motion to t_end_s: the force and pressure loads into `force_n` (3n, zeroed
/// first) at the body's current positions, and the prescribed nodes' velocities. Returns
/// &force_n when some force or pressure load exists, else null.
const Eigen::VectorXd* applyLoadsBeforeFreeMotion(const std::vector<TissueLoad>& loads,
                                                  FemBody& body, double t_end_s, double h_s,
                                                  Eigen::VectorXd& force_n);

/// After the free motion: the prescribed nodes at their positions at t_end_s.
void applyLoadsAfterFreeMotion(const std::vector<TissueLoad>& loads, FemBody& body,
                               double t_end_s);

}  // namespace tactus::sim
