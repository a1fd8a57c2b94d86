// tactus-accuracy: accuracy against computing time of the contact pipeline and of the haptic
// local model (issue "Measure it"). Headless, deterministic, single-threaded; writes CSV files
// that scripts/accuracy_report.py turns into a Markdown table and a Pareto plot.
//
// Part 1, the simulation step. Every run follows the scene's scripted grasper over the same
// span; its contact force on the instrument, total energy, geometric penetration
// (Simulation::geometricMinGap after each step) and complementarity residual are recorded per
// step. The reference of a mesh is a run with the exact compliance and a tight NSGS tolerance at
// the scene's time step (the time-step study uses a reference at the finest step instead).
// Errors: contact force relative RMS sqrt(sum |F - F_ref|^2 / sum |F_ref|^2) and peak
// max |F - F_ref| over the reference's sample times (linear interpolation of the run), energy
// deviation max |E - E_ref| / (max E_ref - min E_ref).
//
// Part 2, the haptic local model (paper 4.2). A prefix run at the scene's time step brings the
// scene to the window start t0; its state (tissue q, v; tool pose and opening) seeds every run of
// the window, so all start identical. The device follows the scripted trajectory plus a small
// tremor. The reference at haptic rate r is a Simulation with time step 1/r driven by the device
// at every tick (the full model re-simulated per tick). The multi-rate model is a Simulation at
// the scene's time step whose snapshot k (device pose x_h(t_k)) serves the ticks of
// [t_k + L h, t_k + (L + 1) h) (L = --latency-steps, 1: the step computed during one period is
// rendered during the next); each tick moves delta_free = delta_free* + J (x_h [-] x_h*) and
// re-solves with warm-started NSGS under a sweep budget exactly as HapticLoop::solveLocalModel
// does (time budget off, so results do not depend on the machine's load). Budget 0 is the
// zero-order hold of the snapshot's force (no local model).
#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/error.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/pose.h"
#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/scene.h"

namespace {

using namespace tactus;
namespace fs = std::filesystem;
using SteadyClock = std::chrono::steady_clock;

double secondsSince(SteadyClock::time_point t0) {
  return std::chrono::duration<double>(SteadyClock::now() - t0).count();
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

const char* complianceName(sim::ComplianceKind k) {
  switch (k) {
    case sim::ComplianceKind::kExact: return "exact";
    case sim::ComplianceKind::kWarped: return "warped";
    case sim::ComplianceKind::kRest: return "rest";
    case sim::ComplianceKind::kUncoupled: return "uncoupled";
  }
  return "?";
}

sim::ComplianceKind parseCompliance(const std::string& s) {
  if (s == "exact") return sim::ComplianceKind::kExact;
  if (s == "warped") return sim::ComplianceKind::kWarped;
  if (s == "rest") return sim::ComplianceKind::kRest;
  if (s == "uncoupled") return sim::ComplianceKind::kUncoupled;
  throw Error("unknown compliance model '" + s + "' (exact, warped, rest, uncoupled)");
}

// ------------------------------------------------------------------------------------------
// options and scenes

struct Options {
  std::string mode = "full";               // quick | full
  fs::path out;
  fs::path root;                           // repository root (scenes/)
  fs::path cache_dir;                      // compliance caches
  bool with_23k = false;
  double duration_s = 0.0;                 // 0: per mode
  double early_until_s = 3.5;              // second error window: t <= this
  double duration_23k_s = 3.5;             // span of the liver_23k runs
  double ref_tolerance = 1e-9;
  int ref_sweeps = 3000;
  double haptic_t0_s = 0.0;                // 0: per mode
  double haptic_window_s = 0.0;            // 0: per mode
  int latency_steps = 1;
  double tremor_mm = 0.5;
  double tremor_hz = 6.0;
  std::string haptic_ref_compliance = "scene";
  std::string log_level = "warn";
};

// The scene of a mesh: liver2 is the paper's scene (scenes/liver_grasp.yaml), liver_23k its
// 23k-tet twin, liver the coarse SOFA liver (596 tets) placed onto liver2 by a similarity fit
// (ICP on the nodes; its lobe tip moved onto liver2's so the same script grasps it).
sim::SceneSpec meshScene(const Options& o, const std::string& mesh) {
  sim::SceneSpec spec;
  if (mesh == "liver2") {
    spec = sim::loadScene(o.root / "scenes/liver_grasp.yaml");
  } else if (mesh == "liver_23k") {
    spec = sim::loadScene(o.root / "scenes/liver_grasp_23k.yaml");
    spec.tissues.at(0).compliance_cache_dir.clear();
  } else if (mesh == "liver") {
    spec = sim::loadScene(o.root / "scenes/liver_grasp.yaml");
    sim::TissueSpec& t = spec.tissues.at(0);
    t.mesh_path = o.root / "scenes/meshes/liver.msh";
    t.scale = 0.1 * 0.290637;
    t.rotation_deg = Eigen::Vector3d(102.2022, 5.6207, -4.4607);
    t.translation_m = Eigen::Vector3d(0.043925, 0.029148, -0.061875);
  } else {
    throw Error("unknown mesh '" + mesh + "' (liver, liver2, liver_23k)");
  }
  spec.haptics.enabled = false;
  spec.output.enabled = false;
  if (!spec.instrument.present) throw Error(spec.source.string() + ": no instrument");
  // The study keeps the grasp it was calibrated on (README.md "Accuracy against time"): the
  // scenes' former round kinematic jaws closing to 0.25 at x = 0.107 m, not the flat pads. (With
  // the pads on the 596-tet liver, NSGS at 1e-6 leaves the exact model's force 1.3 % rms from its
  // 1e-9 reference: README.md "Flat jaw pads and contact compliance".)
  sim::useFormerRoundJaws(spec);
  return spec;
}

// A configuration of the simulation step.
struct SimConfig {
  std::string mesh;
  double h_s = 0.01;
  sim::ComplianceKind compliance = sim::ComplianceKind::kWarped;
  double tol = 1e-6;
  int sweeps = 300;
  std::string key() const {
    return fmt::format("{}|{:.6f}|{}|{:.3e}|{}", mesh, h_s, complianceName(compliance), tol,
                       sweeps);
  }
};

sim::SceneSpec configure(const Options& o, const sim::SceneSpec& base, const std::string& mesh,
                         double h_s, sim::ComplianceKind kind, double tol, int sweeps) {
  sim::SceneSpec spec = base;
  spec.time_step_s = h_s;
  sim::TissueSpec& t = spec.tissues.at(0);
  t.compliance = kind;
  if (kind != sim::ComplianceKind::kExact) {
    // one cache file per mesh and time step: they never evict each other
    t.compliance_cache_dir = o.cache_dir;
    t.name = fmt::format("{}_h{:.3f}ms", mesh, 1e3 * h_s);
  }
  spec.solver.nsgs_tolerance = tol;
  spec.solver.nsgs_max_sweeps = sweeps;
  return spec;
}

// Contact force and torque on the instrument from the problem's forces and frames, as the
// haptic loop computes them (torque about `origin`).
shared::Vector6d contactWrench(const sim::ContactProblemData& p, const double* f,
                               const Eigen::Vector3d& origin) {
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  Eigen::Vector3d torque = Eigen::Vector3d::Zero();
  for (int c = 0; c < p.contacts; ++c) {
    const int r0 = p.row_offset[c];
    const int rows = p.row_offset[c + 1] - r0;
    Eigen::Vector3d fc = f[r0] * p.normal[c];
    if (rows == 3) fc += f[r0 + 1] * p.tangent1[c] + f[r0 + 2] * p.tangent2[c];
    force += fc;
    torque += (p.point_m[c] - origin).cross(fc);
  }
  shared::Vector6d w;
  w << force, torque;
  return w;
}

// ------------------------------------------------------------------------------------------
// part 1: simulation runs

struct SimRun {
  SimConfig cfg;
  int tets = 0;
  int nodes = 0;
  double setup_s = 0.0;
  double wall_s = 0.0;
  std::vector<double> t;                   // end time of each step
  std::vector<Eigen::Vector3d> force;      // contact force on the instrument [N]
  std::vector<double> energy, penetration, complementarity;
  std::vector<double> step_s, solve_s, wbuild_s, nsgs_error, contacts, sweeps;
  // W = H C H^T of each approximate model against the exact one, on the same rows, at states
  // of this (exact) run: relative Frobenius error per sample, by model name
  std::map<std::string, std::vector<double>> w_error;
};

// Probes the compliance models at the run's current state: rows = the x, y, z directions at
// the (up to 24) surface nodes nearest the instrument; W of each model against the exact W.
void probeCompliance(const Options& o, sim::Simulation& sim, const SimConfig& cfg,
                     std::vector<std::unique_ptr<sim::TissueCompliance>>& models,
                     SimRun& run) {
  sim::FemBody& body = sim.tissue(0);
  const Eigen::Vector3d tool = sim.instrument()->pose().pos_m;
  std::vector<std::pair<double, int>> near;
  for (const int n : body.surfaceNodes()) {
    if (body.fixedMask()[static_cast<std::size_t>(n)]) continue;
    near.emplace_back((body.positions().segment<3>(3 * n) - tool).norm(), n);
  }
  const std::size_t k = std::min<std::size_t>(24, near.size());
  std::partial_sort(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(k), near.end());
  std::vector<sim::TissueRow> rows;
  for (std::size_t i = 0; i < k; ++i) {
    for (int d = 0; d < 3; ++d) {
      sim::TissueRow r;
      r.node = {near[i].second, -1, -1};
      r.weight = {1.0, 0.0, 0.0};
      r.dir = Eigen::Vector3d::Unit(d);
      rows.push_back(r);
    }
  }
  const int m = static_cast<int>(rows.size());
  Eigen::MatrixXd w_exact = Eigen::MatrixXd::Zero(m, m);
  sim.compliance(0)->addW(rows, w_exact);   // the run's own (exact) model, current factor
  if (models.empty()) {
    sim::ComplianceOptions co;
    co.h_s = cfg.h_s;
    co.cache_dir = o.cache_dir;
    co.cache_name = fmt::format("{}_h{:.3f}ms", cfg.mesh, 1e3 * cfg.h_s);
    co.show_progress = false;
    for (const auto kind : {sim::ComplianceKind::kWarped, sim::ComplianceKind::kRest,
                            sim::ComplianceKind::kUncoupled}) {
      models.push_back(sim::makeCompliance(kind, body, co));
    }
  }
  for (auto& model : models) {
    model->update(body);
    Eigen::MatrixXd w = Eigen::MatrixXd::Zero(m, m);
    model->addW(rows, w);
    run.w_error[complianceName(model->kind())].push_back((w - w_exact).norm() /
                                                         w_exact.norm());
  }
}

SimRun runSim(const Options& o, const sim::SceneSpec& base, const SimConfig& cfg,
              double duration_s, bool probe_w = false) {
  const sim::SceneSpec spec =
      configure(o, base, cfg.mesh, cfg.h_s, cfg.compliance, cfg.tol, cfg.sweeps);
  SimRun run;
  run.cfg = cfg;
  const auto t_setup = SteadyClock::now();
  sim::Simulation sim(spec);
  run.setup_s = secondsSince(t_setup);
  run.tets = static_cast<int>(sim.tissue(0).mesh().tets.size());
  run.nodes = sim.tissue(0).nodeCount();
  const long steps = std::lround(duration_s / cfg.h_s);
  std::vector<std::unique_ptr<sim::TissueCompliance>> probe_models;
  double probe_s = 0.0;
  const long probe_every = std::max(1L, std::lround(0.1 / cfg.h_s));
  const auto t_run = SteadyClock::now();
  for (long k = 0; k < steps; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    const sim::StepReport r = sim.step();
    if (!r.finite) {
      throw NumericalError(fmt::format("{}: step {}: the state became non-finite", cfg.key(), k));
    }
    const sim::ContactProblemData& p = sim.lastProblem();
    run.t.push_back(sim.time());
    run.force.push_back(contactWrench(p, p.f.data(), p.tool_pose.pos_m).head<3>());
    run.energy.push_back(sim.totalEnergy());
    const double gap = sim.geometricMinGap();
    run.penetration.push_back(std::isfinite(gap) ? std::max(0.0, -gap) : 0.0);
    run.complementarity.push_back(r.complementarity);
    run.step_s.push_back(r.times.total_s);
    if (r.contacts > 0) {
      run.solve_s.push_back(r.times.solve_s);
      run.wbuild_s.push_back(r.times.w_build_s);
      run.nsgs_error.push_back(r.nsgs.error);
      run.contacts.push_back(r.contacts);
      run.sweeps.push_back(r.nsgs.sweeps);
      if (probe_w && k % probe_every == 0) {
        const auto tp = SteadyClock::now();
        probeCompliance(o, sim, cfg, probe_models, run);
        probe_s += secondsSince(tp);
      }
    }
  }
  run.wall_s = secondsSince(t_run) - probe_s;
  return run;
}

struct Errors {
  double force_rel_rms = 0.0;
  double force_peak_n = 0.0;
  double early_rel_rms = 0.0;              // over t <= early_until_s
  double early_peak_n = 0.0;
  double force_ref_peak_n = 0.0;
  double energy_dev_rel = 0.0;
};

// Linear interpolation of a run's series at time t (clamped at the ends).
template <class T>
T sampleAt(const std::vector<double>& ts, const std::vector<T>& v, double t) {
  if (t <= ts.front()) return v.front();
  if (t >= ts.back()) return v.back();
  const auto it = std::lower_bound(ts.begin(), ts.end(), t);
  const std::size_t i = static_cast<std::size_t>(it - ts.begin());
  if (std::abs(ts[i] - t) < 1e-12) return v[i];
  const double u = (t - ts[i - 1]) / (ts[i] - ts[i - 1]);
  return (1.0 - u) * v[i - 1] + u * v[i];
}

Errors compare(const SimRun& run, const SimRun& ref, double early_until_s) {
  Errors e;
  double num = 0.0, den = 0.0, num_early = 0.0, den_early = 0.0;
  double e_min = std::numeric_limits<double>::infinity(), e_max = -e_min, e_dev = 0.0;
  // the reference's samples inside the run's span (a coarser run is interpolated)
  for (std::size_t i = 0; i < ref.t.size(); ++i) {
    const double t = ref.t[i];
    if (t < run.t.front() - 1e-12 || t > run.t.back() + 1e-12) continue;
    const Eigen::Vector3d f = sampleAt(run.t, run.force, t);
    const double d = (f - ref.force[i]).norm();
    num += d * d;
    den += ref.force[i].squaredNorm();
    e.force_peak_n = std::max(e.force_peak_n, d);
    if (t <= early_until_s + 1e-12) {
      num_early += d * d;
      den_early += ref.force[i].squaredNorm();
      e.early_peak_n = std::max(e.early_peak_n, d);
    }
    e.force_ref_peak_n = std::max(e.force_ref_peak_n, ref.force[i].norm());
    e_min = std::min(e_min, ref.energy[i]);
    e_max = std::max(e_max, ref.energy[i]);
    e_dev = std::max(e_dev, std::abs(sampleAt(run.t, run.energy, t) - ref.energy[i]));
  }
  e.force_rel_rms = den > 0.0 ? std::sqrt(num / den) : 0.0;
  e.early_rel_rms = den_early > 0.0 ? std::sqrt(num_early / den_early) : 0.0;
  e.energy_dev_rel = e_max > e_min ? e_dev / (e_max - e_min) : 0.0;
  return e;
}

struct SimRow {
  std::string study;
  std::string label;
  const SimRun* run = nullptr;
  const SimRun* ref = nullptr;
};

// ------------------------------------------------------------------------------------------
// part 2: the haptic local model

struct Tremor {
  double amp_m = 0.0;
  double freq_hz = 6.0;
  Eigen::Vector3d dir = Eigen::Vector3d(0.5, 0.3, 0.8).normalized();
};

// The device: the scripted target plus a sinusoidal tremor (position and its velocity).
sim::DeviceTarget deviceAt(const sim::Simulation& sim, const Tremor& tr, double t_s) {
  sim::DeviceTarget d = sim.scriptedTarget(t_s);
  const double w = 2.0 * M_PI * tr.freq_hz;
  d.pose.pos_m += tr.amp_m * std::sin(w * t_s) * tr.dir;
  d.twist.head<3>() += tr.amp_m * w * std::cos(w * t_s) * tr.dir;
  return d;
}

struct WindowState {
  std::vector<Eigen::VectorXd> q, v;
  shared::Pose tool_pose;
  double opening = 1.0;
};

void seed(sim::Simulation& sim, const WindowState& s) {
  for (int i = 0; i < sim.tissueCount(); ++i) {
    sim.tissue(i).positions() = s.q[static_cast<std::size_t>(i)];
    sim.tissue(i).velocities() = s.v[static_cast<std::size_t>(i)];
  }
  sim.instrument()->reset(s.tool_pose, s.opening);
}

// One tick series (reference or local model) over the window.
struct TickSeries {
  std::vector<Eigen::Vector3d> force;      // per tick
  std::vector<double> penetration;         // linearised: max(0, -min delta_n) [m]
  std::vector<double> complementarity;     // max |f_n delta_n| [N m]
  std::vector<double> time_s;              // per tick (local: the tick; reference: the step)
  std::vector<double> sweeps, residual;
  std::vector<bool> valid;
  std::vector<Eigen::Vector3d> device_pos;  // reference only: x_h(t_j) [m]

  // a tick with no snapshot to compare (before the first arrives, after the last one's span)
  void pushInvalid() {
    force.push_back(Eigen::Vector3d::Zero());
    penetration.push_back(0.0);
    complementarity.push_back(0.0);
    time_s.push_back(0.0);
    sweeps.push_back(0.0);
    residual.push_back(0.0);
    valid.push_back(false);
  }
};

struct HapticRow {
  std::string kind;                        // reference | local | hold
  double rate_hz = 0.0;
  double sim_h_s = 0.0;
  int sweeps = 0;
  TickSeries series;
};

struct LocalModel {
  int budget = 0;                          // sweeps per tick (0: hold)
  double tol = 1e-6;
  shared::NsgsWorkspace ws;
  std::vector<double> f, df, delta;
  long snapshot = -1;
};

// One tick of the local model on `p` (a copy of the snapshot) at device pose x_h, mirroring
// HapticLoop::solveLocalModel without the safety chain. Returns the force; fills metrics.
void localTick(LocalModel& lm, const sim::ContactProblemData& p, long snapshot,
               const shared::Pose& x_h, TickSeries& out) {
  const int m = p.rows;
  const auto t0 = SteadyClock::now();
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  int sweeps = 0;
  if (m > 0) {
    if (lm.snapshot != snapshot) {
      // a new snapshot: warm start from the simulation's forces
      lm.snapshot = snapshot;
      std::copy_n(p.f.data(), m, lm.f.begin());
    }
    const shared::Vector6d dx = shared::poseDifference(x_h, p.device_pose);
    for (int r = 0; r < m; ++r) lm.df[r] = p.delta_free[r] + p.J.row(r).dot(dx);
    shared::ContactProblemView view = p.view();
    view.delta_free = lm.df.data();
    if (lm.budget > 0) {
      shared::NsgsSettings ns;
      ns.tolerance = lm.tol;
      ns.max_sweeps = lm.budget;
      ns.time_budget_ns = 0;
      const shared::NsgsResult res = shared::solveNsgs(view, ns, lm.ws, lm.f.data());
      if (res.status == shared::NsgsStatus::kNonFinite) std::fill_n(lm.f.begin(), m, 0.0);
      sweeps = res.sweeps;
    }
    force = contactWrench(p, lm.f.data(), p.tool_pose.pos_m + dx.head<3>()).head<3>();
  }
  out.time_s.push_back(secondsSince(t0));
  out.force.push_back(force);
  out.sweeps.push_back(sweeps);
  // metrics outside the timed part
  double pen = 0.0, comp = 0.0, res = 0.0;
  if (m > 0) {
    shared::ContactProblemView view = p.view();
    view.delta_free = lm.df.data();
    res = shared::naturalMapError(view, lm.f.data(), lm.delta.data());
    for (int c = 0; c < p.contacts; ++c) {
      const int r0 = p.row_offset[c];
      pen = std::max(pen, -lm.delta[r0]);
      comp = std::max(comp, std::abs(lm.delta[r0] * lm.f[r0]));
    }
  }
  out.penetration.push_back(pen);
  out.complementarity.push_back(comp);
  out.residual.push_back(res);
  out.valid.push_back(true);
}

struct HapticPlan {
  std::string mesh = "liver2";
  std::vector<double> rates_hz;
  std::vector<int> budgets;
  std::vector<double> sim_h_s;
  double t0_s = 2.0;
  double window_s = 1.0;
};

// Runs the window for every rate, budget and simulation step.
std::vector<HapticRow> runHaptic(const Options& o, const HapticPlan& plan) {
  const sim::SceneSpec base = meshScene(o, plan.mesh);
  const sim::ComplianceKind scene_kind = base.tissues.at(0).compliance;
  const sim::ComplianceKind ref_kind = o.haptic_ref_compliance == "scene"
                                           ? scene_kind
                                           : parseCompliance(o.haptic_ref_compliance);
  Tremor tremor;
  tremor.amp_m = 1e-3 * o.tremor_mm;
  tremor.freq_hz = o.tremor_hz;
  const double h_scene = base.time_step_s;

  // prefix at the scene's step up to t0 (scripted device, no tremor before t0)
  spdlog::info("haptic: prefix 0 .. {} s", plan.t0_s);
  WindowState state;
  {
    sim::Simulation sim(configure(o, base, plan.mesh, h_scene, scene_kind,
                                  base.solver.nsgs_tolerance, base.solver.nsgs_max_sweeps));
    const long steps = std::lround(plan.t0_s / h_scene);
    Tremor still;
    still.amp_m = 0.0;
    for (long k = 0; k < steps; ++k) {
      sim.setDeviceTarget(deviceAt(sim, still, sim.time()));
      sim.step();
    }
    for (int i = 0; i < sim.tissueCount(); ++i) {
      state.q.push_back(sim.tissue(i).positions());
      state.v.push_back(sim.tissue(i).velocities());
    }
    state.tool_pose = sim.instrument()->pose();
    state.opening = sim.instrument()->gripperOpening();
  }

  std::vector<HapticRow> rows;
  for (const double rate : plan.rates_hz) {
    const double dt = 1.0 / rate;
    const long ticks = std::lround(plan.window_s * rate);
    // reference: the full model re-simulated at every tick
    spdlog::info("haptic: reference at {} Hz ({} steps)", rate, ticks);
    HapticRow ref;
    ref.kind = "reference";
    ref.rate_hz = rate;
    ref.sim_h_s = dt;
    {
      sim::Simulation sim(configure(o, base, plan.mesh, dt, ref_kind, o.ref_tolerance,
                                    o.ref_sweeps));
      seed(sim, state);
      for (long j = 0; j < ticks; ++j) {
        const double t = plan.t0_s + static_cast<double>(j) * dt;
        sim.setDeviceTarget(deviceAt(sim, tremor, t));
        const sim::StepReport r = sim.step();
        if (!r.finite) throw NumericalError(fmt::format("haptic reference {} Hz diverged", rate));
        const sim::ContactProblemData& p = sim.lastProblem();
        ref.series.force.push_back(contactWrench(p, p.f.data(), p.tool_pose.pos_m).head<3>());
        ref.series.penetration.push_back(r.max_penetration_m);
        ref.series.complementarity.push_back(r.complementarity);
        ref.series.time_s.push_back(r.times.total_s);
        ref.series.sweeps.push_back(r.nsgs.sweeps);
        ref.series.residual.push_back(r.nsgs.error);
        ref.series.valid.push_back(true);
        ref.series.device_pos.push_back(deviceAt(sim, tremor, t).pose.pos_m);
      }
    }
    rows.push_back(std::move(ref));

    for (const double h_sim : plan.sim_h_s) {
      const long n = std::lround(h_sim * rate);
      if (n < 1 || std::abs(static_cast<double>(n) - h_sim * rate) > 1e-9) {
        throw Error(fmt::format("haptic: the simulation step {} ms is not a multiple of the tick "
                                "{} ms",
                                1e3 * h_sim, 1e3 * dt));
      }
      // the multi-rate model: one simulation, every budget on its snapshots
      std::vector<LocalModel> models(plan.budgets.size());
      std::vector<HapticRow> local(plan.budgets.size());
      for (std::size_t b = 0; b < plan.budgets.size(); ++b) {
        const int cap_rows = 3 * base.solver.max_contacts;
        models[b].budget = plan.budgets[b];
        models[b].tol = base.haptics.nsgs_tolerance;
        models[b].ws.reserve(cap_rows, base.solver.max_contacts);
        models[b].f.assign(static_cast<std::size_t>(cap_rows), 0.0);
        models[b].df.assign(static_cast<std::size_t>(cap_rows), 0.0);
        models[b].delta.assign(static_cast<std::size_t>(cap_rows), 0.0);
        local[b].kind = plan.budgets[b] == 0 ? "hold" : "local";
        local[b].rate_hz = rate;
        local[b].sim_h_s = h_sim;
        local[b].sweeps = plan.budgets[b];
      }
      sim::Simulation sim(configure(o, base, plan.mesh, h_sim, scene_kind,
                                    base.solver.nsgs_tolerance, base.solver.nsgs_max_sweeps));
      seed(sim, state);
      const long sim_steps = ticks / n;
      const long lat = o.latency_steps;
      // ticks before the first snapshot arrives are not compared
      for (auto& row : local) {
        for (long j = 0; j < std::min(ticks, lat * n); ++j) {
          row.series.pushInvalid();
        }
      }
      for (long k = 0; k < sim_steps; ++k) {
        const double t_k = plan.t0_s + static_cast<double>(k) * h_sim;
        sim.setDeviceTarget(deviceAt(sim, tremor, t_k));
        const sim::StepReport r = sim.step();
        if (!r.finite) throw NumericalError("haptic multi-rate simulation diverged");
        const sim::ContactProblemData snap = sim.lastProblem();
        for (long j = (k + lat) * n; j < std::min(ticks, (k + lat + 1) * n); ++j) {
          const double t = plan.t0_s + static_cast<double>(j) * dt;
          const shared::Pose x_h = deviceAt(sim, tremor, t).pose;
          for (std::size_t b = 0; b < models.size(); ++b) {
            localTick(models[b], snap, k, x_h, local[b].series);
          }
        }
      }
      for (auto& row : local) {
        // pad to the reference's length (ticks after the last snapshot's span)
        while (static_cast<long>(row.series.force.size()) < ticks) {
          row.series.pushInvalid();
        }
        rows.push_back(std::move(row));
      }
    }
  }
  return rows;
}

// ------------------------------------------------------------------------------------------
// output

std::string fmtG(double v) { return fmt::format("{:.6g}", v); }

void writeSimCsv(const fs::path& file, const std::vector<SimRow>& rows, double early_until_s) {
  std::ofstream out(file);
  if (!out) throw Error("cannot write " + file.string());
  out << "study,label,mesh,tets,h_ms,compliance,nsgs_tol,nsgs_max_sweeps,is_reference,reference,"
         "steps,force_rel_rms,force_peak_err_n,force_ref_peak_n,force_rel_rms_early,"
         "force_peak_err_early_n,max_penetration_mm,"
         "complementarity_max_nm,nsgs_error_max,energy_dev_rel,step_ms_median,"
         "solve_ms_median,wbuild_ms_median,contacts_median,sweeps_median,setup_s,wall_s\n";
  for (const SimRow& row : rows) {
    const SimRun& r = *row.run;
    const bool is_ref = row.run == row.ref;
    const Errors e = compare(r, *row.ref, early_until_s);
    const double pen = r.penetration.empty()
                           ? 0.0
                           : *std::max_element(r.penetration.begin(), r.penetration.end());
    const double comp = r.complementarity.empty() ? 0.0
                                                  : *std::max_element(r.complementarity.begin(),
                                                                      r.complementarity.end());
    out << row.study << ',' << row.label << ',' << r.cfg.mesh << ',' << r.tets << ','
        << fmtG(1e3 * r.cfg.h_s) << ',' << complianceName(r.cfg.compliance) << ','
        << fmtG(r.cfg.tol) << ',' << r.cfg.sweeps << ',' << (is_ref ? 1 : 0) << ','
        << fmt::format("{}/h{}ms/{}/tol{:.0e}", row.ref->cfg.mesh, 1e3 * row.ref->cfg.h_s,
                       complianceName(row.ref->cfg.compliance), row.ref->cfg.tol)
        << ',' << r.t.size() << ',' << fmtG(e.force_rel_rms) << ',' << fmtG(e.force_peak_n)
        << ',' << fmtG(e.force_ref_peak_n) << ',' << fmtG(e.early_rel_rms) << ','
        << fmtG(e.early_peak_n) << ',' << fmtG(1e3 * pen) << ',' << fmtG(comp) << ','
        << fmtG(r.nsgs_error.empty()
                    ? 0.0
                    : *std::max_element(r.nsgs_error.begin(), r.nsgs_error.end()))
        << ',' << fmtG(e.energy_dev_rel) << ','
        << fmtG(1e3 * median(r.step_s)) << ',' << fmtG(1e3 * median(r.solve_s)) << ','
        << fmtG(1e3 * median(r.wbuild_s)) << ',' << fmtG(median(r.contacts)) << ','
        << fmtG(median(r.sweeps)) << ',' << fmtG(r.setup_s) << ',' << fmtG(r.wall_s) << '\n';
  }
}

void writeHapticCsv(const fs::path& file, const std::vector<HapticRow>& rows,
                    const HapticPlan& plan) {
  std::ofstream out(file);
  if (!out) throw Error("cannot write " + file.string());
  out << "kind,mesh,rate_hz,sim_h_ms,sweeps_per_tick,is_reference,ticks_compared,force_rel_rms,"
         "force_peak_err_n,force_ref_peak_n,max_penetration_mm,complementarity_max_nm,"
         "residual_median,work_ref_mj,work_dev_mj,tick_us_median,sweeps_median\n";
  std::map<double, const HapticRow*> refs;
  for (const HapticRow& r : rows) {
    if (r.kind == "reference") refs[r.rate_hz] = &r;
  }
  for (const HapticRow& r : rows) {
    const HapticRow& ref = *refs.at(r.rate_hz);
    const bool is_ref = &r == &ref;
    double num = 0.0, den = 0.0, peak = 0.0, ref_peak = 0.0, pen = 0.0, comp = 0.0;
    double work = 0.0, work_ref = 0.0;  // [J]
    long compared = 0;
    std::vector<double> times, sweeps, resid;
    // ticks compared: those every row of this rate has (the latest first-snapshot tick)
    long first = 0;
    for (const HapticRow& other : rows) {
      if (other.rate_hz != r.rate_hz) continue;
      long j = 0;
      while (j < static_cast<long>(other.series.valid.size()) &&
             !other.series.valid[static_cast<std::size_t>(j)])
        ++j;
      first = std::max(first, j);
    }
    const long n = static_cast<long>(r.series.force.size());
    for (long j = first; j < n; ++j) {
      const auto i = static_cast<std::size_t>(j);
      if (!r.series.valid[i] || !ref.series.valid[i]) continue;
      ++compared;
      const double d = (r.series.force[i] - ref.series.force[i]).norm();
      num += d * d;
      den += ref.series.force[i].squaredNorm();
      peak = std::max(peak, d);
      ref_peak = std::max(ref_peak, ref.series.force[i].norm());
      pen = std::max(pen, r.series.penetration[i]);
      comp = std::max(comp, r.series.complementarity[i]);
      times.push_back(r.series.time_s[i]);
      sweeps.push_back(r.series.sweeps[i]);
      resid.push_back(r.series.residual[i]);
      // work of the force on the hand over the tick's device motion: F_j . (x_{j+1} - x_j)
      if (j + 1 < n) {
        const Eigen::Vector3d dp = ref.series.device_pos[i + 1] - ref.series.device_pos[i];
        work += r.series.force[i].dot(dp);
        work_ref += ref.series.force[i].dot(dp);
      }
    }
    out << r.kind << ',' << plan.mesh << ',' << fmtG(r.rate_hz) << ',' << fmtG(1e3 * r.sim_h_s)
        << ',' << r.sweeps << ',' << (is_ref ? 1 : 0) << ',' << compared << ','
        << fmtG(den > 0.0 ? std::sqrt(num / den) : 0.0) << ',' << fmtG(peak) << ','
        << fmtG(ref_peak) << ',' << fmtG(1e3 * pen) << ',' << fmtG(comp) << ','
        << fmtG(median(resid)) << ',' << fmtG(1e3 * work_ref) << ','
        << fmtG(1e3 * (work - work_ref))
        << ',' << fmtG(1e6 * median(times)) << ',' << fmtG(median(sweeps)) << '\n';
  }
}

// Long-format time series for the report's figures: series,t_s,fx,fy,fz.
void writeSeries(std::ofstream& out, const std::string& name, const std::vector<double>& t,
                 const std::vector<Eigen::Vector3d>& f, const std::vector<bool>* valid = nullptr) {
  for (std::size_t i = 0; i < t.size(); ++i) {
    if (valid != nullptr && !(*valid)[i]) continue;
    out << name << ',' << fmt::format("{:.5f}", t[i]) << ',' << fmtG(f[i].x()) << ','
        << fmtG(f[i].y()) << ',' << fmtG(f[i].z()) << '\n';
  }
}

struct SimPlan {
  std::string main_mesh = "liver2";
  std::vector<std::string> meshes;
  double duration_s = 8.0;
  std::vector<sim::ComplianceKind> compliances;
  std::vector<double> tolerances;          // warped, sweep cap = reference's
  std::vector<int> budgets;                // warped, tolerance 1e-12 (the budget binds)
  std::vector<double> time_steps_s;        // besides the scene's
};

class RunCache {
 public:
  RunCache(const Options& o, double duration_s) : o_(o), duration_s_(duration_s) {}
  const SimRun& get(const sim::SceneSpec& base, const SimConfig& cfg, double duration_s = 0.0,
                    bool probe_w = false) {
    auto it = runs_.find(cfg.key());
    if (it != runs_.end()) return *it->second;
    fmt::print("  run {:<10} h {:>5.1f} ms  {:<9}  tol {:.0e}  sweeps {:>5} ... ", cfg.mesh,
               1e3 * cfg.h_s, complianceName(cfg.compliance), cfg.tol, cfg.sweeps);
    std::fflush(stdout);
    auto run = std::make_unique<SimRun>(
        runSim(o_, base, cfg, duration_s > 0.0 ? duration_s : duration_s_, probe_w));
    fmt::print("{:.1f} s (set-up {:.1f} s), step median {:.2f} ms\n", run->wall_s, run->setup_s,
               1e3 * median(run->step_s));
    std::fflush(stdout);
    const SimRun& ref = *run;
    runs_.emplace(cfg.key(), std::move(run));
    return ref;
  }

 private:
  const Options& o_;
  double duration_s_;
  std::map<std::string, std::unique_ptr<SimRun>> runs_;
};

std::string tolLabel(double tol) { return fmt::format("{:.0e}", tol); }

int run(Options& o) {
  const auto t_all = SteadyClock::now();
  const bool quick = o.mode == "quick";
  SimPlan sp;
  HapticPlan hp;
  if (quick) {
    // under 2 minutes: the coarse liver, a short span, one point per axis
    sp.main_mesh = "liver";
    sp.meshes = {"liver"};
    sp.duration_s = 3.5;
    sp.compliances = {sim::ComplianceKind::kExact, sim::ComplianceKind::kWarped,
                      sim::ComplianceKind::kRest, sim::ComplianceKind::kUncoupled};
    sp.tolerances = {1e-3};
    sp.budgets = {10};
    sp.time_steps_s = {0.02};
    hp.mesh = "liver";
    hp.rates_hz = {500.0, 1000.0};
    hp.budgets = {0, 10};
    hp.sim_h_s = {0.01};
    hp.t0_s = 2.6;
    hp.window_s = 0.3;
  } else {
    sp.main_mesh = "liver2";
    sp.meshes = {"liver", "liver2"};
    if (o.with_23k) sp.meshes.push_back("liver_23k");
    sp.duration_s = 8.0;
    sp.compliances = {sim::ComplianceKind::kExact, sim::ComplianceKind::kWarped,
                      sim::ComplianceKind::kRest, sim::ComplianceKind::kUncoupled};
    sp.tolerances = {1e-2, 1e-3, 1e-4, 1e-6, 1e-8};
    sp.budgets = {3, 10, 30, 100};
    sp.time_steps_s = {0.0025, 0.005, 0.02};
    hp.mesh = "liver2";
    hp.rates_hz = {500.0, 1000.0, 2000.0, 4000.0};
    hp.budgets = {0, 1, 3, 10, 40};
    hp.sim_h_s = {0.01, 0.02};
    hp.t0_s = 2.0;
    hp.window_s = 2.5;
  }
  if (o.duration_s > 0.0) sp.duration_s = o.duration_s;
  if (o.haptic_t0_s > 0.0) hp.t0_s = o.haptic_t0_s;
  if (o.haptic_window_s > 0.0) hp.window_s = o.haptic_window_s;
  fs::create_directories(o.out);
  fs::create_directories(o.cache_dir);

  // ---- part 1: the simulation step
  fmt::print("part 1: simulation step ({} s of the script per run)\n", sp.duration_s);
  RunCache cache(o, sp.duration_s);
  std::vector<SimRow> rows;
  std::map<std::string, sim::SceneSpec> bases;
  for (const std::string& m : sp.meshes) bases[m] = meshScene(o, m);
  const sim::SceneSpec& main_base = bases.at(sp.main_mesh);
  const double h_main = main_base.time_step_s;
  const double scene_tol = main_base.solver.nsgs_tolerance;
  const int scene_sweeps = main_base.solver.nsgs_max_sweeps;
  const SimRun* main_ref = nullptr;
  std::vector<const SimRun*> w_probes;
  for (const std::string& m : sp.meshes) {
    const sim::SceneSpec& base = bases.at(m);
    // liver_23k (opt-in): ~0.4 s per step here, so a shorter span and no second exact run
    const bool big = m == "liver_23k";
    const double dur = big ? o.duration_23k_s : 0.0;
    const SimRun& ref = cache.get(base, {m, h_main, sim::ComplianceKind::kExact, o.ref_tolerance,
                                         o.ref_sweeps}, dur, true);
    w_probes.push_back(&ref);
    if (m == sp.main_mesh) main_ref = &ref;
    rows.push_back({"compliance", "reference", &ref, &ref});
    for (const sim::ComplianceKind k : sp.compliances) {
      if (big && k == sim::ComplianceKind::kExact) continue;
      const SimRun& r = cache.get(base, {m, h_main, k, scene_tol, scene_sweeps}, dur);
      rows.push_back({"compliance", complianceName(k), &r, &ref});
    }
  }
  for (const double tol : sp.tolerances) {
    const SimRun& r = cache.get(main_base, {sp.main_mesh, h_main, sim::ComplianceKind::kWarped,
                                            tol, o.ref_sweeps});
    rows.push_back({"tolerance", "tol " + tolLabel(tol), &r, main_ref});
  }
  for (const int b : sp.budgets) {
    const SimRun& r = cache.get(main_base, {sp.main_mesh, h_main, sim::ComplianceKind::kWarped,
                                            1e-12, b});
    rows.push_back({"sweeps", fmt::format("{} sweeps", b), &r, main_ref});
  }
  {
    std::vector<double> hs = sp.time_steps_s;
    hs.push_back(h_main);
    std::sort(hs.begin(), hs.end());
    hs.erase(std::unique(hs.begin(), hs.end()), hs.end());
    const SimRun& ref = cache.get(main_base, {sp.main_mesh, hs.front(),
                                              sim::ComplianceKind::kExact, o.ref_tolerance,
                                              o.ref_sweeps});
    for (const double h : hs) {
      const SimRun& ex = cache.get(main_base, {sp.main_mesh, h, sim::ComplianceKind::kExact,
                                               o.ref_tolerance, o.ref_sweeps});
      rows.push_back({"time_step", &ex == &ref ? "reference" : fmt::format("exact h {} ms",
                                                                           1e3 * h),
                      &ex, &ref});
      const SimRun& wa = cache.get(main_base, {sp.main_mesh, h, sim::ComplianceKind::kWarped,
                                               scene_tol, scene_sweeps});
      rows.push_back({"time_step", fmt::format("warped h {} ms", 1e3 * h), &wa, &ref});
    }
  }
  writeSimCsv(o.out / "sim_accuracy.csv", rows, o.early_until_s);
  {
    std::ofstream w(o.out / "w_accuracy.csv");
    w << "mesh,tets,compliance,samples,w_rel_err_median,w_rel_err_max\n";
    for (const SimRun* r : w_probes) {
      for (const auto& [name, v] : r->w_error) {
        w << r->cfg.mesh << ',' << r->tets << ',' << name << ',' << v.size() << ','
          << fmtG(median(v)) << ',' << fmtG(v.empty() ? 0.0 : *std::max_element(v.begin(),
                                                                                 v.end()))
          << '\n';
      }
    }
  }
  {
    std::ofstream ts(o.out / "sim_timeseries.csv");
    ts << "series,t_s,fx_n,fy_n,fz_n\n";
    for (const SimRow& r : rows) {
      if (r.study != "compliance" || r.run->cfg.mesh != sp.main_mesh) continue;
      writeSeries(ts, r.label, r.run->t, r.run->force);
    }
  }
  const double part1_s = secondsSince(t_all);

  // ---- part 2: the haptic local model
  fmt::print("part 2: haptic local model ({} mesh, window {} .. {} s, rates {}, sweeps per tick "
             "{})\n",
             hp.mesh, hp.t0_s, hp.t0_s + hp.window_s, fmt::join(hp.rates_hz, "/"),
             fmt::join(hp.budgets, "/"));
  const auto t_h = SteadyClock::now();
  const std::vector<HapticRow> hrows = runHaptic(o, hp);
  writeHapticCsv(o.out / "haptic_accuracy.csv", hrows, hp);
  {
    std::ofstream ts(o.out / "haptic_timeseries.csv");
    ts << "series,t_s,fx_n,fy_n,fz_n\n";
    const double rate = hp.rates_hz.size() > 1 ? hp.rates_hz[1] : hp.rates_hz[0];
    for (const HapticRow& r : hrows) {
      if (r.rate_hz != rate) continue;
      if (r.kind != "reference" && std::abs(r.sim_h_s - hp.sim_h_s.front()) > 1e-12) continue;
      std::vector<double> t(r.series.force.size());
      for (std::size_t j = 0; j < t.size(); ++j) t[j] = hp.t0_s + static_cast<double>(j) / rate;
      const std::string name = r.kind == "reference" ? "reference"
                               : r.kind == "hold"    ? "hold"
                                                     : fmt::format("local {} sweeps", r.sweeps);
      writeSeries(ts, name, t, r.series.force, &r.series.valid);
    }
  }
  const double part2_s = secondsSince(t_h);

  // ---- meta
  {
    std::ofstream meta(o.out / "meta.csv");
    const std::time_t now = std::time(nullptr);
    char date[64];
    std::strftime(date, sizeof date, "%Y-%m-%d %H:%M", std::localtime(&now));
    meta << "key,value\n"
         << "date," << date << '\n'
         << "mode," << o.mode << '\n'
         << "machine," << "loaded 2-core VM (shared with other builds; timings are indicative)\n"
         << "sim_duration_s," << sp.duration_s << '\n'
         << "sim_main_mesh," << sp.main_mesh << '\n'
         << "early_until_s," << o.early_until_s << '\n'
         << "reference_tolerance," << o.ref_tolerance << '\n'
         << "reference_max_sweeps," << o.ref_sweeps << '\n'
         << "scene_tolerance," << scene_tol << '\n'
         << "scene_max_sweeps," << scene_sweeps << '\n'
         << "haptic_mesh," << hp.mesh << '\n'
         << "haptic_t0_s," << hp.t0_s << '\n'
         << "haptic_window_s," << hp.window_s << '\n'
         << "haptic_latency_steps," << o.latency_steps << '\n'
         << "haptic_tolerance," << bases.begin()->second.haptics.nsgs_tolerance << '\n'
         << "haptic_reference_compliance," << o.haptic_ref_compliance << '\n'
         << "tremor_mm," << o.tremor_mm << '\n'
         << "tremor_hz," << o.tremor_hz << '\n'
         << "with_23k," << (o.with_23k ? 1 : 0) << '\n'
         << "duration_23k_s," << o.duration_23k_s << '\n'
         << "part1_s," << fmtG(part1_s) << '\n'
         << "part2_s," << fmtG(part2_s) << '\n'
         << "total_s," << fmtG(secondsSince(t_all)) << '\n';
  }
  fmt::print("done in {:.0f} s (simulation step {:.0f} s, haptic {:.0f} s); CSV in {}\n",
             secondsSince(t_all), part1_s, part2_s, o.out.string());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"tactus-accuracy: accuracy against time of the contact pipeline (compliance "
               "model, NSGS tolerance and sweeps, time step, mesh) and of the haptic local model "
               "(rate, sweeps per tick), each against a reference computed in the same run. "
               "Writes sim_accuracy.csv, haptic_accuracy.csv, *_timeseries.csv and meta.csv."};
  Options o;
  bool quick = false;
  std::string root;
#ifdef TACTUS_SOURCE_DIR
  root = TACTUS_SOURCE_DIR;
#endif
  std::string out, cache;
  app.add_option("--out", out, "Output directory for the CSV files")->required();
  app.add_flag("--quick", quick, "Quick mode (< 2 min): coarse liver, short spans, few points");
  app.add_flag("--with-23k", o.with_23k,
               "Add liver_23k to the mesh study (precomputes a 1.6 GB warped compliance; slow)");
  app.add_option("--root", root, "Repository root (scenes/ is read from it)")
      ->capture_default_str();
  app.add_option("--cache-dir", cache,
                 "Compliance cache directory (default: <root>/.cache/accuracy)");
  app.add_option("--duration", o.duration_s, "Seconds of the script per simulation run "
                                             "(default: 8 full, 3.5 quick)");
  app.add_option("--duration-23k", o.duration_23k_s,
                 "Seconds of the script per liver_23k run (--with-23k)")
      ->capture_default_str();
  app.add_option("--early-until", o.early_until_s,
                 "End of the second force-error window [s] (the grasp and the start of the lift, "
                 "before the exact reference's grasp slips)")
      ->capture_default_str();
  app.add_option("--ref-tolerance", o.ref_tolerance, "NSGS tolerance of the references")
      ->capture_default_str();
  app.add_option("--ref-sweeps", o.ref_sweeps, "NSGS sweep cap of the references")
      ->capture_default_str();
  app.add_option("--haptic-t0", o.haptic_t0_s, "Start of the haptic window [s] (default: 2 full, "
                                               "2.6 quick)");
  app.add_option("--haptic-window", o.haptic_window_s,
                 "Length of the haptic window [s] (default: 2.5 full, 0.3 quick)");
  app.add_option("--latency-steps", o.latency_steps,
                 "Simulation periods between a step's device sample and its snapshot's use")
      ->capture_default_str()
      ->check(CLI::Range(0, 10));
  app.add_option("--tremor-mm", o.tremor_mm, "Tremor amplitude added to the device path [mm]")
      ->capture_default_str();
  app.add_option("--tremor-hz", o.tremor_hz, "Tremor frequency [Hz]")->capture_default_str();
  app.add_option("--haptic-ref-compliance", o.haptic_ref_compliance,
                 "Compliance of the haptic reference: scene (the scene's model, isolating the "
                 "multi-rate error) or exact, warped, rest, uncoupled")
      ->capture_default_str();
  app.add_option("--log-level", o.log_level, "spdlog level")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}))
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::from_str(o.log_level));
  o.mode = quick ? "quick" : "full";
  o.out = out;
  o.root = root;
  o.cache_dir = cache.empty() ? o.root / ".cache/accuracy" : fs::path(cache);
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tactus-accuracy: %s\n", e.what());
    return 1;
  }
}
