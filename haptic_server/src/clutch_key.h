#pragma once
// The clutch on a key, for devices without a clutch button (the simulated hand): while
// haptic_server runs on a terminal, the space bar toggles the workspace mapping's clutch
// (terminals report key presses, not releases, so one press holds and the next releases).
// A non-real-time thread polls stdin; the terminal mode is restored on destruction.

#include <atomic>
#include <thread>

#include <termios.h>

#include "tactus/haptic/workspace_mapping.h"

namespace tactus::haptic {

class ClutchKey {
 public:
  /// Starts listening when stdin is a terminal; otherwise does nothing (active() false).
  explicit ClutchKey(WorkspaceMapping& mapping);
  ~ClutchKey();
  ClutchKey(const ClutchKey&) = delete;
  ClutchKey& operator=(const ClutchKey&) = delete;
  bool active() const noexcept { return active_; }

 private:
  void listen();

  WorkspaceMapping& mapping_;
  bool active_ = false;
  termios saved_{};
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace tactus::haptic
