// A Simulation built from a scene: the model, the physics objects at the initial state, the
// step's scratch, and the list of the stages the scene runs.
#include <spdlog/spdlog.h>

#include "simulation_impl.h"
#include "strain_limit.h"
#include "tissue_contact_stage.h"

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

TissueState buildTissueState(const SimulationModel& model, const TissueSpec& ts,
                             const TissueModel& tissue) {
  const SceneSpec& spec = model.spec;
  const Eigen::Vector3d* gravity = spec.gravity_mps2 ? &*spec.gravity_mps2 : nullptr;
  TissueState state;
  state.body = std::make_unique<FemBody>(tissue.mesh, femMaterial(ts), tissue.fixed_nodes, gravity,
                                         femSolverOptions(spec.solver));
  spdlog::info("tissue '{}': {} nodes, {} tets, {} fixed nodes", ts.name, tissue.mesh.nodeCount(),
               tissue.mesh.tetCount(), tissue.fixed_nodes.size());
  if (!model.has_contacts) return state;
  ComplianceOptions copt;
  copt.h_s = model.h_s;
  copt.cache_dir = ts.compliance_cache_dir;
  copt.cache_name = ts.name;
  copt.exact_correction = ts.exact_correction;
  copt.exact_below_coherence = ts.exact_below_coherence;
  copt.rotation_smoothing_passes = ts.rotation_smoothing_passes;
  copt.c0_single_precision = ts.c0_single_precision;
  state.compliance = makeCompliance(ts.compliance, *state.body, copt);
  spdlog::info("tissue '{}': {} compliance, {:.1f} MiB", ts.name, toString(ts.compliance),
               static_cast<double>(state.compliance->memoryBytes()) / (1024.0 * 1024.0));
  for (int i = 0; i < model.instrument_count; ++i) {
    const InstrumentSpec& in = instrumentSpec(spec, i);
    CollisionOptions col;
    col.alarm_distance_m = in.alarm_distance_m;
    col.contact_distance_m = in.contact_distance_m;
    col.max_contacts = spec.solver.max_contacts;
    col.sphere_vs_triangle = in.face_contacts;
    state.collisions.push_back(
        std::make_unique<Collision>(tissue.surface, state.body->positions(), col));
  }
  return state;
}

}  // namespace

SimulationState buildState(const SimulationModel& model) {
  SimulationState state;
  for (std::size_t t = 0; t < model.tissues.size(); ++t) {
    state.tissues.push_back(buildTissueState(model, model.spec.tissues[t], model.tissues[t]));
  }
  if (!model.spec.obstacles.empty()) {
    state.obstacles = std::make_unique<Obstacles>(model.spec.obstacles, model.spec.obstacle_contact);
    // obstacle_contact.edges: the obstacles' edge points against the tissues' faces
    std::vector<const TetMesh*> meshes;
    std::vector<const SurfaceMesh*> surfaces;
    for (const TissueModel& t : model.tissues) {
      meshes.push_back(&t.mesh);
      surfaces.push_back(&t.surface);
    }
    state.obstacles->attachTissues(meshes, surfaces);
  }
  state.tissue_contacts = makeTissueContacts(model);   // null without tissue_contact pairs
  for (int i = 0; i < model.instrument_count; ++i) {
    const InstrumentSpec& in = instrumentSpec(model.spec, i);
    Instrument& tool = state.instruments.emplace_back(in);
    tool.setWorkspace(model.instrument_workspaces[static_cast<std::size_t>(i)]);
    const DeviceTarget& target = state.targets.emplace_back(scriptedTarget(in, 0.0));
    tool.reset(target.pose, target.gripper_opening);
  }
  state.target_rejected.assign(state.instruments.size(), 0);
  return state;
}

StepScratch buildScratch(const SimulationModel& model) {
  StepScratch scratch;
  scratch.tissues.resize(model.tissues.size());
  const auto n = static_cast<std::size_t>(model.instrument_count);
  scratch.tool_begin.resize(n);
  scratch.wrench.assign(n, shared::Vector6d::Zero());
  scratch.previous_wrench.assign(n, shared::Vector6d::Zero());
  scratch.grip_torque.assign(n, 0.0);
  scratch.previous_grip_torque.assign(n, 0.0);
  scratch.problem.instruments.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    scratch.problem.instruments[i].max_opening_rad =
        instrumentSpec(model.spec, static_cast<int>(i)).max_opening_rad;
  }
  if (model.has_contacts) {
    const int max_contacts = problemContactCapacity(model.spec) +
                             model.spec.obstacle_contact.max_contacts *
                                 static_cast<int>(model.tissues.size()) +
                             tissueContactCapacity(model.spec);
    scratch.workspace.reserve(model.max_rows, max_contacts);
    scratch.groups.reserveStorage(model.max_rows, max_contacts);
  }
  scratch.problem.row_offset.assign(1, 0);
  // W for the largest problem, written now: a step whose problem outgrows the largest so far
  // takes no fresh page (grow_only_matrix.h)
  if (model.has_contacts) {
    scratch.problem.W.reserve(static_cast<std::size_t>(model.max_rows) *
                              static_cast<std::size_t>(model.max_rows));
  }
  return scratch;
}

Simulation::Simulation(const SceneSpec& spec)
    : Simulation(std::make_shared<const SimulationModel>(buildModel(spec))) {}

Simulation::Simulation(std::shared_ptr<const SimulationModel> model)
    : impl_(std::make_unique<Impl>(std::move(model))) {
  impl_->state = buildState(impl_->model);
  impl_->scratch = buildScratch(impl_->model);
  // the compliance models' scratch for the largest problem, written now and not page by page
  // while a grasp's contacts grow (TissueCompliance::reserve)
  for (TissueState& ts : impl_->state.tissues) {
    if (ts.compliance) ts.compliance->reserve(impl_->model.max_rows);
  }
  // the first step's factorisation made now (solver.linear cholmod_reuse): that step solves
  // with it when its system matrix is the one factorised here (FemBody::prepareFreeMotion)
  for (TissueState& ts : impl_->state.tissues) ts.body->prepareFreeMotion(impl_->model.h_s);
  // the step's per-tissue vectors at their size and the volume limiter's maps, written now: the
  // first step and the first contact step took their pages otherwise (a first touch costs
  // about 18 us on the VM measured; docs/design.md, "The step's buffers written at set-up").
  // Every value is written by the step before it is read.
  for (std::size_t t = 0; t < impl_->state.tissues.size(); ++t) {
    const FemBody& body = *impl_->state.tissues[t].body;
    TissueScratch& tx = impl_->scratch.tissues[t];
    for (Eigen::VectorXd* v : {&tx.q_begin, &tx.q_free, &tx.v_free, &tx.dq, &tx.dq_previous}) {
      v->setZero(body.dofCount());
    }
    if (impl_->model.tissues[t].min_volume_ratio > 0.0) prepareStrainLimit(body, tx.strain_limit);
  }
}

Simulation::~Simulation() = default;

std::vector<std::string> Simulation::stages() const {
  const SceneSpec& spec = impl_->model.spec;
  std::vector<std::string> out;
  for (const auto& ts : spec.tissues) {
    std::string effects = ts.law == MaterialLaw::kLinear         ? "linear"
                          : ts.law == MaterialLaw::kCorotational ? "corotational"
                                                                 : "invertible neo-Hookean";
    if (ts.law == MaterialLaw::kCorotational && ts.tangent == TangentKind::kConsistent)
      effects += ", consistent tangent";
    if (ts.element == ElementKind::kEdgeSmoothedTet) effects += ", edge-smoothed tetrahedra";
    effects += ts.damping ? ", Rayleigh damping" : ", no damping";
    effects += spec.gravity_mps2 ? ", gravity" : ", no gravity";
    switch (spec.solver.linear) {
      case LinearSolverKind::kCholmod: effects += ", CHOLMOD"; break;
      case LinearSolverKind::kPcg: effects += ", PCG"; break;
      case LinearSolverKind::kCholmodReuse: effects += ", PCG on a reused CHOLMOD factor"; break;
    }
    out.push_back(fmt::format("free motion of tissue '{}' (implicit Euler; {})", ts.name, effects));
  }
  for (const ObstacleSpec& o : spec.obstacles) {
    out.push_back(fmt::format("obstacle '{}' ({}, friction {}) against the tissues' surface "
                              "vertices (alarm {} mm, at most {} contacts per tissue)",
                              o.name,
                              o.kind == ObstacleKind::kPlane ? "plane"
                              : o.kind == ObstacleKind::kBox ? "box"
                                                             : "triangle surface",
                              o.friction_mu, 1e3 * spec.obstacle_contact.alarm_distance_m,
                              spec.obstacle_contact.max_contacts));
  }
  if (!impl_->model.has_instrument && !impl_->model.has_contacts) {
    out.push_back("no instrument: no collision, no contact problem");
  } else if (!impl_->model.has_instrument) {
    for (const auto& ts : spec.tissues) {
      out.push_back(fmt::format("W = H C H^T with {} compliance of '{}'", toString(ts.compliance),
                                ts.name));
    }
    out.push_back("NSGS on the obstacles' contacts");
    out.push_back("constrained motion (tissues)");
  } else {
    const auto& in = spec.instrument;
    for (int i = 0; i < impl_->model.instrument_count; ++i) {
      const InstrumentSpec& ii = instrumentSpec(spec, i);
      out.push_back(fmt::format("free motion of the {} god object{} (PD coupling k = {} N/m)",
                                ii.kind == InstrumentKind::kGrasper ? "grasper" : "probe",
                                impl_->model.instrument_count > 1
                                    ? fmt::format(" {} '{}'", i, ii.name)
                                    : std::string(),
                                ii.coupling_k_npm));
    }
    if (impl_->model.instrument_count > 1) {
      out.push_back(fmt::format("{} instruments' contacts in one contact problem",
                                impl_->model.instrument_count));
    }
    out.push_back(fmt::format(
        "collision detection (BVH refit, alarm {} mm, at most {} contacts, {}, at the {})",
        1e3 * in.alarm_distance_m, spec.solver.max_contacts,
        in.face_contacts ? "vertex and face contacts" : "vertex contacts only",
        spec.solver.contact_detection == ContactDetection::kStepStart ? "start of the step"
                                                                      : "free state"));
    for (const auto& ts : spec.tissues) {
      out.push_back(fmt::format("W = H C H^T with {} compliance of '{}'", toString(ts.compliance),
                                ts.name));
    }
    for (int i = 0; i < impl_->model.instrument_count; ++i) {
      const double mu = instrumentSpec(spec, i).friction_mu;
      const std::string who =
          impl_->model.instrument_count > 1 ? fmt::format(" (instrument {})", i) : std::string();
      out.push_back(mu > 0.0 ? fmt::format("NSGS with Coulomb friction mu = {} (3 rows per "
                                           "contact){}", mu, who)
                             : "NSGS frictionless (1 row per contact)" + who);
    }
    out.push_back("constrained motion (tissue and instrument)");
  }
  if (spec.output.enabled) {
    out.push_back(fmt::format("VTK output every {} steps into {}", spec.output.every_n_steps,
                              spec.output.directory.string()));
  }
  return out;
}

}  // namespace tactus::sim
