// Tactus from your own program (docs/api.md): load a scene, drive the grasper onto the liver's
// lobe and close it for 100 steps, then read the contact forces and the reactions, and evaluate
// the haptic local model on the last contact problem with the device moved 1 mm up.
//
//   tactus_example [scene.yaml]      (default: the scenes/liver_grasp.yaml it was built with)
#include <algorithm>
#include <cstdio>
#include <exception>
#include <span>
#include <string>

#include "tactus/haptic_model.h"
#include "tactus/tactus.h"

int main(int argc, char** argv) try {
  const tactus::Model model = tactus::Model::fromFile(argc > 1 ? argv[1] : TACTUS_EXAMPLE_SCENE);
  tactus::Simulation sim(model);
  std::printf("%s: %d tissue(s), %d nodes, %d instrument(s), time step %.4g s\n",
              model.name().c_str(), model.tissueCount(), model.nodeCount(0),
              model.instrumentCount(), model.timeStep());

  // the grasper from its initial pose to where the scene's script grasps (its pose at 2 s) in
  // 60 steps, then the jaws close over 30 steps
  const tactus::DeviceTarget start = sim.scriptedTarget(0, 0.0);
  const tactus::DeviceTarget grasp = sim.scriptedTarget(0, 2.0);
  tactus::StepReport report;
  for (int k = 0; k < 100; ++k) {
    const double s = std::min(1.0, (k + 1) / 60.0);
    tactus::DeviceTarget target = grasp;
    target.pose.pos_m = (1.0 - s) * start.pose.pos_m + s * grasp.pose.pos_m;
    target.gripper_opening = k < 60 ? 1.0 : std::max(0.0, 1.0 - (k - 60) / 30.0);
    sim.setDeviceTarget(0, target);
    report = sim.step();
  }
  std::printf("after %ld steps (t = %.2f s): %d contacts, NSGS %s in %d sweeps, total normal "
              "force %.3f N\n",
              sim.stepIndex(), sim.time(), report.contacts,
              std::string(tactus::shared::toString(report.nsgs.status)).c_str(),
              report.nsgs.sweeps, report.total_normal_force_n);

  // the contact forces: per contact in its frame (f), and in world axes on the tissue
  const tactus::ContactProblem& problem = sim.lastProblem();
  Eigen::Vector3d on_tissue = Eigen::Vector3d::Zero();
  for (int c = 0; c < problem.contacts; ++c) on_tissue += problem.forceOnTissue(c);
  std::printf("contact force on the tissue (sum over %d contacts): [%.4f %.4f %.4f] N\n",
              problem.contacts, on_tissue.x(), on_tissue.y(), on_tissue.z());
  const tactus::InstrumentState tool = sim.instrument(0);
  std::printf("grasper: jaw opening %.3f, contact force on the tool [%.4f %.4f %.4f] N\n",
              tool.gripper_opening, tool.contact_wrench[0], tool.contact_wrench[1],
              tool.contact_wrench[2]);

  // what holds the liver
  const tactus::ReactionForces r = sim.reactions();
  std::printf("reactions: fixed nodes [%.4f %.4f %.4f] N, from the instrument [%.4f %.4f %.4f] N, "
              "weight [%.4f %.4f %.4f] N, imbalance %.2e N\n",
              r.fixed_total_n.x(), r.fixed_total_n.y(), r.fixed_total_n.z(),
              r.instrument_force_n.x(), r.instrument_force_n.y(), r.instrument_force_n.z(),
              r.weight_n.x(), r.weight_n.y(), r.weight_n.z(), r.imbalance_n().norm());

  // the haptic local model on this problem, as haptic_server would every millisecond
  tactus::HapticModel haptic;
  const tactus::PrepareStatus status = haptic.adopt(problem);
  const tactus::LocalModelResult here = haptic.solve();
  tactus::Pose up = problem.device_pose;
  up.pos_m.z() += 1e-3;
  const tactus::LocalModelResult lifted = haptic.solve(std::span<const tactus::Pose>(&up, 1));
  std::printf("haptic local model (%s): force on the tool [%.4f %.4f %.4f] N (%s, %d sweeps); "
              "device 1 mm up: [%.4f %.4f %.4f] N (%s)\n",
              std::string(tactus::haptic::toString(status)).c_str(), here.force_n[0][0],
              here.force_n[0][1], here.force_n[0][2],
              std::string(tactus::haptic::toString(here.used)).c_str(), here.sweeps,
              lifted.force_n[0][0], lifted.force_n[0][1], lifted.force_n[0][2],
              std::string(tactus::haptic::toString(lifted.used)).c_str());
  return report.contacts > 0 && status == tactus::PrepareStatus::kReady ? 0 : 1;
} catch (const std::exception& e) {
  std::fprintf(stderr, "tactus_example: %s\n", e.what());
  return 2;
}
