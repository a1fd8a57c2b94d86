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

const std::filesystem::path& kWorkspaceScenes = test_support::kSceneDir;
const std::string& kWorkspaceHead = test_support::kSceneHead;
std::string workspaceError(const std::string& yaml) { return test_support::snippetError(yaml); }

TEST(SceneWorkspace, ParsesScaleOffsetRotationAndClutchButton) {
  const SceneSpec s =
      parseScene(kWorkspaceHead +
                     "haptics:\n  workspace: {scale: 2.5, offset: [0.1, -0.2, 0.3], "
                     "rotation_deg: [90, 0, 0], clutch_button: 1}\n",
                 "s.yaml", kWorkspaceScenes);
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
  const SceneSpec plain = parseScene(kWorkspaceHead + "haptics: {max_force: 4, rate: 2000}\n",
                                     "s.yaml", kWorkspaceScenes);
  EXPECT_TRUE(plain.haptics.workspace.isIdentity());
  EXPECT_THAT(hapticServerOptions(plain.haptics),
              ElementsAre("--rate=2000", "--max-force=4", "--force-scale=1", "--watchdog-ms=50",
                          "--max-sweeps=50", "--tolerance=9.9999999999999995e-07"));
  // the tick's Anderson acceleration and the snapshot blend reach haptic_server when the scene
  // asks for them, after the defaults
  const auto withDefaults = [](const std::string& extra) {
    return std::vector<std::string>{"--rate=1000", "--max-force=8", "--force-scale=1",
                                    "--watchdog-ms=50", "--max-sweeps=50",
                                    "--tolerance=9.9999999999999995e-07", extra};
  };
  const auto optionsOf = [](const std::string& haptics) {
    return hapticServerOptions(
        parseScene(kWorkspaceHead + "haptics: " + haptics + "\n", "s.yaml", kWorkspaceScenes)
            .haptics);
  };
  EXPECT_EQ(optionsOf("{nsgs_anderson_depth: 3}"), withDefaults("--nsgs-anderson-depth=3"));
  EXPECT_EQ(optionsOf("{snapshot_blend_ms: 10}"), withDefaults("--snapshot-blend-ms=10"));
  EXPECT_EQ(optionsOf("{local_model: full}"), withDefaults("--local-model=full"));
  EXPECT_EQ(optionsOf("{local_model: linearized}"), withDefaults("--local-model=linearized"));
  EXPECT_EQ(optionsOf("{local_model: automatic}").size(), 6u);   // the default: no option
  // haptics off: haptic_server keeps its own defaults
  EXPECT_TRUE(
      hapticServerOptions(parseScene(kWorkspaceHead, "s.yaml", kWorkspaceScenes).haptics).empty());
}

TEST(SceneWorkspace, OutOfRangeValuesAreErrorsWithTheirPosition) {
  EXPECT_THAT(workspaceError("haptics: {workspace: {scale: 0}}\n"),
              StartsWith("s.yaml:4:30: haptics.workspace.scale: must be > 0 (got 0)"));
  EXPECT_THAT(workspaceError("haptics: {workspace: {scale: 1000}}\n"),
              StartsWith("s.yaml:4:30: haptics.workspace.scale: must be in [0.01, 100]"));
  EXPECT_THAT(workspaceError("haptics: {workspace: {scale: .nan}}\n"),
              StartsWith("s.yaml:4:30: haptics.workspace.scale: must be a number"));
  EXPECT_THAT(workspaceError("haptics: {workspace: {offset: [0, 1e9, 0]}}\n"),
              StartsWith("s.yaml:4:35: haptics.workspace.offset[1]: must be in [-100, 100]"));
  EXPECT_THAT(workspaceError("haptics: {workspace: {quaternion: [1, 0, 0.5, 0]}}\n"),
              StartsWith("s.yaml:4:35: haptics.workspace.quaternion: must be a unit quaternion"));
  // (1e300 degrees used to be accepted silently)
  EXPECT_THAT(workspaceError("haptics: {workspace: {rotation_deg: [1e300, 0, 0]}}\n"),
              StartsWith("s.yaml:4:38: haptics.workspace.rotation_deg[0]: must be in "
                         "[-1000000, 1000000] (got 1e+300)"));
  EXPECT_THAT(workspaceError("haptics: {workspace: {clutch_button: 32}}\n"),
              StartsWith("s.yaml:4:38: haptics.workspace.clutch_button: must be in [-1, 31]"));
  EXPECT_THAT(workspaceError("haptics: {workspace: {gain: 2}}\n"),
              HasSubstr("haptics.workspace.gain: unknown key"));
  EXPECT_THAT(workspaceError("haptics: {workspace: 3}\n"),
              HasSubstr("haptics.workspace: must be a map"));
}

// haptics.workspaces: one mapping per device, entry i for instrument/device i.
const std::string kTwoProbes = "instruments:\n  - {type: probe}\n  - {type: probe}\n";

TEST(SceneWorkspaces, EachDeviceGetsItsOwnMappingAndItsOwnOptions) {
  const SceneSpec s = parseScene(
      kWorkspaceHead + kTwoProbes +
          "haptics:\n  workspaces:\n    - {}\n"
          "    - {scale: 2, offset: [0, 0.5, 0], rotation_deg: [0, 0, 90], clutch_button: 3}\n",
      "s.yaml", kWorkspaceScenes);
  ASSERT_EQ(s.haptics.workspaces.size(), 2u);
  EXPECT_TRUE(s.haptics.workspaces[0].isIdentity());
  const shared::WorkspaceMappingParams& w = s.haptics.workspaces[1];
  EXPECT_DOUBLE_EQ(w.scale, 2.0);
  EXPECT_DOUBLE_EQ(w.offset_m[1], 0.5);
  EXPECT_NEAR(w.rotation_wxyz[0], std::sqrt(0.5), 1e-15);   // a quarter turn about z
  EXPECT_NEAR(w.rotation_wxyz[3], std::sqrt(0.5), 1e-15);
  EXPECT_EQ(w.clutch_button, 3);
  EXPECT_TRUE(s.haptics.workspace.isIdentity());
  EXPECT_THAT(hapticServerOptions(s.haptics),
              ElementsAre("--rate=1000", "--max-force=8", "--force-scale=1", "--watchdog-ms=50",
                          "--max-sweeps=50", "--tolerance=9.9999999999999995e-07",
                          "--workspace-option=0:scale=1", "--workspace-option=0:offset=0,0,0",
                          "--workspace-option=0:rotation=1,0,0,0",
                          "--workspace-option=0:clutch_button=-1",
                          "--workspace-option=1:scale=2", "--workspace-option=1:offset=0,0.5,0",
                          StartsWith("--workspace-option=1:rotation=0.707106781186547"),
                          "--workspace-option=1:clutch_button=3"));
  // one entry for two instruments: device 1 keeps haptic_server's plain (identity) mapping
  const SceneSpec one =
      parseScene(kWorkspaceHead + kTwoProbes + "haptics:\n  workspaces:\n    - {scale: 0.5}\n",
                 "s.yaml", kWorkspaceScenes);
  ASSERT_EQ(one.haptics.workspaces.size(), 1u);
  EXPECT_DOUBLE_EQ(one.haptics.workspaces[0].scale, 0.5);
}

TEST(SceneWorkspaces, ErrorsCarryTheirPositionAndTheSameRanges) {
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics:\n  workspaces:\n    - {}\n    - {scale: 0}\n"),
              StartsWith("s.yaml:10:15: haptics.workspaces[1].scale: must be > 0 (got 0)"));
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics:\n  workspaces:\n    - {offset: [0, 1e9, 0]}\n"),
              StartsWith("s.yaml:9:20: haptics.workspaces[0].offset[1]: must be in [-100, 100]"));
  EXPECT_THAT(
      workspaceError(kTwoProbes + "haptics:\n  workspaces:\n    - {quaternion: [1, 0, 0.5, 0]}\n"),
      HasSubstr("haptics.workspaces[0].quaternion: must be a unit quaternion"));
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics:\n  workspaces:\n    - {clutch_button: 32}\n"),
              HasSubstr("haptics.workspaces[0].clutch_button: must be in [-1, 31]"));
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics:\n  workspaces:\n    - {scale: .nan}\n"),
              HasSubstr("haptics.workspaces[0].scale: must be a number"));
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics:\n  workspaces:\n    - {gain: 2}\n"),
              HasSubstr("haptics.workspaces[0].gain: unknown key"));
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics:\n  workspaces:\n    - 3\n"),
              StartsWith("s.yaml:9:7: haptics.workspaces[0]: must be a map"));
  // more entries than instruments, an empty list, not a list
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics:\n  workspaces: [{}, {}, {}]\n"),
              StartsWith("s.yaml:8:15: haptics.workspaces: must be a list of 1 to 2 workspace "
                         "maps, one per instrument (got 3 items)"));
  EXPECT_THAT(workspaceError("instrument: {type: probe}\nhaptics: {workspaces: [{}, {}]}\n"),
              HasSubstr("haptics.workspaces: must be a list of 1 to 1 workspace maps"));
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics: {workspaces: []}\n"),
              HasSubstr("haptics.workspaces: must be a list of 1 to 2"));
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics: {workspaces: {scale: 2}}\n"),
              HasSubstr("haptics.workspaces: must be a list of 1 to 2"));
  // both forms
  EXPECT_THAT(workspaceError(kTwoProbes + "haptics: {workspace: {scale: 2}, workspaces: [{}]}\n"),
              HasSubstr("haptics.workspaces: give either `workspace:` (every device) or "
                        "`workspaces:` (one per device), not both"));
}

}  // namespace
}  // namespace tactus::sim
