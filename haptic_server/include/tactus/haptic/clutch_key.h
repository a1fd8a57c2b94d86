#pragma once
// The clutch on a key, for devices without a clutch button (the simulated hand): while
// haptic_server runs on a terminal, the space bar toggles the workspace mapping's clutch
// (terminals report key presses, not releases, so one press holds and the next releases).
// A non-real-time thread polls the terminal; its mode is restored on destruction.

#include <atomic>
#include <thread>

#include <termios.h>

#include "tactus/haptic/workspace_mapping.h"

namespace tactus::haptic {

class ClutchKey {
 public:
  /// Starts listening when `fd` (stdin by default) is a terminal, switched to unbuffered
  /// no-echo input; otherwise does nothing (active() false).
  explicit ClutchKey(WorkspaceMapping& mapping, int fd = 0);
  ~ClutchKey();
  ClutchKey(const ClutchKey&) = delete;
  ClutchKey& operator=(const ClutchKey&) = delete;
  bool active() const noexcept { return active_; }

 private:
  void listen();

  WorkspaceMapping& mapping_;
  int fd_;
  bool active_ = false;
  termios saved_{};
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace tactus::haptic
