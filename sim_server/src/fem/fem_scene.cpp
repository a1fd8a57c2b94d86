// From a scene's tissue and solver sections to the FEM's inputs: material, solver options, the
// mesh placed in the scene, and the nodes fixed by boxes.
#include <Eigen/Geometry>
#include <cmath>
#include <vector>

#include "tactus/sim/fem.h"

namespace tactus::sim {

FemMaterial femMaterial(const TissueSpec& tissue) {
  FemMaterial m;
  m.law = tissue.law;
  m.tangent = tissue.tangent;
  m.element = tissue.element;
  m.young_pa = tissue.young_pa;
  m.poisson = tissue.poisson;
  m.density_kgpm3 = tissue.density_kgpm3;
  m.damping = tissue.damping;
  return m;
}

FemSolverOptions femSolverOptions(const SolverSpec& solver) {
  FemSolverOptions o;
  o.linear = solver.linear;
  o.cg_tolerance = solver.cg_tolerance;
  o.cg_max_iterations = solver.cg_max_iterations;
  o.refactor_iterations = solver.refactor_iterations;
  o.refactor_every_steps = solver.refactor_every_steps;
  o.background_refactor_lag_steps = solver.background_refactor_lag_steps;
  o.background_refactor_free_lag_steps = solver.background_refactor_free_lag_steps;
  o.background_refactor_when_ready = solver.background_refactor_when_ready;
  o.preconditioner_precision = solver.preconditioner_precision;
  o.pcg_local_correction_threshold = solver.pcg_local_correction_threshold;
  return o;
}

void transformMesh(TetMesh& mesh, double scale, const Eigen::Vector3d& rotation_deg,
                   const Eigen::Vector3d& translation_m) {
  const double k = M_PI / 180.0;
  const Eigen::Matrix3d r =
      (Eigen::AngleAxisd(rotation_deg.z() * k, Eigen::Vector3d::UnitZ()) *
       Eigen::AngleAxisd(rotation_deg.y() * k, Eigen::Vector3d::UnitY()) *
       Eigen::AngleAxisd(rotation_deg.x() * k, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  mesh.nodes = ((r * (scale * mesh.nodes)).colwise() + translation_m).eval();
}

std::vector<int> nodesInBoxes(const TetMesh& mesh, const std::vector<BoxSpec>& boxes) {
  std::vector<int> out;
  for (int i = 0; i < mesh.nodeCount(); ++i) {
    const Eigen::Vector3d p = mesh.nodes.col(i);
    for (const auto& b : boxes)
      if ((p.array() >= b.min_m.array()).all() && (p.array() <= b.max_m.array()).all()) {
        out.push_back(i);
        break;
      }
  }
  return out;
}

}  // namespace tactus::sim
