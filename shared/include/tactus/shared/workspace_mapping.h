#pragma once
// Workspace mapping parameters of one device (docs/design.md, "Workspace mapping"): how a
// device-frame pose becomes a scene-frame pose, and which button clutches. Shared because the
// scene loader validates them (with file:line:col) and the haptic loop applies them
// (tactus/haptic/workspace_mapping.h); both use these ranges.
//
//   p_scene = offset_m + scale * R p_device          (R = rotation_wxyz, device -> scene)
//   q_scene = R q_device q_bias                      (q_bias: identity until a clutch re-bases it)
//   f_device = R^T f_scene / scale,  tau_device = R^T tau_scene
//
// The force map divides by the scale so that the stiffness felt at the hand equals the scene's
// (times HapticSettings::force_scale) whatever the position scale: a hand motion d moves the
// instrument scale * d, the tissue pushes back k * scale * d, and the hand feels k * d.

#include <array>
#include <string>

namespace tactus::shared {

struct WorkspaceMappingLimits {
  static constexpr double kMinScale = 0.01;         ///< scale in [this, kMaxScale]
  static constexpr double kMaxScale = 100.0;
  static constexpr double kMaxOffsetM = 100.0;      ///< each offset component within +-this m
  static constexpr double kUnitTolerance = 1e-6;    ///< | |q| - 1 | <= this for the rotation
  static constexpr int kMaxButton = 31;             ///< clutch_button in [-1, this]
};

struct WorkspaceMappingParams {
  double scale = 1.0;                                ///< scene metres per device metre
  std::array<double, 3> offset_m{};                  ///< scene position of the device origin
  std::array<double, 4> rotation_wxyz{1.0, 0.0, 0.0, 0.0};  ///< device -> scene, unit
  int clutch_button = -1;                            ///< button bit that clutches (-1: none)

  /// Empty when every field is finite and in range (WorkspaceMappingLimits), else a message
  /// naming the first bad field, its value and the range.
  std::string problem() const;
  /// Throws tactus::Error with problem() when it is not empty.
  void validate() const;
  bool isIdentity() const noexcept;
  /// The inverse of the pose map without clutch re-basing: p = R^T (p_scene - offset) / scale,
  /// q = R^T q_scene (unit). For scripts written in the scene frame that a device replays
  /// (sim_server --export-trajectory), so the mapping brings them back where they were written.
  void sceneToDevice(std::array<double, 3>& pos_m, std::array<double, 4>& quat_wxyz) const
      noexcept;
};

}  // namespace tactus::shared
