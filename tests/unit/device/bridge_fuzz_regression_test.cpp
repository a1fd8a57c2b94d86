// Replays the bridge decoder's fuzz corpus (valid datagrams, accepted) and saved crashing
// inputs (refused or accepted within the contract of tests/fuzz/feed_bridge.h), and checks that
// the seeds are what the encoder writes.
#include <gtest/gtest.h>

#include "../../fuzz/feed_bridge.h"
#include "../../fuzz/regression_inputs.h"

namespace tactus::fuzz {
namespace {

TEST(BridgeFuzzRegression, CorpusSeedsAreAccepted) {
  const auto files = inputFiles(corpusDir("bridge"));
  ASSERT_GE(files.size(), 2u) << corpusDir("bridge");
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    bool ok = false;
    EXPECT_NO_THROW(ok = feedBridge(readBytes(f)));
    EXPECT_TRUE(ok);
  }
}

TEST(BridgeFuzzRegression, SavedCrashesAreRefusedOrWithinTheContract) {
  for (const auto& f : inputFiles(regressionDir("bridge"))) {
    SCOPED_TRACE(f.string());
    EXPECT_NO_THROW(feedBridge(readBytes(f)));
  }
}

TEST(BridgeFuzzRegression, EveryTruncationAndEveryFlippedByteOfAStateKeepsTheContract) {
  device::DeviceState s;
  s.pos_m = {0.01, -0.02, 0.03};
  s.quat_wxyz = {0.5, 0.5, 0.5, 0.5};
  std::string d(device::bridge::kStateBytes, '\0');
  device::bridge::encodeState(3, 1000, s, reinterpret_cast<unsigned char*>(d.data()));
  EXPECT_TRUE(feedBridge(d));
  for (std::size_t n = 0; n < d.size(); ++n) EXPECT_FALSE(feedBridge(d.substr(0, n))) << n;
  for (std::size_t i = 0; i < d.size(); ++i) {
    for (unsigned char flip : {0x01, 0x80, 0xff}) {
      std::string e = d;
      e[i] = static_cast<char>(e[i] ^ flip);
      EXPECT_NO_THROW(feedBridge(e)) << i;
    }
  }
}

}  // namespace
}  // namespace tactus::fuzz
