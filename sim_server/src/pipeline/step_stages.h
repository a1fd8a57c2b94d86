#pragma once
// The stages of one simulation step (paper 3.1; docs/design.md section 2), each a function named
// after the paper's stage and timed under its own StageTimes field. Simulation::step()
// (pipeline.cpp) calls them in this order:
//
//   freeMotion -> detectCollisions -> [updateCompliance, when a pass first has rows] buildW
//   -> solveContacts
//   -> constrainedMotion [-> nextContactPass: detectCollisions, back to buildW]
//
// Each reads the model, changes the state, reuses the scratch and records into the report (times,
// figures) and the run's counters.

#include <span>

#include "simulation_model.h"
#include "simulation_state.h"
#include "step_scratch.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {

/// Implicit Euler of every tissue and the god object toward the device target, without contact
/// forces; keeps the start-of-step positions and pose (for the friction rows).
void freeMotion(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                StepReport& report);

/// Refits every tissue's trees at its current positions and finds the contacts with the
/// instrument. Returns the smallest gap (+inf if none); sets scratch.min_excess_gap.
double detectCollisions(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                        StepReport& report, PipelineCounters& counters);

/// The normal force the last solve put on `contact`: the force of its id; for a sphere's face
/// contact (kSphereTriangle, a pad sample's) whose id the solve did not have, the force of the
/// same feature's contact in `solved` on a triangle sharing an edge with its own whose tissue
/// point, at the positions `q`, lies within half the sphere's radius `radius_m` of this one's
/// (the smaller if several): the sphere's closest point crossed that edge after the solve, so the
/// contact that carries the force is found on the neighbour triangle, under another id. Farther,
/// the contact has moved over the tissue and is new. 0 when none. `solved`: the contacts of the
/// last solve on the contact's tissue with the instruments.
double lastNormalForce(const SimulationState& state, std::span<const Contact> solved,
                       const Contact& contact, const Eigen::VectorXd& q, double radius_m);

/// The contact's gap + c f_n, f_n its normal force in the last solve by its id: its penetration
/// beyond what the contact compliance c allows (the gap itself when c = 0 or the contact is new).
double gapBeyondCompliance(const SimulationState& state, const Contact& contact,
                           double compliance_mpn);

/// As above with f_n from lastNormalForce (a sphere's contact renamed across an edge keeps it).
/// detectCollisions passes the solved contacts with step-start detection only, else none.
double gapBeyondCompliance(const SimulationState& state, const Contact& contact,
                           double compliance_mpn, std::span<const Contact> solved,
                           const Eigen::VectorXd& q, double radius_m);

/// detectCollisions without its timing and counter (Simulation::geometricMinGap).
double queryContacts(const SimulationModel& model, SimulationState& state, StepScratch& scratch);

/// The compliance at the free state: C ~ R C0 R^T (warped, eq. 12), the current tangent's
/// (exact); rest and uncoupled keep C0.
void updateCompliance(SimulationState& state, StepReport& report);

/// updateCompliance at the step's free state (scratch.q_free) if scratch.compliance_pending: the
/// step calls it when a pass first has contact rows (buildW), so a step without any skips the
/// update (on liver_grasp_23k the warped model's node rotations, 5-9 ms); the rotations are
/// those of the free state whichever pass first needs them, as if updated right after the free
/// motion. Simulation::saveState and Simulation::compliance call it too, so the compliance's
/// state after a step is always that of its free state. `report` may be null (no timing).
void ensureCompliance(SimulationState& state, StepScratch& scratch, StepReport* report);

/// Copies the free state (positions, velocities, god object), which every contact pass corrects.
void keepFreeState(SimulationState& state, StepScratch& scratch);

/// Where the contacts buildW uses were detected.
enum class FoundAt { kFreeState, kStepStart, kCorrectedState };

/// The contact problem of the contacts last detected: rows H (n, t1, t2 per contact), delta_free
/// (carried to the free state when found elsewhere), W = sum_tissue H C H^T + H_tool C6 H_tool^T
/// (+ c_g g g^T with a dynamic grip, + c I with a contact compliance) and J (build_w.cpp).
void buildW(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
            StepReport& report, PipelineCounters& counters, FoundAt found_at);

/// NSGS on the assembled problem, warm-started by contact id; keeps the forces for the next
/// solve's warm start.
void solveContacts(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                   StepReport& report, PipelineCounters& counters);

/// With no contact torque on the jaws (no contact problem, or a pass without rows): each dynamic
/// grip's range [0, max opening] still bounds what the free motion left (instrument.h).
void boundGripsWithoutContactTorque(SimulationState& state);

/// Tissue dq = C H^T f (per model), tool dx = C6 H_tool^T f, from the free state (restored first
/// when `restore_free`, a later pass); the largest penetration and complementarity it leaves.
void constrainedMotion(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                       StepReport& report, bool restore_free);

/// After pass `pass`: detects the contacts at the corrected state and says whether another pass
/// runs (solver.contact_iterations; a gap beyond -penetration_tolerance). A pass that ended
/// worse than the one before sends the next to the mean of the two corrections.
bool nextContactPass(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                     StepReport& report, PipelineCounters& counters, int pass,
                     double& previous_gap);

}  // namespace tactus::sim
