// Space bar -> clutch toggle (non-real-time thread).
#include "tactus/haptic/clutch_key.h"

#include <poll.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

namespace tactus::haptic {

ClutchKey::ClutchKey(WorkspaceMapping& mapping, int fd) : mapping_(mapping), fd_(fd) {
  if (::isatty(fd_) == 0 || ::tcgetattr(fd_, &saved_) != 0) return;
  termios raw = saved_;
  raw.c_lflag &= static_cast<tcflag_t>(~(ICANON | ECHO));
  raw.c_cc[VMIN] = 1;
  raw.c_cc[VTIME] = 0;
  if (::tcsetattr(fd_, TCSANOW, &raw) != 0) return;
  active_ = true;
  thread_ = std::thread([this] { listen(); });
}

ClutchKey::~ClutchKey() {
  if (!active_) return;
  stop_.store(true);
  thread_.join();
  ::tcsetattr(fd_, TCSANOW, &saved_);
}

void ClutchKey::listen() {
  bool held = false;
  while (!stop_.load()) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, 100) <= 0) continue;
    char c = 0;
    if (::read(fd_, &c, 1) != 1) return;   // end of input: leave the clutch as it is
    if (c != ' ') continue;
    held = !held;
    mapping_.setClutchRequest(held);
    spdlog::info("clutch {}", held ? "held (the instrument stays; move the hand freely)"
                                   : "released");
  }
}

}  // namespace tactus::haptic
