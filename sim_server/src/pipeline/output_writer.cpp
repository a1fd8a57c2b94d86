// VTK frames and the .pvd series of a run.
#include "output_writer.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>

#include "reactions_stage.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim {

bool OutputWriter::writeIfDue(const SimulationModel& model, SimulationState& state,
                              const StepScratch& scratch) {
  const OutputSpec& out = model.spec.output;
  if (!out.enabled) return false;
  if (state.step % std::max(1, out.every_n_steps) != 0) return false;
  const std::filesystem::path dir = out.directory;
  std::filesystem::create_directories(dir);
  bool any_fixed = false;
  for (const TissueModel& t : model.tissues) any_fixed = any_fixed || !t.fixed_nodes.empty();
  ReactionForces reactions;
  if (any_fixed || model.has_contacts) reactions = computeReactions(model, state, scratch);
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    const FemBody& body = *state.tissues[t].body;
    const Eigen::VectorXd& q = body.positions();
    const int n = body.nodeCount();
    Eigen::Matrix3Xd pos = Eigen::Map<const Eigen::Matrix3Xd>(q.data(), 3, n);
    Eigen::Matrix3Xd disp =
        pos - Eigen::Map<const Eigen::Matrix3Xd>(body.restPositions().data(), 3, n);
    Eigen::VectorXd vm;
    body.vonMises(vm);
    Eigen::VectorXd volume_ratio;
    body.volumeRatios(volume_ratio);
    const std::string file = fmt::format("{}_{:06d}.vtu", model.tissues[t].name, frame_);
    std::vector<NamedPointVectors> forces;
    if (t < reactions.tissues.size()) {
      forces.emplace_back("reaction_force", reactions.tissues[t].fixed_reaction_n);
      forces.emplace_back("contact_force", reactions.tissues[t].contact_force_n);
    }
    writeVtu(dir / file, body.mesh(), pos, disp, vm, volume_ratio, forces);
    files_.push_back(file);
    times_s_.push_back(state.t_s);
  }
  ++frame_;
  writePvd(dir / "series.pvd", files_, times_s_);
  return true;
}

void OutputWriter::finish(const SimulationModel& model) const {
  const OutputSpec& out = model.spec.output;
  if (!out.enabled || files_.empty()) return;
  writePvd(out.directory / "series.pvd", files_, times_s_);
  spdlog::info("VTK series: {} ({} frames)", (out.directory / "series.pvd").string(), frame_);
}

}  // namespace tactus::sim
