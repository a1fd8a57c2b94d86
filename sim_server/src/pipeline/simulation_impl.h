#pragma once
// What a Simulation holds, in the manner of MuJoCo's mjModel / mjData (simulation_model.h has
// the overview): the model a scene defines, the state a step advances, the scratch a step
// reuses, and, outside the physics, the counters.

#include <memory>

#include "simulation_model.h"
#include "simulation_state.h"
#include "step_scratch.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {

struct Simulation::Impl {
  explicit Impl(std::shared_ptr<const SimulationModel> m)
      : shared_model(std::move(m)), model(*shared_model) {}
  std::shared_ptr<const SimulationModel> shared_model;   ///< shared with tactus::Model
  const SimulationModel& model;   ///< immutable
  SimulationState state;
  StepScratch scratch;
  PipelineCounters counters;
};

/// The physics objects of the model's tissues and instrument at the scene's initial state:
/// FEM bodies, compliance models (C0 precomputed or loaded from the cache), collision trees and
/// the god object at the trajectory's first pose (simulation_build.cpp).
SimulationState buildState(const SimulationModel& model);

/// Scratch sized for the model (one TissueScratch per tissue, the NSGS workspace).
StepScratch buildScratch(const SimulationModel& model);

/// The instrument target the scene's trajectory gives at t_s: keyframes interpolated (slerp and
/// linear opening) with the twist of the segment; the initial pose without a trajectory
/// (scripted_target.cpp).
DeviceTarget scriptedTarget(const InstrumentSpec& instrument, double t_s);

}  // namespace tactus::sim
