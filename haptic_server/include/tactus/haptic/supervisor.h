#pragma once
// The non-real-time side of haptic_server: attaches to the simulation's segment when it appears
// (either daemon may start first), notices when it disappears or is replaced (simulation stopped,
// crashed or restarted), hands links to the real-time loop through HapticLoop::offerLink, and
// drains the loop's event ring into spdlog.

#include <memory>
#include <string>

#include "tactus/haptic/haptic_loop.h"

namespace tactus::haptic {

class Supervisor {
 public:
  Supervisor(HapticLoop& loop, std::string segment_name);
  /// Withdraws the link and frees it only once the tick has let go of it (HapticLoop::stopped()
  /// after the real-time thread ended, or a tick that adopted the withdrawal, within a bounded
  /// wait). A link the tick may still hold is never freed: it stays mapped until the process
  /// ends (logged).
  ~Supervisor();

  /// Attach / detach / re-attach as needed, watch the tick (watchTick) and log the devices'
  /// diagnostics. Call every ~50-100 ms. Never blocks for long.
  void poll();
  /// The watchdog of the real-time thread: when the tick now running has been running for
  /// longer than twice the loop's watchdog_ms, it is stuck (a device read or write that blocks,
  /// against the device contract): logs it once per episode and, the first time the stuck tick
  /// is seen inside a device's call (also when the episode began outside one, e.g. the tick
  /// preempted before the call), asks that device to halt (Device::halt: a plugin that supports
  /// it stops its force and returns), or says that it cannot, and says so again once if the call
  /// still has not returned after as long again.
  /// Returns true while the tick is stuck. Called by poll().
  bool watchTick(std::int64_t now_ns);
  /// Logs the loop's pending events (spdlog). Returns how many.
  int drainEvents();
  /// Detaches (waits until the loop has let go of the link; the loop must be ticking).
  void detach();
  bool attached() const { return link_ != nullptr; }
  /// The attached segment (nullptr when none): for status lines.
  const shared::Segment* segment() const;

 private:
  void retire(std::unique_ptr<AttachedSegment> old);

  HapticLoop& loop_;
  std::string name_;
  std::unique_ptr<AttachedSegment> link_;
  std::unique_ptr<AttachedSegment> retired_;     ///< detached, waiting for the loop's ack
  std::string last_open_message_;
  bool creator_alive_ = true;
  bool stuck_ = false;                           ///< in a stuck-tick episode (logged once)
  int halt_device_ = -1;                          ///< the device asked to halt this episode
  std::int64_t halt_requested_ns_ = 0;           ///< the tick's running time at that request
  bool still_stuck_reported_ = false;            ///< ... and still stuck after the halt
  std::int64_t stuck_longest_ns_ = 0;            ///< how long the episode's tick ran so far
};

}  // namespace tactus::haptic
