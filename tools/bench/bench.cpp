// tactus-bench: end-to-end benchmark of a scene, headless. Runs N steps (default: the scene's
// duration / time step) following the scene's scripted instrument, and reports per-stage medians
// (free_motion, detect_collisions, update_compliance, build_w, solve_contacts, constrained_motion:
// the functions of Simulation::step(); then publish), contacts, sweeps, and the haptic
// tick's solve for the same snapshots: each step's problem, published into a private segment's
// snapshot slot exactly as sim_server does, is re-solved from the slot as the haptic loop would
// (delta_free moved by J times a small device displacement, NSGS warm-started as the loop's first
// tick on a snapshot: the simulation's f plus the correction carried from the previous snapshot,
// shared/warm_start.h; the loop's sweep and time budget). --json writes everything for comparison
// between commits. The scene runs through the headless runner (tactus/sim/runner.h), as
// sim_server --steps does; sim_server --record-snapshots records the same snapshots.
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <unistd.h>

#include "tactus/shared/cli.h"
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <memory>
#include <string>
#include <vector>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/percentiles.h"
#include "tactus/shared/pose.h"
#include "tactus/shared/segment.h"
#include "tactus/shared/snapshot_file.h"
#include "tactus/haptic/local_model.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/runner.h"
#include "tactus/sim/scene.h"

namespace {

using namespace tactus;

// Nearest-rank percentile of unsorted values (the project's one definition, shared/percentiles.h).
double pct(const std::vector<double>& v, double q) { return shared::percentile(v, q); }

// CPU time of the calling thread (excludes time the benchmark was preempted on a busy machine).
std::int64_t processCpuNs() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

std::int64_t threadCpuNs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// Minor page faults of the calling thread so far (first touches of memory the kernel maps then:
// fresh allocations).
long threadMinorFaults() {
  rusage u{};
  getrusage(RUSAGE_THREAD, &u);
  return u.ru_minflt;
}

struct Series {
  std::string name;
  std::vector<double> v;
};

// Writes the step's problem into the slot and publishes it, as sim_server's SegmentHost does;
// a problem larger than the segment would silently drop from the figures: an error.
void publishProblem(const sim::Simulation& sim, shared::SnapshotPublisher& pub, std::uint64_t seq,
                    double max_opening_rad) {
  shared::SnapshotWriter slot = pub.slot();
  if (!sim::writeSnapshot(sim, max_opening_rad, seq, shared::monotonicNs(), 0, slot)) {
    throw Error(fmt::format("step {}: the contact problem does not fit the segment ({} rows, {} "
                            "contacts at most)",
                            seq, slot.layout().max_rows, slot.layout().max_contacts));
  }
  pub.publish();
}

struct BenchOptions {
  std::string scene;
  long steps = 0;
  std::string json;
  std::string trace;
  std::string state_out;
  double budget_us = 0.0;
  int tick_sweeps = 0;
  double displacement_mm = 0.2;
  std::string log_level = "warn";
  int jaw_samples = 0;                 ///< > 0: overrides instrument.grasper.samples
  int jaw_rows = 0;                    ///< > 0: overrides instrument.grasper.width_samples
  double jaw_width_mm = -1.0;          ///< >= 0: overrides instrument.grasper.width
  double grip_stiffness = -1.0;        ///< >= 0: overrides instrument.grasper.grip_stiffness
  int anderson_depth = -1;             ///< >= 0: overrides solver.nsgs_anderson_depth
  int min_contacts = 0;                ///< > 0: a second table over the steps with this many
  double contact_compliance = -1.0;    ///< >= 0: overrides instrument.contact_compliance [m/N]
  double pad_width_mm = -1.0;          ///< >= 0: overrides instrument.grasper.pad_width
  std::string linear;                  ///< non-empty: overrides solver.linear
  int instruments = 0;                 ///< > 0: keep only the scene's first N instruments
  std::string split_contact_groups;    ///< "true"/"false": overrides solver.split_contact_groups
  std::string local_model;             ///< non-empty: overrides haptics.local_model
  int background_lag = -1;             ///< >= 0: overrides solver.background_refactor_lag_steps
  int background_free_lag = -1;        ///< >= 0: overrides ..._refactor_free_lag_steps
  std::string when_ready;              ///< "true"/"false": overrides ..._refactor_when_ready
  std::string precondition_precision;  ///< "double"/"float"/"half": overrides it
};

int run(const BenchOptions& o) {
  sim::SceneSpec spec = sim::loadScene(o.scene);
  spec.haptics.enabled = false;
  spec.output.enabled = false;
  if (o.jaw_samples > 0) spec.instrument.jaw_samples = o.jaw_samples;
  if (o.jaw_rows > 0) spec.instrument.jaw_rows = o.jaw_rows;
  if (o.jaw_width_mm >= 0.0) spec.instrument.jaw_width_m = 1e-3 * o.jaw_width_mm;
  if (o.grip_stiffness >= 0.0) spec.instrument.grip_k_nmprad = o.grip_stiffness;
  if (o.anderson_depth >= 0) spec.solver.nsgs_anderson_depth = o.anderson_depth;
  if (o.contact_compliance >= 0.0) spec.instrument.contact_compliance_mpn = o.contact_compliance;
  if (o.pad_width_mm >= 0.0) spec.instrument.pad_width_m = 1e-3 * o.pad_width_mm;
  if (o.instruments > 0 && o.instruments < sim::instrumentCount(spec)) {
    spec.additional_instruments.resize(static_cast<std::size_t>(o.instruments - 1));
  }
  if (!o.split_contact_groups.empty()) {
    spec.solver.split_contact_groups = o.split_contact_groups == "true";
  }
  if (o.background_lag >= 0) spec.solver.background_refactor_lag_steps = o.background_lag;
  if (o.background_free_lag >= 0)
    spec.solver.background_refactor_free_lag_steps = o.background_free_lag;
  if (!o.when_ready.empty()) spec.solver.background_refactor_when_ready = o.when_ready == "true";
  if (o.precondition_precision == "double")
    spec.solver.preconditioner_precision = sim::PreconditionerPrecision::kDouble;
  if (o.precondition_precision == "float")
    spec.solver.preconditioner_precision = sim::PreconditionerPrecision::kFloat;
  if (o.precondition_precision == "half")
    spec.solver.preconditioner_precision = sim::PreconditionerPrecision::kHalf;
  if (o.linear == "cholmod") spec.solver.linear = sim::LinearSolverKind::kCholmod;
  if (o.linear == "pcg") spec.solver.linear = sim::LinearSolverKind::kPcg;
  if (o.linear == "cholmod_reuse") spec.solver.linear = sim::LinearSolverKind::kCholmodReuse;
  const double h = spec.time_step_s;
  const long steps = o.steps > 0 ? o.steps : static_cast<long>(std::llround(spec.duration_s / h));
  if (steps <= 0) throw Error(o.scene + ": no duration in the scene; pass --steps N");
  const double rate_hz = spec.haptics.rate_hz > 0.0 ? spec.haptics.rate_hz : 1000.0;
  const double budget_us = o.budget_us > 0.0 ? o.budget_us : 0.4 * 1e6 / rate_hz;
  const int tick_sweeps = o.tick_sweeps > 0 ? o.tick_sweeps : spec.haptics.max_sweeps_per_tick;

  const std::int64_t t_build = shared::monotonicNs();
  sim::Simulation sim(spec);
  const double build_s = 1e-9 * static_cast<double>(shared::monotonicNs() - t_build);
  if (!sim.hasInstrument()) throw Error(o.scene + ": no instrument: nothing to benchmark");

  // a private segment with the capacity sim_server would create for this scene
  const std::string seg_name = fmt::format("tactus-bench-{}", static_cast<long>(::getpid()));
  // (instruments', obstacles' and tissue pairs' contacts: the capacity sim_server creates)
  shared::Segment seg = shared::Segment::create(seg_name, sim::problemCapacity(spec));
  shared::SnapshotPublisher pub = seg.snapshotPublisher();
  shared::SnapshotSubscriber sub = seg.snapshotSubscriber();
  // the haptic side's local model, the one the loop solves (haptic/local_model.h): each snapshot
  // prepared at the device's pose, then one tick 5 um further along the displacement
  haptic::LocalModelSettings model_settings;
  model_settings.kind = spec.haptics.local_model == sim::HapticLocalModel::kFull
                            ? haptic::LocalModelKind::kFull
                        : spec.haptics.local_model == sim::HapticLocalModel::kLinearized
                            ? haptic::LocalModelKind::kLinearized
                            : haptic::LocalModelKind::kAutomatic;
  if (o.local_model == "full") model_settings.kind = haptic::LocalModelKind::kFull;
  if (o.local_model == "linearized") model_settings.kind = haptic::LocalModelKind::kLinearized;
  if (o.local_model == "automatic") model_settings.kind = haptic::LocalModelKind::kAutomatic;
  model_settings.tolerance = spec.haptics.nsgs_tolerance;
  model_settings.max_sweeps = tick_sweeps;
  model_settings.anderson_depth = spec.haptics.nsgs_anderson_depth;
  haptic::OfflineLocalModel model(seg.capacity().max_rows, seg.capacity().max_contacts,
                                  model_settings);
  // the device displacement from x_h*: a fixed small translation (mm) along (1, -1, -1) / sqrt(3)
  const Eigen::Vector3d direction = Eigen::Vector3d(1.0, -1.0, -1.0).normalized();
  const Eigen::Vector3d dx = 1e-3 * o.displacement_mm * direction;
  const Eigen::Vector3d tick_step = 5e-6 * direction;
  std::vector<double> prepare_ms;
  long tick_linearized = 0, tick_corrected = 0, tick_fallbacks = 0;

  // total: the step and the publish
  std::vector<Series> stages = {{"free_motion", {}},       {"detect_collisions", {}},
                                {"update_compliance", {}}, {"build_w", {}},
                                {"solve_contacts", {}},    {"constrained_motion", {}},
                                {"publish", {}},           {"total", {}},
                                {"step_cpu", {}}};
  std::vector<Series> busy = stages;   // the steps with at least o.min_contacts contacts
  std::vector<double> busy_contacts;
  std::vector<double> contacts, rows, sim_sweeps, tick_us, tick_cpu_us, tick_sweeps_v, tick_err, passes,
      geometric_pen_mm, excess_pen_mm, distinct_nodes, total_fn, fem_cg, fem_local, groups;
  long fem_factorisations = 0;
  long tick_converged = 0;
  long sim_converged = 0;
  long split_steps = 0;   // steps whose problem was split in more than one group
  int max_contacts_step = -1, max_contacts_nodes = 0;
  double load_at_max_fn = 0.0, max_load = 0.0, max_fn = -1.0;   // contact force on the tool against gravity [N]
  const Eigen::Vector3d up =
      spec.gravity_mps2 ? Eigen::Vector3d(-spec.gravity_mps2->normalized()) : Eigen::Vector3d::UnitZ();
  std::FILE* trace = nullptr;
  if (!o.trace.empty()) {
    trace = std::fopen(o.trace.c_str(), "w");
    if (trace == nullptr) throw Error("cannot write " + o.trace);
    std::fprintf(trace, "step,t_s,contacts,rows,sim_sweeps,step_ms,tick_solve_us,tick_sweeps,groups,solve_ms,"
                        "free_ms,detect_ms,compliance_ms,build_w_ms,constrained_ms,cpu_ms,passes,"
                        "factorisations,cg_iterations,publish_ms,minor_faults,factor_wait_ms,pcg_local_nodes\n");
  }
  const std::int64_t t0 = shared::monotonicNs();
  // each step of the headless runner: publish, the figures, the haptic tick on the snapshot
  // step_cpu: the CPU time of this thread from the end of one afterStep to the start of the
  // next (the step alone: steadier than the wall times on a shared machine)
  std::int64_t cpu_mark = threadCpuNs();
  // the other threads' CPU over the run (the background factorisations): the process's less
  // this thread's
  const std::int64_t run_process_cpu0 = processCpuNs(), run_thread_cpu0 = threadCpuNs();
  double step_cpu_s = 0.0;
  // the trace's minor page faults of the step's thread over the step and its publish
  long faults_mark = threadMinorFaults(), step_faults = 0;
  // the trace's per-step stage times [ms], the step's thread CPU, passes and the linear solve
  // and the step's waits for the background factorisation (FemBody counters, all tissues)
  const auto waitedS = [&] {
    double s = 0.0;
    for (int i = 0; i < sim.tissueCount(); ++i) s += sim.tissue(i).counters().background_wait_s;
    return s;
  };
  double wait_mark = waitedS();
  const auto traceStages = [&](const sim::StepReport& r) {
    const double waited = waitedS();
    const double step_wait_s = waited - wait_mark;
    wait_mark = waited;
    std::fprintf(trace, "%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%d,%d,%d,%.4f,%ld,%.4f,%d\n",
                 1e3 * r.times.free_motion_s, 1e3 * r.times.detect_collisions_s,
                 1e3 * r.times.update_compliance_s, 1e3 * r.times.build_w_s,
                 1e3 * r.times.constrained_motion_s, 1e3 * step_cpu_s, r.contact_passes,
                 static_cast<int>(r.fem_factorisations), static_cast<int>(r.fem_cg_iterations),
                 1e3 * stages[6].v.back(), step_faults, 1e3 * step_wait_s, r.fem_pcg_local_nodes);
  };
  const auto afterStepInner = [&](long k, const sim::StepReport& r) {
    const std::int64_t tp = shared::monotonicNs();
    publishProblem(sim, pub, static_cast<std::uint64_t>(k + 1), spec.instrument.max_opening_rad);
    seg.beat(shared::Side::kSim);
    const double publish_s = 1e-9 * static_cast<double>(shared::monotonicNs() - tp);
    step_faults = threadMinorFaults() - faults_mark;
    stages[0].v.push_back(r.times.free_motion_s);
    fem_cg.push_back(r.fem_cg_iterations);
    fem_local.push_back(r.fem_pcg_local_nodes);
    fem_factorisations += r.fem_factorisations;
    stages[1].v.push_back(r.times.detect_collisions_s);
    stages[2].v.push_back(r.times.update_compliance_s);
    stages[3].v.push_back(r.times.build_w_s);
    stages[4].v.push_back(r.times.solve_contacts_s);
    stages[5].v.push_back(r.times.constrained_motion_s);
    stages[6].v.push_back(publish_s);
    stages[7].v.push_back(r.times.total_s + publish_s);
    stages[8].v.push_back(step_cpu_s);
    if (o.min_contacts > 0 && r.contacts >= o.min_contacts) {
      for (std::size_t i = 0; i < stages.size(); ++i) busy[i].v.push_back(stages[i].v.back());
      busy_contacts.push_back(r.contacts);
    }
    // contact figures over the steps in contact
    if (r.contacts > 0) {
      contacts.push_back(r.contacts);
      rows.push_back(r.rows);
      sim_sweeps.push_back(r.nsgs.sweeps);
      groups.push_back(r.contact_groups);
      if (r.contact_groups > 1) ++split_steps;
      passes.push_back(r.contact_passes);
      geometric_pen_mm.push_back(1e3 * r.geometric_penetration_m);
      excess_pen_mm.push_back(1e3 * r.excess_penetration_m);
      distinct_nodes.push_back(r.distinct_tissue_nodes);
      const double load = -r.tool_wrench.head<3>().dot(up);   // the tissue pulls the tool down
      if (r.total_normal_force_n > max_fn) {
        max_fn = r.total_normal_force_n;
        load_at_max_fn = load;
      }
      max_load = std::max(max_load, load);
      total_fn.push_back(r.total_normal_force_n);
      if (r.nsgs.status == shared::NsgsStatus::kConverged) ++sim_converged;
      if (r.contacts > max_contacts_step) {
        max_contacts_step = r.contacts;
        max_contacts_nodes = r.distinct_tissue_nodes;
      }
    }
    if (trace != nullptr && r.contacts <= 0) {
      std::fprintf(trace, "%ld,%.4f,0,0,0,%.4f,0,0,0,0,", k, sim.time(), 1e3 * stages[7].v.back());
      traceStages(r);
    }

    // the haptic side's tick on this snapshot, read back from the slot
    const shared::SnapshotView snap = sub.latest();
    if (snap.contacts() <= 0) {
      model.reset();
      return;
    }
    const shared::PoseSample& xs = snap.header().device_pose;
    shared::Pose pose;
    pose.pos_m = Eigen::Vector3d(xs.pos_m[0], xs.pos_m[1], xs.pos_m[2]) + dx;
    pose.rot = Eigen::Quaterniond(xs.quat_wxyz[0], xs.quat_wxyz[1], xs.quat_wxyz[2],
                                  xs.quat_wxyz[3]).normalized();
    const shared::Pose* poses[] = {&pose};
    (void)model.adopt(snap, poses);   // the preparation (off the tick in haptic_server)
    prepare_ms.push_back(1e-6 * static_cast<double>(model.prepared().prepareNs()));
    pose.pos_m += tick_step;
    const std::int64_t cpu0 = threadCpuNs();
    const haptic::LocalModelResult res =
        model.solve(poses, shared::monotonicNs() + static_cast<std::int64_t>(budget_us * 1e3));
    tick_cpu_us.push_back(1e-3 * static_cast<double>(threadCpuNs() - cpu0));
    tick_us.push_back(1e-3 * static_cast<double>(res.elapsed_ns));
    tick_sweeps_v.push_back(res.sweeps);
    tick_err.push_back(res.error);
    if (res.converged()) ++tick_converged;
    if (res.used == haptic::LocalModelUsed::kLinearized) ++tick_linearized;
    if (res.used == haptic::LocalModelUsed::kCorrected) ++tick_corrected;
    if (res.used == haptic::LocalModelUsed::kFallback) ++tick_fallbacks;
    if (trace != nullptr) {
      std::fprintf(trace, "%ld,%.4f,%d,%d,%d,%.4f,%.3f,%d,%d,%.4f", k, sim.time(),
                   r.contacts, r.rows, r.nsgs.sweeps, 1e3 * stages[7].v.back(),
                   1e-3 * static_cast<double>(res.elapsed_ns), res.sweeps, r.contact_groups,
                   1e3 * r.times.solve_contacts_s);
      std::fputc(',', trace);
      traceStages(r);
    }
  };
  const auto afterStep = [&](long k, const sim::StepReport& r) {
    step_cpu_s = 1e-9 * static_cast<double>(threadCpuNs() - cpu_mark);
    afterStepInner(k, r);
    cpu_mark = threadCpuNs();
    faults_mark = threadMinorFaults();
  };
  const sim::HeadlessResult run =
      sim::runHeadless(sim, {.steps = steps, .after_step = afterStep});
  const double other_threads_cpu_s =
      1e-9 * static_cast<double>((processCpuNs() - run_process_cpu0) -
                                 (threadCpuNs() - run_thread_cpu0));
  if (trace != nullptr) std::fclose(trace);
  if (!o.state_out.empty()) {
    // the state after the run (Simulation::saveState): two builds that step alike write the same
    // bytes
    const std::string bytes = sim.saveState();
    std::FILE* out = std::fopen(o.state_out.c_str(), "wb");
    if (out == nullptr || std::fwrite(bytes.data(), 1, bytes.size(), out) != bytes.size()) {
      if (out != nullptr) std::fclose(out);
      throw Error("cannot write " + o.state_out);
    }
    std::fclose(out);
  }
  if (run.end == sim::RunEnd::kNonFinite) {
    throw NumericalError(fmt::format("step {}: the state became non-finite", run.steps - 1));
  }
  const double wall_s = 1e-9 * static_cast<double>(shared::monotonicNs() - t0);

  // table
  std::printf("%s: %ld steps of %.1f ms (%.1f s simulated) in %.1f s wall; set-up %.1f s\n",
              o.scene.c_str(), steps, 1e3 * h, static_cast<double>(steps) * h, wall_s, build_s);
  std::printf("%-19s %10s %10s %10s %10s\n", "stage [ms]", "median", "p90", "p99", "max");
  for (const auto& s : stages) {
    std::printf("%-19s %10.3f %10.3f %10.3f %10.3f\n", s.name.c_str(), 1e3 * pct(s.v, 0.5),
                1e3 * pct(s.v, 0.9), 1e3 * pct(s.v, 0.99), 1e3 * pct(s.v, 1.0));
  }
  if (o.min_contacts > 0 && !busy_contacts.empty()) {
    std::printf("over the %zu steps with >= %d contacts (contacts median %.0f, max %.0f):\n",
                busy_contacts.size(), o.min_contacts, pct(busy_contacts, 0.5),
                pct(busy_contacts, 1.0));
    for (const auto& s : busy) {
      std::printf("  %-19s %10.3f %10.3f %10.3f %10.3f\n", s.name.c_str(), 1e3 * pct(s.v, 0.5),
                  1e3 * pct(s.v, 0.9), 1e3 * pct(s.v, 0.99), 1e3 * pct(s.v, 1.0));
    }
  } else if (o.min_contacts > 0) {
    std::printf("no step had >= %d contacts\n", o.min_contacts);
  }
  long background_factorisations = 0, background_waits = 0, background_not_ready = 0;
  long prepared_factorisations = 0;
  double background_wait_max_s = 0.0, background_wait_s = 0.0;
  for (int i = 0; i < sim.tissueCount(); ++i) {
    const sim::FemBody::Counters& c = sim.tissue(i).counters();
    background_factorisations += c.background_factorisations;
    background_waits += c.background_waits;
    background_not_ready += c.background_not_ready;
    background_wait_max_s = std::max(background_wait_max_s, c.background_wait_max_s);
    background_wait_s += c.background_wait_s;
    prepared_factorisations += c.prepared_factorisations;
  }
  std::printf("free motion linear solve: %ld CHOLMOD factorisations on the step's thread, %ld "
              "at set-up and %ld in the background in %ld steps (%ld steps waited for the "
              "background one, %.2f ms in all, at most %.2f ms; %ld went on without it, not "
              "ready); PCG iterations per step median %.0f, p90 %.0f, max %.0f; nodes in its "
              "local correction median %.0f, p90 %.0f, max %.0f\n",
              fem_factorisations, prepared_factorisations, background_factorisations, steps,
              background_waits, 1e3 * background_wait_s, 1e3 * background_wait_max_s,
              background_not_ready, pct(fem_cg, 0.5), pct(fem_cg, 0.9), pct(fem_cg, 1.0),
              pct(fem_local, 0.5), pct(fem_local, 0.9), pct(fem_local, 1.0));
  std::printf("CPU of the run's other threads (the background factorisations): %.2f s, %.2f ms "
              "per step\n", other_threads_cpu_s,
              1e3 * other_threads_cpu_s / static_cast<double>(std::max(1L, steps)));
  const sim::BlasLockFigures blas_lock = sim::blasLockFigures();
  std::printf("CHOLMOD calls that waited for the BLAS lock (another thread's supernodal "
              "factorisation or solve): %ld, %.1f ms in all\n", blas_lock.contended_calls,
              1e3 * blas_lock.waited_s);
  std::printf(
      "steps in contact: %zu of %ld; over those: contacts median %.0f, max %.0f (rows "
      "median %.0f, max %.0f); sim NSGS sweeps median %.0f\n",
      contacts.size(), steps, pct(contacts, 0.5), pct(contacts, 1.0), pct(rows, 0.5),
      pct(rows, 1.0), pct(sim_sweeps, 0.5));
  std::printf("groups of coupled bodies solved apart (solver.split_contact_groups %s): median "
              "%.0f, max %.0f; steps split in more than one: %ld\n",
              spec.solver.split_contact_groups ? "true" : "false", pct(groups, 0.5),
              pct(groups, 1.0), split_steps);
  std::printf(
      "sim NSGS: converged %ld / %zu, sweeps p90 %.0f, max %.0f; distinct tissue nodes median "
      "%.0f, max %.0f (%d at the %d-contact step); total normal force median %.3f N, max %.3f N "
      "(the tissue's pull on the tool against gravity at that step %.3f N, at most %.3f N)\n",
      sim_converged, contacts.size(), pct(sim_sweeps, 0.9), pct(sim_sweeps, 1.0),
      pct(distinct_nodes, 0.5), pct(distinct_nodes, 1.0), max_contacts_nodes, max_contacts_step,
      pct(total_fn, 0.5), pct(total_fn, 1.0), load_at_max_fn, max_load);
  if (spec.solver.contact_iterations > 1) {
    const auto extra = std::count_if(passes.begin(), passes.end(), [](double p) { return p > 1; });
    std::printf(
        "contact passes (at most %d): median %.0f, max %.0f, steps with more than one %ld; "
        "geometric penetration after the step: median %.3f mm, max %.3f mm; beyond the contact "
        "compliance's give: median %.3f mm, max %.3f mm (tolerance %.3f mm)\n",
        spec.solver.contact_iterations, pct(passes, 0.5), pct(passes, 1.0),
        static_cast<long>(extra), pct(geometric_pen_mm, 0.5), pct(geometric_pen_mm, 1.0),
        pct(excess_pen_mm, 0.5), pct(excess_pen_mm, 1.0),
        1e3 * spec.solver.penetration_tolerance_m);
  }
  std::printf(
      "haptic local model (%s; each snapshot prepared %.2f mm from x_h*, the tick 5 um further; "
      "<= %d sweeps, deadline %.0f us): tick wall median %.1f us, p99 %.1f us, max %.1f us; "
      "thread CPU median %.1f us, p99 %.1f us; sweeps median %.0f, p99 %.0f; error median "
      "%.2e; converged %ld / %zu; linearized %ld, corrected %ld, fallback %ld; preparation "
      "median %.2f ms, "
      "p99 %.2f ms\n",
      std::string(haptic::toString(model_settings.kind)).c_str(), o.displacement_mm, tick_sweeps,
      budget_us, pct(tick_us, 0.5), pct(tick_us, 0.99), pct(tick_us, 1.0), pct(tick_cpu_us, 0.5),
      pct(tick_cpu_us, 0.99), pct(tick_sweeps_v, 0.5), pct(tick_sweeps_v, 0.99),
      pct(tick_err, 0.5), tick_converged, tick_us.size(), tick_linearized, tick_corrected,
      tick_fallbacks, pct(prepare_ms, 0.5), pct(prepare_ms, 0.99));

  if (!o.json.empty()) {
    std::string js = fmt::format(
        "{{\n  \"scene\": \"{}\",\n  \"steps\": {},\n  \"h_ms\": {},\n"
        "  \"wall_s\": {:.3f},\n  \"setup_s\": {:.3f},\n  \"stages_ms\": {{\n",
        o.scene, steps, 1e3 * h, wall_s, build_s);
    for (std::size_t i = 0; i < stages.size(); ++i) {
      const auto& v = stages[i].v;
      js += fmt::format(
          "    \"{}\": {{\"median\": {:.6f}, \"p90\": {:.6f}, \"p99\": {:.6f}, "
          "\"max\": {:.6f}}}{}\n",
          stages[i].name, 1e3 * pct(v, 0.5), 1e3 * pct(v, 0.9), 1e3 * pct(v, 0.99),
          1e3 * pct(v, 1.0), i + 1 < stages.size() ? "," : "");
    }
    js += fmt::format(
        "  }},\n  \"steps_in_contact\": {},\n  \"contacts\": {{\"median\": {}, \"max\": {}}},\n"
        "  \"rows\": {{\"median\": {}, \"max\": {}}},\n  \"sim_sweeps_median\": {},\n"
        "  \"contact_groups\": {{\"median\": {}, \"max\": {}, \"split_steps\": {}}},\n"
        "  \"contact_passes\": {{\"median\": {}, \"max\": {}}},\n"
        "  \"geometric_penetration_mm\": {{\"median\": {:.4f}, \"max\": {:.4f}}},\n"
        "  \"geometric_penetration_mm_max\": {:.4f},\n"
        "  \"excess_penetration_mm\": {{\"median\": {:.4f}, \"max\": {:.4f}}},\n"
        "  \"haptic_tick\": {{\"displacement_mm\": {}, \"max_sweeps\": {}, \"budget_us\": {}, "
        "\"solve_us_median\": {:.3f}, \"solve_us_p99\": {:.3f}, \"solve_us_max\": {:.3f}, "
        "\"cpu_us_median\": {:.3f}, \"cpu_us_p99\": {:.3f}, "
        "\"sweeps_median\": {}, \"sweeps_p99\": {}, \"error_median\": {:.3e}, "
        "\"converged\": {}, \"solves\": {}, \"local_model\": \"{}\", \"linearized\": {}, "
        "\"corrected\": {}, \"fallbacks\": {}, \"prepare_ms_median\": {:.3f}, \"prepare_ms_p99\": {:.3f}}}\n}}\n",
        contacts.size(), pct(contacts, 0.5), pct(contacts, 1.0), pct(rows, 0.5), pct(rows, 1.0),
        pct(sim_sweeps, 0.5), pct(groups, 0.5), pct(groups, 1.0), split_steps, pct(passes, 0.5),
        pct(passes, 1.0), pct(geometric_pen_mm, 0.5), pct(geometric_pen_mm, 1.0),
        pct(geometric_pen_mm, 1.0), pct(excess_pen_mm, 0.5), pct(excess_pen_mm, 1.0),
        o.displacement_mm, tick_sweeps, budget_us, pct(tick_us, 0.5),
        pct(tick_us, 0.99), pct(tick_us, 1.0), pct(tick_cpu_us, 0.5), pct(tick_cpu_us, 0.99),
        pct(tick_sweeps_v, 0.5), pct(tick_sweeps_v, 0.99), pct(tick_err, 0.5), tick_converged,
        tick_us.size(), haptic::toString(model_settings.kind), tick_linearized, tick_corrected,
        tick_fallbacks, pct(prepare_ms, 0.5), pct(prepare_ms, 0.99));
    std::FILE* fj = std::fopen(o.json.c_str(), "w");
    if (fj == nullptr) throw Error("cannot write " + o.json);
    std::fwrite(js.data(), 1, js.size(), fj);
    std::fclose(fj);
    std::printf("JSON written to %s\n", o.json.c_str());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  namespace cli = tactus::shared::cli;
  cli::App app{
      "tactus-bench: per-stage timing of a scene and the haptic tick's solve on its "
      "snapshots (headless, scripted instrument)"};
  app.footer(
      "Snapshots for tactus-jitter --replay are recorded by sim_server (the same headless run):\n"
      "  sim_server SCENE --steps N --record-snapshots FILE\n"
      "\n"
      "Example:\n"
      "  tactus-bench scenes/liver_grasp.yaml --json bench.json");
  BenchOptions o;
  // the one --record-snapshots is sim_server's: a hidden option that says so
  std::string record_snapshots;
  app.addOption("--record-snapshots", record_snapshots)->group("");
  app.addOption("scene", o.scene, "Scene YAML file")->required()->check(cli::existingFile());
  app.addOption("--steps", o.steps, "Steps to run (default: the scene's duration / time step)");
  app.addOption("--json", o.json, "Write the results as JSON");
  app.addOption("--trace", o.trace, "Write one CSV row per step (contacts, sweeps, timings, minor page faults)");
  app.addOption("--state-out", o.state_out,
                 "Write the simulation's state after the run (Simulation::saveState) to this file");
  app.addOption("--budget-us", o.budget_us,
                 "Haptic solve time budget [us] (default: 40 % of the scene's haptic period)");
  app.addOption("--tick-sweeps", o.tick_sweeps,
                 "Haptic sweeps per tick (default: the scene's haptics.max_sweeps_per_tick)");
  app.addOption("--displacement-mm", o.displacement_mm,
                 "Device displacement applied to each snapshot before the haptic re-solve")
      ->captureDefault();
  app.addOption("--jaw-samples", o.jaw_samples,
                 "Override the grasper's samples per jaw (denser jaws: more contacts)");
  app.addOption("--jaw-rows", o.jaw_rows,
                 "Override the grasper's rows of samples across each jaw pad");
  app.addOption("--jaw-width-mm", o.jaw_width_mm,
                 "Override the grasper's pad width (span of the sample rows) [mm]");
  app.addOption("--anderson-depth", o.anderson_depth,
                 "Override solver.nsgs_anderson_depth (NSGS Anderson acceleration, 0: off)")
      ->check(cli::range(0, tactus::shared::kMaxAndersonDepth));
  app.addOption("--grip-stiffness", o.grip_stiffness,
                 "Override the grasper's grip stiffness [N m/rad] (0: kinematic jaws)");
  app.addOption("--contact-compliance", o.contact_compliance,
                 "Override the instrument's contact compliance [m/N]");
  app.addOption("--pad-width-mm", o.pad_width_mm,
                 "Override the grasper's flat pad width [mm] (0: round jaws)");
  app.addOption("--min-contacts", o.min_contacts,
                 "Also report the stages over the steps with at least this many contacts");
  app.addOption("--instruments", o.instruments,
                 "Keep only the scene's first N instruments (two hands against one)")
      ->check(cli::range(1, shared::kMaxInstruments));
  app.addOption("--split-contact-groups", o.split_contact_groups,
                 "Override the scene's solver.split_contact_groups (true: one NSGS per group of "
                 "coupled bodies; false: one over the whole W)")
      ->check(cli::isMember({"true", "false"}));
  app.addOption("--local-model", o.local_model,
                 "Override the scene's haptics.local_model (full, linearized, automatic)")
      ->check(cli::isMember({"full", "linearized", "automatic"}));
  app.addOption("--background-refactor-lag-steps", o.background_lag,
                 "Override the scene's solver.background_refactor_lag_steps (> 0: refactorise "
                 "on a worker thread)")
      ->check(cli::range(0, 1000));
  app.addOption("--background-refactor-free-lag-steps", o.background_free_lag,
                 "Override the scene's solver.background_refactor_free_lag_steps (the lag over "
                 "steps without contact; 0: the lag)")
      ->check(cli::range(0, 1000));
  app.addOption("--background-refactor-when-ready", o.when_ready,
                 "Override the scene's solver.background_refactor_when_ready (true: no step "
                 "waits for the worker)")
      ->check(cli::isMember({"true", "false"}));
  app.addOption("--preconditioner-precision", o.precondition_precision,
                 "Override the scene's solver.preconditioner_precision (PCG's preconditioner "
                 "solves in double, float or half)")
      ->check(cli::isMember({"double", "float", "half"}));
  app.addOption("--linear", o.linear, "Override the scene's solver.linear")
      ->check(cli::isMember({"cholmod", "pcg", "cholmod_reuse"}));
  app.addOption("--log-level", o.log_level, "spdlog level of the simulation library")
      ->check(cli::isMember({"trace", "debug", "info", "warn", "error"}))
      ->captureDefault();
  TACTUS_CLI_PARSE(app, argc, argv);
  if (!record_snapshots.empty()) {
    std::fprintf(stderr, "tactus-bench: snapshots are recorded by sim_server: sim_server %s "
                 "--steps N --record-snapshots %s\n", o.scene.c_str(), record_snapshots.c_str());
    return 2;
  }
  spdlog::set_level(spdlog::level::from_str(o.log_level));
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tactus-bench: %s\n", e.what());
    return 1;
  }
}
