// Boundary extraction: faces owned by exactly one tetrahedron, oriented outward.

#include <algorithm>
#include <tuple>

#include "tactus/sim/mesh.h"

namespace tactus::sim {

SurfaceMesh extractSurface(const TetMesh& mesh) {
  // faces of a positively oriented tet (a, b, c, d) with outward normals
  static constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  struct Face {
    std::array<int, 3> key;  // sorted node indices
    int tet;
    int local;
  };
  std::vector<Face> faces;
  faces.reserve(mesh.tets.size() * 4);
  for (std::size_t t = 0; t < mesh.tets.size(); ++t) {
    for (int f = 0; f < 4; ++f) {
      std::array<int, 3> key = {mesh.tets[t][kFaces[f][0]], mesh.tets[t][kFaces[f][1]],
                                mesh.tets[t][kFaces[f][2]]};
      std::sort(key.begin(), key.end());
      faces.push_back({key, static_cast<int>(t), f});
    }
  }
  std::sort(faces.begin(), faces.end(), [](const Face& a, const Face& b) {
    return std::tie(a.key, a.tet, a.local) < std::tie(b.key, b.tet, b.local);
  });
  SurfaceMesh surface;
  // runs of equal keys: a run of one is a boundary face
  for (std::size_t i = 0; i < faces.size();) {
    std::size_t j = i + 1;
    while (j < faces.size() && faces[j].key == faces[i].key) ++j;
    if (j - i == 1) {
      const auto& tet = mesh.tets[static_cast<std::size_t>(faces[i].tet)];
      const int f = faces[i].local;
      surface.triangles.push_back({tet[kFaces[f][0]], tet[kFaces[f][1]], tet[kFaces[f][2]]});
      surface.triangle_tet.push_back(faces[i].tet);
    }
    i = j;
  }
  for (const auto& tri : surface.triangles) {
    surface.nodes.insert(surface.nodes.end(), tri.begin(), tri.end());
  }
  std::sort(surface.nodes.begin(), surface.nodes.end());
  surface.nodes.erase(std::unique(surface.nodes.begin(), surface.nodes.end()),
                      surface.nodes.end());
  return surface;
}

}  // namespace tactus::sim
