// Mesh readers: counts of every shipped mesh, repairs, error messages of the bad fixtures,
// VTK fixtures against their Gmsh original, and robustness against truncated/corrupted input.

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "tactus/shared/error.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::sim {
namespace {

const std::filesystem::path kIoMeshes = std::filesystem::path(TACTUS_TEST_DATA_DIR) / "meshes";

std::string meshPath(const std::string& file) { return (kIoMeshes / file).string(); }

std::string readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

double tetVolume(const TetMesh& m, int t) {
  const auto& q = m.tets[static_cast<std::size_t>(t)];
  const Eigen::Vector3d a = m.nodes.col(q[0]);
  return (m.nodes.col(q[1]) - a).dot((m.nodes.col(q[2]) - a).cross(m.nodes.col(q[3]) - a)) / 6.0;
}

double totalVolume(const TetMesh& m) {
  double v = 0.0;
  for (int t = 0; t < m.tetCount(); ++t) v += tetVolume(m, t);
  return v;
}

// The message a failing load throws.
std::string loadError(const std::string& file) {
  try {
    loadTetMesh(meshPath(file));
  } catch (const MeshError& e) {
    return e.what();
  }
  return "(no error)";
}

struct Expected {
  const char* file;
  const char* format;
  int nodes;
  int tets;
  int ignored;
  int flipped;
  int dropped;
};

class EveryMesh : public ::testing::TestWithParam<Expected> {};

TEST_P(EveryMesh, LoadsWithExpectedCountsAndPositiveTets) {
  const Expected& e = GetParam();
  MeshReport report;
  const TetMesh m = loadTetMesh(meshPath(e.file), &report);
  EXPECT_EQ(m.nodeCount(), e.nodes);
  EXPECT_EQ(m.tetCount(), e.tets);
  EXPECT_EQ(report.format, e.format);
  EXPECT_EQ(report.ignored_elements, e.ignored);
  EXPECT_EQ(report.flipped_tets, e.flipped);
  EXPECT_EQ(report.dropped_nodes, e.dropped);
  EXPECT_EQ(m.source, meshPath(e.file));
  // every node referenced, every tet positively oriented, indices in range
  std::vector<int> uses(static_cast<std::size_t>(m.nodeCount()), 0);
  for (int t = 0; t < m.tetCount(); ++t) {
    for (int k : m.tets[static_cast<std::size_t>(t)]) {
      ASSERT_GE(k, 0);
      ASSERT_LT(k, m.nodeCount());
      ++uses[static_cast<std::size_t>(k)];
    }
    EXPECT_GT(tetVolume(m, t), 0.0) << "tet " << t;
  }
  EXPECT_EQ(std::count(uses.begin(), uses.end(), 0), 0);
}

INSTANTIATE_TEST_SUITE_P(
    Meshes, EveryMesh,
    ::testing::Values(Expected{"liver2.msh", "gmsh1", 507, 1493, 931, 0, 0},
                      Expected{"liver.msh", "gmsh1", 181, 596, 0, 0, 0},
                      Expected{"liver_23k.msh", "gmsh2", 6259, 23099, 0, 0, 0},
                      Expected{"cube_low_res.msh", "gmsh2", 26, 44, 0, 0, 0},
                      Expected{"cylinder_8x30x6.msh", "gmsh1", 1446, 6750, 0, 0, 0},
                      Expected{"truthcylinder1.msh", "gmsh1", 642, 2524, 778, 0, 0},
                      Expected{"msh4_cube.msh", "gmsh4", 14, 24, 44, 0, 0},
                      Expected{"single_tetra.msh", "gmsh2", 4, 1, 0, 1, 0},
                      Expected{"negative_orientation.msh", "gmsh1", 6, 3, 1, 2, 1},
                      Expected{"cube_low_res_legacy.vtk", "vtk-legacy", 26, 44, 3, 0, 0},
                      Expected{"cube_low_res_legacy51.vtk", "vtk-legacy", 26, 44, 0, 0, 0},
                      Expected{"cube_low_res_ascii.vtu", "vtu", 26, 44, 0, 0, 0},
                      Expected{"cube_low_res_base64.vtu", "vtu", 26, 44, 0, 0, 0},
                      Expected{"cube_low_res_zlib.vtu", "vtu", 26, 44, 0, 0, 0},
                      Expected{"cube_low_res_appended.vtu", "vtu", 26, 44, 0, 0, 0}),
    [](const ::testing::TestParamInfo<Expected>& info) {
      std::string n = info.param.file;
      for (char& c : n) {
        if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
      }
      return n;
    });

TEST(MeshIo, KnownVolumes) {
  // the unit cube and the 7 x 7 x 7 cube, in file units
  EXPECT_NEAR(totalVolume(loadTetMesh(meshPath("msh4_cube.msh"))), 1.0, 1e-12);
  EXPECT_NEAR(totalVolume(loadTetMesh(meshPath("cube_low_res.msh"))), 343.0, 1e-9);
  EXPECT_NEAR(totalVolume(loadTetMesh(meshPath("single_tetra.msh"))), 12.5, 1e-12);
}

TEST(MeshIo, SparseIdsRenumberedInFileOrderAndRepaired) {
  MeshReport report;
  const TetMesh m = loadTetMesh(meshPath("negative_orientation.msh"), &report);
  // file order 40 7 12 3 25 (99 unused) 8 -> 0 1 2 3 4 5
  ASSERT_EQ(m.nodeCount(), 6);
  EXPECT_EQ(m.nodes.col(0), Eigen::Vector3d(0, 0, 0));
  EXPECT_EQ(m.nodes.col(4), Eigen::Vector3d(1, 1, 1));
  EXPECT_EQ(m.nodes.col(5), Eigen::Vector3d(-1, 0, 0));
  // first tet kept as is, the second had two nodes swapped
  EXPECT_EQ(m.tets[0], (std::array<int, 4>{0, 1, 2, 3}));
  EXPECT_EQ(m.tets[1], (std::array<int, 4>{1, 3, 4, 2}));
  EXPECT_NEAR(totalVolume(m), 1.0 / 6 + 1.0 / 3 + 1.0 / 6, 1e-15);
}

TEST(MeshIo, VtkFixturesMatchTheGmshOriginal) {
  const TetMesh original = loadTetMesh(meshPath("cube_low_res.msh"));
  const double volume = totalVolume(original);
  for (const char* file : {"cube_low_res_legacy.vtk", "cube_low_res_legacy51.vtk",
                           "cube_low_res_ascii.vtu", "cube_low_res_base64.vtu",
                           "cube_low_res_zlib.vtu", "cube_low_res_appended.vtu"}) {
    SCOPED_TRACE(file);
    const TetMesh m = loadTetMesh(meshPath(file));
    EXPECT_NEAR(totalVolume(m), volume, 1e-12 * volume);
    ASSERT_EQ(m.nodeCount(), original.nodeCount());
    EXPECT_EQ(m.nodes, original.nodes);  // written with round-trip precision
    EXPECT_EQ(m.tets, original.tets);
  }
}

TEST(MeshIo, SixTetraBadHasDuplicateElementIds) {
  // all six elements of SOFA's 6_tetra_bad.msh carry the id 44 (and one is inverted): every
  // duplicate is listed, each with its line
  const std::string m = meshPath("6_tetra_bad.msh");
  std::string expected = m + ": 5 problems in the mesh:";
  for (int line = 27; line <= 31; ++line)
    expected += "\n" + m + ":" + std::to_string(line) +
                ": element 44 is defined twice (first at line 26)";
  EXPECT_EQ(loadError("6_tetra_bad.msh"), expected);
}

TEST(MeshIo, BadFixturesNameFileAndLine) {
  EXPECT_EQ(loadError("bad_missing_node.msh"),
            meshPath("bad_missing_node.msh") +
                ":15: element 2 refers to node 99 which is not defined");
  EXPECT_EQ(loadError("bad_zero_volume.msh"),
            meshPath("bad_zero_volume.msh") +
                ":15: element 7 is degenerate: volume 0 is zero at the mesh size 1.73 (its nodes "
                "are coplanar)");
  EXPECT_EQ(loadError("bad_truncated.msh"),
            meshPath("bad_truncated.msh") +
                ":45: unexpected end of file while reading an element in $Elements (started at "
                "line 33)");
  EXPECT_EQ(loadError("bad_no_tets.msh"),
            meshPath("bad_no_tets.msh") +
                ":13: no tetrahedra (4-node elements) in the file (1 other elements ignored)");
  EXPECT_EQ(loadError("bad_missing_elements.msh"),
            meshPath("bad_missing_elements.msh") +
                ":10: no element section ($Elements or $ELM) in the file");
  EXPECT_EQ(loadError("bad_missing_point.vtk"),
            meshPath("bad_missing_point.vtk") +
                ":12: cell 1 refers to point 9 which is not defined");
  EXPECT_EQ(loadError("bad_truncated_zlib.vtu"),
            meshPath("bad_truncated_zlib.vtu") +
                ":12: unexpected end of file: <DataArray> is not closed");
  EXPECT_EQ(loadError("does_not_exist.msh"),
            meshPath("does_not_exist.msh") +
                ": cannot open mesh file: No such file or directory (check the path)");
}

TEST(MeshIo, InMemoryErrors) {
  const auto error = [](const std::string& text) {
    try {
      parseTetMesh(text, "mem.msh");
    } catch (const MeshError& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  EXPECT_EQ(error("solid cube\n"),
            "mem.msh:1: unrecognised mesh format (expected Gmsh .msh, legacy VTK .vtk or VTK XML "
            ".vtu)");
  EXPECT_EQ(error("$MeshFormat\n2.2 1 8\n$EndMeshFormat\n"),
            "mem.msh:2: binary Gmsh files are not supported: re-save the mesh as ASCII (gmsh "
            "-save -format msh22 or msh41)");
  EXPECT_EQ(error("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n2\n1 0 0 0\n1 1 0 0\n"
                  "$EndNodes\n$Elements\n0\n$EndElements\n"),
            "mem.msh: 2 problems in the mesh:\nmem.msh:7: node 1 is defined twice (first at line "
            "6)\nmem.msh:11: no tetrahedra (4-node elements) in the file (0 other elements "
            "ignored)");
  EXPECT_EQ(error("$NOD\n1\n1 0 0 nan\n$ENDNOD\n$ELM\n0\n$ENDELM\n"),
            "mem.msh: 2 problems in the mesh:\nmem.msh:3: node 1 has a non-finite coordinate\n"
            "mem.msh:7: no tetrahedra (4-node elements) in the file (0 other elements ignored)");
  EXPECT_EQ(error("$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n$ELM\n1\n"
                  "1 4 1 1 4 1 2 3 x\n$ENDELM\n"),
            "mem.msh:10: expected an integer (node id), got 'x'");
  EXPECT_EQ(error("$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n$ELM\n1\n"
                  "1 4 1 1 4 1 2 3 3\n$ENDELM\n"),
            "mem.msh:10: element 1 is degenerate: it uses node 3 twice");
  EXPECT_EQ(error("$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n$ELM\n2\n"
                  "1 4 1 1 4 1 2 3 4\n$ENDELM\n"),
            "mem.msh:11: expected an integer (element id), got '$ENDELM'");
  EXPECT_EQ(error("$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n$ELM\n1\n"
                  "1 4 1 1 4 1 2 3 4\n2 4 1 1 4 1 2 4 3\n$ENDELM\n"),
            "mem.msh:11: expected $ENDELM to close $ELM (started at line 8), got "
            "'2 4 1 1 4 1 2 4 3' (wrong count?)");
}

// A Gmsh 1.0 file of the given nodes ("id x y z") and tets ("id a b c d").
std::string gmsh1(const std::vector<std::string>& nodes, const std::vector<std::string>& tets) {
  std::string t = "$NOD\n" + std::to_string(nodes.size()) + "\n";
  for (const auto& n : nodes) t += n + "\n";
  t += "$ENDNOD\n$ELM\n" + std::to_string(tets.size()) + "\n";
  for (const auto& e : tets) {
    std::istringstream in(e);
    std::string id, rest, word;
    in >> id;
    while (in >> word) rest += " " + word;
    t += id + " 4 1 1 4" + rest + "\n";
  }
  return t + "$ENDELM\n";
}

TEST(MeshChecks, ANodePushedThroughAFaceIsATangleNamedWithItsElements) {
  // the second tet's apex, node 5, beyond the plane x + y + z = 1 of the shared face (2, 3, 4):
  // a valid mesh (its reversed node order repaired); pushed through the face to node 1's side,
  // the two tets overlap
  const std::string untangled =
      gmsh1({"1 0 0 0", "2 1 0 0", "3 0 1 0", "4 0 0 1", "5 0.6 0.6 0.6"},
            {"10 1 2 3 4", "11 5 2 3 4"});
  MeshReport report;
  EXPECT_EQ(parseTetMesh(untangled, "ok.msh", &report).tetCount(), 2);
  EXPECT_EQ(report.flipped_tets, 1);   // a reversed tet of a valid mesh is repaired
  const std::string tangled =
      gmsh1({"1 0 0 0", "2 1 0 0", "3 0 1 0", "4 0 0 1", "5 0.2 0.2 0.2"},
            {"10 1 2 3 4", "11 5 2 3 4"});
  try {
    parseTetMesh(tangled, "tangled.msh");
    ADD_FAILURE() << "a tangled mesh loaded";
  } catch (const MeshError& e) {
    EXPECT_EQ(std::string(e.what()),
              "tangled.msh:12: elements 10 and 11 overlap: both lie on the same side of their "
              "shared face (the mesh is tangled, e.g. a node pushed through a face)");
  }
}

// A mesh as Gmsh 1.0 text (ids from 1).
std::string gmsh1(const TetMesh& m) {
  std::vector<std::string> nodes, tets;
  for (int i = 0; i < m.nodeCount(); ++i) {
    std::ostringstream line;
    line.precision(17);
    line << i + 1 << " " << m.nodes(0, i) << " " << m.nodes(1, i) << " " << m.nodes(2, i);
    nodes.push_back(line.str());
  }
  for (int t = 0; t < m.tetCount(); ++t) {
    std::string line = std::to_string(t + 1);
    for (int k : m.tets[static_cast<std::size_t>(t)]) {
      line += ' ';   // not " " + std::to_string(): GCC 12 warns falsely (-Wrestrict) on it at -O3
      line += std::to_string(k + 1);
    }
    tets.push_back(line);
  }
  return gmsh1(nodes, tets);
}

std::string parseError(const std::string& text, const std::string& name) {
  try {
    parseTetMesh(text, name);
  } catch (const MeshError& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(MeshChecks, ATangledBoxMeshIsReportedWithEveryFoldedFace) {
  // a 3 x 3 x 3 box (162 tets); its interior node (1, 1, 1) pushed 1.5 cells along x, through
  // the faces of its star
  TetMesh box = makeBoxTetMesh(3, 3, 3, Eigen::Vector3d::Constant(3.0));
  const int moved = 1 + 4 * (1 + 4 * 1);
  ASSERT_TRUE(box.nodes.col(moved).isApprox(Eigen::Vector3d(1, 1, 1)));
  EXPECT_EQ(parseTetMesh(gmsh1(box), "box.msh").tetCount(), 162);
  box.nodes(0, moved) += 1.5;
  const std::string message = parseError(gmsh1(box), "tangled.msh");
  std::printf("[mesh] %s\n", message.c_str());
  EXPECT_THAT(message, ::testing::StartsWith("tangled.msh: "));
  EXPECT_THAT(message, ::testing::HasSubstr(" problems in the mesh"));
  EXPECT_THAT(message, ::testing::HasSubstr("overlap: both lie on the same side of their shared "
                                            "face (the mesh is tangled"));
}

TEST(MeshChecks, EveryProblemIsListedUpToTwentyAndAllAreCounted) {
  // 30 tets, each referring to a node that does not exist, one zero-volume tet and a duplicate
  std::vector<std::string> tets;
  for (int t = 1; t <= 30; ++t) tets.push_back(std::to_string(t) + " 1 2 3 99");
  const std::string text = gmsh1({"1 0 0 0", "2 1 0 0", "3 0 1 0", "4 0 0 1"}, tets);
  const std::string message = parseError(text, "many.msh");
  EXPECT_THAT(message,
              ::testing::StartsWith("many.msh: 30 problems in the mesh (the first 20 listed):\n"
                                    "many.msh:10: element 1 refers to node 99 which is not "
                                    "defined\n"));
  EXPECT_EQ(std::count(message.begin(), message.end(), '\n'), 20);
  // several kinds at once: each one listed with its line
  const std::string mixed = gmsh1({"1 0 0 0", "2 1 0 0", "3 0 1 0", "4 0 0 1", "5 1 1 0"},
                                  {"7 1 2 3 4", "7 1 2 4 99", "8 1 2 3 5"});
  EXPECT_EQ(parseError(mixed, "mixed.msh"),
            "mixed.msh: 3 problems in the mesh:\n"
            "mixed.msh:12: element 7 is defined twice (first at line 11)\n"
            "mixed.msh:12: element 7 refers to node 99 which is not defined\n"
            "mixed.msh:13: element 8 is degenerate: volume 0 is zero at the mesh size 1.73 (its "
            "nodes are coplanar)");
}

TEST(MeshChecks, ANearSliverLoadsWithItsCountAndTheWorstQuality) {
  // a sliver of height 1e-8 m over 1 cm edges beside a well-shaped tet
  const std::string text =
      gmsh1({"1 0 0 0", "2 0.01 0 0", "3 0 0.01 0", "4 0 0 0.01", "5 0.005 0.005 -1e-8"},
            {"1 1 2 3 4", "2 1 3 2 5"});
  MeshReport report;
  const TetMesh m = parseTetMesh(text, "sliver.msh", &report);
  EXPECT_EQ(m.tetCount(), 2);
  EXPECT_EQ(report.sliver_tets, 1);
  EXPECT_GT(report.worst_mean_ratio, 0.0);
  EXPECT_LT(report.worst_mean_ratio, 1e-3);
  EXPECT_EQ(report.worst_mean_ratio_line, 12);
  MeshReport good;
  parseTetMesh(gmsh1({"1 0 0 0", "2 1 0 0", "3 0 1 0", "4 0 0 1"}, {"1 1 2 3 4"}), "one.msh",
               &good);
  EXPECT_EQ(good.sliver_tets, 0);
  EXPECT_GT(good.worst_mean_ratio, 0.8);   // the corner tet of a cube: 0.84
}

// Truncations at every byte and random byte corruption: a result or a MeshError, nothing else.
TEST(MeshIo, NeverCrashesOnTruncatedOrCorruptedInput) {
  std::mt19937 rng(12345);
  int parsed = 0, rejected = 0;
  for (const char* file : {"cube_low_res.msh", "msh4_cube.msh", "negative_orientation.msh",
                           "cube_low_res_legacy.vtk", "cube_low_res_legacy51.vtk",
                           "cube_low_res_ascii.vtu", "cube_low_res_base64.vtu",
                           "cube_low_res_zlib.vtu", "cube_low_res_appended.vtu",
                           "box_groups.msh", "box_groups_v22.msh"}) {
    SCOPED_TRACE(file);
    const std::string text = readFile(meshPath(file));
    const auto attempt = [&](const std::string& input) {
      try {
        const TetMesh m = parseTetMesh(input, file);
        for (const auto& t : m.tets) {
          for (int k : t) ASSERT_TRUE(k >= 0 && k < m.nodeCount());
        }
        for (const NodeGroup& g : m.groups) {
          for (int k : g.nodes) ASSERT_TRUE(k >= 0 && k < m.nodeCount());
        }
        ++parsed;
      } catch (const MeshError&) {
        ++rejected;
      }
    };
    for (std::size_t cut = 0; cut < text.size(); cut += 7) attempt(text.substr(0, cut));
    for (int trial = 0; trial < 300; ++trial) {
      std::string bad = text;
      const int edits = 1 + static_cast<int>(rng() % 4);
      for (int e = 0; e < edits; ++e) {
        bad[rng() % bad.size()] = static_cast<char>(rng() % 256);
      }
      attempt(bad);
    }
  }
  EXPECT_GT(rejected, 1000);
  EXPECT_GT(parsed, 0);  // some corruptions hit only comments or insignificant digits
}

}  // namespace
}  // namespace tactus::sim
