// Replays the trajectory fuzz corpus and the saved crashing inputs through Trajectory::parseCsv
// and sample(): every file gives a trajectory (increasing times, unit quaternions) or a
// tactus::Error.
#include <gtest/gtest.h>

#include "../../fuzz/feed_trajectory.h"
#include "../../fuzz/regression_inputs.h"

namespace tactus::fuzz {
namespace {

TEST(TrajectoryFuzzRegression, CorpusSeedsAreAccepted) {
  const auto files = inputFiles(corpusDir("trajectory"));
  ASSERT_GE(files.size(), 2u) << corpusDir("trajectory");
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    bool ok = false;
    EXPECT_NO_THROW(ok = feedTrajectory(readBytes(f)));
    EXPECT_TRUE(ok);
  }
}

TEST(TrajectoryFuzzRegression, SavedCrashesGiveATrajectoryOrADeviceError) {
  for (const auto& f : inputFiles(regressionDir("trajectory"))) {
    SCOPED_TRACE(f.string());
    EXPECT_NO_THROW(feedTrajectory(readBytes(f)));
  }
}

// Found by the fuzzer: a component near DBL_MAX overflowed the norm to inf and the row was
// accepted with the quaternion (0, 0, 0, 0).
TEST(TrajectoryFuzzRegression, HugeQuaternionComponentsNormaliseToUnit) {
  const std::string csv = std::string(device::Trajectory::kCsvHeader) +
                          "\n0,0,0,0,0.5,0.5,0.5,1.5e308,0\n1,0,0,0,-1e308,0,1e308,0,0\n";
  const auto traj = device::Trajectory::parseCsv(csv, "huge.csv");
  ASSERT_EQ(traj.points().size(), 2u);
  const auto& a = traj.points()[0].quat_wxyz;
  const auto& b = traj.points()[1].quat_wxyz;
  EXPECT_NEAR(a[3], 1.0, 1e-12);
  EXPECT_NEAR(a[0], 0.0, 1e-12);
  EXPECT_NEAR(b[0], -std::sqrt(0.5), 1e-12);
  EXPECT_NEAR(b[2], std::sqrt(0.5), 1e-12);
  EXPECT_TRUE(feedTrajectory(csv));
  // zero stays an error, tiny but non-zero is normalised
  EXPECT_THROW(device::Trajectory::parseCsv(std::string(device::Trajectory::kCsvHeader) +
                                                "\n0,0,0,0,0,0,0,0,0\n",
                                            "zero.csv"),
               tactus::Error);
  const auto tiny = device::Trajectory::parseCsv(
      std::string(device::Trajectory::kCsvHeader) + "\n0,0,0,0,0,0,3e-9,4e-9,0\n", "tiny.csv");
  EXPECT_NEAR(tiny.points()[0].quat_wxyz[2], 0.6, 1e-12);
}

}  // namespace
}  // namespace tactus::fuzz
