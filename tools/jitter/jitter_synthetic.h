#pragma once
// Synthetic mode of the jitter tool: no device, no simulation. A private segment receives
// synthetic contact snapshots of m rows at a simulation-like rate, and the real HapticLoop
// (tactus::haptic) re-solves them every period on a pinned real-time thread, driven by a
// scripted in-process device. The stats ring of that segment is then read exactly as in attach
// mode, so the solver's share of the tick can be seen for a chosen problem size.
//
// The synthetic problem imitates what the simulation publishes for a grasper pressing a liver:
// nc = m / 3 frictional contacts (3 rows each, mu ~ 0.5) spread over a 2 cm patch of a curved
// surface, W = F^T (c_t K (x) I3 + c_l I) F + J_g C_tool J_g^T, where K_ij = exp(-|p_i - p_j| / l)
// (a positive-definite kernel: tissue compliance decaying with distance), F the contact frames,
// c_l a local compliance and the last term the instrument's (god object's) compliance seen
// through the contacts' lever arms. delta_free mixes penetrating (to -1 mm) and open (to
// +0.5 mm) gaps, small tangential free slips, and drifts by a few tens of micrometres between
// publications; f is the problem's converged solution. J = d delta_free / d x_h is the
// contacts' geometric sensitivity to the tool twist times the coupling's transmission ratio.

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "jitter_rig.h"
#include "tactus/device/device.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/messages.h"
#include "tactus/shared/segment.h"

namespace tactus::haptic::jitter {

struct SyntheticProblemOptions {
  int rows = 450;                          ///< m; rounded down to a multiple of 3 (>= 3)
  double mu = 0.5;                         ///< mean friction coefficient (+-0.1 per contact)
  double compliance_m_per_n = 1e-3;        ///< c_t: tissue compliance scale
  double kernel_length_m = 0.008;          ///< l
  double local_compliance_m_per_n = 2e-4;  ///< c_l
  double patch_radius_m = 0.02;
  unsigned seed = 1;
};

/// A contact problem with the fields a ContactSnapshot carries (row-major, ld = rows).
struct SyntheticProblem {
  int contacts = 0;
  int rows = 0;
  std::vector<std::int32_t> row_offset;
  std::vector<std::uint64_t> contact_id;
  std::vector<double> mu;
  std::vector<double> W;  ///< rows x rows, row-major
  std::vector<double> delta_free;
  std::vector<double> f;                         ///< converged solution for delta_free
  std::vector<double> J;                         ///< rows x 6, row-major
  std::vector<double> point_m, normal, tangent;  ///< 3, 3 and 6 per contact
  std::vector<double> drift_phase;               ///< per contact, for the publication drift
  shared::PoseSample device_pose;                ///< x_h*
  shared::PoseSample tool_pose;
  int solve_sweeps = 0;  ///< sweeps the cold solve took
  double solve_error = 0.0;
};

/// Builds the problem and solves it (cold NSGS to 1e-8, up to 2000 sweeps). Throws tactus::Error
/// on rows < 3.
SyntheticProblem makeSyntheticProblem(const SyntheticProblemOptions& options);

/// Fills a snapshot slot with the problem, normal gaps shifted by drift_m * sin(phase_i + t).
void writeSnapshot(const SyntheticProblem& problem, shared::SnapshotWriter slot, std::uint64_t seq,
                   double t_s, double drift_m);

struct SyntheticOptions : LoopRunOptions {
  SyntheticProblemOptions problem;
  double sim_rate_hz = 100.0;          ///< snapshot publication rate
  double drift_m = 2e-5;               ///< amplitude of the gap drift between publications
};

/// The synthetic set-up: private segment, snapshot publisher thread, haptic loop thread
/// (jitter_rig.h), the device circling about the problem's device pose.
class SyntheticRig {
 public:
  /// Builds the problem, creates the segment "tactus-jitter-<pid>-<n>" and publishes the first
  /// snapshot. Throws tactus::Error subclasses.
  explicit SyntheticRig(const SyntheticOptions& options);
  SyntheticRig(const SyntheticRig&) = delete;
  SyntheticRig& operator=(const SyntheticRig&) = delete;

  /// Starts the publisher and the real-time haptic thread; returns once the latter is set up.
  void start();
  /// Stops both threads (idempotent).
  void stop() { rig_.stop(); }

  const shared::Segment& segment() const { return rig_.segment(); }
  const SyntheticProblem& problem() const { return problem_; }
  std::int64_t periodNs() const { return rig_.periodNs(); }
  int core() const { return rig_.core(); }
  /// What the real-time set-up refused (empty: pinned, SCHED_FIFO, memory locked).
  const std::string& rtSummary() const { return rig_.rtSummary(); }
  HapticLoop& loop() { return rig_.loop(); }
  std::uint64_t published() const { return rig_.published(); }

 private:
  void publish(double t_s);

  SyntheticOptions options_;
  SyntheticProblem problem_;
  std::int64_t t0_ns_ = 0;
  LoopRig rig_;
};

}  // namespace tactus::haptic::jitter
