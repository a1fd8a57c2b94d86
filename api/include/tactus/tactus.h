#pragma once
// Tactus as a library (docs/api.md): include this one header.
//
//   tactus::Model        a scene compiled once (model.h)              Tactus::simulation
//   tactus::Simulation   its state stepped in time, read in place (simulation.h)
//   tactus::State        a state as a value: copy, compare, save, restore (state.h)
//   tactus::ContactProblem and NSGS on it, FCLIB and snapshot files (contact.h)
//                                                                     Tactus::contact_solver
//   tactus::HapticModel  the haptic local model on a ContactProblem (haptic_model.h)
//                                                                     Tactus::haptic_model
//   StepReport, ReactionForces, DeviceTarget, ...: plain data (types.h)
//   tactus::Error and its kinds (tactus/shared/error.h)
//   TACTUS_VERSION_STRING and its parts (version.h)

#include "tactus/contact.h"
#include "tactus/haptic_model.h"
#include "tactus/model.h"
#include "tactus/shared/error.h"
#include "tactus/simulation.h"
#include "tactus/state.h"
#include "tactus/types.h"
#include "tactus/version.h"
