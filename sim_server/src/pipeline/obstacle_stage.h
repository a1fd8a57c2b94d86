#pragma once
// The static obstacles' part of a step (obstacles.h; docs/design.md, "Obstacles"): their contacts
// with every tissue's surface vertices are detected beside the instrument's, and their rows are
// appended to the tissue's rows, so they enter the same contact problem: H has no tool part for
// them (the obstacle does not move), W = H C H^T as usual, each with its obstacle's friction.

#include "simulation_model.h"
#include "tactus/shared/segment.h"
#include "simulation_state.h"
#include "step_scratch.h"
#include "step_stages.h"

namespace tactus::sim {

/// Rows the obstacles may add to the contact problem: max_contacts per tissue, 3 rows each when
/// some obstacle has friction (0 without obstacles).
int obstacleRowCapacity(const SceneSpec& spec);

// problemCapacity(spec): declared in tactus/sim/pipeline.h (tools size their segments with it)

/// Contacts of every tissue's surface vertices (at its current positions) with the obstacles, into
/// TissueState::obstacle_found; the smallest gap (+inf if none).
double detectObstacleContacts(const SimulationModel& model, SimulationState& state);

/// Appends tissue t's obstacle contacts to its rows (tx.rows, tx.grip) and to
/// scratch.all_contacts: a vertex row -dir (n, and t1, t2 when the obstacle has friction), no
/// tool part; delta_free the gap carried to the free state (gap + n . (x_detected - x_free)) and
/// the tangential motion of the vertex over the free motion, negated. Returns the contacts added.
int appendObstacleRows(const SimulationState& state, StepScratch& scratch, std::size_t t,
                       FoundAt found_at);

/// Friction coefficient of an obstacle's contact (kObstacleVertex): its obstacle's (0 for any
/// other contact).
double obstacleFriction(const SimulationState& state, const Contact& contact);

}  // namespace tactus::sim
