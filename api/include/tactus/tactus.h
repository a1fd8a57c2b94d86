#pragma once
// Tactus as a library (docs/api.md): include this one header.
//
//   tactus::Model       a scene compiled once (model.h)
//   tactus::Simulation  its state stepped in time, read in place (simulation.h)
//   tactus::State       a state as a value: copy, compare, save, restore (state.h)
//   tactus::ContactProblem, StepReport, ReactionForces, DeviceTarget: plain data (types.h)

#include "tactus/model.h"
#include "tactus/shared/error.h"
#include "tactus/simulation.h"
#include "tactus/state.h"
#include "tactus/types.h"
