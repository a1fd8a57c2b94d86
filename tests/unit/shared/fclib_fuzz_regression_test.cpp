// Replays the FCLIB fuzz corpus and the saved crashing inputs through readFclibText and
// readFclibReference: every file gives a consistent problem/reference or a tactus::Error.
#include <gtest/gtest.h>

#include <unistd.h>

#include "../../fuzz/feed_fclib.h"
#include "../../fuzz/regression_inputs.h"

namespace tactus::fuzz {
namespace {

TEST(FclibFuzzRegression, CorpusSeedsAreReadCleanly) {
  const auto files = inputFiles(corpusDir("fclib"));
  ASSERT_GE(files.size(), 3u) << corpusDir("fclib");
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    int accepted = -1;
    EXPECT_NO_THROW(accepted = feedFclibFile(f));
    // a problem is not a reference and vice versa: exactly one reader accepts each seed
    EXPECT_EQ(accepted, 1);
  }
}

TEST(FclibFuzzRegression, SavedCrashesGiveAProblemOrAnError) {
  for (const auto& f : inputFiles(regressionDir("fclib"))) {
    SCOPED_TRACE(f.string());
    EXPECT_NO_THROW(feedFclibFile(f));
  }
}

// Found by the fuzzer: "nc = 999999999" in a short file allocated 8 GB for mu before noticing
// that the values were missing. Now nothing larger than the values left is reserved and the
// file fails at its end ("unexpected end of file"), as any short file does.
TEST(FclibFuzzRegression, CountsLargerThanTheFileFailAtItsEndWithoutHugeAllocations) {
  const auto path = std::filesystem::temp_directory_path() /
                    ("tactus_fclib_count_" + std::to_string(::getpid()) + ".fc3d.txt");
  auto expectTruncated = [&](const std::string& text, const std::string& what) {
    { std::ofstream(path) << text; }
    try {
      shared::readFclibText(path);
      ADD_FAILURE() << "accepted: " << text;
    } catch (const tactus::Error& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("unexpected end of file"), std::string::npos)
          << e.what();
    }
  };
  expectTruncated("999999999\n0.3\n", "expected mu[1]");
  expectTruncated("1\n0.3\n0 0 1\n2000000000\n0 0 1.0\n", "expected W entry 1 row");
  // the exact sizes still read
  { std::ofstream(path) << "1\n0.3\n0 0 1\n1\n0 0 2.0\n"; }
  const auto p = shared::readFclibText(path);
  EXPECT_EQ(p.contacts, 1);
  EXPECT_EQ(p.W[0], 2.0);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace tactus::fuzz
