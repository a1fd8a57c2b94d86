#pragma once
// The tissue-against-tissue part of a step (tissue_contact.h; docs/design.md, "Tissue against
// tissue"): the contacts between tissues (and of a tissue with itself) are detected beside the
// instrument's and the obstacles', and their rows are appended after every tissue's own rows.
// Each such row acts on two tissues (or twice on one), so it is made of parts, one per tissue:
// W = sum_t H_t C_t H_t^T is assembled per tissue over its own rows and its parts of the pair
// rows (one addW call, scattered into W), and each tissue's correction is C_t H_t^T f over the
// same rows. The warped, exact, rest and uncoupled models all support it through addW and
// correction unchanged.

#include <memory>

#include "simulation_model.h"
#include "simulation_state.h"
#include "step_scratch.h"
#include "step_stages.h"
#include "tactus/sim/tissue_contact.h"

namespace tactus::sim {

/// The detector of the scene's pairs (null without any).
std::unique_ptr<TissueContacts> makeTissueContacts(const SimulationModel& model);

/// Detects every pair at the tissues' current positions. Returns the smallest gap (+inf if none)
/// and lowers scratch.min_excess_gap by the gaps beyond the pairs' contact compliance.
double detectTissueContacts(SimulationState& state, StepScratch& scratch);

/// Appends the pairs' rows after the tissues' (global rows from `row_begin`, contacts from
/// `contact_begin`) into scratch.pair_rows, their parts into each tissue's scratch, and their
/// contacts to scratch.all_contacts. delta_free: the n row the gap carried to the free state
/// (gap - n . ((v_detected - v_free) - (s_detected - s_free))), the t rows the relative
/// tangential motion (v - s) over the free motion. Returns the contacts added.
int appendTissueContactRows(const SimulationState& state, StepScratch& scratch, FoundAt found_at,
                            int row_begin, int contact_begin);

/// W += H_t C_t H_t^T over tissue t's own rows and its parts of the pair rows, when it has such
/// parts (else the caller adds its own block directly).
void addCoupledTissueW(TissueState& ts, TissueScratch& tx,
                       shared::GrowOnlyMatrix<Eigen::RowMajor>& W);

/// dq = C_t H_t^T f over tissue t's own rows and pair parts (tissues with parts).
void coupledTissueCorrection(TissueState& ts, TissueScratch& tx, const Eigen::VectorXd& f);

/// Friction coefficient of a kTissueTissue contact: its pair's.
double tissueContactFriction(const SimulationState& state, const Contact& contact);

}  // namespace tactus::sim
