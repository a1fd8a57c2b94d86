#pragma once
// Test support shared by the grasp tests: the tip of liver2's right lobe in the liver_grasp
// frame (rest x > 0.088 m), whose mean height tells whether a grasp lifted it.

#include <vector>

#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/scene.h"

namespace tactus::test_support {

class LiverLobe {
 public:
  explicit LiverLobe(const sim::FemBody& liver) : liver_(liver) {
    for (int i = 0; i < liver.nodeCount(); ++i) {
      if (liver.restPositions()[3 * i] > 0.088) nodes_.push_back(i);
    }
  }
  /// Mean z of the lobe's nodes at the body's current positions [m].
  double meanZ() const {
    double z = 0.0;
    for (int i : nodes_) z += liver_.positions()[3 * i + 2];
    return z / static_cast<double>(nodes_.size());
  }

 private:
  const sim::FemBody& liver_;
  std::vector<int> nodes_;
};

/// liver_grasp's grasper and approach as they were before the flat pads: the tests
/// of the contact passes, the grip DOF and the display were written for it.
inline void useRoundKinematicJaws(sim::SceneSpec& spec) {
  sim::useFormerLiverGraspScript(spec);
  sim::useFormerRoundJaws(spec);
}

}  // namespace tactus::test_support
