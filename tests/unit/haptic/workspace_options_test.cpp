// haptic_server's --workspace-option I:key=value (workspace_options.h): device I's own mapping
// over the common one, field by field; every malformed or out-of-range option refused.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "tactus/haptic/workspace_options.h"
#include "tactus/shared/error.h"

namespace tactus::haptic {
namespace {

using ::testing::HasSubstr;
using shared::WorkspaceMappingParams;

std::string refusal(const std::vector<std::string>& options, std::size_t devices = 2) {
  try {
    deviceWorkspaces(WorkspaceMappingParams{}, options, devices);
  } catch (const Error& e) {
    return e.what();
  }
  return "(accepted)";
}

TEST(WorkspaceOptions, OverrideOnlyTheirDeviceAndTheirFieldOverTheCommonMapping) {
  WorkspaceMappingParams common;
  common.scale = 0.5;
  common.offset_m = {0.0, 0.0, 0.1};
  common.clutch_button = 2;
  const std::vector<WorkspaceMappingParams> w = deviceWorkspaces(
      common,
      {"1:offset=0.01,-0.02,0.03", "1:rotation=0,1,0,0", "2:scale=3", "2:scale=4",
       "1:clutch_button=-1"},
      3);
  ASSERT_EQ(w.size(), 3u);
  // device 0: the common mapping untouched
  EXPECT_EQ(w[0].scale, 0.5);
  EXPECT_EQ(w[0].offset_m, common.offset_m);
  EXPECT_EQ(w[0].rotation_wxyz, common.rotation_wxyz);
  EXPECT_EQ(w[0].clutch_button, 2);
  // device 1: its offset, rotation and clutch button, the common scale
  EXPECT_EQ(w[1].scale, 0.5);
  EXPECT_EQ(w[1].offset_m, (std::array<double, 3>{0.01, -0.02, 0.03}));
  EXPECT_EQ(w[1].rotation_wxyz, (std::array<double, 4>{0.0, 1.0, 0.0, 0.0}));
  EXPECT_EQ(w[1].clutch_button, -1);
  // device 2: the last of its options wins
  EXPECT_EQ(w[2].scale, 4.0);
  EXPECT_EQ(w[2].offset_m, common.offset_m);
  // no options: every device the common mapping
  const std::vector<WorkspaceMappingParams> plain = deviceWorkspaces(common, {}, 2);
  EXPECT_EQ(plain[1].scale, 0.5);
  EXPECT_EQ(plain[1].clutch_button, 2);
  EXPECT_THAT(describeWorkspace(w[1]),
              HasSubstr("scale 0.5, offset (0.01, -0.02, 0.03) m, rotation (0, 1, 0, 0), "
                        "clutch button -1"));
}

TEST(WorkspaceOptions, RefusesMalformedAndOutOfRangeOptionsNamingThem) {
  EXPECT_THAT(refusal({"2:scale=2"}), HasSubstr("'2:scale=2': no such device: 2 device(s)"));
  EXPECT_THAT(refusal({"0:scale=2"}, 0), HasSubstr("no such device"));
  EXPECT_THAT(refusal({"1234:scale=2"}), HasSubstr("no such device"));
  EXPECT_THAT(refusal({"scale=2"}), HasSubstr("expected I:key=value"));
  EXPECT_THAT(refusal({"1:scale"}), HasSubstr("expected I:key=value"));
  EXPECT_THAT(refusal({"1:zoom=2"}), HasSubstr("unknown key 'zoom'"));
  EXPECT_THAT(refusal({"1:scale=nan"}), HasSubstr("'nan' is not a finite number"));
  EXPECT_THAT(refusal({"1:scale=-inf"}), HasSubstr("'-inf' is not a finite number"));
  EXPECT_THAT(refusal({"1:scale=1e400"}), HasSubstr("not a finite number"));
  EXPECT_THAT(refusal({"1:scale=2,3"}), HasSubstr("expects 1 comma-separated number(s), got 2"));
  EXPECT_THAT(refusal({"1:offset=1,2,"}), HasSubstr("'' is not a finite number"));
  EXPECT_THAT(refusal({"1:clutch_button=0.5"}), HasSubstr("must be an integer"));
  // the ranges are shared::WorkspaceMappingLimits', checked on the device's final mapping
  EXPECT_THAT(refusal({"1:scale=0.001"}), HasSubstr("device 1: workspace scale = 0.001"));
  EXPECT_THAT(refusal({"0:offset=0,0,101"}), HasSubstr("device 0: workspace offset[2] = 101"));
  EXPECT_THAT(refusal({"1:rotation=1,0,0,0.01"}), HasSubstr("unit quaternion"));
  EXPECT_THAT(refusal({"1:clutch_button=32"}), HasSubstr("clutch button = 32"));
  EXPECT_THAT(refusal({"1:scale=100"}), "(accepted)");
  EXPECT_THAT(refusal({"1:clutch_button=31", "0:clutch_button=-1"}), "(accepted)");
}

}  // namespace
}  // namespace tactus::haptic
