#pragma once
// The one-contact problem the haptic tests publish: one frictionless contact below the
// instrument along scene +z, W = w, delta_free = gap with the device at `device_m` (x_h*, the
// tool's pose too), J = [0 0 1 0 0 0] (moving the device up opens the gap), the simulation's own
// force `f_n`, the contact at `point_m` with normal +z.

#include <array>
#include <cstdint>

#include "tactus/shared/messages.h"

namespace tactus::test {

/// Writes the problem into `slot` (seq and t_ns stamped, flags valid and with a Jacobian);
/// false when the slot cannot hold one contact.
inline bool writeOneContactProblem(shared::SnapshotWriter slot, std::uint64_t seq,
                                   std::int64_t t_ns, double gap_m, double w_m_per_n,
                                   const std::array<double, 3>& device_m, double f_n,
                                   const std::array<double, 3>& point_m = {}) {
  if (!slot.setSize(1, 1)) return false;
  auto& h = slot.header();
  h.seq = seq;
  h.t_ns = t_ns;
  h.flags = shared::kSnapshotValid | shared::kSnapshotHasJacobian;
  h.device_pose.pos_m = device_m;
  h.tool_pose.pos_m = device_m;
  slot.rowOffset()[0] = 0;
  slot.rowOffset()[1] = 1;
  slot.contactId()[0] = 1;
  slot.mu()[0] = 0.0;
  slot.W()[0] = w_m_per_n;
  slot.deltaFree()[0] = gap_m;
  slot.f()[0] = f_n;
  for (int k = 0; k < 6; ++k) slot.J()[k] = k == 2 ? 1.0 : 0.0;
  for (int k = 0; k < 3; ++k) {
    slot.contactPoint()[k] = point_m[static_cast<std::size_t>(k)];
    slot.contactNormal()[k] = k == 2 ? 1.0 : 0.0;
  }
  return true;
}

}  // namespace tactus::test
