// The stages of one step but buildW (build_w.cpp): free motion, collision detection, compliance
// update, NSGS, constrained motion and the contact passes' control.
#include "step_stages.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "obstacle_stage.h"
#include "tactus/shared/clock.h"
#include "tissue_contact_stage.h"

namespace tactus::sim {

void freeMotion(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                StepReport& report) {
  const double h = model.h_s;
  const std::int64_t t0 = shared::monotonicNs();
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    FemBody& body = *state.tissues[t].body;
    const std::vector<TissueLoad>& loads = model.tissues[t].loads;
    TissueScratch& tx = scratch.tissues[t];
    const Eigen::VectorXd* load_force =
        loads.empty() ? nullptr
                      : applyLoadsBeforeFreeMotion(loads, body, state.t_s + h, h, tx.load_force);
    tx.has_load_force = load_force != nullptr;
    if (model.has_contacts) tx.q_begin = body.positions();
    const FemStepStats st = body.freeMotion(h, load_force);
    if (!loads.empty()) applyLoadsAfterFreeMotion(loads, body, state.t_s + h);
    if (!st.ok) report.finite = false;
    report.inverted_elements += st.inverted_elements;
    report.fem_cg_iterations += st.cg_iterations;
    report.fem_pcg_local_nodes += st.pcg_local_nodes;
    if ((st.factor_refreshed && !st.factor_prepared) ||
        model.spec.solver.linear == LinearSolverKind::kCholmod)
      ++report.fem_factorisations;
  }
  for (std::size_t i = 0; i < state.instruments.size(); ++i) {
    const DeviceTarget& target = state.targets[i];
    scratch.tool_begin[i] = state.instruments[i].pose();
    state.instruments[i].freeMotion(h, target.pose, target.twist, target.gripper_opening);
    scratch.problem.instruments[i].device_pose = target.pose;
    scratch.problem.instruments[i].device_gripper = target.gripper_opening;
  }
  if (!state.instruments.empty()) {
    scratch.problem.device_pose = state.targets[0].pose;
    scratch.problem.device_gripper = state.targets[0].gripper_opening;
  }
  report.times.free_motion_s += shared::secondsSinceNs(t0);
}

double lastNormalForce(const SimulationState& state, std::span<const Contact> solved,
                       const Contact& contact, const Eigen::VectorXd& q, double radius_m) {
  const auto it = state.warm_start_f.find(contact.id);
  if (it != state.warm_start_f.end()) return it->second[0];
  if (contact.kind != ContactKind::kSphereTriangle) return 0.0;
  // the same sphere's contact across an edge of its triangle (two shared nodes), its tissue
  // point (at q) within half the sphere's radius of this one's
  double f = std::numeric_limits<double>::infinity();
  for (const Contact& k : solved) {
    if (k.kind != ContactKind::kSphereTriangle || k.feature != contact.feature ||
        k.instrument != contact.instrument) {
      continue;
    }
    int shared = 0;
    for (const int a : k.nodes) {
      for (const int b : contact.nodes) shared += a >= 0 && a == b ? 1 : 0;
    }
    if (shared < 2) continue;
    if (!((tissuePointAt(k, q) - contact.tissue_point_m).norm() <= 0.5 * radius_m)) continue;
    const auto jt = state.warm_start_f.find(k.id);
    f = std::min(f, jt == state.warm_start_f.end() ? 0.0 : jt->second[0]);
  }
  return std::isfinite(f) ? f : 0.0;
}

double gapBeyondCompliance(const SimulationState& state, const Contact& contact,
                           double compliance_mpn) {
  if (!(compliance_mpn > 0.0)) return contact.gap_m;
  const auto it = state.warm_start_f.find(contact.id);
  return it == state.warm_start_f.end() ? contact.gap_m
                                        : contact.gap_m + compliance_mpn * it->second[0];
}

double gapBeyondCompliance(const SimulationState& state, const Contact& contact,
                           double compliance_mpn, std::span<const Contact> solved,
                           const Eigen::VectorXd& q, double radius_m) {
  // a contact outside the tissue penetrates nothing: no look for a renamed one's force
  if (!(compliance_mpn > 0.0) || !(contact.gap_m < 0.0)) {
    return gapBeyondCompliance(state, contact, compliance_mpn);
  }
  return contact.gap_m + compliance_mpn * lastNormalForce(state, solved, contact, q, radius_m);
}

namespace {

// One tissue's contacts with every instrument: the one collision's list, or (several
// instruments) their lists merged in instrument order, each contact tagged with its instrument.
void detectTissue(SimulationState& state, TissueState& ts) {
  const std::size_t n = state.instruments.size();
  for (std::size_t i = 0; i < n; ++i) ts.collisions[i]->refit(ts.body->positions());
  if (n == 1) {
    ts.found = &ts.collisions[0]->detect(state.instruments[0]);
    return;
  }
  ts.merged.clear();
  for (std::size_t i = 0; i < n; ++i) {
    for (Contact k : ts.collisions[i]->detect(state.instruments[i])) {
      k.instrument = static_cast<int>(i);
      k.id |= static_cast<std::uint64_t>(i) << 58;   // above the kind (bits 56-57)
      ts.merged.push_back(k);
    }
  }
  ts.found = &ts.merged;
}

// The tissue's contacts with the instruments in the last assembled problem (buildW: at
// scratch.all_contacts[contact_begin], one per row block of its rows).
std::span<const Contact> solvedInstrumentContacts(const StepScratch& scratch, std::size_t t) {
  const TissueScratch& tx = scratch.tissues[t];
  if (tx.rows.row_offset.empty()) return {};
  const auto begin = static_cast<std::size_t>(tx.contact_begin);
  const std::size_t count = tx.rows.row_offset.size() - 1;
  if (begin + count > scratch.all_contacts.size()) return {};
  return std::span<const Contact>(scratch.all_contacts).subspan(begin, count);
}

}  // namespace

double queryContacts(const SimulationModel& model, SimulationState& state, StepScratch& scratch) {
  double min_gap = std::numeric_limits<double>::infinity();
  scratch.min_excess_gap = min_gap;
  static const std::vector<Contact> kNone;
  // the obstacles' contacts (no contact compliance on them)
  min_gap = std::min(min_gap, detectObstacleContacts(model, state));
  scratch.min_excess_gap = min_gap;
  // between tissues (lowers min_excess_gap itself: their contact compliance)
  min_gap = std::min(min_gap, detectTissueContacts(state, scratch));
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    TissueState& ts = state.tissues[t];
    if (state.instruments.empty()) {
      ts.found = &kNone;
      continue;
    }
    detectTissue(state, ts);
    // the renamed contacts' forces with the first pass's contacts found at the step's start only
    // (docs/design.md, "Additions beyond the paper": contact passes)
    const std::span<const Contact> solved =
        model.spec.solver.contact_detection == ContactDetection::kStepStart
            ? solvedInstrumentContacts(scratch, t)
            : std::span<const Contact>{};
    for (const Contact& k : *ts.found) {
      min_gap = std::min(min_gap, k.gap_m);
      const double c = instrumentSpec(model.spec, k.instrument).contact_compliance_mpn;
      const std::span<const ToolFeature> features =
          state.instruments[static_cast<std::size_t>(k.instrument)].features();
      const double radius = k.feature >= 0 && k.feature < static_cast<int>(features.size())
                                ? features[static_cast<std::size_t>(k.feature)].radius_m
                                : 0.0;
      scratch.min_excess_gap =
          std::min(scratch.min_excess_gap,
                   gapBeyondCompliance(state, k, c, solved, ts.body->positions(), radius));
    }
  }
  return min_gap;
}

double detectCollisions(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                        StepReport& report, PipelineCounters& counters) {
  const std::int64_t t0 = shared::monotonicNs();
  const double min_gap = queryContacts(model, state, scratch);
  counters.collision_queries += static_cast<long>(state.tissues.size());
  report.times.detect_collisions_s += shared::secondsSinceNs(t0);
  return min_gap;
}

void updateCompliance(SimulationState& state, StepReport& report) {
  const std::int64_t t0 = shared::monotonicNs();
  for (TissueState& ts : state.tissues) ts.compliance->update(*ts.body);
  report.times.update_compliance_s += shared::secondsSinceNs(t0);
}

void ensureCompliance(SimulationState& state, StepScratch& scratch, StepReport* report) {
  if (!scratch.compliance_pending) return;
  scratch.compliance_pending = false;
  // the free state's positions in place for the update (a pass's correction or the strain
  // limiter may have moved the nodes since): the buffers are swapped, not copied, and back
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    state.tissues[t].body->positions().swap(scratch.tissues[t].q_free);
  }
  StepReport untimed;
  updateCompliance(state, report != nullptr ? *report : untimed);
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    state.tissues[t].body->positions().swap(scratch.tissues[t].q_free);
  }
}

void keepFreeState(SimulationState& state, StepScratch& scratch) {
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    scratch.tissues[t].q_free = state.tissues[t].body->positions();
    scratch.tissues[t].v_free = state.tissues[t].body->velocities();
  }
  scratch.tool_free = state.instruments;
}

void solveContacts(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                   StepReport& report, PipelineCounters& counters) {
  ContactProblemData& p = scratch.problem;
  const int rows = p.rows;
  const int contacts = p.contacts;
  const std::int64_t t0 = shared::monotonicNs();
  p.f.setZero(rows);
  for (int c = 0; c < contacts; ++c) {
    auto it = state.warm_start_f.find(p.contact_id[c]);
    if (it == state.warm_start_f.end()) continue;
    const int r0 = p.row_offset[c];
    const int nr = p.row_offset[c + 1] - r0;
    for (int k = 0; k < nr; ++k) p.f[r0 + k] = it->second[k];
  }
  if (rows > 0) {
    // zeroes f on NaN; one NSGS per group of coupled bodies (contact_groups.h); the contacts
    // of groups without instrument are marked for the haptic loop either way
    scratch.groups.find(state, scratch);
    scratch.groups.markUnreachable(p.contact_instrument, p.unreachable);
    if (model.spec.solver.split_contact_groups) {
      report.contact_groups = scratch.groups.count();
      report.nsgs = scratch.groups.solve(p.view(), model.nsgs, scratch.workspace, p.f.data());
      report.solved_on_blocks = scratch.groups.solvedOnBlocks();
    } else {
      report.contact_groups = 1;
      report.solved_on_blocks = 0;
      report.nsgs = shared::solveNsgs(p.view(), model.nsgs, scratch.workspace, p.f.data());
    }
    ++counters.solves;
  } else {
    report.contact_groups = 0;
    report.solved_on_blocks = 0;
    p.unreachable.clear();
    report.nsgs = shared::NsgsResult{};
  }
  p.solve = report.nsgs;
  state.warm_start_f.clear();
  for (int c = 0; c < contacts; ++c) {
    const int r0 = p.row_offset[c];
    const int nr = p.row_offset[c + 1] - r0;
    std::array<double, 3> fc{0.0, 0.0, 0.0};
    for (int k = 0; k < nr; ++k) fc[k] = p.f[r0 + k];
    state.warm_start_f.emplace(p.contact_id[c], fc);
  }
  report.total_normal_force_n = 0.0;
  for (int c = 0; c < contacts; ++c) report.total_normal_force_n += p.f[p.row_offset[c]];
  report.times.solve_contacts_s += shared::secondsSinceNs(t0);
}

namespace {

void restoreFreeState(SimulationState& state, const StepScratch& scratch) {
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    state.tissues[t].body->positions() = scratch.tissues[t].q_free;
    state.tissues[t].body->velocities() = scratch.tissues[t].v_free;
  }
  state.instruments = scratch.tool_free;
}

}  // namespace

void boundGripsWithoutContactTorque(SimulationState& state) {
  for (Instrument& tool : state.instruments) {
    if (tool.dynamicGrip()) tool.applyGripCorrection(0.0);
  }
}

void constrainedMotion(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                       StepReport& report, bool restore_free) {
  const double h = model.h_s;
  const ContactProblemData& p = scratch.problem;
  const int rows = p.rows;
  const int contacts = p.contacts;
  const std::int64_t t0 = shared::monotonicNs();
  if (restore_free) restoreFreeState(state, scratch);
  report.max_penetration_m = 0.0;
  report.complementarity = 0.0;
  const std::size_t tools = state.instruments.size();
  if (rows > 0) {
    for (std::size_t t = 0; t < state.tissues.size(); ++t) {
      TissueState& ts = state.tissues[t];
      TissueScratch& tx = scratch.tissues[t];
      if (!tx.pair_parts.empty()) {
        coupledTissueCorrection(ts, tx, p.f);   // with its parts of the rows between tissues
      } else if (tx.rows.rows() == 0) {
        continue;
      } else {
        ts.compliance->correction(*ts.body, tx.rows.tissue, p.f.data() + tx.row_begin, tx.dq);
      }
      ts.body->positions() += tx.dq;
      ts.body->velocities() += tx.dq / h;
    }
    // each instrument moves by C6 H_i^T f over its own rows
    if (tools == 1) {
      scratch.wrench[0] = scratch.h_tool.transpose() * p.f;
      scratch.grip_torque[0] = state.instruments[0].dynamicGrip() ? p.grip.dot(p.f) : 0.0;
    } else {
      for (std::size_t i = 0; i < tools; ++i) {
        scratch.wrench[i].setZero();
        scratch.grip_torque[i] = 0.0;
      }
      for (int r = 0; r < rows; ++r) {
        const int tool = scratch.row_instrument[static_cast<std::size_t>(r)];
        if (tool < 0) continue;   // an obstacle's row: no instrument
        const auto i = static_cast<std::size_t>(tool);
        scratch.wrench[i] += scratch.h_tool.row(r).transpose() * p.f[r];
        if (state.instruments[i].dynamicGrip()) scratch.grip_torque[i] += p.grip[r] * p.f[r];
      }
    }
    for (std::size_t i = 0; i < tools; ++i) {
      Instrument& tool = state.instruments[i];
      tool.applyCorrection(scratch.wrench[i]);
      if (tool.dynamicGrip()) tool.applyGripCorrection(scratch.grip_torque[i]);
    }
    if (tools > 0) report.tool_wrench = scratch.wrench[0];
    // linearised gaps after the correction: delta = W f + delta_free, left by NSGS on exit
    // (not when it refused the problem as larger than its workspace: then computed here)
    Eigen::VectorXd unsolved_delta;
    const double* delta = scratch.workspace.delta.data();
    if (report.nsgs.status == shared::NsgsStatus::kEmpty) {
      unsolved_delta = p.W * p.f + p.delta_free;
      delta = unsolved_delta.data();
    }
    double pen = 0.0;
    double comp = 0.0;
    for (int c = 0; c < contacts; ++c) {
      const int r0 = p.row_offset[c];
      pen = std::max(pen, -delta[r0]);
      comp = std::max(comp, std::abs(delta[r0] * p.f[r0]));
    }
    report.max_penetration_m = pen;
    report.complementarity = comp;
  } else {
    for (std::size_t i = 0; i < tools; ++i) {
      scratch.wrench[i].setZero();
      scratch.grip_torque[i] = 0.0;
    }
    boundGripsWithoutContactTorque(state);
  }
  report.tool_wrenches = scratch.wrench;
  report.times.constrained_motion_s += shared::secondsSinceNs(t0);
}

namespace {

// State = free state + the mean of this pass's and the previous pass's corrections (tissue dq,
// tool wrench, grip torque; each correction is linear in its force, so this is the correction of
// the mean force).
void blendWithPreviousPass(const SimulationModel& model, SimulationState& state,
                           StepScratch& scratch) {
  const double h = model.h_s;
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    FemBody& body = *state.tissues[t].body;
    const TissueScratch& tx = scratch.tissues[t];
    const Eigen::VectorXd dq = 0.5 * (body.positions() - tx.q_free + tx.dq_previous);
    body.positions() = tx.q_free + dq;
    body.velocities() = tx.v_free + dq / h;
  }
  for (std::size_t i = 0; i < state.instruments.size(); ++i) {
    scratch.wrench[i] = 0.5 * (scratch.wrench[i] + scratch.previous_wrench[i]);
    scratch.grip_torque[i] = 0.5 * (scratch.grip_torque[i] + scratch.previous_grip_torque[i]);
    Instrument& tool = state.instruments[i];
    tool = scratch.tool_free[i];
    tool.applyCorrection(scratch.wrench[i]);
    if (tool.dynamicGrip()) tool.applyGripCorrection(scratch.grip_torque[i]);
  }
}

}  // namespace

bool nextContactPass(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                     StepReport& report, PipelineCounters& counters, int pass,
                     double& previous_gap) {
  const SolverSpec& solver = model.spec.solver;
  const int passes = std::max(1, solver.contact_iterations);
  if (passes == 1) return false;
  // the nonlinear gaps at the corrected state
  const double geometric_gap = detectCollisions(model, state, scratch, report, counters);
  report.geometric_penetration_m =
      std::isfinite(geometric_gap) ? std::max(0.0, -geometric_gap) : 0.0;
  // with a contact compliance a contact may penetrate by c f_n: the passes look at the rest
  const double min_gap = scratch.min_excess_gap;
  report.excess_penetration_m = std::isfinite(min_gap) ? std::max(0.0, -min_gap) : 0.0;
  if (!(min_gap < -solver.penetration_tolerance_m) || pass + 1 >= passes) return false;
  if (pass > 0 && min_gap < previous_gap) {
    // worse than the previous pass: the linearisations alternate (the contact set flips
    // between two states). Linearise the next pass at the mean of the two corrections. (A step
    // never ends on such a mean: the last pass's state is its own solution, so the published
    // forces are those that moved it.)
    const std::int64_t t0 = shared::monotonicNs();
    blendWithPreviousPass(model, state, scratch);
    report.times.constrained_motion_s += shared::secondsSinceNs(t0);
    detectCollisions(model, state, scratch, report, counters);
  }
  previous_gap = min_gap;
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    scratch.tissues[t].dq_previous = state.tissues[t].body->positions() - scratch.tissues[t].q_free;
  }
  scratch.previous_wrench = scratch.wrench;
  scratch.previous_grip_torque = scratch.grip_torque;
  return true;
}

}  // namespace tactus::sim
