// VTK frames and the .pvd series of a run.
#include "output_writer.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>

#include "tactus/sim/fem.h"
#include "tactus/sim/vtk_writer.h"

namespace tactus::sim {

bool OutputWriter::writeIfDue(Simulation& sim) {
  const SceneSpec& spec = sim.spec();
  const OutputSpec& out = spec.output;
  if (!out.enabled) return false;
  if (sim.stepIndex() % std::max(1, out.every_n_steps) != 0) return false;
  const std::filesystem::path dir = out.directory;
  std::filesystem::create_directories(dir);
  bool any_fixed = false;
  for (int t = 0; t < sim.tissueCount(); ++t) {
    const std::vector<bool>& fixed = sim.tissue(t).fixedMask();
    any_fixed = any_fixed || std::find(fixed.begin(), fixed.end(), true) != fixed.end();
  }
  ReactionForces reactions;
  if (any_fixed || sim.hasContactProblem()) reactions = sim.reactions();
  for (int t = 0; t < sim.tissueCount(); ++t) {
    const FemBody& body = sim.tissue(t);
    const Eigen::VectorXd& q = body.positions();
    const int n = body.nodeCount();
    Eigen::Matrix3Xd pos = Eigen::Map<const Eigen::Matrix3Xd>(q.data(), 3, n);
    Eigen::Matrix3Xd disp =
        pos - Eigen::Map<const Eigen::Matrix3Xd>(body.restPositions().data(), 3, n);
    Eigen::VectorXd vm;
    body.vonMises(vm);
    Eigen::VectorXd volume_ratio;
    body.volumeRatios(volume_ratio);
    const std::string file =
        fmt::format("{}_{:06d}.vtu", spec.tissues[static_cast<std::size_t>(t)].name, frame_);
    std::vector<NamedPointVectors> forces;
    if (static_cast<std::size_t>(t) < reactions.tissues.size()) {
      const TissueReactions& r = reactions.tissues[static_cast<std::size_t>(t)];
      forces.emplace_back("reaction_force", r.fixed_reaction_n);
      forces.emplace_back("contact_force", r.contact_force_n);
    }
    writeVtu(dir / file, body.mesh(), pos, disp, vm, volume_ratio, forces);
    files_.push_back(file);
    times_s_.push_back(sim.time());
  }
  ++frame_;
  writePvd(dir / "series.pvd", files_, times_s_);
  return true;
}

void OutputWriter::finish(const SceneSpec& spec) const {
  const OutputSpec& out = spec.output;
  if (!out.enabled || files_.empty()) return;
  writePvd(out.directory / "series.pvd", files_, times_s_);
  spdlog::info("VTK series: {} ({} frames)", (out.directory / "series.pvd").string(), frame_);
}

}  // namespace tactus::sim
