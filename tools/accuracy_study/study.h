#pragma once
// tactus-accuracy: accuracy against computing time of the contact pipeline and of the haptic
// local model (README "Accuracy against time"). Headless, deterministic, single-threaded; writes
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
// Part 2, the haptic local model (haptic_study.cpp, paper 4.2). A prefix run at the scene's time
// step brings the scene to the window start t0; its state (tissue q, v; tool pose and opening)
// seeds every run of the window, so all start identical. The device follows the scripted
// trajectory plus a small tremor. The reference at haptic rate r is a Simulation with time step
// 1/r driven by the device at every tick (the full model re-simulated per tick). The multi-rate
// model is a Simulation at the scene's time step whose snapshot k (device pose x_h(t_k)) serves
// the ticks of [t_k + L h, t_k + (L + 1) h) (L = --latency-steps, 1: the step computed during one
// period is rendered during the next); each tick moves delta_free = delta_free* + J (x_h [-] x_h*)
// and re-solves with warm-started NSGS under a sweep budget exactly as
// HapticLoop::solveLocalModel does (time budget off, so results do not depend on the machine's
// load). Budget 0 is the zero-order hold of the snapshot's force (no local model).
//
// The tool links the simulation and the haptic loop, so it lives in tools/, apart from both
// processes' rooms.

#include <Eigen/Core>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "tactus/shared/pose.h"
#include "tactus/sim/compliance.h"
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
  double duration_s = 0.0;                 ///< 0: per mode
  double early_until_s = 3.5;              ///< second error window: t <= this [s]
  double duration_23k_s = 3.5;             ///< span of the liver_23k runs [s]
  double ref_tolerance = 1e-9;
  int ref_sweeps = 3000;
  double haptic_t0_s = 0.0;                ///< 0: per mode
  double haptic_window_s = 0.0;            ///< 0: per mode
  int latency_steps = 1;
  double tremor_mm = 0.5;
  double tremor_hz = 6.0;
  std::string haptic_ref_compliance = "scene";
  std::string log_level = "warn";
};

// ---- common pieces (study_common.cpp)

/// Median of v (upper median for even sizes); 0 for an empty vector.
double median(std::vector<double> v);
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

// ---- part 2: the haptic local model (haptic_study.cpp)

/// One tick series (reference or local model) over the window.
struct TickSeries {
  std::vector<Eigen::Vector3d> force;      ///< per tick [N]
  std::vector<double> penetration;         ///< linearised: max(0, -min delta_n) [m]
  std::vector<double> complementarity;     ///< max |f_n delta_n| [N m]
  std::vector<double> time_s;              ///< per tick (local: the tick; reference: the step)
  std::vector<double> sweeps, residual;
  std::vector<bool> valid;
  std::vector<Eigen::Vector3d> device_pos;  ///< reference only: x_h(t_j) [m]

  /// A tick with no snapshot to compare (before the first arrives, after the last one's span).
  void pushInvalid();
};

struct HapticRow {
  std::string kind;                        ///< reference | local | hold
  double rate_hz = 0.0;
  double sim_h_s = 0.0;
  int sweeps = 0;
  TickSeries series;
};

struct HapticPlan {
  std::string mesh = "liver2";
  std::vector<double> rates_hz;
  std::vector<int> budgets;
  std::vector<double> sim_h_s;
  double t0_s = 2.0;
  double window_s = 1.0;
};

/// Runs the window for every rate, budget and simulation step.
std::vector<HapticRow> runHaptic(const Options& o, const HapticPlan& plan);
/// haptic_accuracy.csv's text.
std::string hapticCsv(const std::vector<HapticRow>& rows, const HapticPlan& plan);

}  // namespace tactus::study
