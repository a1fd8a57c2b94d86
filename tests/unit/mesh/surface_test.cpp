// Surface extraction: closed, consistently outward, bounding the tet volume (divergence theorem).

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <filesystem>
#include <map>
#include <set>

#include "tactus/sim/mesh.h"

namespace tactus::sim {
namespace {

const std::filesystem::path kSurfaceMeshes = std::filesystem::path(TACTUS_TEST_DATA_DIR) / "meshes";

class SurfaceOf : public ::testing::TestWithParam<const char*> {};

TEST_P(SurfaceOf, IsClosedOutwardAndBoundsTheVolume) {
  const TetMesh mesh = loadTetMesh(kSurfaceMeshes / GetParam());
  const SurfaceMesh s = extractSurface(mesh);
  ASSERT_FALSE(s.triangles.empty());
  ASSERT_EQ(s.triangle_tet.size(), s.triangles.size());
  // every directed edge exactly once and its reverse exactly once: closed, manifold along
  // edges and consistently oriented
  std::map<std::pair<int, int>, int> directed;
  for (const auto& t : s.triangles) {
    for (int k = 0; k < 3; ++k) ++directed[{t[k], t[(k + 1) % 3]}];
  }
  for (const auto& [edge, count] : directed) {
    ASSERT_EQ(count, 1) << "edge " << edge.first << "-" << edge.second;
    ASSERT_EQ(directed.count({edge.second, edge.first}), 1u)
        << "open edge " << edge.first << "-" << edge.second;
  }
  // divergence theorem: sum of p0 . (p1 x p2) / 6 over outward triangles = enclosed volume
  double surface_volume = 0.0;
  for (const auto& t : s.triangles) {
    surface_volume +=
        mesh.nodes.col(t[0]).dot(mesh.nodes.col(t[1]).cross(mesh.nodes.col(t[2]))) / 6.0;
  }
  double tet_volume = 0.0;
  for (const auto& q : mesh.tets) {
    const Eigen::Vector3d a = mesh.nodes.col(q[0]);
    tet_volume += (mesh.nodes.col(q[1]) - a)
                      .dot((mesh.nodes.col(q[2]) - a).cross(mesh.nodes.col(q[3]) - a)) /
                  6.0;
  }
  EXPECT_GT(surface_volume, 0.0);
  EXPECT_NEAR(surface_volume, tet_volume, 1e-9 * tet_volume);
  // each triangle is a face of its tet, and its normal points away from the tet's fourth node
  for (std::size_t i = 0; i < s.triangles.size(); ++i) {
    const auto& t = s.triangles[i];
    const auto& q = mesh.tets[static_cast<std::size_t>(s.triangle_tet[i])];
    int apex = -1;
    for (int v : q) {
      if (v != t[0] && v != t[1] && v != t[2]) apex = v;
    }
    ASSERT_GE(apex, 0);
    ASSERT_EQ(std::count_if(q.begin(), q.end(),
                            [&](int v) { return v == t[0] || v == t[1] || v == t[2]; }),
              3);
    const Eigen::Vector3d n = (mesh.nodes.col(t[1]) - mesh.nodes.col(t[0]))
                                  .cross(mesh.nodes.col(t[2]) - mesh.nodes.col(t[0]));
    EXPECT_LT(n.dot(mesh.nodes.col(apex) - mesh.nodes.col(t[0])), 0.0);
  }
  // surface nodes: sorted, unique, exactly the triangle corners
  std::set<int> corners;
  for (const auto& t : s.triangles) corners.insert(t.begin(), t.end());
  EXPECT_EQ(s.nodes, std::vector<int>(corners.begin(), corners.end()));
  // Euler characteristic of a closed genus-0 surface: V - E + F = 2
  const auto v = static_cast<long>(s.nodes.size());
  const auto f = static_cast<long>(s.triangles.size());
  EXPECT_EQ(v - f * 3 / 2 + f, 2);
}

INSTANTIATE_TEST_SUITE_P(Livers, SurfaceOf,
                         ::testing::Values("liver.msh", "liver2.msh", "liver_23k.msh",
                                           "msh4_cube.msh", "cube_low_res.msh"),
                         [](const ::testing::TestParamInfo<const char*>& info) {
                           std::string n = info.param;
                           return n.substr(0, n.find('.'));
                         });

TEST(Surface, SingleTetHasItsFourFaces) {
  const TetMesh mesh = loadTetMesh(kSurfaceMeshes / "single_tetra.msh");
  const SurfaceMesh s = extractSurface(mesh);
  EXPECT_EQ(s.triangles.size(), 4u);
  EXPECT_EQ(s.nodes, (std::vector<int>{0, 1, 2, 3}));
  EXPECT_EQ(s.triangle_tet, (std::vector<int>{0, 0, 0, 0}));
}

TEST(Surface, TwoTetsShareAnInteriorFace) {
  TetMesh mesh;
  mesh.nodes.resize(3, 5);
  mesh.nodes << 0, 1, 0, 0, 1,  //
      0, 0, 1, 0, 1,            //
      0, 0, 0, 1, 1;
  mesh.tets = {{0, 1, 2, 3}, {1, 3, 2, 4}};
  const SurfaceMesh s = extractSurface(mesh);
  EXPECT_EQ(s.triangles.size(), 6u);  // 8 faces minus the shared one counted twice
  EXPECT_EQ(std::count(s.triangle_tet.begin(), s.triangle_tet.end(), 0), 3);
}

}  // namespace
}  // namespace tactus::sim
