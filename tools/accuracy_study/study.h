#pragma once
// tactus-accuracy: accuracy against computing time of the contact pipeline and of the haptic
// local model (docs/measurements.md, "Accuracy against time"). Headless, deterministic, single-threaded; writes
// CSV files that scripts/accuracy_report.py turns into a Markdown table and a Pareto plot.
//
// Part 1, the simulation step (sim_study.cpp). Every run follows the scene's scripted grasper
// over the same span; its contact force on the instrument, total energy, geometric penetration
// (Simulation::geometricMinGap after each step) and complementarity residual are recorded per
// step. The reference of a mesh is a run with the exact compliance and a tight NSGS tolerance at
// the scene's time step (the time-step study uses a reference at the finest step instead).
// Errors: contact force relative RMS sqrt(sum |F - F_ref|^2 / sum |F_ref|^2) and peak
// max |F - F_ref| over the reference's sample times (linear interpolation of the run), energy
// deviation max |E - E_ref| / (max E_ref - min E_ref).
//
// Part 2, the haptic loop (haptic_study.cpp, paper 4.2). A prefix run at the scene's time step
// brings the scene to the window start t0 (the jaws on the lobe); its state (tissue q, v; the
// god object) seeds every run, so all start identical. The device then follows a closed motion
// (DeviceMotion: slow press, tremor, fast tap) around the scripted pose at t0. Two references,
// computed in the same run, separate the errors:
//  * R1, the local model's own error: at every tick j, the simulation's state before the step
//    whose snapshot serves j is restored into an exact simulation (exact W, direct CHOLMOD,
//    tolerance --ref-tolerance) which takes one full step (collision redone, contact passes)
//    at the simulation's time step with the device pose of tick j; its contact force is R1(j).
//    The saved state is not advanced: R1 is the problem the local model linearises, solved
//    exactly at the tick's pose.
//  * R2, the time step's: a Simulation with time step 1/rate driven by the device at every tick
//    (the full model re-simulated at the haptic rate).
// The multi-rate simulation (the scene's compliance and solver at step h) publishes snapshot k
// (device pose x_h(t_k)); it serves the ticks of [t_k + L h, t_k + (L + 1) h)
// (L = --latency-steps). Methods on those ticks: hold (the snapshot's force), extrapolate
// (F_k + (F_k - F_k-1)(t - t_k)/h), coupling (a virtual-coupling spring to the snapshot's god
// object, F = K_c (p_god - x_h) + B_c (v_god - v_h) with the scene's coupling gains, re-evaluated
// every tick: the CHAI3D-style proxy) and the local model (delta_free = delta_free* +
// J (x_h [-] x_h*) and warm-started NSGS under a sweep budget, as HapticLoop::solveLocalModel,
// time budget off so results do not depend on the machine's load). haptic_report.cpp turns the
// series into errors against R1 and R2, stiffness felt, penetration, energy and time per tick.
//
// The tool links the simulation and the haptic loop, so it lives in tools/, apart from both
// processes' rooms.

#include <Eigen/Core>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "tactus/shared/pose.h"
#include "tactus/sim/compliance.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/scene.h"

namespace tactus::study {

namespace fs = std::filesystem;

/// Command-line options (see main.cpp's --help).
struct Options {
  std::string mode = "full";               ///< quick | full
  fs::path out;                            ///< output folder of the CSV files
  fs::path root;                           ///< repository root (scenes/)
  fs::path cache_dir;                      ///< compliance caches
  bool overwrite = false;                  ///< replace CSV files an earlier run left in `out`
  bool with_23k = false;
  std::string part = "all";                ///< all | sim | states | haptic
  /// exact_below_coherence of the bounded warped model in the state comparison
  double coherence_bound = 0.9995;
  double duration_s = 0.0;                 ///< 0: per mode
  double early_until_s = 3.5;              ///< second error window: t <= this [s]
  double duration_23k_s = 3.5;             ///< span of the liver_23k runs [s]
  double ref_tolerance = 1e-9;
  int ref_sweeps = 3000;
  double haptic_t0_s = 0.0;                ///< 0: per mode
  int latency_steps = 1;
  double tremor_mm = 0.5;
  double tremor_hz = 8.0;
  std::string log_level = "warn";
};

// ---- common pieces (study_common.cpp)

/// Median of v (nearest rank: the lower median for even sizes, tactus/shared/percentiles.h); 0
/// for an empty vector.
double median(const std::vector<double>& v);
const char* complianceName(sim::ComplianceKind k);
/// "exact" | "warped" | "rest" | "uncoupled"; throws tactus::Error otherwise.
sim::ComplianceKind parseCompliance(const std::string& s);
/// "%.6g" of v, the CSV files' number format.
std::string fmtG(double v);

/// The scene of a mesh: liver2 is the paper's scene (scenes/liver_grasp.yaml), liver_23k its
/// 23k-tet twin, liver the coarse SOFA liver (596 tets) placed onto liver2 by a similarity fit
/// (ICP on the nodes; its lobe tip moved onto liver2's so the same script grasps it). Haptics
/// and output off.
sim::SceneSpec meshScene(const Options& o, const std::string& mesh);

/// A configuration of the simulation step.
struct SimConfig {
  std::string mesh;
  double h_s = 0.01;
  sim::ComplianceKind compliance = sim::ComplianceKind::kWarped;
  double tol = 1e-6;
  int sweeps = 300;
  /// Identity of the configuration (runs are cached by it).
  std::string key() const;
};

/// `base` with the time step, compliance model and NSGS settings of a configuration; the
/// approximate models cache their C0 per mesh and time step in o.cache_dir.
sim::SceneSpec configure(const Options& o, const sim::SceneSpec& base, const std::string& mesh,
                         double h_s, sim::ComplianceKind kind, double tol, int sweeps);

/// Contact force and torque on the instrument from the problem's forces `f` and frames, as the
/// haptic loop computes them (torque about `origin`).
shared::Vector6d contactWrench(const sim::ContactProblemData& p, const double* f,
                               const Eigen::Vector3d& origin);

/// Long-format time series for the report's figures: lines "series,t_s,fx,fy,fz" appended to
/// `out` (ticks with valid[i] false are left out).
void appendSeries(std::string& out, const std::string& name, const std::vector<double>& t,
                  const std::vector<Eigen::Vector3d>& f, const std::vector<bool>* valid = nullptr);

/// Writes one output file of the study into o.out through the checked writer (temporary file,
/// fsync, rename; an existing file is replaced only with o.overwrite). Throws FileError.
void writeOutput(const Options& o, const std::string& name, const std::string& text);

// ---- part 1: the simulation step (sim_study.cpp)

/// The per-step record of one simulation run.
struct SimRun {
  SimConfig cfg;
  int tets = 0;
  int nodes = 0;
  double setup_s = 0.0;
  double wall_s = 0.0;
  std::vector<double> t;                   ///< end time of each step [s]
  std::vector<Eigen::Vector3d> force;      ///< contact force on the instrument [N]
  std::vector<double> energy, penetration, complementarity;
  std::vector<double> step_s, solve_s, wbuild_s, nsgs_error, contacts, sweeps;
  /// W = H C H^T of each approximate model against the exact one, on the same rows, at states
  /// of this (exact) run: relative Frobenius error per sample, by model name
  std::map<std::string, std::vector<double>> w_error;
};

/// W = H C H^T of the warped, rest and uncoupled models against the exact W of `sim` (an exact
/// simulation, after a step) on rows x, y, z at the 24 free surface nodes nearest the tool; the
/// relative Frobenius errors are appended to run.w_error by model name. `models` is built on
/// first use (C0 cached in o.cache_dir).
void probeCompliance(const Options& o, sim::Simulation& sim, const SimConfig& cfg,
                     std::vector<std::unique_ptr<sim::TissueCompliance>>& models, SimRun& run);

/// Runs `cfg` over duration_s of the scene's script; with probe_w, every 0.1 s of contact the
/// compliance models are compared with the run's own W (probeCompliance).
SimRun runSim(const Options& o, const sim::SceneSpec& base, const SimConfig& cfg,
              double duration_s, bool probe_w = false);

/// Errors of a run against a reference run (see the header comment).
struct Errors {
  double force_rel_rms = 0.0;
  double force_peak_n = 0.0;
  double early_rel_rms = 0.0;              ///< over t <= early_until_s
  double early_peak_n = 0.0;
  double force_ref_peak_n = 0.0;
  double energy_dev_rel = 0.0;
};
Errors compare(const SimRun& run, const SimRun& ref, double early_until_s);

/// One line of sim_accuracy.csv: a run and its reference.
struct SimRow {
  std::string study;
  std::string label;
  const SimRun* run = nullptr;
  const SimRun* ref = nullptr;
};
/// sim_accuracy.csv's text.
std::string simCsv(const std::vector<SimRow>& rows, double early_until_s);

// ---- saved states (compliance_states.cpp)

/// Everything a step of the pipeline starts from: tissue q, v and the god object (NSGS's warm
/// start aside, which a tight tolerance makes irrelevant; a kCholmod body keeps no factor between
/// steps).
struct SavedState {
  std::vector<Eigen::VectorXd> q, v;
  std::unique_ptr<sim::Instrument> tool;
};
void save(sim::Simulation& sim, SavedState& s);
void restore(sim::Simulation& sim, const SavedState& s);
/// The exact reference configuration: exact W, direct CHOLMOD every step, NSGS at
/// o.ref_tolerance.
sim::SceneSpec referenceSpec(const Options& o, const sim::SceneSpec& base, const std::string& mesh,
                             double h_s);

// ---- part 1b: compliance models on the same states (compliance_states.cpp)

/// One sampled state of the exact reference trajectory; per model (StateComparison::models).
struct StateRow {
  double t_s = 0.0;                        ///< start of the step
  int contacts = 0;
  double force_exact_n = 0.0;
  double normal_sum_n = 0.0;               ///< sum of the exact solve's normal forces
  std::vector<double> w_err;               ///< ||W_m - W_exact||_F / ||W_exact||_F, whole problem
  std::vector<double> force_err;           ///< |F_m - F_exact| / |F_exact|
  std::vector<double> probe_w_err;         ///< tissue W on the probe rows (probeCompliance)
  std::vector<double> step_s, wbuild_s;    ///< the probe step's times
  std::vector<bool> fallback;              ///< the bounded model used the exact W
  int inverted_near = 0;                   ///< inverted elements at the probe nodes
  double min_det_near = 1.0;
  double min_coherence_near = 1.0;         ///< |sum v_e R_e|_F / (sqrt 3 sum v_e), 1: coherent
};

/// Compliance models compared on the same states: one exact reference run (referenceSpec, the
/// scene's script and contact passes); every `every_steps` steps in contact its pre-step state is
/// restored into one simulation per model (exact, warped, warped_bounded (warped with
/// exact_below_coherence = o.coherence_bound), rest, uncoupled; one contact pass),
/// which steps with the same device target: the same contacts, rows and delta_free, only W
/// differs. Per state and model: the problem's W error, the contact force error against the
/// exact model's, the probe's tissue W error, the step's times, and diagnostics of the elements
/// at the nodes nearest the tool.
struct StateComparison {
  std::string mesh;
  std::vector<std::string> models;         ///< models[0] = exact
  std::vector<StateRow> rows;
  int skipped = 0;                         ///< states whose probes assembled different rows
};
StateComparison compareStates(const Options& o, const sim::SceneSpec& base,
                              const std::string& mesh, double duration_s, int every_steps);
/// w_states.csv's text.
std::string statesCsv(const StateComparison& sc);

// ---- part 2: the haptic loop (haptic_study.cpp runs it, haptic_report.cpp measures it)

/// A closed device motion relative to the anchor pose (the scripted pose at the window start):
/// still for lead_in_s, then the motion, which starts and ends at zero offset. Deterministic.
///  * slow_press: raised cosine 0 -> amplitude -> 0 along `dir` (into the tissue) over motion_s
///  * tremor:     amplitude sin(2 pi freq t) along `dir` (oblique), whole cycles
///  * fast_tap:   raised cosine press and release along `dir` over motion_s (tens of ms)
struct DeviceMotion {
  std::string name;
  double lead_in_s = 0.1;
  double motion_s = 1.0;
  double tail_s = 0.05;                    ///< still after the motion
  double amplitude_m = 3e-3;
  double freq_hz = 0.0;                    ///< tremor only
  Eigen::Vector3d dir = Eigen::Vector3d::UnitX();
  double duration_s() const { return lead_in_s + motion_s + tail_s; }
  Eigen::Vector3d offset(double t_s) const;      ///< t_s from the window start [m]
  Eigen::Vector3d velocity(double t_s) const;    ///< d offset / dt [m/s]
};

/// What one rendering method gives the hand at every tick of a case.
struct MethodSeries {
  std::string method;                      ///< r1 | r2 | hold | extrapolate | coupling | local
  std::string label;                       ///< for tables and plots
  int sweeps = 0;                          ///< local: sweeps per tick (budget)
  std::vector<Eigen::Vector3d> force;      ///< contact force on the tool = force on the hand [N]
  /// linearised penetration of the tool the method renders: max(0, -min delta_n) [m]
  std::vector<double> penetration;
  std::vector<double> time_s;              ///< per tick (r1, r2: the full step)
  std::vector<bool> valid;
  void push(const Eigen::Vector3d& f, double pen, double t_s);
  void pushInvalid();
};

/// One device motion at one haptic rate and one simulation step: R1, R2 and every method.
struct HapticCase {
  std::string motion;
  double rate_hz = 1000.0;
  double sim_h_s = 0.01;
  /// W of the multi-rate simulation's snapshots: "scene" (the scene's model) or "exact"
  /// (isolates the local model's linearisation from the compliance model's error)
  std::string snapshot_w = "scene";
  /// ticks before this are not measured: R2 starts stepping at 1/rate from a state the scene's
  /// step left, a transient of a few ms (half the motion's still lead-in)
  double settle_s = 0.05;
  std::vector<Eigen::Vector3d> device_pos; ///< x_h(t_j) per tick [m]
  std::vector<long> snapshot;              ///< per tick: the snapshot serving it (-1: none)
  std::vector<MethodSeries> series;        ///< series[0] = R1, series[1] = R2
};

struct HapticPlan {
  std::string mesh = "liver2";
  double t0_s = 3.0;                       ///< window start on the scene's script
  std::vector<DeviceMotion> motions;
  /// (haptic rate [Hz], simulation step [s]) pairs; the step a multiple of the tick
  std::vector<std::pair<double, double>> rates;
  /// the first this many pairs once more with exact-W snapshots (HapticCase::snapshot_w)
  int exact_snapshot_pairs = 1;
  std::vector<int> budgets;                ///< local model sweeps per tick; <= 0: converged
  int replay_steps = 20;                   ///< steps of the R1 replay check
};

/// Consistency of R1 (restoring a saved state into the reference simulation and stepping it):
/// an exact simulation run along the first motion, each of its steps replayed from the saved
/// pre-step state with the same device target; the largest force difference relative to the
/// largest force.
struct ReplayCheck {
  int steps = 0;
  double max_rel_diff = 0.0;
  double max_force_n = 0.0;
};

/// Runs every motion at every (rate, step) pair; fills `replay`.
std::vector<HapticCase> runHaptic(const Options& o, const HapticPlan& plan, ReplayCheck& replay);
/// haptic_accuracy.csv's text (haptic_report.cpp; the metrics are described there).
std::string hapticCsv(const std::vector<HapticCase>& cases, const std::string& mesh);
/// Force series of one case in long format (haptic_timeseries.csv).
std::string hapticSeries(const HapticCase& c, double t0_s);

}  // namespace tactus::study
