#pragma once
// Running a scene: the headless runner (runHeadless: a fixed number of steps as fast as
// possible, the instruments following the scene's script) that sim_server --steps, tactus-bench
// and pad_grasp_study run scenes with; the one snapshot recorder (sim_server's
// --record-snapshots); and sim_server's loop, offline through the headless runner or paced to
// real time, publishing each step's contact problem to the haptic process and reading its device
// samples when the scene enables haptics.

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "tactus/sim/pipeline.h"

namespace tactus::shared {
class SnapshotFileWriter;
}

namespace tactus::sim {

/// Largest snapshot recording [MiB]: what tactus-jitter --replay reads
/// (shared::kMaxSnapshotFileBytes).
inline constexpr int kMaxRecordingMiB = 2048;

/// sim_server's --record-snapshots, --record-snapshots-max-mb and --record-snapshots-from-step.
struct SnapshotRecordingOptions {
  std::filesystem::path path;        ///< empty: nothing recorded
  int max_mb = kMaxRecordingMiB;     ///< 1..kMaxRecordingMiB
  bool overwrite = false;            ///< replace an existing file
  /// The first step recorded (1: every step): a part of a long run (the hold of a 23k grasp,
  /// whose whole run passes the file cap) without the steps before it.
  long first_step = 1;
};

struct RunOptions {
  std::filesystem::path scene_path;
  long steps = 0;                    ///< > 0: offline, exactly this many steps, unpaced
  double duration_s = 0.0;           ///< > 0: stop at this simulated time (else the scene's)
  std::string output_dir;            ///< overrides the scene's VTK output directory
  int output_every = 0;              ///< overrides the scene's output period (steps)
  std::string segment = "tactus";
  bool no_haptics = false;
  bool status = false;               ///< log a status line every second
  std::string stats_json;            ///< write per-stage statistics here at the end
  std::string export_trajectory;     ///< write the scripted trajectory (device CSV) and exit
  int export_instrument = 0;         ///< whose trajectory export_trajectory writes
  bool overwrite = false;            ///< replace an existing stats_json / export_trajectory file,
                                     ///< or an earlier run's VTK series in the output folder
  /// Record every step's contact snapshot to this file (SnapshotRecorder), for tactus-jitter
  /// --replay; written at the end of the run.
  std::string record_snapshots;
  /// The recording stops (with a warning; the run goes on) before the file passes this size
  /// [MiB]; at most kMaxRecordingMiB.
  int record_snapshots_max_mb = kMaxRecordingMiB;
  /// The first step recorded (1-based; SnapshotRecordingOptions::first_step).
  long record_snapshots_from_step = 1;
};

/// Writes the scene's instrument trajectory in the replay device's CSV format
/// (`t_s,x,y,z,qw,qx,qy,qz,gripper`, gripper in radians of jaw opening), sampled every
/// `dt_s`, so the simulated device can follow the same script as the simulation.
/// Written through a temporary file and renamed into place; an existing file is only replaced
/// when `overwrite`. Throws tactus::FileError on any write failure (the target is then untouched),
/// SceneError when the scene has no instrument `instrument`.
void exportTrajectory(const SceneSpec& spec, const std::filesystem::path& csv, double dt_s = 0.01,
                      bool overwrite = false, int instrument = 0);

/// Percentile summary of one stage over a run [s] (nearest rank, tactus/shared/percentiles.h).
struct StageSummary {
  std::string name;
  double median_s = 0.0;
  double p90_s = 0.0;
  double p99_s = 0.0;
  double max_s = 0.0;
  double mean_s = 0.0;
};

/// Collects per-step reports and summarises them.
class RunStatistics {
 public:
  void add(const StepReport& report);
  std::vector<StageSummary> stages() const;
  long steps() const { return static_cast<long>(total_.size()); }
  double medianContacts() const;
  double medianSweeps() const;
  int maxContacts() const;
  double maxPenetration() const { return max_penetration_m_; }
  /// Inverted tetrahedra (StepReport::inverted_elements): most in one step, and in the last.
  int maxInvertedElements() const { return max_inverted_; }
  int lastInvertedElements() const { return last_inverted_; }
  /// Fixed-width table for the console.
  std::string table() const;
  /// JSON object (stages with percentiles, contacts, sweeps) for comparison between commits.
  std::string json(const std::string& scene) const;
  /// The reactions at the end of the run (reactions.h), written into json() as "reactions".
  void setReactions(const ReactionForces& reactions) { reactions_ = reactions; }

 private:
  std::vector<double> free_motion_, detect_collisions_, update_compliance_, build_w_,
      solve_contacts_, constrained_motion_, output_, total_;
  std::vector<double> contacts_, sweeps_;
  double max_penetration_m_ = 0.0;
  int max_inverted_ = 0;
  int last_inverted_ = 0;
  std::optional<ReactionForces> reactions_;
};

/// Records every step's contact snapshot (shared/snapshot_file.h: the problem sim_server
/// publishes, stamped with the simulated time) for tactus-jitter --replay. The one recorder of the
/// project: sim_server's --record-snapshots, offline and as a daemon.
class SnapshotRecorder {
 public:
  /// Checks the target now, before the run: an existing file is refused unless
  /// options.overwrite (FileError naming --overwrite); a cap outside 1..kMaxRecordingMiB is
  /// refused (Error naming --record-snapshots-max-mb).
  SnapshotRecorder(const SceneSpec& spec, const SnapshotRecordingOptions& options);
  ~SnapshotRecorder();
  SnapshotRecorder(const SnapshotRecorder&) = delete;
  SnapshotRecorder& operator=(const SnapshotRecorder&) = delete;

  /// Appends the last step's problem (`seq`: the step's number, from 1). A scene without an
  /// instrument records nothing. At the cap the recording stops with one warning; the run goes
  /// on and the file keeps what was recorded.
  void record(const Simulation& sim, std::uint64_t seq);
  std::uint64_t count() const;
  /// Writes the file into place and logs how many snapshots it holds. Throws FileError.
  void commit();

 private:
  SnapshotRecordingOptions options_;
  double max_opening_rad_ = 0.0;
  std::unique_ptr<shared::SnapshotFileWriter> writer_;
  shared::SnapshotLayout layout_;
  std::vector<double> slot_;   // doubles: 8-byte aligned for every array of the layout
  bool full_ = false;          // the recording reached its cap and stopped
};

/// How a headless run (runHeadless) ended.
enum class RunEnd { kSteps, kStopped, kNonFinite };

/// One headless run: the step count and what each step feeds.
struct HeadlessRun {
  long steps = 0;                              ///< steps to run
  const std::atomic<bool>* stop = nullptr;     ///< polled before each step when set
  SnapshotRecorder* recorder = nullptr;        ///< each step's snapshot, when set
  RunStatistics* statistics = nullptr;         ///< each step's report, when set
  /// After each finite step (its index from 0 and its report), before the statistics take the
  /// report: the caller's own per-step figures and work (it may add its output time).
  std::function<void(long, StepReport&)> after_step;
};

struct HeadlessResult {
  long steps = 0;   ///< steps taken (a non-finite one included)
  RunEnd end = RunEnd::kSteps;
};

/// Steps `sim` headless and unpaced: before each step every instrument takes the scene's
/// scripted target at the simulated time; after it the snapshot goes to the recorder, the
/// caller's after_step runs and the statistics take the report. A step whose state became
/// non-finite ends the run (the statistics take it; it is neither recorded nor passed on).
HeadlessResult runHeadless(Simulation& sim, const HeadlessRun& run);

/// Runs a scene until `stop`, the step count or the duration. Returns the process exit code.
int runSimulation(const RunOptions& options, const std::atomic<bool>& stop);

}  // namespace tactus::sim
