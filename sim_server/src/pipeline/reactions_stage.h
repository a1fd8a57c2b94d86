#pragma once
// Reaction forces of the current state and the last step's contact forces (reactions.h).

#include "simulation_model.h"
#include "simulation_state.h"
#include "step_scratch.h"
#include "tactus/sim/reactions.h"

namespace tactus::sim {

/// Computes the reactions (reactions.h). Not part of a step: costs one elastic-force evaluation
/// per tissue with fixed nodes (it also refreshes the element rotations at the current positions,
/// which the next free motion recomputes anyway).
ReactionForces computeReactions(const SimulationModel& model, SimulationState& state,
                                const StepScratch& scratch);

}  // namespace tactus::sim
