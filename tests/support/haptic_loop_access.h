#pragma once
// The tests' access to HapticLoop's insides (a friend of the class): its tick's phases one at a
// time on device 0, a construction that skips HapticSettings::validate() (so the final guard
// meets nonsense settings) and the hook the tick calls while it adopts a link. The real-time
// class itself carries no test-only entry points.

#include <array>
#include <cstdint>
#include <memory>

#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/clock.h"

namespace tactus::haptic {

struct HapticLoopTestAccess {
  /// A loop on `device` with `settings` as given, not validated.
  static std::unique_ptr<HapticLoop> unchecked(device::Device& device,
                                               const HapticSettings& settings) {
    return std::unique_ptr<HapticLoop>(new HapticLoop(device, settings, HapticLoop::Unchecked{}));
  }
  /// `hook(context)` runs inside the tick between its first read of the offered link and
  /// publishing it as in use (nullptr: none).
  static void setAdoptionHook(HapticLoop& l, void (*hook)(void*), void* context) {
    l.adoption_hook_ = hook;
    l.adoption_context_ = context;
  }

  // the tick's phases, in the tick's order, on device 0
  static void adoptOfferedLink(HapticLoop& l) { l.adoptOfferedLink(); }
  static device::IoStatus readDevice(HapticLoop& l, std::int64_t now, TickOutput& out) {
    return l.readDevice(l.channels_[0], 0, now, out);
  }
  static void publishSample(HapticLoop& l, std::int64_t now, device::IoStatus io) {
    l.publishSample(l.channels_[0], 0, now, io);
  }
  /// `now`: the tick's clock; `t_now_ns`: the real clock at that moment (by default the call's:
  /// the snapshot taken at once).
  static void takeSnapshot(HapticLoop& l, std::int64_t now, TickOutput& out,
                           std::int64_t t_now_ns = shared::monotonicNs()) {
    l.takeSnapshot(now, t_now_ns, 0, out);
  }
  /// Prepares the newest snapshot (as the preparer thread would) and adopts it; its sequence.
  static std::uint64_t prepareNewest(HapticLoop& l, AttachedSegment& link) {
    (void)link.preparer.prepareNewest(l.model_settings_);
    bool fresh = false;
    const PreparedSnapshot* p = link.preparer.latest(&fresh);
    if (fresh) link.model.adopt(p);
    return p->seq();
  }
  /// The local model on the adopted snapshot with device 0 at `device_pose`.
  static void solveLocalModel(HapticLoop& l, AttachedSegment& link,
                              const shared::Pose& device_pose, TickOutput& out) {
    std::array<const shared::Pose*, shared::kMaxInstruments> poses{};
    poses[0] = &device_pose;
    l.solveLocalModel(link, poses, 0, out);
  }
  static void applySafetyChain(HapticLoop& l, TickOutput& out, std::array<double, 3>& force,
                               std::array<double, 3>& torque) {
    l.applySafetyChain(l.channels_[0], 0, out, out, force, torque);
  }
  static void writeDevice(HapticLoop& l, const std::array<double, 3>& force,
                          const std::array<double, 3>& torque) {
    l.writeDevice(l.channels_[0], force, torque);
  }
  static void recordStats(HapticLoop& l, std::int64_t scheduled_ns, std::int64_t woken_ns,
                          const TickOutput& out, const std::array<double, 3>& force) {
    l.recordStats(scheduled_ns, woken_ns, out, force);
  }
};

}  // namespace tactus::haptic
