// Replays the scene fuzz corpus and the saved crashing inputs through parseScene: every file
// gives a SceneSpec or a tactus::Error (never a yaml-cpp exception or a crash).
#include <gtest/gtest.h>

#include "../../fuzz/feed_scene.h"
#include "../../fuzz/regression_inputs.h"

namespace tactus::fuzz {
namespace {

const std::filesystem::path kBase = std::filesystem::path(TACTUS_TEST_DATA_DIR) / "scenes";

TEST(SceneFuzzRegression, CorpusSeedsAreAccepted) {
  const auto files = inputFiles(corpusDir("scene"));
  ASSERT_GE(files.size(), 3u) << corpusDir("scene");
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    bool ok = false;
    EXPECT_NO_THROW(ok = feedScene(readBytes(f), kBase));
    EXPECT_TRUE(ok);  // copies of tests/data/scenes, all valid
  }
}

TEST(SceneFuzzRegression, SavedCrashesGiveASceneOrASceneError) {
  for (const auto& f : inputFiles(regressionDir("scene"))) {
    SCOPED_TRACE(f.string());
    EXPECT_NO_THROW(feedScene(readBytes(f), kBase));
  }
}

TEST(SceneFuzzRegression, MalformedYamlIsASceneError) {
  EXPECT_FALSE(feedScene("tissues: [ {mesh: ", kBase));
  EXPECT_FALSE(feedScene("\t- : : \x01", kBase));
  EXPECT_FALSE(feedScene("", kBase));
}

}  // namespace
}  // namespace tactus::fuzz
