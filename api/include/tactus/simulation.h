#pragma once
// A running simulation of a Model, in the manner of MuJoCo's mjData with mj_step (docs/api.md):
// its state and the scratch a step reuses, stepped one time step at a time (paper 3.1: free
// motion, collision detection, contact problem, NSGS, constrained motion; docs/design.md
// section 2). Instruments follow device targets you set (or the scene's script). Read the tissues'
// positions and velocities in place, the contact problem the last step solved and the reactions;
// copy the state out and back with state() / setState().
//
// Not thread-safe: one thread steps and reads a Simulation at a time. Several Simulations (of one
// Model or several) may run on separate threads.

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "tactus/model.h"
#include "tactus/state.h"
#include "tactus/types.h"

namespace tactus {

/// An instrument's god object after the last step.
struct InstrumentState {
  Pose pose;                              ///< tool point and orientation
  Vector6d twist = Vector6d::Zero();      ///< [v; w], world frame
  double gripper_opening = 1.0;           ///< jaw opening, 0 closed .. 1 open
  double grip_rate_radps = 0.0;           ///< d phi / dt of a finite grip (0: kinematic jaws)
  DeviceTarget target;                    ///< the target it followed
  /// What its coupling pulls the hand with, the wrench a device renders [force_n; torque_nm]
  Vector6d rendered_wrench = Vector6d::Zero();
  /// The contact wrench on the tool of the last step [force_n; torque_nm about the tool point]
  Vector6d contact_wrench = Vector6d::Zero();
};

class Simulation {
 public:
  /// Builds the model's tissues, compliance models (C0 precomputed, or read from the scene's
  /// compliance cache), collision structures and instruments at the scene's initial state.
  /// Throws tactus::Error subclasses with clear messages.
  explicit Simulation(const Model& model);
  ~Simulation();
  Simulation(Simulation&&) noexcept;
  Simulation& operator=(Simulation&&) noexcept;
  /// A copy is a new Simulation of the same model set to this one's state:
  /// `Simulation b(a.model()); b.setState(a.state());`
  Simulation(const Simulation&) = delete;
  Simulation& operator=(const Simulation&) = delete;

  const Model& model() const;

  /// Advances one time step (Model::timeStep()).
  StepReport step();

  /// The target instrument i follows from the next step on (0 <= i < instrumentCount()). A
  /// non-finite pose, twist or opening is not taken: the last valid target is held.
  void setDeviceTarget(int instrument, const DeviceTarget& target);
  /// The scene's scripted target of instrument i at time t_s (its initial pose without a script).
  DeviceTarget scriptedTarget(int instrument, double t_s) const;
  /// Every instrument follows the scene's script at the current time (what sim_server does
  /// without a device).
  void followScript();

  double time() const;                    ///< simulated time [s]
  long stepIndex() const;                 ///< steps taken
  int instrumentCount() const;
  InstrumentState instrument(int i) const;

  /// Node positions and velocities of a tissue, 3 x nodeCount, in place (valid until the next
  /// step or setState) [m, m/s].
  Eigen::Map<const Eigen::Matrix3Xd> positions(int tissue) const;
  Eigen::Map<const Eigen::Matrix3Xd> velocities(int tissue) const;

  /// The contact problem of the last step, its solution f included: contact points, frames,
  /// forces, W, delta_free, the devices' Jacobian J (what the haptic local model re-solves).
  /// Empty before the first step and after setState.
  const ContactProblem& lastProblem() const;
  /// Reactions at the fixed nodes, contact force per obstacle and from the instrument, at the
  /// current state with the last step's contact forces.
  ReactionForces reactions();
  /// Kinetic + elastic + gravity energy of the tissues and the instruments [J].
  double totalEnergy() const;
  /// What each step runs, one line per stage (what sim_server prints at start).
  std::vector<std::string> stages() const;

  /// The state, a copy (State: save it, compare it, restore it).
  State state() const;
  /// Continues from a state of this model: the steps that follow give the same bits as those
  /// that followed the state() call that made it. lastProblem() is empty until the next step.
  /// Throws StateError (a state of another model, another format version, corrupt); the
  /// simulation is then unchanged.
  void setState(const State& state);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tactus
