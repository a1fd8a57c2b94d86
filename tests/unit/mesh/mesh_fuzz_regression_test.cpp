// Replays the mesh fuzz corpus and the saved crashing inputs through parseTetMesh: every file
// gives a mesh or a tactus::Error, never a crash, another exception or a broken mesh.
#include <gtest/gtest.h>

#include <spdlog/spdlog.h>

#include "../../fuzz/feed_mesh.h"
#include "../../fuzz/regression_inputs.h"

namespace tactus::fuzz {
namespace {

TEST(MeshFuzzRegression, CorpusSeedsAreAcceptedOrRejectedCleanly) {
  spdlog::set_level(spdlog::level::err);  // the seeds' repairs are logged as warnings
  const auto files = inputFiles(corpusDir("mesh"));
  ASSERT_GE(files.size(), 10u) << corpusDir("mesh");
  int accepted = 0, rejected = 0;
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    bool ok = false;
    EXPECT_NO_THROW(ok = feedMesh(readBytes(f)));
    // the seeds are copies of tests/data/meshes: bad_* must be rejected, the others read
    const bool bad = f.filename().string().find("bad") != std::string::npos;
    EXPECT_EQ(ok, !bad);
    (ok ? accepted : rejected)++;
  }
  EXPECT_GT(accepted, 0);
  EXPECT_GT(rejected, 0);
}

TEST(MeshFuzzRegression, SavedCrashesGiveAMeshOrAMeshError) {
  for (const auto& f : inputFiles(regressionDir("mesh"))) {
    SCOPED_TRACE(f.string());
    EXPECT_NO_THROW(feedMesh(readBytes(f)));
  }
}

}  // namespace
}  // namespace tactus::fuzz
