// Node regions: each selector chooses the nodes it says on a structured box,
// the scene parser reads them with file:line:col errors, and a fixed region that selects no node
// stops the scene with an error naming the region.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <functional>
#include <string>

#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"
#include "tactus/sim/node_regions.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

const std::filesystem::path kRegionsData = TACTUS_TEST_DATA_DIR;

// 4 x 3 x 2 cells over [0, 0.04] x [0, 0.03] x [0, 0.02]: node (i, j, k) at 1 cm spacing
const TetMesh& grid() {
  static const TetMesh mesh = makeBoxTetMesh(4, 3, 2, Eigen::Vector3d(0.04, 0.03, 0.02));
  return mesh;
}

std::vector<int> expected(const std::function<bool(int, int, int)>& in) {
  std::vector<int> out;
  for (int k = 0; k <= 2; ++k)
    for (int j = 0; j <= 3; ++j)
      for (int i = 0; i <= 4; ++i)
        if (in(i, j, k)) out.push_back(i + 5 * (j + 4 * k));
  std::sort(out.begin(), out.end());
  return out;
}

TEST(RegionsTest, BoxSelectsTheNodesInsideIt) {
  RegionSpec r;
  r.kind = RegionKind::kBox;
  r.min_m = Eigen::Vector3d(0.015, -1, 0.005);
  r.max_m = Eigen::Vector3d(0.031, 1, 1);
  EXPECT_EQ(selectRegionNodes(grid(), r),
            expected([](int i, int, int k) { return (i == 2 || i == 3) && k >= 1; }));
}

TEST(RegionsTest, PlaneSideSelectsTheNodesOnTheNormalsSide) {
  RegionSpec r;
  r.kind = RegionKind::kPlaneSide;
  // x + y >= 0.05 (diagonal plane through (0.05, 0, 0)), normal (1, 1, 0)/sqrt 2
  r.point_m = Eigen::Vector3d(0.05, 0, 0);
  r.normal = Eigen::Vector3d(1, 1, 0).normalized();
  EXPECT_EQ(selectRegionNodes(grid(), r), expected([](int i, int j, int) { return i + j >= 5; }));
  // a tolerance of 1.2 cm / sqrt 2 along the normal takes in the diagonal below (i + j = 4, at
  // 1 cm / sqrt 2) but not the next
  r.tolerance_m = 0.012 / std::sqrt(2.0);
  EXPECT_EQ(selectRegionNodes(grid(), r), expected([](int i, int j, int) { return i + j >= 4; }));
}

TEST(RegionsTest, LowestAndHighestSelectTheExtremeLayersWithinTheTolerance) {
  RegionSpec r;
  r.kind = RegionKind::kLowest;
  r.axis = 2;
  EXPECT_EQ(selectRegionNodes(grid(), r), expected([](int, int, int k) { return k == 0; }));
  r.tolerance_m = 0.0101;   // one layer more
  EXPECT_EQ(selectRegionNodes(grid(), r), expected([](int, int, int k) { return k <= 1; }));
  r.kind = RegionKind::kHighest;
  r.axis = 0;
  r.tolerance_m = 1e-6;
  EXPECT_EQ(selectRegionNodes(grid(), r), expected([](int i, int, int) { return i == 4; }));
  r.axis = 1;
  EXPECT_EQ(selectRegionNodes(grid(), r), expected([](int, int j, int) { return j == 3; }));
}

const std::string kHead =
    "time_step: 0.01\n"
    "tissues:\n"
    "  - mesh: meshes/cube_low_res.msh\n"
    "    transform: {scale: 0.01}\n";

SceneSpec parseRegions(const std::string& yaml) { return parseScene(yaml, "s.yaml", kRegionsData); }

std::string regionsSceneError(const std::string& yaml) {
  try {
    Simulation sim(parseRegions(yaml));
  } catch (const SceneError& e) {
    return e.what();
  }
  return "";
}

TEST(RegionsTest, TheSceneReadsEverySelector) {
  const SceneSpec spec =
      parseRegions(kHead +
                   "    fixed:\n"
                   "      regions:\n"
                   "        - {box: {min: [-1, -1, -1], max: [1, 1, -0.03]}}\n"
                   "        - {plane: {point: [0, 0, 0.03], normal: [0, 0, 2]}}\n"
                   "        - {lowest: x, tolerance: 0.001}\n"
                   "        - {highest: y}\n");
  const std::vector<RegionSpec>& r = spec.tissues[0].fixed_regions;
  ASSERT_EQ(r.size(), 4u);
  EXPECT_EQ(r[0].kind, RegionKind::kBox);
  EXPECT_EQ(r[0].max_m, Eigen::Vector3d(1, 1, -0.03));
  EXPECT_EQ(r[0].where, "s.yaml:7:11: tissues[0].fixed.regions[0]");
  EXPECT_EQ(r[1].kind, RegionKind::kPlaneSide);
  EXPECT_EQ(r[1].normal, Eigen::Vector3d(0, 0, 1));   // normalised
  EXPECT_EQ(r[2].kind, RegionKind::kLowest);
  EXPECT_EQ(r[2].axis, 0);
  EXPECT_EQ(r[2].tolerance_m, 0.001);
  EXPECT_EQ(r[3].kind, RegionKind::kHighest);
  EXPECT_EQ(r[3].axis, 1);
}

TEST(RegionsTest, BadRegionsAreSceneErrorsWithTheirPlace) {
  auto error = [](const std::string& yaml) {
    try {
      parseRegions(yaml);
    } catch (const SceneError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(error(kHead + "    fixed: {regions: [{lowest: z, highest: z}]}\n"),
            "s.yaml:5:23: tissues[0].fixed.regions[0]: must have exactly one selector of box, "
            "plane, lowest, highest, group (got 2)");
  EXPECT_EQ(error(kHead + "    fixed: {regions: [{lowest: w}]}\n"),
            "s.yaml:5:32: tissues[0].fixed.regions[0].lowest: must be one of x, y, z (got 'w')");
  EXPECT_EQ(error(kHead + "    fixed: {regions: [{plane: {point: [0, 0, 0], normal: [0, 0, 0]}}]}\n"),
            "s.yaml:5:58: tissues[0].fixed.regions[0].plane.normal: must not be the zero vector");
  EXPECT_EQ(error(kHead + "    fixed: {regions: [{lowest: z, tolerance: -1}]}\n"),
            "s.yaml:5:46: tissues[0].fixed.regions[0].tolerance: must be >= 0 (got -1)");
  EXPECT_NE(error(kHead + "    fixed: {regions: [{lowest: z, tolerance: .nan}]}\n")
                .find("tissues[0].fixed.regions[0].tolerance: must be"),
            std::string::npos);
}

TEST(RegionsTest, AFixedRegionThatSelectsNoNodeIsAnErrorNamingIt) {
  // a box given in centimetres instead of metres: nowhere near the 7 cm cube
  EXPECT_EQ(
      regionsSceneError(kHead + "    fixed: {boxes: [{min: [-1, -1, -1], max: [1, 1, 1]},\n"
                                "                    {min: [-5, -5, -5], max: [5, 5, -4]}]}\n"),
      "s.yaml:6:21: tissues[0].fixed.boxes[1]: the fixed region, the box [-5, -5, -5].."
      "[5, 5, -4] m, selects no node of tissue 'tissue' (its placed mesh spans "
      "[-0.035, -0.035, -0.035]..[0.035, 0.035, 0.035] m)");
  EXPECT_EQ(
      regionsSceneError(
          kHead + "    fixed: {regions: [{plane: {point: [0, 0, 0.5], normal: [0, 0, 1]}}]}\n"),
      "s.yaml:5:23: tissues[0].fixed.regions[0]: the fixed region, the side of the plane "
      "through [0, 0, 0.5] m along normal [0, 0, 1] (tolerance 0 m), selects no node of "
      "tissue 'tissue' (its placed mesh spans [-0.035, -0.035, -0.035]..[0.035, 0.035, "
      "0.035] m)");
  // and the regions that select nodes fix exactly those
  Simulation sim(parseRegions(kHead + "    fixed: {regions: [{lowest: z, tolerance: 1e-4}]}\n"));
  const FemBody& body = sim.tissue(0);
  int fixed = 0;
  for (int i = 0; i < body.nodeCount(); ++i) {
    const bool bottom = body.restPositions()[3 * i + 2] < -0.035 + 1e-4;
    EXPECT_EQ(body.fixedMask()[static_cast<std::size_t>(i)], bottom) << "node " << i;
    fixed += bottom ? 1 : 0;
  }
  EXPECT_GT(fixed, 3);
}

}  // namespace
}  // namespace tactus::sim
