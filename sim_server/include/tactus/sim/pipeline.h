#pragma once
// The simulation pipeline built from a scene (paper 3.1; docs/design.md section 2). One step is
// the paper's stages, each a named function timed under its own name (StageTimes):
//
//   freeMotion (tissues, instrument) -> detectCollisions -> updateCompliance (C ~ R C0 R^T)
//   -> buildW (rows H, W = H C H^T) -> solveContacts (NSGS) -> constrainedMotion
//   -> [publish snapshot] -> [VTK output]
//
// Only the stages a scene calls for are constructed: no collision, W or solve without an
// instrument; no tangential rows when friction is zero; no rotation extraction for linear
// materials; no damping terms without damping; no VTK writer without output. `stages()` lists
// what will run and the server prints it at start.

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "tactus/shared/messages.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/pose.h"
#include "tactus/shared/segment.h"
#include "tactus/sim/collision.h"
#include "tactus/sim/reactions.h"
#include "tactus/sim/scene.h"
#include "tactus/types.h"

namespace tactus::sim {

class FemBody;
class TissueCompliance;
class Instrument;
struct SimulationModel;

// The step's plain data are the public API's (tactus/types.h): DeviceTarget, StageTimes,
// StepReport, InstrumentProblemData, ContactProblem (here ContactProblemData).
using tactus::DeviceTarget;
using tactus::InstrumentProblemData;
using tactus::StageTimes;
using tactus::StepReport;
using ContactProblemData = tactus::ContactProblem;

/// Counters that prove absent effects cost nothing.
struct PipelineCounters {
  long steps = 0;
  long collision_queries = 0;
  long w_builds = 0;
  long solves = 0;
  long tangential_rows = 0;
  long rotation_extractions = 0;     ///< summed over tissues
  long damping_evaluations = 0;      ///< summed over tissues
};

class Simulation {
 public:
  /// Builds everything the scene calls for (meshes, FEM, compliance precomputation, collision
  /// structures, instrument). Throws tactus::Error subclasses with clear messages.
  explicit Simulation(const SceneSpec& spec);
  /// The same from a model built once (buildModel, simulation_model.h) and shared by several
  /// simulations (tactus::Model).
  explicit Simulation(std::shared_ptr<const SimulationModel> model);
  ~Simulation();
  Simulation(const Simulation&) = delete;
  Simulation& operator=(const Simulation&) = delete;

  const SceneSpec& spec() const;
  /// Human-readable list of the stages this scene runs (printed at start).
  std::vector<std::string> stages() const;

  /// Sets the device target of instrument 0 for the next steps (device sample or scripted
  /// trajectory).
  void setDeviceTarget(const DeviceTarget& target);
  /// The same for instrument i (0 <= i < instrumentCount()).
  void setDeviceTarget(int i, const DeviceTarget& target);
  /// The scripted target at time t (the scene's trajectory; the initial pose if none) of
  /// instrument 0, or of instrument i.
  DeviceTarget scriptedTarget(double t_s) const;
  DeviceTarget scriptedTarget(int i, double t_s) const;
  bool hasInstrument() const;
  int instrumentCount() const;
  /// The scene has a contact problem each step (an instrument, obstacles or tissue contact).
  bool hasContactProblem() const;
  /// The target instrument i follows (after setDeviceTarget's checks).
  const DeviceTarget& deviceTarget(int i) const;
  /// The contact wrench on instrument i of the last step [force_n; torque_nm] (zero before the
  /// first step and after restoreState).
  shared::Vector6d contactWrench(int i) const;

  /// Advances one time step.
  StepReport step();

  double time() const;
  long stepIndex() const;
  int tissueCount() const;
  FemBody& tissue(int i);
  const FemBody& tissue(int i) const;
  /// Tissue i's compliance model, its state (the warped model's rotations) that of the last
  /// step's free state. A step without contact rows leaves the update to the first call that
  /// needs it (a later pass's rows, this, saveState), which then makes it at that free state.
  TissueCompliance* compliance(int i);
  /// Instrument 0 (nullptr without one), or instrument i.
  Instrument* instrument();
  Instrument& instrument(int i);
  const Instrument& instrument(int i) const;
  const ContactProblemData& lastProblem() const;
  /// The contacts of tissue i found by the last collision query of the last step (empty
  /// without an instrument or before the first step).
  std::span<const Contact> contacts(int i) const;
  const PipelineCounters& counters() const;

  /// Smallest gap [m] between the instrument and the tissues at the current (corrected) state,
  /// by a fresh collision query (negative: penetration; +inf when nothing is within the alarm
  /// distance). For tests and diagnostics: costs a refit and a query per tissue.
  double geometricMinGap();

  /// Reactions at the fixed nodes, contact force per obstacle and from the instrument, at the
  /// current state with the last step's contact forces (reactions.h). Costs one elastic-force
  /// evaluation per tissue with fixed nodes.
  ReactionForces reactions();

  /// Sum over tissues and the instrument of kinetic + elastic + gravity energy [J].
  double totalEnergy() const;
  /// Force the god object's coupling applies to the hand (what a device renders) [N, N m]: of
  /// instrument 0, or of instrument i.
  Eigen::Matrix<double, 6, 1> renderedWrench() const;
  Eigen::Matrix<double, 6, 1> renderedWrench(int i) const;

  /// The state: everything a step changes and the next step reads (time, step index, device
  /// targets, per tissue q, v, the element rotations, A, the factor of record and what it was
  /// computed from, the warm starts of the linear solve, the compliance's rotations, the
  /// collision memory; the god objects; the warm-start forces by contact id), as bytes with a
  /// header tying them to this model (docs/design.md, "State: copy, save, restore").
  std::string saveState() const;
  /// Continues from a state saveState() returned for this model: the steps that follow give the
  /// same bits as those that followed the save. The outputs of the last step (lastProblem(),
  /// contacts(), the contact forces in reactions()) are cleared until the next step. Throws
  /// StateError naming `source` (a state of another model, another format version, truncated
  /// or corrupt bytes); the simulation is then left as it was.
  void restoreState(std::string_view bytes, const std::string& source = "state");
  /// What a model's state is tied to: the scene's text, the time step, each tissue's placed rest
  /// mesh and fixed nodes (FNV-1a).
  std::uint64_t modelIdentity() const;


 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Format of Simulation::saveState's bytes: "TACTSTAT", this version (u32), the model name's
/// length (u32), the model identity (u64), the step index (i64), the time (f64), the model name,
/// then the state's fields (state_archive.h). A state of another version is refused.
/// Version 2 added a FemBody's flag of a contact solve in its last step and a running background
/// job's weighed age (FemSolverOptions::background_refactor_free_lag_steps).
inline constexpr std::uint32_t kStateFormatVersion = 2;

/// The header of a saved state.
struct StateHeader {
  std::uint32_t version = 0;
  std::uint64_t model_identity = 0;
  long step = 0;
  double t_s = 0.0;
  std::string model_name;        ///< the scene it was saved from (its file, or the name given)
  std::size_t body_offset = 0;   ///< where the fields start
};

/// Reads and checks the header (magic, version, sizes). Throws StateError naming `source`.
StateHeader readStateHeader(std::string_view bytes, const std::string& source);

/// The capacity a published contact problem needs: max_contacts per instrument plus the
/// obstacles' per tissue and the contacts between tissues, 3 rows per contact when an
/// instrument, an obstacle or a tissue pair has friction (devices: 1; the callers set one per
/// instrument). sim_server's segment and every tool that publishes snapshots use it.
shared::SegmentCapacity problemCapacity(const SceneSpec& spec);

/// Writes the last step's contact problem into a snapshot slot (what sim_server publishes each
/// step; also used by tests and tools that run the haptic loop beside an in-process simulation).
/// `max_opening_rad` maps the jaw opening to the gripper angle reported in the poses. Returns
/// false (and writes an empty problem without kSnapshotValid, which the haptic side treats as
/// stale) when the problem exceeds the slot's capacity.
bool writeSnapshot(const Simulation& sim, double max_opening_rad, std::uint64_t seq,
                   std::int64_t t_ns, std::uint64_t device_seq, shared::SnapshotWriter& slot);

}  // namespace tactus::sim
