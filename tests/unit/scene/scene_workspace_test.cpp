// The scene's haptics.workspace section: values, ranges with file:line:col errors, and the
// haptic_server options sim_server --print-haptic-options derives from it.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "tactus/shared/error.h"
#include "../../support/scene_snippet.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::StartsWith;

const std::filesystem::path& kScenes = test_support::kSceneDir;
const std::string& kHead = test_support::kSceneHead;
std::string error(const std::string& yaml) { return test_support::snippetError(yaml); }

TEST(SceneWorkspace, ParsesScaleOffsetRotationAndClutchButton) {
  const SceneSpec s = parseScene(
      kHead + "haptics:\n  workspace: {scale: 2.5, offset: [0.1, -0.2, 0.3], "
              "rotation_deg: [90, 0, 0], clutch_button: 1}\n",
      "s.yaml", kScenes);
  const shared::WorkspaceMappingParams& w = s.haptics.workspace;
  EXPECT_DOUBLE_EQ(w.scale, 2.5);
  EXPECT_DOUBLE_EQ(w.offset_m[1], -0.2);
  EXPECT_NEAR(w.rotation_wxyz[0], std::sqrt(0.5), 1e-15);
  EXPECT_NEAR(w.rotation_wxyz[1], std::sqrt(0.5), 1e-15);
  EXPECT_EQ(w.clutch_button, 1);
  EXPECT_EQ(w.problem(), "");
  EXPECT_THAT(hapticServerOptions(s.haptics),
              ElementsAre("--rate=1000", "--max-force=8", "--force-scale=1", "--watchdog-ms=50",
                          "--max-sweeps=50", "--tolerance=9.9999999999999995e-07",
                          "--workspace-scale=2.5",
                          "--workspace-offset=0.10000000000000001,-0.20000000000000001,"
                          "0.29999999999999999",
                          StartsWith("--workspace-rotation=0.707106781186547"),
                          "--clutch-button=1"));
  // no workspace section: the identity, no workspace options, but the scene's clamp and rate
  // reach haptic_server (start.sh passed only the workspace before: a scene's max_force was lost)
  const SceneSpec plain =
      parseScene(kHead + "haptics: {max_force: 4, rate: 2000}\n", "s.yaml", kScenes);
  EXPECT_TRUE(plain.haptics.workspace.isIdentity());
  EXPECT_THAT(hapticServerOptions(plain.haptics),
              ElementsAre("--rate=2000", "--max-force=4", "--force-scale=1", "--watchdog-ms=50",
                          "--max-sweeps=50", "--tolerance=9.9999999999999995e-07"));
  // haptics off: haptic_server keeps its own defaults
  EXPECT_TRUE(hapticServerOptions(parseScene(kHead, "s.yaml", kScenes).haptics).empty());
}

TEST(SceneWorkspace, OutOfRangeValuesAreErrorsWithTheirPosition) {
  EXPECT_THAT(error("haptics: {workspace: {scale: 0}}\n"),
              StartsWith("s.yaml:4:30: haptics.workspace.scale: must be > 0 (got 0)"));
  EXPECT_THAT(error("haptics: {workspace: {scale: 1000}}\n"),
              StartsWith("s.yaml:4:30: haptics.workspace.scale: must be in [0.01, 100]"));
  EXPECT_THAT(error("haptics: {workspace: {scale: .nan}}\n"),
              StartsWith("s.yaml:4:30: haptics.workspace.scale: must be a number"));
  EXPECT_THAT(error("haptics: {workspace: {offset: [0, 1e9, 0]}}\n"),
              StartsWith("s.yaml:4:35: haptics.workspace.offset[1]: must be in [-100, 100]"));
  EXPECT_THAT(error("haptics: {workspace: {quaternion: [1, 0, 0.5, 0]}}\n"),
              StartsWith("s.yaml:4:35: haptics.workspace.quaternion: must be a unit quaternion"));
  EXPECT_THAT(error("haptics: {workspace: {clutch_button: 32}}\n"),
              StartsWith("s.yaml:4:38: haptics.workspace.clutch_button: must be in [-1, 31]"));
  EXPECT_THAT(error("haptics: {workspace: {gain: 2}}\n"),
              HasSubstr("haptics.workspace.gain: unknown key"));
  EXPECT_THAT(error("haptics: {workspace: 3}\n"),
              HasSubstr("haptics.workspace: must be a map"));
}

}  // namespace
}  // namespace tactus::sim
