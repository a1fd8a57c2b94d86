// Collision, the tissue surface's upkeep for the broad phase: triangle adjacency, node -> triangle
// lists and the boxes the AABB trees refit (the normals, computed on demand once per refit, are
// inline in collision_impl.h: the narrow phases call them per candidate).

#include <algorithm>
#include <cmath>
#include <vector>

#include "collision_impl.h"

namespace tactus::sim {

using namespace collision_detail;

void Collision::Impl::buildAdjacency() {
  const int nt = static_cast<int>(surface.triangles.size());
  tri_neighbor.assign(nt, {-1, -1, -1});
  struct EdgeRef {
    int lo, hi, tri, k;
  };
  std::vector<EdgeRef> edges;
  edges.reserve(3 * nt);
  for (int t = 0; t < nt; ++t) {
    for (int k = 0; k < 3; ++k) {
      const int u = surface.triangles[t][k], v = surface.triangles[t][(k + 1) % 3];
      edges.push_back({std::min(u, v), std::max(u, v), t, k});
    }
  }
  std::sort(edges.begin(), edges.end(), [](const EdgeRef& a, const EdgeRef& b) {
    return a.lo != b.lo ? a.lo < b.lo : a.hi != b.hi ? a.hi < b.hi : a.tri < b.tri;
  });
  // link the triangles sharing an edge (cyclically when non-manifold)
  for (std::size_t i = 0; i < edges.size();) {
    std::size_t j = i;
    while (j < edges.size() && edges[j].lo == edges[i].lo && edges[j].hi == edges[i].hi) ++j;
    if (j - i >= 2) {
      for (std::size_t e = i; e < j; ++e) {
        const EdgeRef& next = edges[e + 1 < j ? e + 1 : i];
        tri_neighbor[edges[e].tri][edges[e].k] = next.tri;
      }
    }
    i = j;
  }
}

void Collision::Impl::buildVertexTriangles() {
  vt_offset.assign(node_count + 1, 0);
  for (const auto& tri : surface.triangles) {
    for (int node : tri) ++vt_offset[node + 1];
  }
  for (int i = 0; i < node_count; ++i) vt_offset[i + 1] += vt_offset[i];
  vt_tri.resize(vt_offset[node_count]);
  std::vector<int> fill(vt_offset.begin(), vt_offset.end() - 1);
  for (int t = 0; t < static_cast<int>(surface.triangles.size()); ++t) {
    for (int node : surface.triangles[t]) vt_tri[fill[node]++] = t;
  }
}

// Boxes of the current positions; normals become stale (new epoch).
void Collision::Impl::updateGeometry() {
  ++epoch;
  const int nt = static_cast<int>(surface.triangles.size());
  for (int t = 0; t < nt; ++t) {
    const auto& tri = surface.triangles[t];
    Box box(pos(tri[0]));
    box.extend(pos(tri[1]));
    box.extend(pos(tri[2]));
    tri_boxes[t] = box;
  }
  for (std::size_t i = 0; i < surface.nodes.size(); ++i) {
    const Eigen::Vector3d p = pos(surface.nodes[i]);
    vertex_boxes[i] = Box(p, p);
  }
}

}  // namespace tactus::sim
