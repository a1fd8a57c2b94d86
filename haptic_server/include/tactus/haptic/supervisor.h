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
  ~Supervisor();

  /// Attach / detach / re-attach as needed. Call every ~100 ms. Never blocks for long.
  void poll();
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
};

}  // namespace tactus::haptic
