// Device <-> scene frame mapping with a clutch (docs/design.md, "Workspace mapping").
#include "tactus/haptic/workspace_mapping.h"

namespace tactus::haptic {
namespace {

Eigen::Vector3d vec(const std::array<double, 3>& a) noexcept { return {a[0], a[1], a[2]}; }

void store(const Eigen::Vector3d& v, std::array<double, 3>& a) noexcept {
  a = {v.x(), v.y(), v.z()};
}

}  // namespace

void WorkspaceMapping::configure(const shared::WorkspaceMappingParams& params) {
  params.validate();
  params_ = params;
  const auto& q = params.rotation_wxyz;
  rotation_ = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized();
  offset_m_ = vec(params.offset_m);
  bias_ = Eigen::Quaterniond::Identity();
  clutched_ = false;
  have_output_ = false;
}

void WorkspaceMapping::toScene(device::DeviceState& state) noexcept {
  const auto& qa = state.quat_wxyz;
  Eigen::Quaterniond q_device(qa[0], qa[1], qa[2], qa[3]);
  const double n = q_device.norm();
  q_device = n > 1e-9 ? Eigen::Quaterniond(q_device.coeffs() / n) : Eigen::Quaterniond::Identity();
  const Eigen::Vector3d p_rotated = params_.scale * (rotation_ * vec(state.pos_m));
  const Eigen::Quaterniond q_rotated = rotation_ * q_device;

  const bool button = params_.clutch_button >= 0 &&
                      ((state.buttons >> static_cast<unsigned>(params_.clutch_button)) & 1u) != 0;
  const bool clutch = button || clutch_request_.load(std::memory_order_relaxed);
  if (clutch && have_output_) {
    clutched_ = true;   // hold the instrument; the hand moves freely
    store(held_pos_m_, state.pos_m);
    state.quat_wxyz = {held_rot_.w(), held_rot_.x(), held_rot_.y(), held_rot_.z()};
    state.vel_mps = {};
    state.angvel_radps = {};
    return;
  }
  if (clutched_) {
    // released: re-base so that this device pose maps exactly onto the held scene pose
    offset_m_ = held_pos_m_ - p_rotated;
    bias_ = q_rotated.conjugate() * held_rot_;
    clutched_ = false;
  }
  held_pos_m_ = offset_m_ + p_rotated;
  held_rot_ = (q_rotated * bias_).normalized();
  have_output_ = true;
  clutched_ = clutch;   // a clutch held from the very first sample holds that sample's pose
  store(held_pos_m_, state.pos_m);
  state.quat_wxyz = {held_rot_.w(), held_rot_.x(), held_rot_.y(), held_rot_.z()};
  store(params_.scale * (rotation_ * vec(state.vel_mps)), state.vel_mps);
  store(rotation_ * vec(state.angvel_radps), state.angvel_radps);
  if (clutched_) {
    state.vel_mps = {};
    state.angvel_radps = {};
  }
}

void WorkspaceMapping::wrenchToDevice(std::array<double, 3>& force_n,
                                      std::array<double, 3>& torque_nm) const noexcept {
  if (clutched_) {
    force_n = {};
    torque_nm = {};
    return;
  }
  const Eigen::Quaterniond to_device = rotation_.conjugate();
  store((to_device * vec(force_n)) / params_.scale, force_n);
  store(to_device * vec(torque_nm), torque_nm);
}

}  // namespace tactus::haptic
