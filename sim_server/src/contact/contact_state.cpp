// The god object's and the collision memory's state through the state archive (state_archive.h;
// docs/design.md, "State: copy, save, restore").
#include "collision_impl.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/state_archive.h"

namespace tactus::sim {

void Instrument::transferState(StateArchive& ar) {
  ar("pose", pose_);
  ar("twist", twist_);
  ar("target", target_);
  ar("target_twist", target_twist_);
  ar("opening", opening_);
  ar("grip_rate", grip_rate_);
  ar("grip_held_open", grip_held_open_);
  ar("grip_torque_last", grip_torque_last_nm_);
  ar("h", h_s_);
  ar("theta0", theta0_);
  ar("rot_step", rot_step_);
  // Not state: the model (spec_, workspace_, grip_dynamic_), the statistics (clamped_targets_);
  // features_ follow from the pose and opening.
  if (ar.loading()) updateFeatures();
}

void Collision::transferState(StateArchive& ar) {
  Impl& s = *impl_;
  const std::size_t features = 1u << 16;   // far above any tool's feature count
  ar.resizable("side", s.side_prev, features);
  ar("pad_side", s.pad_side);
  ar("pad_side_detect", s.pad_side_detect);
  ar("detect_count", s.detect_count);
  // Not state: the surface and the trees' topology (model), the positions, boxes and normals
  // (refit() recomputes them before every detect()), the candidates and contacts (detect()'s
  // output) and the statistics.
}

}  // namespace tactus::sim
