#pragma once
// The sim_server main loop: offline (a fixed number of steps, as fast as possible) or paced to
// real time, publishing each step's contact problem to the haptic process and reading its
// device samples when the scene enables haptics.

#include <atomic>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "tactus/sim/pipeline.h"

namespace tactus::sim {

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
  /// Record every step's contact snapshot (shared/snapshot_file.h, stamped with the simulated
  /// time) to this file, for tactus-jitter --replay; written at the end of the run.
  std::string record_snapshots;
  /// The recording stops (with a warning; the run goes on) before the file passes this size
  /// [MiB]; at most 2048, what tactus-jitter --replay reads.
  int record_snapshots_max_mb = 2048;
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

/// Runs a scene until `stop`, the step count or the duration. Returns the process exit code.
int runSimulation(const RunOptions& options, const std::atomic<bool>& stop);

}  // namespace tactus::sim
