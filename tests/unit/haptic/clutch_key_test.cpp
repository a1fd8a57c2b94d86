// The clutch key on a real pseudo-terminal: the space bar toggles the workspace mapping's
// clutch (held, then released), other keys do nothing, and a descriptor that is not a terminal
// leaves it inactive. Waits for the listener thread; asserts no durations.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <chrono>
#include <thread>

#include "tactus/haptic/clutch_key.h"

namespace tactus::haptic {
namespace {

// Maps a sample until the mapping's clutch state is `held` (the key thread sets the request).
bool waitForClutch(WorkspaceMapping& mapping, bool held) {
  for (int i = 0; i < 50'000; ++i) {
    device::DeviceState s;
    s.pos_m = {0.001 * (i % 10), 0.0, 0.0};
    mapping.toScene(s);
    if (mapping.clutched() == held) return true;
    std::this_thread::sleep_for(std::chrono::microseconds(100));
  }
  return false;
}

TEST(ClutchKey, TheSpaceBarTogglesTheClutchOnATerminal) {
  const int master = ::posix_openpt(O_RDWR | O_NOCTTY);
  ASSERT_GE(master, 0);
  ASSERT_EQ(::grantpt(master), 0);
  ASSERT_EQ(::unlockpt(master), 0);
  const int terminal = ::open(::ptsname(master), O_RDWR | O_NOCTTY);
  ASSERT_GE(terminal, 0);
  WorkspaceMapping mapping;
  {
    ClutchKey key(mapping, terminal);
    ASSERT_TRUE(key.active());
    EXPECT_TRUE(waitForClutch(mapping, false));
    ASSERT_EQ(::write(master, "x ", 2), 2);   // 'x' ignored, space: held
    EXPECT_TRUE(waitForClutch(mapping, true));
    ASSERT_EQ(::write(master, " ", 1), 1);    // released
    EXPECT_TRUE(waitForClutch(mapping, false));
  }
  ::close(terminal);
  ::close(master);
}

TEST(ClutchKey, IsInactiveWithoutATerminal) {
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  WorkspaceMapping mapping;
  ClutchKey key(mapping, fds[0]);
  EXPECT_FALSE(key.active());
  ::close(fds[0]);
  ::close(fds[1]);
}

}  // namespace
}  // namespace tactus::haptic
