#pragma once
// What one step rebuilds and reuses (simulation_model.h has the overview): the free state the
// contact passes correct, the contact rows, the assembled problem and the solver's workspace.
// Every step overwrites these before it reads them; they are kept between steps only so their
// memory is reused, and so the last step's problem can be published (Simulation::lastProblem).

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <vector>

#include "contact_groups.h"
#include "strain_limit.h"
#include "tool_terms.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/pose.h"
#include "tactus/sim/collision.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {

/// One tissue's part of the step.
struct TissueScratch {
  Eigen::VectorXd q_begin;               ///< positions at the start of the step
  Eigen::VectorXd q_free, v_free;        ///< after the free motion
  ContactRows rows;                      ///< this pass's rows on this tissue
  std::vector<double> grip;              ///< per row: d gap / d phi (dynamic grip)
  int row_begin = 0;                     ///< first global row
  int contact_begin = 0;                 ///< first global contact
  Eigen::VectorXd dq;                    ///< this pass's correction
  Eigen::VectorXd dq_previous;           ///< the previous contact pass's correction
  Eigen::VectorXd load_force;            ///< the loads' nodal forces of this step (loads.h)
  bool has_load_force = false;           ///< load_force holds some force or pressure
  // tissue against tissue (tissue_contact_stage.h): this tissue's parts of the pair rows
  std::vector<TissueRow> pair_parts;     ///< one per part (a self-contact row has two)
  std::vector<int> pair_part_row;        ///< the global row of each part
  std::vector<TissueRow> coupled_rows;   ///< own rows, then the pair parts (addW, correction)
  std::vector<int> coupled_global;       ///< the global row of each coupled row
  Eigen::MatrixXd coupled_w;             ///< H C H^T over the coupled rows
  std::vector<double> coupled_f;         ///< f on the coupled rows
  std::vector<int> group_begin;          ///< coupled rows of one global row (addCoupledTissueW)
  StrainLimitScratch strain_limit;       ///< the volume limiter's (strain_limit.h)
};

/// The rows of the contacts between tissues, after every tissue's own rows.
struct PairRowsScratch {
  int row_begin = 0;                     ///< first global row
  int contact_begin = 0;                 ///< first global contact
  std::vector<int> row_offset;           ///< per contact, relative to row_begin (contacts + 1)
  std::vector<double> delta_free;        ///< per row
  std::vector<double> compliance_mpn;    ///< per row: the pair's contact compliance
  int rows() const { return static_cast<int>(delta_free.size()); }
};

struct StepScratch {
  std::vector<TissueScratch> tissues;    ///< as SimulationModel::tissues
  /// The assembled contact problem of the last pass (W, delta_free, f, J, ...); after the step,
  /// the one the haptic process re-solves.
  ContactProblemData problem;
  shared::NsgsWorkspace workspace;
  ContactGroups groups;                  ///< the problem's groups of coupled bodies (solve)
  std::vector<Contact> all_contacts;     ///< every tissue's contacts in row order
  PairRowsScratch pair_rows;             ///< the contacts between tissues (last in row order)
  std::vector<const Eigen::VectorXd*> tissue_positions;   ///< per tissue (detectTissueContacts)
  ToolRows h_tool;                       ///< H_tool, rows x 6 (each row: its own instrument's)
  ToolRows b_tool;                       ///< H_tool L, C6 = L L^T (the row's instrument's L)
  ToolTerms tool_terms;                  ///< b_tool by columns, W's rows one by one (one instrument)
  std::vector<int> row_instrument;       ///< per row: the instrument of its contact
  std::vector<std::int64_t> node_keys;   ///< countDistinctNodes
  /// The compliance update of this step's free state has not run yet: updateCompliance runs when
  /// a pass first has rows (ensureCompliance), so a step without contact rows skips it
  bool compliance_pending = false;
  // per instrument:
  std::vector<shared::Pose> tool_begin;  ///< god object pose at the start of the step
  std::vector<Instrument> tool_free;     ///< god object after its free motion
  /// god object at the start of the step (contact_detection: step_start; contacts found there)
  std::vector<Instrument> tool_start;
  /// This pass's and the previous pass's tool wrench and grip torque (the blend of two passes)
  std::vector<shared::Vector6d> wrench;
  std::vector<shared::Vector6d> previous_wrench;
  std::vector<double> grip_torque;       ///< g^T f of the last correction (dynamic grip)
  std::vector<double> previous_grip_torque;
  /// Smallest gap + c f_n of the last detection (penetration beyond the contact compliance)
  double min_excess_gap = 0.0;
};

}  // namespace tactus::sim
