// The simulation step built from a scene: only the stages the scene calls for exist.
#include "tactus/shared/clock.h"
#include "tactus/sim/pipeline.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <limits>
#include <cmath>
#include <unordered_map>

#include "tactus/shared/error.h"
#include "tactus/sim/collision.h"
#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim {
namespace {

const char* toString(ComplianceKind k) {
  switch (k) {
    case ComplianceKind::kExact: return "exact";
    case ComplianceKind::kWarped: return "warped";
    case ComplianceKind::kRest: return "rest";
    case ComplianceKind::kUncoupled: return "uncoupled";
  }
  return "?";
}

bool allFinite(const Eigen::VectorXd& v) { return v.allFinite(); }

}  // namespace

shared::ContactProblemView ContactProblemData::view() const {
  shared::ContactProblemView v;
  v.contacts = contacts;
  v.rows = rows;
  v.row_offset = row_offset.data();
  v.W = W.data();
  v.ld = rows;
  v.delta_free = delta_free.data();
  v.mu = mu.data();
  return v;
}

/// One deformable object and the stages attached to it.
struct TissueState {
  std::string name;
  TetMesh mesh;
  SurfaceMesh surface;
  std::unique_ptr<FemBody> body;
  std::unique_ptr<TissueCompliance> compliance;   ///< only with an instrument
  std::unique_ptr<Collision> collision;           ///< only with an instrument
  ContactRows rows;                               ///< this step's rows on this tissue
  std::vector<double> grip;                       ///< per row: d gap / d phi (dynamic grip)
  int row_begin = 0;                              ///< first global row
  int contact_begin = 0;                          ///< first global contact
  Eigen::VectorXd dq;                             ///< correction scratch
  Eigen::VectorXd dq_previous;                    ///< the previous contact pass's correction
  Eigen::VectorXd q_begin;                        ///< positions at the start of the step
  Eigen::VectorXd q_free, v_free;                 ///< after the free motion
  const std::vector<Contact>* found = nullptr;    ///< contacts of the last detection
};

struct Simulation::Impl {
  SceneSpec spec;
  std::vector<TissueState> tissues;
  std::unique_ptr<Instrument> instrument;
  DeviceTarget target;
  double t_s = 0.0;
  long step = 0;
  ContactProblemData problem;
  shared::NsgsWorkspace workspace;
  shared::NsgsSettings nsgs;
  std::unordered_map<std::uint64_t, std::array<double, 3>> previous_f;
  std::vector<Contact> all_contacts;
  PipelineCounters counters;
  // VTK output
  std::vector<std::string> vtk_files;
  std::vector<double> vtk_times;
  long frame = 0;
  Eigen::Matrix<double, 6, 1> last_wrench = Eigen::Matrix<double, 6, 1>::Zero();
  double last_grip_torque = 0.0;                  ///< g^T f of the last correction (dynamic grip)
  Eigen::Matrix<double, 6, 1> previous_wrench = Eigen::Matrix<double, 6, 1>::Zero();  ///< pass k-1
  double previous_grip_torque = 0.0;              ///< pass k-1
  shared::Pose tool_begin;                        ///< god object pose at the start of the step
  bool target_rejected = false;                   ///< the last setDeviceTarget was non-finite
  std::unique_ptr<Instrument> tool_free;          ///< god object after its free motion
  /// god object at the start of the step (kStepStart only: the contacts are found there)
  std::unique_ptr<Instrument> tool_start;
  Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor> h_tool;   ///< H_tool, rows x 6
  Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor> b_tool;   ///< H_tool L, C6 = L L^T

  void buildTissues();
  void solveContacts(StepReport& report);
  double queryContacts();
  double min_excess_gap = 0.0;                    ///< of the last queryContacts
  double detectContacts(StepReport& report);
  /// Where the contacts assembleProblem uses were detected.
  enum class FoundAt { kFreeState, kStepStart, kCorrectedState };
  void assembleProblem(StepReport& report, FoundAt found_at);
  void solveAndCorrect(StepReport& report, bool restore_free);
  void blendWithPreviousPass();
  int countDistinctNodes();
  std::vector<std::int64_t> node_keys;            ///< scratch of countDistinctNodes
};

void Simulation::Impl::buildTissues() {
  const Eigen::Vector3d* gravity = spec.gravity_mps2 ? &*spec.gravity_mps2 : nullptr;
  for (const TissueSpec& ts : spec.tissues) {
    TissueState state;
    state.name = ts.name;
    MeshReport mesh_report;
    state.mesh = loadTetMesh(ts.mesh_path, &mesh_report);
    transformMesh(state.mesh, ts.scale, ts.rotation_deg, ts.translation_m);
    std::vector<int> fixed = ts.fixed_nodes;
    for (int n : fixed) {
      if (n < 0 || n >= state.mesh.nodeCount()) {
        throw SceneError(fmt::format("{}: tissue '{}': fixed node {} is not in the mesh ({} nodes)",
                                     spec.source.string(), ts.name, n, state.mesh.nodeCount()));
      }
    }
    const std::vector<int> boxed = nodesInBoxes(state.mesh, ts.fixed_boxes);
    fixed.insert(fixed.end(), boxed.begin(), boxed.end());
    std::sort(fixed.begin(), fixed.end());
    fixed.erase(std::unique(fixed.begin(), fixed.end()), fixed.end());
    state.body = std::make_unique<FemBody>(state.mesh, femMaterial(ts), fixed, gravity,
                                           femSolverOptions(spec.solver));
    spdlog::info("tissue '{}': {} nodes, {} tets, {} fixed nodes", ts.name, state.mesh.nodeCount(),
                 state.mesh.tetCount(), fixed.size());
    if (spec.instrument.present) {
      state.surface = extractSurface(state.mesh);
      ComplianceOptions copt;
      copt.h_s = spec.time_step_s;
      copt.cache_dir = ts.compliance_cache_dir;
      copt.cache_name = ts.name;
      copt.exact_correction = ts.exact_correction;
      copt.exact_below_coherence = ts.exact_below_coherence;
      copt.c0_single_precision = ts.c0_single_precision;
      state.compliance = makeCompliance(ts.compliance, *state.body, copt);
      spdlog::info("tissue '{}': {} compliance, {:.1f} MiB", ts.name, toString(ts.compliance),
                   static_cast<double>(state.compliance->memoryBytes()) / (1024.0 * 1024.0));
      CollisionOptions col;
      col.alarm_distance_m = spec.instrument.alarm_distance_m;
      col.contact_distance_m = spec.instrument.contact_distance_m;
      col.max_contacts = spec.solver.max_contacts;
      col.sphere_vs_triangle = spec.instrument.face_contacts;
      state.collision =
          std::make_unique<Collision>(state.surface, state.body->positions(), col);
    }
    tissues.push_back(std::move(state));
  }
}

Simulation::Simulation(const SceneSpec& spec) : impl_(std::make_unique<Impl>()) {
  Impl& s = *impl_;
  s.spec = spec;
  if (!(spec.time_step_s > 0.0)) throw SceneError("time_step must be > 0");
  s.buildTissues();
  if (spec.instrument.present) {
    s.instrument = std::make_unique<Instrument>(spec.instrument);
    // the device target stays within a box around the scene (instrument.h "Workspace")
    Eigen::AlignedBox3d bounds;
    for (const TissueState& ts : s.tissues) {
      const Eigen::VectorXd& x = ts.body->positions();
      for (Eigen::Index i = 0; i + 2 < x.size(); i += 3) bounds.extend(x.segment<3>(i));
    }
    s.instrument->setWorkspace(instrumentWorkspace(spec.instrument, bounds));
    s.target = scriptedTarget(0.0);
    s.instrument->reset(s.target.pose, s.target.gripper_opening);
    const int max_rows = (spec.instrument.friction_mu > 0.0 ? 3 : 1) * spec.solver.max_contacts;
    s.workspace.reserve(max_rows, spec.solver.max_contacts);
    s.nsgs.tolerance = spec.solver.nsgs_tolerance;
    s.nsgs.max_sweeps = spec.solver.nsgs_max_sweeps;
    s.nsgs.sor = spec.solver.nsgs_sor;
    s.nsgs.coupling = shared::NsgsCoupling::kSymmetricRowUpdate;   // W is symmetrised above
  }
  s.problem.row_offset.assign(1, 0);
}

Simulation::~Simulation() = default;

const SceneSpec& Simulation::spec() const { return impl_->spec; }

std::vector<std::string> Simulation::stages() const {
  const Impl& s = *impl_;
  std::vector<std::string> out;
  for (const auto& ts : s.spec.tissues) {
    std::string effects = ts.law == MaterialLaw::kCorotational ? "corotational" : "linear";
    effects += ts.damping ? ", Rayleigh damping" : ", no damping";
    effects += s.spec.gravity_mps2 ? ", gravity" : ", no gravity";
    switch (s.spec.solver.linear) {
      case LinearSolverKind::kCholmod: effects += ", CHOLMOD"; break;
      case LinearSolverKind::kPcg: effects += ", PCG"; break;
      case LinearSolverKind::kCholmodReuse: effects += ", PCG on a reused CHOLMOD factor"; break;
    }
    out.push_back(fmt::format("free motion of tissue '{}' (implicit Euler; {})", ts.name, effects));
  }
  if (!s.instrument) {
    out.push_back("no instrument: no collision, no contact problem");
  } else {
    const auto& in = s.spec.instrument;
    out.push_back(fmt::format("free motion of the {} god object (PD coupling k = {} N/m)",
                              in.kind == InstrumentKind::kGrasper ? "grasper" : "probe",
                              in.coupling_k_npm));
    out.push_back(fmt::format(
        "collision detection (BVH refit, alarm {} mm, at most {} contacts, {}, at the {})",
        1e3 * in.alarm_distance_m, s.spec.solver.max_contacts,
        in.face_contacts ? "vertex and face contacts" : "vertex contacts only",
        s.spec.solver.contact_detection == ContactDetection::kStepStart ? "start of the step"
                                                                        : "free state"));
    for (const auto& ts : s.spec.tissues) {
      out.push_back(fmt::format("W = H C H^T with {} compliance of '{}'", toString(ts.compliance),
                                ts.name));
    }
    out.push_back(in.friction_mu > 0.0
                      ? fmt::format("NSGS with Coulomb friction mu = {} (3 rows per contact)",
                                    in.friction_mu)
                      : std::string("NSGS frictionless (1 row per contact)"));
    out.push_back("constrained motion (tissue and instrument)");
  }
  if (s.spec.output.enabled) {
    out.push_back(fmt::format("VTK output every {} steps into {}", s.spec.output.every_n_steps,
                              s.spec.output.directory.string()));
  }
  return out;
}

// A non-finite or degenerate device target (NaN/Inf from a device or a caller) never reaches the
// god object: the pose is held at the last valid target (at rest), a bad twist is zeroed and a
// bad gripper value keeps the last opening. Without this guard one NaN sample made the
// instrument's pose NaN for good (hard_cases: NonFiniteDeviceTargetsDoNotCorruptTheSimulation).
void Simulation::setDeviceTarget(const DeviceTarget& target) {
  Impl& s = *impl_;
  const double qn = target.pose.rot.norm();
  const bool pose_ok = target.pose.pos_m.allFinite() && target.pose.rot.coeffs().allFinite() &&
                       std::isfinite(qn) && qn > 1e-9;
  const bool twist_ok = target.twist.allFinite();
  const bool gripper_ok = std::isfinite(target.gripper_opening);
  if (pose_ok && twist_ok && gripper_ok) {
    if (s.target_rejected) spdlog::info("device target finite again");
    s.target_rejected = false;
    s.target = target;
    return;
  }
  if (!s.target_rejected) {
    spdlog::warn("non-finite device target ({}{}{}) ignored: holding the last valid target",
                 pose_ok ? "" : "pose ", twist_ok ? "" : "twist ", gripper_ok ? "" : "gripper");
  }
  s.target_rejected = true;
  if (pose_ok) {
    s.target.pose = target.pose;
    s.target.twist = twist_ok ? target.twist : Eigen::Matrix<double, 6, 1>::Zero();
  } else {
    s.target.twist.setZero();
  }
  if (gripper_ok) s.target.gripper_opening = target.gripper_opening;
}

DeviceTarget Simulation::scriptedTarget(double t_s) const {
  const InstrumentSpec& in = impl_->spec.instrument;
  DeviceTarget out;
  out.pose = toPose(in.initial_pose);
  out.gripper_opening = 1.0;
  const auto& keys = in.trajectory;
  if (keys.empty()) return out;
  if (t_s <= keys.front().t_s || keys.size() == 1) {
    out.pose = toPose(keys.front().pose);
    out.gripper_opening = keys.front().gripper_opening;
    return out;
  }
  if (t_s >= keys.back().t_s) {
    out.pose = toPose(keys.back().pose);
    out.gripper_opening = keys.back().gripper_opening;
    return out;
  }
  std::size_t i = 1;
  while (keys[i].t_s < t_s) ++i;
  const TrajectoryKey& a = keys[i - 1];
  const TrajectoryKey& b = keys[i];
  const double dt = b.t_s - a.t_s;
  const double u = dt > 0.0 ? (t_s - a.t_s) / dt : 1.0;
  const shared::Pose pa = toPose(a.pose);
  const shared::Pose pb = toPose(b.pose);
  out.pose = shared::interpolate(pa, pb, u);
  out.gripper_opening = (1.0 - u) * a.gripper_opening + u * b.gripper_opening;
  if (dt > 0.0) out.twist = shared::poseDifference(pb, pa) / dt;
  return out;
}

bool Simulation::hasInstrument() const { return impl_->instrument != nullptr; }

// Refits and queries every tissue at the current state; the smallest gap (+inf if none).
// min_excess_gap: the smallest gap + c f_n, with f_n the normal force the contact (by id) had in
// the last solve: the penetration beyond what the contact compliance c allows.
double Simulation::Impl::queryContacts() {
  double min_gap = std::numeric_limits<double>::infinity();
  min_excess_gap = min_gap;
  const double c = spec.instrument.contact_compliance_mpn;
  for (TissueState& ts : tissues) {
    ts.collision->refit(ts.body->positions());
    ts.found = &ts.collision->detect(*instrument);
    for (const Contact& k : *ts.found) {
      min_gap = std::min(min_gap, k.gap_m);
      double allowed = 0.0;
      if (c > 0.0) {
        const auto it = previous_f.find(k.id);
        if (it != previous_f.end()) allowed = c * it->second[0];
      }
      min_excess_gap = std::min(min_excess_gap, k.gap_m + allowed);
    }
  }
  return min_gap;
}

double Simulation::Impl::detectContacts(StepReport& report) {
  const std::int64_t t0 = shared::monotonicNs();
  const double min_gap = queryContacts();
  counters.collision_queries += static_cast<long>(tissues.size());
  report.times.collision_s += shared::secondsSinceNs(t0);
  return min_gap;
}

void Simulation::Impl::solveContacts(StepReport& report) {
  const int passes = std::max(1, spec.solver.contact_iterations);
  // the free state, which every pass corrects
  for (TissueState& ts : tissues) {
    ts.q_free = ts.body->positions();
    ts.v_free = ts.body->velocities();
  }
  if (!tool_free) {
    tool_free = std::make_unique<Instrument>(*instrument);
  } else {
    *tool_free = *instrument;
  }
  // kStepStart: step() detected the contacts before the free motion; their gaps are carried to
  // the free state like those of a later pass
  const bool detected_at_start = spec.solver.contact_detection == ContactDetection::kStepStart;
  if (!detected_at_start) detectContacts(report);
  double previous_gap = std::numeric_limits<double>::infinity();
  for (int pass = 0;; ++pass) {
    assembleProblem(report, pass > 0            ? FoundAt::kCorrectedState
                            : detected_at_start ? FoundAt::kStepStart
                                                : FoundAt::kFreeState);
    solveAndCorrect(report, pass > 0);
    report.contact_passes = pass + 1;
    if (passes == 1) break;
    // the nonlinear gaps at the corrected state
    const double geometric_gap = detectContacts(report);
    report.geometric_penetration_m =
        std::isfinite(geometric_gap) ? std::max(0.0, -geometric_gap) : 0.0;
    // with a contact compliance a contact may penetrate by c f_n: the passes look at the rest
    const double min_gap = min_excess_gap;
    if (!(min_gap < -spec.solver.penetration_tolerance_m) || pass + 1 >= passes) break;
    const double pass_gap = min_gap;
    if (pass > 0 && min_gap < previous_gap) {
      // worse than the previous pass: the linearisations alternate (the contact set flips
      // between two states). Linearise the next pass at the mean of the two corrections. (A step
      // never ends on such a mean: the last pass's state is its own solution, so the published
      // forces are those that moved it.)
      blendWithPreviousPass();
      detectContacts(report);
    }
    previous_gap = pass_gap;
    for (TissueState& ts : tissues) ts.dq_previous = ts.body->positions() - ts.q_free;
    previous_wrench = last_wrench;
    previous_grip_torque = last_grip_torque;
  }
}

// State = free state + the mean of this pass's and the previous pass's corrections (tissue dq,
// tool wrench, grip torque; each correction is linear in its force, so this is the correction of
// the mean force).
void Simulation::Impl::blendWithPreviousPass() {
  const double h = spec.time_step_s;
  for (TissueState& ts : tissues) {
    const Eigen::VectorXd dq = 0.5 * (ts.body->positions() - ts.q_free + ts.dq_previous);
    ts.body->positions() = ts.q_free + dq;
    ts.body->velocities() = ts.v_free + dq / h;
  }
  last_wrench = 0.5 * (last_wrench + previous_wrench);
  last_grip_torque = 0.5 * (last_grip_torque + previous_grip_torque);
  *instrument = *tool_free;
  instrument->applyCorrection(last_wrench);
  if (instrument->dynamicGrip()) instrument->applyGripCorrection(last_grip_torque);
}

// Contact rows of every tissue from the contacts last detected, and W = sum H C H^T + H_tool C6
// H_tool^T. delta_free is the gap at the free state: with kFreeState the contacts were detected
// there; otherwise (kCorrectedState: at the current state, kStepStart: at the start of the step)
// their gaps are carried to the free state along the rows (gap - H (x_detected - x_free)).
// Friction rows: the relative tangential displacement of the tool point over the free motion.
void Simulation::Impl::assembleProblem(StepReport& report, FoundAt found_at) {
  const double h = spec.time_step_s;
  const double mu = spec.instrument.friction_mu;
  const bool relinearise = found_at != FoundAt::kFreeState;
  const bool at_start = found_at == FoundAt::kStepStart;
  const Instrument& detected = at_start ? *tool_start : *instrument;   // where found
  const shared::Pose& tool_pose = detected.pose();
  const shared::Pose& free_pose = tool_free->pose();
  std::int64_t t0 = shared::monotonicNs();
  int rows = 0;
  int contacts = 0;
  all_contacts.clear();
  report.contacts_dropped = 0;
  for (TissueState& ts : tissues) {
    const std::vector<Contact>& found = *ts.found;
    report.contacts_dropped += ts.collision->stats().overflow;
    buildContactRows(found, mu, tool_pose.pos_m, ts.rows);
    // the jaw angle's column: a row's gap grows by dir . dp/dphi per radian of opening
    ts.grip.assign(static_cast<std::size_t>(ts.rows.rows()), 0.0);
    if (instrument->dynamicGrip()) {
      for (std::size_t c = 0; c < found.size(); ++c) {
        const Contact& k = found[c];
        const Eigen::Vector3d dp = detected.gripJacobian(k.feature, k.tool_point_m);
        const int r0 = ts.rows.row_offset[c];
        ts.grip[static_cast<std::size_t>(r0)] = k.n.dot(dp);
        if (ts.rows.row_offset[c + 1] - r0 == 3) {
          ts.grip[static_cast<std::size_t>(r0 + 1)] = k.t1.dot(dp);
          ts.grip[static_cast<std::size_t>(r0 + 2)] = k.t2.dot(dp);
        }
      }
    }
    const Eigen::VectorXd& q = at_start ? ts.q_begin : ts.body->positions();
    for (std::size_t c = 0; c < found.size(); ++c) {
      const Contact& k = found[c];
      const int r0 = ts.rows.row_offset[c];
      Eigen::Vector3d tissue_free = Eigen::Vector3d::Zero();
      Eigen::Vector3d tissue_detected = Eigen::Vector3d::Zero();
      Eigen::Vector3d tissue_begin = Eigen::Vector3d::Zero();
      for (int j = 0; j < 3; ++j) {
        const int n = k.nodes[j];
        if (n < 0) continue;
        tissue_free += k.weights[j] * ts.q_free.segment<3>(3 * n);
        tissue_detected += k.weights[j] * q.segment<3>(3 * n);
        tissue_begin += k.weights[j] * ts.q_begin.segment<3>(3 * n);
      }
      Eigen::Vector3d tool_free_point = free_pose.pos_m + free_pose.rot * k.tool_local_m;
      if (relinearise && instrument->dynamicGrip()) {
        // the jaw point at the free opening (first order in the opening change)
        const double dphi = (detected.gripperOpening() - tool_free->gripperOpening()) *
                            spec.instrument.max_opening_rad;
        tool_free_point -= dphi * tool_free->gripJacobian(k.feature, tool_free_point);
      }
      if (relinearise) {
        const Eigen::Vector3d moved =
            (k.tool_point_m - tool_free_point) - (tissue_detected - tissue_free);
        ts.rows.delta_free[r0] = k.gap_m - k.n.dot(moved);
      }
      if (ts.rows.row_offset[c + 1] - r0 == 3) {
        const Eigen::Vector3d slip = (tool_free_point - (tool_begin.pos_m + tool_begin.rot *
                                                                              k.tool_local_m)) -
                                     (tissue_free - tissue_begin);
        ts.rows.delta_free[r0 + 1] = slip.dot(k.t1);
        ts.rows.delta_free[r0 + 2] = slip.dot(k.t2);
      }
    }
    ts.row_begin = rows;
    ts.contact_begin = contacts;
    rows += ts.rows.rows();
    contacts += static_cast<int>(found.size());
    all_contacts.insert(all_contacts.end(), found.begin(), found.end());
  }
  report.times.collision_s += shared::secondsSinceNs(t0);

  // assemble the problem: W = sum_tissue H C H^T + H_tool C6 H_tool^T
  t0 = shared::monotonicNs();
  ContactProblemData& p = problem;
  p.contacts = contacts;
  p.rows = rows;
  p.row_offset.assign(1, 0);
  p.contact_id.resize(contacts);
  p.mu.assign(contacts, mu);
  p.point_m.resize(contacts);
  p.normal.resize(contacts);
  p.tangent1.resize(contacts);
  p.tangent2.resize(contacts);
  p.W.setZero(rows, rows);
  p.delta_free.resize(rows);
  p.J.resize(rows, 6);
  h_tool.resize(rows, 6);
  p.grip.resize(rows);
  for (TissueState& ts : tissues) {
    const int m = ts.rows.rows();
    const int nc = static_cast<int>(ts.rows.row_offset.size()) - 1;
    for (int c = 1; c <= nc; ++c) p.row_offset.push_back(ts.row_begin + ts.rows.row_offset[c]);
    if (m == 0) continue;
    // the tissue's block in place: W is symmetric, so the transposed view of the row-major block
    // (column-major for the model) is the same matrix
    auto block = p.W.block(ts.row_begin, ts.row_begin, m, m).transpose();
    ts.compliance->addW(ts.rows.tissue, block);
    h_tool.middleRows(ts.row_begin, m) = ts.rows.tool;
    for (int r = 0; r < m; ++r) p.grip[ts.row_begin + r] = ts.grip[static_cast<std::size_t>(r)];
    for (int r = 0; r < m; ++r) p.delta_free[ts.row_begin + r] = ts.rows.delta_free[r];
    ++counters.w_builds;
  }
  for (int c = 0; c < contacts; ++c) {
    p.contact_id[c] = all_contacts[c].id;
    p.point_m[c] = all_contacts[c].tissue_point_m;
    p.normal[c] = all_contacts[c].n;
    p.tangent1[c] = all_contacts[c].t1;
    p.tangent2[c] = all_contacts[c].t2;
  }
  if (rows > 0) {
    // + H_tool C6 H_tool^T = B B^T with B = H_tool L (C6 = L L^T), each pair (i, j) computed
    // once and written to both halves: W stays symmetric to the bit (the tissue blocks are), so
    // NSGS may use its symmetric sweep
    // (+ c_g g g^T for a dynamic grip, g the jaw angle's column)
    const shared::Matrix6d c6 = instrument->compliance6(h);
    const shared::Matrix6d l6 = c6.llt().matrixL();
    b_tool.noalias() = h_tool * l6;
    const double c_grip = instrument->gripCompliance(h);
    for (int i = 0; i < rows; ++i) {
      const auto bi = b_tool.row(i);
      double* wi = p.W.row(i).data();
      const double gi = c_grip * p.grip[i];
      for (int j = i; j < rows; ++j) {
        const double w = bi.dot(b_tool.row(j)) + gi * p.grip[j];
        wi[j] += w;
        if (j != i) p.W(j, i) += w;
      }
    }
    p.J.noalias() = h_tool * tool_free->freeMotionSensitivity(h);
    // contact compliance (collision.h): W + c I, penetration c f_n per contact
    p.W.diagonal().array() += spec.instrument.contact_compliance_mpn;
  }
  report.distinct_tissue_nodes = countDistinctNodes();
  if (mu > 0.0) counters.tangential_rows += rows - contacts;
  report.contacts = contacts;
  report.rows = rows;
  report.times.w_build_s += shared::secondsSinceNs(t0);
}

// Tissue nodes with a non-zero weight in some contact of the last assembled problem.
int Simulation::Impl::countDistinctNodes() {
  node_keys.clear();
  for (std::size_t t = 0; t < tissues.size(); ++t) {
    for (const Contact& k : *tissues[t].found) {
      for (int j = 0; j < 3; ++j) {
        if (k.nodes[j] >= 0 && k.weights[j] != 0.0) {
          node_keys.push_back((static_cast<std::int64_t>(t) << 32) | k.nodes[j]);
        }
      }
    }
  }
  std::sort(node_keys.begin(), node_keys.end());
  return static_cast<int>(std::unique(node_keys.begin(), node_keys.end()) - node_keys.begin());
}

// Warm start by contact identity, NSGS, then the constrained motion from the free state:
// tissue dq = C H^T f (per model), tool dx = C6 H_tool^T f.
void Simulation::Impl::solveAndCorrect(StepReport& report, bool restore_free) {
  const double h = spec.time_step_s;
  ContactProblemData& p = problem;
  const int rows = p.rows;
  const int contacts = p.contacts;
  std::int64_t t0 = shared::monotonicNs();
  p.f.setZero(rows);
  for (int c = 0; c < contacts; ++c) {
    auto it = previous_f.find(p.contact_id[c]);
    if (it == previous_f.end()) continue;
    const int r0 = p.row_offset[c];
    const int nr = p.row_offset[c + 1] - r0;
    for (int k = 0; k < nr; ++k) p.f[r0 + k] = it->second[k];
  }
  if (rows > 0) {
    report.nsgs = shared::solveNsgs(p.view(), nsgs, workspace, p.f.data());  // zeroes f on NaN
    ++counters.solves;
  } else {
    report.nsgs = shared::NsgsResult{};
  }
  p.solve = report.nsgs;
  previous_f.clear();
  for (int c = 0; c < contacts; ++c) {
    const int r0 = p.row_offset[c];
    const int nr = p.row_offset[c + 1] - r0;
    std::array<double, 3> fc{0.0, 0.0, 0.0};
    for (int k = 0; k < nr; ++k) fc[k] = p.f[r0 + k];
    previous_f.emplace(p.contact_id[c], fc);
  }
  report.times.solve_s += shared::secondsSinceNs(t0);
  report.total_normal_force_n = 0.0;
  for (int c = 0; c < contacts; ++c) report.total_normal_force_n += p.f[p.row_offset[c]];

  t0 = shared::monotonicNs();
  if (restore_free) {
    for (TissueState& ts : tissues) {
      ts.body->positions() = ts.q_free;
      ts.body->velocities() = ts.v_free;
    }
    *instrument = *tool_free;
  }
  report.max_penetration_m = 0.0;
  report.complementarity = 0.0;
  if (rows > 0) {
    for (TissueState& ts : tissues) {
      if (ts.rows.rows() == 0) continue;
      ts.compliance->correction(*ts.body, ts.rows.tissue, p.f.data() + ts.row_begin, ts.dq);
      ts.body->positions() += ts.dq;
      ts.body->velocities() += ts.dq / h;
    }
    const shared::Vector6d wrench = h_tool.transpose() * p.f;
    last_wrench = wrench;
    report.tool_wrench = wrench;
    instrument->applyCorrection(wrench);
    last_grip_torque = instrument->dynamicGrip() ? p.grip.dot(p.f) : 0.0;
    if (instrument->dynamicGrip()) instrument->applyGripCorrection(last_grip_torque);
    // linearised gaps after the correction: delta = W f + delta_free, left by NSGS on exit
    // (not when it refused the problem as larger than its workspace: then computed here)
    Eigen::VectorXd unsolved_delta;
    const double* delta = workspace.delta.data();
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
    last_wrench.setZero();
    last_grip_torque = 0.0;
  }
  report.times.correction_s += shared::secondsSinceNs(t0);
}

StepReport Simulation::step() {
  Impl& s = *impl_;
  StepReport report;
  const std::int64_t t_step = shared::monotonicNs();
  const double h = s.spec.time_step_s;

  // kStepStart: contacts at the start-of-step state (carried to the free state when assembled,
  // from q_begin and tool_start)
  if (s.instrument && s.spec.solver.contact_detection == ContactDetection::kStepStart) {
    s.detectContacts(report);
    if (!s.tool_start) {
      s.tool_start = std::make_unique<Instrument>(*s.instrument);
    } else {
      *s.tool_start = *s.instrument;
    }
  }

  // free motion of every object (no contact forces)
  std::int64_t t0 = shared::monotonicNs();
  for (TissueState& ts : s.tissues) {
    if (s.instrument) ts.q_begin = ts.body->positions();
    const FemStepStats st = ts.body->freeMotion(h);
    if (!st.ok) report.finite = false;
    report.inverted_elements += st.inverted_elements;
    report.fem_cg_iterations += st.cg_iterations;
    if (st.factor_refreshed || s.spec.solver.linear == LinearSolverKind::kCholmod)
      ++report.fem_factorisations;
  }
  if (s.instrument) {
    s.tool_begin = s.instrument->pose();
    s.instrument->freeMotion(h, s.target.pose, s.target.twist, s.target.gripper_opening);
    s.problem.device_pose = s.target.pose;
    s.problem.device_gripper = s.target.gripper_opening;
  }
  report.times.free_motion_s = shared::secondsSinceNs(t0);

  if (s.instrument) {
    t0 = shared::monotonicNs();
    for (TissueState& ts : s.tissues) ts.compliance->update(*ts.body);
    report.times.w_build_s = shared::secondsSinceNs(t0);
    s.solveContacts(report);
    s.problem.tool_pose = s.instrument->pose();
  }

  s.t_s += h;
  ++s.step;
  ++s.counters.steps;
  s.counters.rotation_extractions = 0;
  s.counters.damping_evaluations = 0;
  for (TissueState& ts : s.tissues) {
    s.counters.rotation_extractions += ts.body->counters().rotation_extractions;
    s.counters.damping_evaluations += ts.body->counters().damping_evaluations;
    report.finite = report.finite && allFinite(ts.body->positions()) &&
                    allFinite(ts.body->velocities());
  }
  if (s.instrument) {
    report.finite = report.finite && s.instrument->pose().pos_m.allFinite() &&
                    s.instrument->twist().allFinite();
  }
  report.times.total_s = shared::secondsSinceNs(t_step);
  return report;
}

double Simulation::time() const { return impl_->t_s; }
long Simulation::stepIndex() const { return impl_->step; }
int Simulation::tissueCount() const { return static_cast<int>(impl_->tissues.size()); }
FemBody& Simulation::tissue(int i) { return *impl_->tissues.at(i).body; }
const FemBody& Simulation::tissue(int i) const { return *impl_->tissues.at(i).body; }
std::span<const Contact> Simulation::contacts(int i) const {
  const auto& ts = impl_->tissues.at(static_cast<std::size_t>(i));
  if (ts.found == nullptr) return {};
  return *ts.found;
}
TissueCompliance* Simulation::compliance(int i) { return impl_->tissues.at(i).compliance.get(); }
Instrument* Simulation::instrument() { return impl_->instrument.get(); }
const ContactProblemData& Simulation::lastProblem() const { return impl_->problem; }
const PipelineCounters& Simulation::counters() const { return impl_->counters; }

double Simulation::geometricMinGap() {
  if (!impl_->instrument) return std::numeric_limits<double>::infinity();
  return impl_->queryContacts();
}

double Simulation::totalEnergy() const {
  double e = 0.0;
  for (const TissueState& ts : impl_->tissues) {
    e += ts.body->kineticEnergy() + ts.body->elasticEnergy() + ts.body->gravityEnergy();
  }
  if (impl_->instrument) e += impl_->instrument->kineticEnergy();
  return e;
}

Eigen::Matrix<double, 6, 1> Simulation::renderedWrench() const {
  return impl_->instrument ? impl_->instrument->couplingWrench()
                           : Eigen::Matrix<double, 6, 1>::Zero();
}

void Simulation::writeOutputIfDue() {
  Impl& s = *impl_;
  if (!s.spec.output.enabled) return;
  if (s.step % std::max(1, s.spec.output.every_n_steps) != 0) return;
  const std::filesystem::path dir = s.spec.output.directory;
  std::filesystem::create_directories(dir);
  for (const TissueState& ts : s.tissues) {
    const Eigen::VectorXd& q = ts.body->positions();
    const int n = ts.body->nodeCount();
    Eigen::Matrix3Xd pos = Eigen::Map<const Eigen::Matrix3Xd>(q.data(), 3, n);
    Eigen::Matrix3Xd disp =
        pos - Eigen::Map<const Eigen::Matrix3Xd>(ts.body->restPositions().data(), 3, n);
    Eigen::VectorXd vm;
    ts.body->vonMises(vm);
    Eigen::VectorXd volume_ratio;
    ts.body->volumeRatios(volume_ratio);
    const std::string file = fmt::format("{}_{:06d}.vtu", ts.name, s.frame);
    writeVtu(dir / file, ts.body->mesh(), pos, disp, vm, volume_ratio);
    s.vtk_files.push_back(file);
    s.vtk_times.push_back(s.t_s);
  }
  ++s.frame;
  ++s.counters.vtk_frames;
  writePvd(dir / "series.pvd", s.vtk_files, s.vtk_times);
}

void Simulation::finishOutput() {
  Impl& s = *impl_;
  if (!s.spec.output.enabled || s.vtk_files.empty()) return;
  writePvd(s.spec.output.directory / "series.pvd", s.vtk_files, s.vtk_times);
  spdlog::info("VTK series: {} ({} frames)", (s.spec.output.directory / "series.pvd").string(),
               s.frame);
}

}  // namespace tactus::sim
