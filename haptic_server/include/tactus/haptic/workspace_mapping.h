#pragma once
// The workspace mapping of one device (docs/design.md, "Workspace mapping"): device frame ->
// scene frame for the pose, scene frame -> device frame for the wrench, and the clutch.
//
// The haptic loop applies it in exactly one place, right after a device read (HapticLoop's
// readDevice phase): from there on the tick, the local model and the sample published to the
// simulation all hold the scene-frame pose. The wrench is mapped back before the safety chain,
// so the clamp, slew limit and final guard act last, on the device-frame command.
//
// Clutch: while the clutch is held (the params' clutch_button pressed in the sample's buttons,
// or setClutchRequest(true) from any thread, e.g. a key), the scene pose stays where it was when
// the clutch engaged (zero velocity) and no force is commanded, so the hand moves freely. On
// release the offset (position) and an orientation bias are re-based so that the current device
// pose maps exactly onto the held scene pose: the instrument does not jump.
//
// Everything but configure() is real-time safe: no allocation, lock, logging or exception.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <atomic>

#include "tactus/device/device.h"
#include "tactus/shared/workspace_mapping.h"

namespace tactus::haptic {

class WorkspaceMapping {
 public:
  WorkspaceMapping() = default;   ///< identity, no clutch button
  WorkspaceMapping(const WorkspaceMapping&) = delete;
  WorkspaceMapping& operator=(const WorkspaceMapping&) = delete;

  /// Non-real-time: validates (throws tactus::Error) and resets the clutch state and offset.
  void configure(const shared::WorkspaceMappingParams& params);
  const shared::WorkspaceMappingParams& params() const noexcept { return params_; }

  /// Maps a device sample with finite pose to the scene frame, in place: position, velocity,
  /// orientation (normalised; a zero quaternion counts as identity) and angular velocity.
  /// Time stamp, gripper and buttons are kept.
  void toScene(device::DeviceState& state) noexcept;

  /// Maps a scene-frame wrench (force, torque) to the device frame, in place. While clutched it
  /// becomes zero. Non-finite input stays non-finite (the safety chain zeroes it).
  void wrenchToDevice(std::array<double, 3>& force_n, std::array<double, 3>& torque_nm) const
      noexcept;

  /// Any thread: a clutch request besides the button (a key for a device without buttons).
  void setClutchRequest(bool held) noexcept {
    clutch_request_.store(held, std::memory_order_relaxed);
  }
  /// The clutch state after the last toScene().
  bool clutched() const noexcept { return clutched_; }
  /// The current scene position of the device origin (re-based by each clutch release).
  Eigen::Vector3d offsetM() const noexcept { return offset_m_; }

 private:
  shared::WorkspaceMappingParams params_;
  Eigen::Quaterniond rotation_ = Eigen::Quaterniond::Identity();   // device -> scene
  Eigen::Vector3d offset_m_ = Eigen::Vector3d::Zero();
  Eigen::Quaterniond bias_ = Eigen::Quaterniond::Identity();       // right factor, re-based
  bool clutched_ = false;
  bool have_output_ = false;
  Eigen::Vector3d held_pos_m_ = Eigen::Vector3d::Zero();           // last scene pose output
  Eigen::Quaterniond held_rot_ = Eigen::Quaterniond::Identity();
  std::atomic<bool> clutch_request_{false};
};

}  // namespace tactus::haptic
