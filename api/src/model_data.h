#pragma once
// What a tactus::Model holds (not installed): the simulation library's compiled model, shared by
// the Simulations made from it, and what the public accessors return.

#include <memory>
#include <string>
#include <vector>

#include "simulation_model.h"
#include "tactus/model.h"

namespace tactus::detail {

struct ModelData {
  std::shared_ptr<const sim::SimulationModel> model;
  std::string name;
  std::uint64_t identity = 0;
  std::vector<sim::SurfaceMesh> surfaces;       ///< per tissue (the model's, or extracted)
  std::vector<std::string> instrument_names;

  const sim::TissueModel& tissue(int i) const;
};

}  // namespace tactus::detail
