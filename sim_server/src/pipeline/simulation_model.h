#pragma once
// The simulation's model, in the manner of MuJoCo's mjModel (docs/design.md, "Model, state,
// scratch"): what the scene defines, built once by the Simulation constructor and never changed by
// a step. The stages take it as `const SimulationModel&`.
//
//   SimulationModel  (this file)        what the scene defines: spec, meshes, fixed nodes, solver
//                                       settings, the instrument's workspace
//   SimulationState  (simulation_state.h)  what a step changes and the next step starts from
//   StepScratch      (step_scratch.h)   what a step rebuilds and reuses: rows, W, free state
//   PipelineCounters                    statistics, outside the physics
//
// The physics objects carry the same split inside them: FemBody's data is FemModel (rest shape,
// material, element data, A's pattern, the rest factorisation), FemState (q, v, rotations, the
// factor of record) and FemScratch (the step's buffers) (fem_body_impl.h); TissueCompliance's C0
// is its model, its rotations its state; Instrument's spec and workspace its model, its pose and
// twist its state. They live whole in SimulationState because a step changes them; what they
// hold of the model is built from this one and not changed by a step either.

#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

#include "tactus/shared/nsgs.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/scene.h"
#include "loads.h"

namespace tactus::sim {

/// One deformable object as the scene defines it.
struct TissueModel {
  std::string name;
  TetMesh mesh;                    ///< rest mesh, scaled, rotated and placed as the scene says
  SurfaceMesh surface;             ///< its boundary (only with an instrument or obstacles)
  std::vector<int> fixed_nodes;    ///< Dirichlet nodes: the listed ones and those in the boxes
                                   ///< and regions, and those a displacement load moves
  std::vector<TissueLoad> loads;   ///< forces, pressures, displacements (loads.h)
  /// strain_limit.min_volume_ratio (0: off) and, when on, six times each tet's rest volume
  double min_volume_ratio = 0.0;
  std::vector<double> rest_volume6;
};

struct SimulationModel {
  SceneSpec spec;
  double h_s = 0.0;                      ///< time step
  std::vector<TissueModel> tissues;
  bool has_instrument = false;
  int instrument_count = 0;              ///< instrumentCount(spec)
  /// A contact problem each step: an instrument or static obstacles (obstacles.h)
  bool has_contacts = false;
  int max_rows = 0;                      ///< rows of the largest contact problem
  shared::NsgsSettings nsgs;             ///< the simulation's NSGS settings
  /// Per instrument: where its device target may go (instrument.h)
  std::vector<BoxSpec> instrument_workspaces;
};

/// Loads and places the meshes, collects the fixed nodes and derives the solver settings.
/// Throws SceneError / MeshError with the scene's file in the message.
SimulationModel buildModel(const SceneSpec& spec);

/// What a saved state is tied to (Simulation::modelIdentity): FNV-1a of the scene's text, the
/// time step, each tissue's placed rest mesh and fixed nodes.
std::uint64_t modelIdentity(const SimulationModel& model);

}  // namespace tactus::sim
