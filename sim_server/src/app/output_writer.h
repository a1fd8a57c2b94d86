#pragma once
// The VTK output of a run (scene key output; an application part of sim_server, tactus::sim_app):
// one .vtu per tissue every output.every_n_steps steps (positions, displacement, von Mises stress,
// volume ratio; with fixed nodes or contacts the per-node "reaction_force" and "contact_force" of
// reactions.h) and the series.pvd that lists them by time. Outside the physics (the reactions
// refresh the element rotations only).

#include <string>
#include <vector>

#include "tactus/sim/pipeline.h"

namespace tactus::sim {

class OutputWriter {
 public:
  /// Writes the frame of the simulation's current state when its scene enables output and the
  /// step is due; returns whether it wrote one.
  bool writeIfDue(Simulation& sim);
  /// Rewrites the series file at the end of the run and logs where it is.
  void finish(const SceneSpec& spec) const;
  long frames() const { return frame_; }

 private:
  std::vector<std::string> files_;   ///< every .vtu written, relative to the output directory
  std::vector<double> times_s_;      ///< simulated time of each
  long frame_ = 0;
};

}  // namespace tactus::sim
