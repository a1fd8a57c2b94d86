// The scene's scripted instrument trajectory, interpolated between keyframes.
#include "simulation_impl.h"

namespace tactus::sim {

DeviceTarget scriptedTarget(const InstrumentSpec& in, double t_s) {
  DeviceTarget out;
  out.pose = toPose(in.initial_pose);
  out.gripper_opening = 1.0;
  const auto& keys = in.trajectory;
  if (keys.empty()) return out;
  if (t_s <= keys.front().t_s || keys.size() == 1) {
    out.pose = toPose(keys.front().pose);
    out.gripper_opening = keys.front().gripper_opening;
    return out;
  }
  if (t_s >= keys.back().t_s) {
    out.pose = toPose(keys.back().pose);
    out.gripper_opening = keys.back().gripper_opening;
    return out;
  }
  std::size_t i = 1;
  while (keys[i].t_s < t_s) ++i;
  const TrajectoryKey& a = keys[i - 1];
  const TrajectoryKey& b = keys[i];
  const double dt = b.t_s - a.t_s;
  const double u = dt > 0.0 ? (t_s - a.t_s) / dt : 1.0;
  const shared::Pose pa = toPose(a.pose);
  const shared::Pose pb = toPose(b.pose);
  out.pose = shared::interpolate(pa, pb, u);
  out.gripper_opening = (1.0 - u) * a.gripper_opening + u * b.gripper_opening;
  if (dt > 0.0) out.twist = shared::poseDifference(pb, pa) / dt;
  return out;
}

DeviceTarget Simulation::scriptedTarget(double t_s) const {
  return sim::scriptedTarget(impl_->model.spec.instrument, t_s);
}

DeviceTarget Simulation::scriptedTarget(int i, double t_s) const {
  return sim::scriptedTarget(instrumentSpec(impl_->model.spec, i), t_s);
}

}  // namespace tactus::sim
