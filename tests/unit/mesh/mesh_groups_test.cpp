// Gmsh physical groups: the readers keep $PhysicalNames and the elements'
// physical tags (2.2: an element's first tag; 4.1: its entity's physical tags in $Entities) as
// node sets in the mesh's numbering (after unreferenced nodes are dropped), and reject malformed
// group sections with the line.

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <set>
#include <string>

#include "tactus/shared/error.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim {
namespace {

const std::filesystem::path kMeshes = std::filesystem::path(TACTUS_TEST_DATA_DIR) / "meshes";

// Two tetrahedra on sparse, unordered node ids. Node 99 (third in the file) is used by no
// tetrahedron, only by the point group "orphan", so it is dropped and every later node moves
// down by one: file ids 10 5 99 7 3 20 become mesh nodes 0 1 - 2 3 4.
const std::string kNodes22 =
    "$Nodes\n6\n10 0 0 0\n5 1 0 0\n99 5 5 5\n7 0 1 0\n3 0 0 1\n20 0 0 -1\n$EndNodes\n";

const std::string kNames22 =
    "$PhysicalNames\n4\n0 4 \"orphan\"\n2 1 \"base\"\n2 9 \"unused\"\n3 3 \"liver volume\"\n"
    "$EndPhysicalNames\n";

// physical point 4 (node 99), line 1 (unnamed: same tag as the surface "base", another
// dimension), surfaces 1 "base" and 2 (unnamed), volume 3; two triangles in no group (no tags,
// physical tag 0)
const std::string kElements22 =
    "$Elements\n8\n"
    "1 15 2 4 1 99\n"
    "2 2 2 1 1 10 5 7\n"
    "3 2 2 2 2 10 5 3\n"
    "4 1 2 1 5 7 3\n"
    "5 4 2 3 1 10 5 7 3\n"
    "6 4 2 3 1 10 7 5 20\n"
    "7 2 0 10 7 20\n"
    "8 2 2 0 5 5 7 20\n"
    "$EndElements\n";

const std::string kFormat22 = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n";

const std::string kEntities41 =
    "$Entities\n1 1 3 1\n"
    "1 5 5 5 1 4\n"                                  // point 1: physical 4
    "1 0 0 0 0 1 1 1 1 2 1 2\n"                      // curve 1: physical 1
    "1 0 0 0 1 1 0 1 1 0\n"                          // surface 1: "base"
    "2 0 0 0 1 0 1 1 2 0\n"                          // surface 2: unnamed
    "3 0 0 -1 1 1 0 0 0\n"                           // surface 3: no group
    "1 0 0 -1 1 1 1 2 3 8 0\n"                       // volume 1: physicals 3 and 8
    "$EndEntities\n";

const std::string kBody41 =
    "$Nodes\n1 6 3 99\n3 1 0 6\n10\n5\n99\n7\n3\n20\n"
    "0 0 0\n1 0 0\n5 5 5\n0 1 0\n0 0 1\n0 0 -1\n$EndNodes\n"
    "$Elements\n6 7 1 7\n"
    "0 1 15 1\n1 99\n"
    "1 1 1 1\n4 7 3\n"
    "2 1 2 1\n2 10 5 7\n"
    "2 2 2 1\n3 10 5 3\n"
    "2 3 2 1\n7 10 7 20\n"
    "3 1 4 2\n5 10 5 7 3\n6 10 7 5 20\n"
    "$EndElements\n";

const std::string kFormat41 = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n";

std::string meshError(const std::string& text) {
  try {
    parseTetMesh(text, "mem.msh");
  } catch (const MeshError& e) {
    return e.what();
  }
  return "(no error)";
}

// The positions of a group's nodes, so the node indices are checked against the coordinates the
// file gives the ids, independently of the reader's numbering.
std::set<std::array<double, 3>> positions(const TetMesh& mesh, const NodeGroup& g) {
  std::set<std::array<double, 3>> out;
  for (int n : g.nodes) out.insert({mesh.nodes(0, n), mesh.nodes(1, n), mesh.nodes(2, n)});
  return out;
}

// The groups of the two-tetrahedra mesh, whichever format it came in. `volume_tags` are the
// physical tags its volume carries.
void expectTwoTetGroups(const TetMesh& m, std::vector<int> volume_tags) {
  ASSERT_EQ(m.nodeCount(), 5);
  ASSERT_EQ(m.tetCount(), 2);
  using Points = std::set<std::array<double, 3>>;
  struct Expected {
    int dimension, tag;
    std::string name;
    std::vector<int> nodes;
    Points at;   // the positions the file gives those nodes' ids
  };
  const Points all = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0, 0, -1}};
  std::vector<Expected> expected = {
      {0, 4, "orphan", {}, {}},   // its only node is used by no tetrahedron
      {1, 1, "1", {2, 3}, {{0, 1, 0}, {0, 0, 1}}},   // unnamed: its tag; ids 7 3 after 99 dropped
      {2, 1, "base", {0, 1, 2}, {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}},
      {2, 2, "2", {0, 1, 3}, {{0, 0, 0}, {1, 0, 0}, {0, 0, 1}}},
      {2, 9, "unused", {}, {}}};   // named, no element
  for (int t : volume_tags) {   // names keep their spaces
    expected.push_back({3, t, t == 3 ? "liver volume" : std::to_string(t), {0, 1, 2, 3, 4}, all});
  }
  ASSERT_EQ(m.groups.size(), expected.size());   // ordered by (dimension, tag)
  for (std::size_t i = 0; i < expected.size(); ++i) {
    const NodeGroup& g = m.groups[i];
    SCOPED_TRACE(expected[i].name);
    EXPECT_EQ(g.dimension, expected[i].dimension);
    EXPECT_EQ(g.tag, expected[i].tag);
    EXPECT_EQ(g.name, expected[i].name);
    EXPECT_EQ(g.nodes, expected[i].nodes);
    EXPECT_EQ(positions(m, g), expected[i].at);
  }
}

TEST(MeshGroups, Gmsh22KeepsNamedAndUnnamedGroupsOfEveryDimension) {
  MeshReport report;
  const TetMesh m = parseTetMesh(kFormat22 + kNames22 + kNodes22 + kElements22, "two.msh", &report);
  EXPECT_EQ(report.dropped_nodes, 1);
  EXPECT_EQ(report.ignored_elements, 6);
  expectTwoTetGroups(m, {3});
}

TEST(MeshGroups, Gmsh41TakesTheGroupsFromTheEntitiesOfTheElementBlocks) {
  MeshReport report;
  const TetMesh m =
      parseTetMesh(kFormat41 + kNames22 + kEntities41 + kBody41, "two41.msh", &report);
  EXPECT_EQ(report.format, "gmsh4");
  EXPECT_EQ(report.dropped_nodes, 1);
  expectTwoTetGroups(m, {3, 8});   // an entity in two groups puts its elements in both
  // $Entities after $Elements (unusual, but the format does not forbid it): the same groups
  const TetMesh late = parseTetMesh(kFormat41 + kBody41 + kEntities41 + kNames22, "late.msh");
  expectTwoTetGroups(late, {3, 8});
}

TEST(MeshGroups, Gmsh10UsesTheRegPhysColumn) {
  const TetMesh m = parseTetMesh(
      "$NOD\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 9 9 9\n$ENDNOD\n$ELM\n2\n"
      "1 4 6 1 4 1 2 3 4\n2 2 3 2 3 1 2 3\n$ENDELM\n",
      "v1.msh");
  ASSERT_EQ(m.groups.size(), 2u);
  EXPECT_EQ(m.groups[0].dimension, 2);
  EXPECT_EQ(m.groups[0].tag, 3);
  EXPECT_EQ(m.groups[0].nodes, (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(m.groups[1].name, "6");
  EXPECT_EQ(m.groups[1].nodes, (std::vector<int>{0, 1, 2, 3}));
}

TEST(MeshGroups, FilesWithoutGroupsHaveNone) {
  const TetMesh gmsh = loadTetMesh(kMeshes / "cube_low_res.msh");   // 2.2, no physical tags
  EXPECT_TRUE(gmsh.groups.empty());
  EXPECT_TRUE(loadTetMesh(kMeshes / "cube_low_res_legacy.vtk").groups.empty());
  EXPECT_TRUE(loadTetMesh(kMeshes / "cube_low_res_ascii.vtu").groups.empty());
}

// The shipped box, written by Gmsh itself in both formats: the groups are the nodes on their
// faces, found here from the coordinates alone.
TEST(MeshGroups, GmshWrittenBoxGroupsAreTheFacesNodes) {
  for (const char* file : {"box_groups.msh", "box_groups_v22.msh"}) {
    SCOPED_TRACE(file);
    const TetMesh m = loadTetMesh(kMeshes / file);
    ASSERT_EQ(m.nodeCount(), 78);
    ASSERT_EQ(m.groups.size(), 4u);
    const auto on = [&m](int axis, double value) {
      std::vector<int> out;
      for (int i = 0; i < m.nodeCount(); ++i) {
        if (std::abs(m.nodes(axis, i) - value) < 1e-12) out.push_back(i);
      }
      return out;
    };
    std::vector<int> all(static_cast<std::size_t>(m.nodeCount()));
    for (int i = 0; i < m.nodeCount(); ++i) all[static_cast<std::size_t>(i)] = i;
    const struct {
      int dimension, tag;
      const char* name;
      std::vector<int> nodes;
    } expected[] = {{2, 1, "base", on(2, 0.0)},
                    {2, 2, "top", on(2, 0.02)},
                    {2, 7, "7", on(0, 0.0)},
                    {3, 8, "body", all}};
    for (std::size_t i = 0; i < 4; ++i) {
      EXPECT_EQ(m.groups[i].dimension, expected[i].dimension);
      EXPECT_EQ(m.groups[i].tag, expected[i].tag);
      EXPECT_EQ(m.groups[i].name, expected[i].name);
      EXPECT_EQ(m.groups[i].nodes, expected[i].nodes) << expected[i].name;
      EXPECT_GE(m.groups[i].nodes.size(), 6u);
    }
  }
}

TEST(MeshGroups, MalformedGroupSectionsAreMeshErrorsWithTheLine) {
  const std::string tail = kNodes22 + kElements22;
  const auto names = [&](const std::string& section) {
    return meshError(kFormat22 + "$PhysicalNames\n" + section + "$EndPhysicalNames\n" + tail);
  };
  // lines: 4 $PhysicalNames, 5 the count, 6... the entries
  EXPECT_EQ(names("2\n2 1 \"base\"\n3 3 liver\n"),
            "mem.msh:7: a physical name line needs: dimension tag \"name\" (the name in double "
            "quotes), got '3 3 liver'");
  EXPECT_EQ(names("1\n2 1 \"base\n"),
            "mem.msh:6: a physical name line needs: dimension tag \"name\" (the name in double "
            "quotes), got '2 1 \"base'");
  EXPECT_EQ(names("1\n2 1\n"),
            "mem.msh:6: a physical name line needs: dimension tag \"name\" (the name in double "
            "quotes), got '2 1'");
  EXPECT_EQ(names("1\n5 1 \"base\"\n"), "mem.msh:6: physical dimension must be 0 to 3, got 5");
  EXPECT_EQ(names("1\n2 x \"base\"\n"), "mem.msh:6: expected an integer (physical tag), got 'x'");
  EXPECT_EQ(names("1\n2 99999999999 \"base\"\n"),
            "mem.msh:6: physical tag 99999999999 is out of range");
  EXPECT_EQ(names("2\n2 1 \"base\"\n2 1 \"top\"\n"),
            "mem.msh:7: physical group (dimension 2, tag 1) is named twice (first at line 6)");
  EXPECT_EQ(names("1\n2 1 \"base\"\n2 2 \"top\"\n"),
            "mem.msh:7: expected $EndPhysicalNames to close $PhysicalNames (started at line 4), "
            "got '2 2 \"top\"' (wrong count?)");
  EXPECT_EQ(meshError(kFormat22 + "$PhysicalNames\n2\n2 1 \"base\"\n"),
            "mem.msh:6: unexpected end of file while reading a physical name in $PhysicalNames "
            "(started at line 4)");
  // $Entities (4.1): lines 4 $Entities, 5 the counts, 6 the point
  EXPECT_EQ(meshError(kFormat41 + "$Entities\n1 0 0 0\n1 5 5 5 2 4\n$EndEntities\n" + kBody41),
            "mem.msh:6: entity 1 declares 2 physical tags but its line holds 1 values after the "
            "count");
  EXPECT_EQ(meshError(kFormat41 + "$Entities\n2 0 0 0\n1 5 5 5 0\n1 5 5 5 0\n$EndEntities\n" +
                      kBody41),
            "mem.msh:7: entity (dimension 0, tag 1) is defined twice");
  // a volume in 20000 groups: 80000 node copies of its 2 tetrahedra (8 nodes), more than 16 times
  // those plus 65536: refused rather than amplified (a large entity would ask for gigabytes)
  std::string many = "$Entities\n0 0 0 1\n1 0 0 -1 1 1 1 20000";
  for (int t = 1; t <= 20000; ++t) {
    many += ' ';
    many += std::to_string(t);
  }
  many += " 0\n$EndEntities\n";
  EXPECT_EQ(meshError(kFormat41 + many + kBody41),
            "mem.msh:4: the physical groups of $Entities would hold over 65664 element nodes, 16 "
            "times those of the elements: too many groups per entity");
  // an element of a group that refers to a node the file does not define (line 16: element 2)
  std::string dangling = kElements22;
  dangling.replace(dangling.find("2 2 2 1 1 10 5 7"), 16, "2 2 2 1 1 10 5 77");
  EXPECT_EQ(meshError(kFormat22 + kNodes22 + dangling),
            "mem.msh:16: an element of physical group '1' (dimension 2, tag 1) refers to node 77 "
            "which is not defined");
}

}  // namespace
}  // namespace tactus::sim
