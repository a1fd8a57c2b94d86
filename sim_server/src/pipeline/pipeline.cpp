// One simulation step (Simulation::step) calling the paper's stages, and the Simulation's
// accessors. The parts: simulation_model.h (model, state, scratch), step_stages.h (the stages),
// simulation_build.cpp (construction), output_writer.h (VTK), scripted_target.cpp.
#include <spdlog/spdlog.h>

#include <cmath>
#include <limits>

#include "simulation_impl.h"
#include "reactions_stage.h"
#include "step_stages.h"
#include "strain_limit.h"
#include "tactus/shared/clock.h"

namespace tactus::sim {

// One step, the paper's stages in order (docs/design.md section 2): the free motion, the contacts
// and the compliance at the free state, W, NSGS and the constrained motion, repeated from the
// free state while the contact passes (solver.contact_iterations) find the corrected state still
// penetrating.
namespace {

// strain limiting (strain_limit.h) after each pass's correction, before the next detection
// looks at the corrected state: the contacts' nodes keep their corrected positions where the
// tet has another node to move, and what the sweeps cannot lift goes back to the step's start
// (q_begin: every tet at its bound when the last step ended)
void limitStrain(const SimulationModel& m, SimulationState& s, StepScratch& x, StepReport& report) {
  report.strain_limit_unresolved = 0;   // the last pass's; the tets limited add up over the passes
  for (std::size_t t = 0; t < s.tissues.size(); ++t) {
    const TissueModel& tm = m.tissues[t];
    if (tm.min_volume_ratio <= 0.0) continue;
    TissueScratch& tx = x.tissues[t];
    const StrainLimitResult limited = limitVolumes(*s.tissues[t].body, tm.rest_volume6,
                                                   tm.min_volume_ratio, m.h_s, tx.rows.tissue,
                                                   tx.rows.row_offset, tx.strain_limit,
                                                   &tx.q_begin);
    report.strain_limited_elements += limited.limited;
    report.strain_limit_unresolved += limited.unresolved;
  }
}

}  // namespace

StepReport Simulation::step() {
  const SimulationModel& m = impl_->model;
  SimulationState& s = impl_->state;
  StepScratch& x = impl_->scratch;
  PipelineCounters& counters = impl_->counters;
  StepReport report;
  const std::int64_t t_step = shared::monotonicNs();
  const bool detect_at_start = m.spec.solver.contact_detection == ContactDetection::kStepStart;

  // step_start: contacts at the start-of-step state (buildW carries them to the free state, from
  // q_begin and tool_start)
  if (m.has_contacts && detect_at_start) {
    detectCollisions(m, s, x, report, counters);
    x.tool_start = s.instruments;
  }

  freeMotion(m, s, x, report);

  if (m.has_contacts) {
    // the compliance at the free state, updated when a pass first has rows (ensureCompliance)
    keepFreeState(s, x);
    x.compliance_pending = true;
    if (!detect_at_start) detectCollisions(m, s, x, report, counters);
    double previous_gap = std::numeric_limits<double>::infinity();
    for (int pass = 0;; ++pass) {
      buildW(m, s, x, report, counters,
             pass > 0          ? FoundAt::kCorrectedState
             : detect_at_start ? FoundAt::kStepStart
                               : FoundAt::kFreeState);
      solveContacts(m, s, x, report, counters);
      constrainedMotion(m, s, x, report, pass > 0);
      limitStrain(m, s, x, report);
      report.contact_passes = pass + 1;
      if (!nextContactPass(m, s, x, report, counters, pass, previous_gap)) break;
    }
    for (std::size_t i = 0; i < s.instruments.size(); ++i) {
      x.problem.instruments[i].tool_pose = s.instruments[i].pose();
    }
    if (!s.instruments.empty()) x.problem.tool_pose = s.instruments[0].pose();
  } else {
    boundGripsWithoutContactTorque(s);
  }
  s.t_s += m.h_s;
  ++s.step;
  x.problem.step = s.step;
  x.problem.h_s = m.h_s;
  ++counters.steps;
  counters.rotation_extractions = 0;
  counters.damping_evaluations = 0;
  for (const TissueState& ts : s.tissues) {
    counters.rotation_extractions += ts.body->counters().rotation_extractions;
    counters.damping_evaluations += ts.body->counters().damping_evaluations;
    report.finite = report.finite && ts.body->positions().allFinite() &&
                    ts.body->velocities().allFinite();
  }
  for (const Instrument& tool : s.instruments) {
    report.finite = report.finite && tool.pose().pos_m.allFinite() && tool.twist().allFinite();
  }
  report.times.total_s = shared::secondsSinceNs(t_step);
  return report;
}

// A non-finite or degenerate device target (NaN/Inf from a device or a caller) never reaches the
// god object: the pose is held at the last valid target (at rest), a bad twist is zeroed and a
// bad gripper value keeps the last opening. Without this guard one NaN sample made the
// instrument's pose NaN for good (hard_cases: NonFiniteDeviceTargetsDoNotCorruptTheSimulation).
void Simulation::setDeviceTarget(const DeviceTarget& target) { setDeviceTarget(0, target); }

void Simulation::setDeviceTarget(int i, const DeviceTarget& target) {
  SimulationState& s = impl_->state;
  const auto k = static_cast<std::size_t>(i);
  if (k >= s.targets.size()) return;   // no such instrument: nothing to drive
  DeviceTarget& current = s.targets[k];
  char& rejected = s.target_rejected[k];
  const double qn = target.pose.rot.norm();
  const bool pose_ok = target.pose.pos_m.allFinite() && target.pose.rot.coeffs().allFinite() &&
                       std::isfinite(qn) && qn > 1e-9;
  const bool twist_ok = target.twist.allFinite();
  const bool gripper_ok = std::isfinite(target.gripper_opening);
  if (pose_ok && twist_ok && gripper_ok) {
    if (rejected) spdlog::info("device target finite again");
    rejected = false;
    current = target;
    return;
  }
  if (!rejected) {
    spdlog::warn("non-finite device target ({}{}{}) ignored: holding the last valid target",
                 pose_ok ? "" : "pose ", twist_ok ? "" : "twist ", gripper_ok ? "" : "gripper");
  }
  rejected = true;
  if (pose_ok) {
    current.pose = target.pose;
    current.twist = twist_ok ? target.twist : Eigen::Matrix<double, 6, 1>::Zero();
  } else {
    current.twist.setZero();
  }
  if (gripper_ok) current.gripper_opening = target.gripper_opening;
}

const SceneSpec& Simulation::spec() const { return impl_->model.spec; }
bool Simulation::hasInstrument() const { return !impl_->state.instruments.empty(); }
bool Simulation::hasContactProblem() const { return impl_->model.has_contacts; }
int Simulation::instrumentCount() const {
  return static_cast<int>(impl_->state.instruments.size());
}
const DeviceTarget& Simulation::deviceTarget(int i) const {
  return impl_->state.targets.at(static_cast<std::size_t>(i));
}
shared::Vector6d Simulation::contactWrench(int i) const {
  return impl_->scratch.wrench.at(static_cast<std::size_t>(i));
}
double Simulation::time() const { return impl_->state.t_s; }
long Simulation::stepIndex() const { return impl_->state.step; }
int Simulation::tissueCount() const { return static_cast<int>(impl_->state.tissues.size()); }
FemBody& Simulation::tissue(int i) { return *impl_->state.tissues.at(i).body; }
const FemBody& Simulation::tissue(int i) const { return *impl_->state.tissues.at(i).body; }
std::span<const Contact> Simulation::contacts(int i) const {
  const TissueState& ts = impl_->state.tissues.at(static_cast<std::size_t>(i));
  if (ts.found == nullptr) return {};
  return *ts.found;
}
TissueCompliance* Simulation::compliance(int i) {
  // at the last step's free state, also after a step without contact rows (ensureCompliance)
  ensureCompliance(impl_->state, impl_->scratch, nullptr);
  return impl_->state.tissues.at(i).compliance.get();
}
Instrument* Simulation::instrument() {
  return impl_->state.instruments.empty() ? nullptr : &impl_->state.instruments[0];
}
Instrument& Simulation::instrument(int i) {
  return impl_->state.instruments.at(static_cast<std::size_t>(i));
}
const Instrument& Simulation::instrument(int i) const {
  return impl_->state.instruments.at(static_cast<std::size_t>(i));
}
const ContactProblemData& Simulation::lastProblem() const { return impl_->scratch.problem; }
const PipelineCounters& Simulation::counters() const { return impl_->counters; }

double Simulation::geometricMinGap() {
  if (!impl_->model.has_contacts) return std::numeric_limits<double>::infinity();
  return queryContacts(impl_->model, impl_->state, impl_->scratch);
}

ReactionForces Simulation::reactions() {
  return computeReactions(impl_->model, impl_->state, impl_->scratch);
}

double Simulation::totalEnergy() const {
  double e = 0.0;
  for (const TissueState& ts : impl_->state.tissues) {
    e += ts.body->kineticEnergy() + ts.body->elasticEnergy() + ts.body->gravityEnergy();
  }
  for (const Instrument& tool : impl_->state.instruments) e += tool.kineticEnergy();
  return e;
}

Eigen::Matrix<double, 6, 1> Simulation::renderedWrench() const {
  return impl_->state.instruments.empty() ? Eigen::Matrix<double, 6, 1>::Zero()
                                          : renderedWrench(0);
}

Eigen::Matrix<double, 6, 1> Simulation::renderedWrench(int i) const {
  return instrument(i).couplingWrench();
}

}  // namespace tactus::sim
