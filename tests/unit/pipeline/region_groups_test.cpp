// Regions by physical group: `group: <name or tag>` fixes or loads exactly the
// nodes of a Gmsh physical group (compared with the face nodes found from the coordinates), and a
// group the mesh does not have is an error naming the region, the group and the mesh's groups.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "../../../sim_server/src/pipeline/loads.h"
#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/node_regions.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

const std::filesystem::path kGroupsData = TACTUS_TEST_DATA_DIR;

// The 4 x 3 x 2 cm box Gmsh wrote with the groups base (z = 0), top (z = 0.02), 7 (unnamed,
// x = 0) and body (tests/data/README.md)
const std::string kGroupsHead =
    "time_step: 0.01\n"
    "tissues:\n"
    "  - name: box\n"
    "    mesh: meshes/box_groups.msh\n"
    "    material: {law: linear, young_modulus: 10000, poisson_ratio: 0.3, density: 1000}\n";

SceneSpec parseGroups(const std::string& yaml) { return parseScene(yaml, "g.yaml", kGroupsData); }

// The nodes of the box (as loaded) whose coordinate `axis` is `value`: the group's nodes found
// without the group.
std::vector<int> nodesOn(int axis, double value) {
  const TetMesh mesh = loadTetMesh(kGroupsData / "meshes" / "box_groups.msh");
  std::vector<int> out;
  for (int i = 0; i < mesh.nodeCount(); ++i) {
    if (std::abs(mesh.nodes(axis, i) - value) < 1e-12) out.push_back(i);
  }
  return out;
}

// The SceneError `f` throws.
std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const SceneError& e) {
    return e.what();
  }
  return "(no error)";
}

std::string groupsSceneError(const std::string& yaml) {
  return errorOf([&yaml] { Simulation sim(parseGroups(yaml)); });
}

TEST(RegionGroupsTest, AFixedGroupPinsExactlyItsNodes) {
  const std::vector<int> base = nodesOn(2, 0.0);
  ASSERT_GE(base.size(), 6u);
  Simulation sim(parseGroups(kGroupsHead + "    fixed: {regions: [{group: base}]}\n" +
                             "gravity: [0, 0, -9.81]\n"));
  const FemBody& body = sim.tissue(0);
  std::vector<int> fixed;
  for (int i = 0; i < body.nodeCount(); ++i) {
    if (body.fixedMask()[static_cast<std::size_t>(i)]) fixed.push_back(i);
  }
  EXPECT_EQ(fixed, base);
  // and they stay put under gravity while the rest sags
  for (int k = 0; k < 20; ++k) ASSERT_TRUE(sim.step().finite);
  double sag = 0.0;
  for (int i = 0; i < body.nodeCount(); ++i) {
    const double dz = body.positions()[3 * i + 2] - body.restPositions()[3 * i + 2];
    if (body.fixedMask()[static_cast<std::size_t>(i)]) {
      EXPECT_EQ(dz, 0.0) << "node " << i;
    } else {
      sag = std::min(sag, dz);
    }
  }
  EXPECT_LT(sag, 0.0);
}

TEST(RegionGroupsTest, LoadRegionsSelectGroupsByNameOrTag) {
  const SceneSpec spec = parseGroups(kGroupsHead +
                                     "    fixed: {regions: [{group: base}]}\n"
                                     "    loads:\n"
                                     "      - {region: {group: top}, force: [0, 0, -0.01]}\n"
                                     "      - {region: {group: 7}, pressure: 10}\n"
                                     "      - {region: {group: '2'}, force: [0.01, 0, 0]}\n");
  ASSERT_EQ(spec.tissues[0].loads.size(), 3u);
  EXPECT_EQ(spec.tissues[0].loads[0].region.kind, RegionKind::kGroup);
  EXPECT_EQ(spec.tissues[0].loads[0].region.group, "top");
  const TetMesh mesh = loadTetMesh(spec.tissues[0].mesh_path);
  const std::vector<TissueLoad> loads = buildTissueLoads(mesh, spec.tissues[0], "g.yaml");
  ASSERT_EQ(loads.size(), 3u);
  EXPECT_EQ(loads[0].nodes, nodesOn(2, 0.02));
  EXPECT_EQ(loads[1].nodes, nodesOn(0, 0.0));   // "7" is the unnamed group's name
  EXPECT_FALSE(loads[1].triangles.empty());     // the x = 0 face's boundary triangles
  for (const auto& t : loads[1].triangles) {
    for (int n : t) EXPECT_EQ(mesh.nodes(0, n), 0.0);
  }
  EXPECT_EQ(loads[2].nodes, nodesOn(2, 0.02));  // no group is named "2": the tag of "top"
}

TEST(RegionGroupsTest, ADisplacedGroupFollowsItsPath) {
  Simulation sim(parseGroups(kGroupsHead + "    fixed: {regions: [{group: base}]}\n"
                                           "    loads:\n"
                                           "      - region: {group: top}\n"
                                           "        displacement: [{t: 0, offset: [0, 0, 0]}, "
                                           "{t: 0.1, offset: [0, 0, -0.001]}]\n"));
  for (int k = 0; k < 20; ++k) ASSERT_TRUE(sim.step().finite);
  const FemBody& body = sim.tissue(0);
  const std::vector<int> top = nodesOn(2, 0.02);
  for (int n : top) {
    EXPECT_NEAR(body.positions()[3 * n + 2], 0.02 - 0.001, 1e-15) << "node " << n;
  }
  // only base and top are Dirichlet nodes
  std::vector<int> fixed, expected = nodesOn(2, 0.0);
  expected.insert(expected.end(), top.begin(), top.end());
  std::sort(expected.begin(), expected.end());
  for (int i = 0; i < body.nodeCount(); ++i) {
    if (body.fixedMask()[static_cast<std::size_t>(i)]) fixed.push_back(i);
  }
  EXPECT_EQ(fixed, expected);
}

TEST(RegionGroupsTest, AnUnknownGroupNamesTheRegionTheGroupAndTheMeshsGroups) {
  const std::string yaml = kGroupsHead + "    fixed: {regions: [{group: bottom}]}\n";
  const std::string mesh = parseGroups(yaml).tissues[0].mesh_path.string();
  EXPECT_EQ(
      groupsSceneError(yaml),
      "g.yaml:6:23: tissues[0].fixed.regions[0]: the group 'bottom' is not a physical group "
      "of the mesh of tissue 'box' (" +
          mesh + "): its groups are " +
          fmt::format("'base' (surface 1, {} nodes), 'top' (surface 2, {} nodes), '7' "
                      "(surface 7, {} nodes), 'body' (volume 8, 78 nodes)",
                      nodesOn(2, 0.0).size(), nodesOn(2, 0.02).size(), nodesOn(0, 0.0).size()));
  // in a load's region, and a mesh without groups says so
  EXPECT_NE(groupsSceneError(kGroupsHead + "    loads: [{region: {group: 3}, force: [0, 0, 1]}]\n")
                .find("g.yaml:6:22: tissues[0].loads[0].region: the group '3' is not a physical "
                      "group of the mesh of tissue 'box'"),
            std::string::npos);
  const std::string vtk =
      "time_step: 0.01\ntissues:\n  - mesh: meshes/cube_low_res_ascii.vtu\n"
      "    fixed: {regions: [{group: base}]}\n";
  const std::string none = groupsSceneError(vtk);
  EXPECT_NE(none.find("g.yaml:4:23: tissues[0].fixed.regions[0]: the group 'base' is not a "
                      "physical group"),
            std::string::npos)
      << none;
  EXPECT_NE(none.find("it has no physical groups"), std::string::npos) << none;
}

TEST(RegionGroupsTest, GroupRegionGrammar) {
  const auto error = [](const std::string& yaml) {
    return errorOf([&yaml] { parseGroups(yaml); });
  };
  EXPECT_EQ(error(kGroupsHead + "    fixed: {regions: [{group: base, lowest: z}]}\n"),
            "g.yaml:6:23: tissues[0].fixed.regions[0]: must have exactly one selector of box, "
            "plane, lowest, highest, group (got 2)");
  EXPECT_EQ(error(kGroupsHead + "    fixed: {regions: [{group: base, tolerance: 0.001}]}\n"),
            "g.yaml:6:48: tissues[0].fixed.regions[0].tolerance: has no meaning for a group "
            "region");
  EXPECT_EQ(error(kGroupsHead + "    fixed: {regions: [{group: [base]}]}\n"),
            "g.yaml:6:31: tissues[0].fixed.regions[0].group: must be a non-empty string (got a "
            "list)");
  EXPECT_EQ(error(kGroupsHead + "    fixed: {regions: [{group: ''}]}\n"),
            "g.yaml:6:31: tissues[0].fixed.regions[0].group: must be a non-empty string (got "
            "'')");
}

// Two tetrahedra whose $PhysicalNames name a surface group with no element ("empty") and give the
// name "twice" to a surface and to the volume.
TetMesh namedGroupsMesh() {
  return parseTetMesh(
      "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n"
      "$PhysicalNames\n3\n2 5 \"empty\"\n2 1 \"twice\"\n3 1 \"twice\"\n$EndPhysicalNames\n"
      "$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0 0 -1\n$EndNodes\n"
      "$Elements\n3\n1 2 2 1 1 1 2 3\n2 4 2 1 1 1 2 3 4\n3 4 2 1 1 1 3 2 5\n$EndElements\n",
      "named.msh");
}

TEST(RegionGroupsTest, AnEmptyGroupSelectsNoNodeAndAnAmbiguousOneIsAnError) {
  const TetMesh mesh = namedGroupsMesh();
  RegionSpec r;
  r.kind = RegionKind::kGroup;
  r.group = "empty";
  r.where = "s.yaml:3:4: tissues[0].fixed.regions[0]";
  const auto error = [&mesh](const RegionSpec& region) {
    return errorOf([&] { requireRegionNodes(mesh, region, "t", "fixed", "fallback"); });
  };
  EXPECT_EQ(error(r),
            "s.yaml:3:4: tissues[0].fixed.regions[0]: the fixed region, the physical group "
            "'empty', selects no node of tissue 't' (its placed mesh spans [0, 0, -1]..[1, 1, 1] "
            "m)");
  r.group = "twice";
  EXPECT_EQ(error(r),
            "s.yaml:3:4: tissues[0].fixed.regions[0]: the group 'twice' is ambiguous in the mesh "
            "of tissue 't' (named.msh): it matches 'twice' (surface 1, 3 nodes), 'twice' (volume "
            "1, 5 nodes); give the name or tag of just one");
  r.group = "1";   // no group is named "1": the tag, in two dimensions
  EXPECT_NE(error(r).find("the group '1' is ambiguous"), std::string::npos);
  r.group = "5";   // the tag of "empty"
  r.where.clear();
  EXPECT_EQ(error(r).substr(0, 57), "fallback: the fixed region, the physical group '5', selec");
  EXPECT_TRUE(selectRegionNodes(mesh, r).empty());
}

}  // namespace
}  // namespace tactus::sim
