#pragma once
// Test support shared by the grasp tests: the tip of liver2's right lobe in the liver_grasp
// frame (rest x > 0.088 m), whose mean height tells whether a grasp lifted it.

#include <cmath>
#include <vector>

#include "tactus/sim/fem.h"
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

/// liver_grasp's grasper and approach as they were before the flat pads (issue 15): round
/// kinematic jaws of radius 2 mm with 8 samples each, closing to 0.25, no contact compliance,
/// the hinge at x = 0.107 m (the pads go 7 mm deeper). The tests of the contact passes, the grip
/// DOF and the display were written for it.
inline void useRoundKinematicJaws(sim::SceneSpec& spec) {
  sim::InstrumentSpec& in = spec.instrument;
  in.pad_width_m = 0.0;
  in.contact_compliance_mpn = 0.0;
  in.jaw_radius_m = 0.002;
  in.jaw_samples = 8;
  in.grip_k_nmprad = 0.0;
  in.grip_b_nmsprad = 0.0;
  for (sim::TrajectoryKey& k : in.trajectory) {
    if (k.gripper_opening < 1.0) k.gripper_opening = 0.25;
    if (std::abs(k.pose.position_m.x() - 0.100) < 1e-9) k.pose.position_m.x() = 0.107;
  }
}

}  // namespace tactus::test_support
