// Collision, the tissue surface's upkeep for the broad phase: triangle adjacency, node -> triangle
// lists, the boxes the AABB trees refit, and the normals computed on demand once per refit.

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

Eigen::Vector3d Collision::Impl::triNormal(int t) {
  if (tri_normal_epoch[t] != epoch) {
    const auto& tri = surface.triangles[t];
    const Eigen::Vector3d p0 = pos(tri[0]);
    const Eigen::Vector3d nrm = (pos(tri[1]) - p0).cross(pos(tri[2]) - p0);
    const double len = nrm.norm();
    tri_normal.col(t) = len > 0.0 ? Eigen::Vector3d(nrm / len) : Eigen::Vector3d::Zero();
    tri_normal_epoch[t] = epoch;
  }
  return tri_normal.col(t);
}

// Angle-weighted pseudo-normal of a surface node (unit; zero if degenerate).
Eigen::Vector3d Collision::Impl::vertexNormal(int node) {
  if (vertex_normal_epoch[node] != epoch) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    const Eigen::Vector3d p = pos(node);
    for (int i = vt_offset[node]; i < vt_offset[node + 1]; ++i) {
      const int t = vt_tri[i];
      const auto& tri = surface.triangles[t];
      const int k = tri[0] == node ? 0 : (tri[1] == node ? 1 : 2);
      const Eigen::Vector3d e1 = pos(tri[(k + 1) % 3]) - p, e2 = pos(tri[(k + 2) % 3]) - p;
      const double angle = std::atan2(e1.cross(e2).norm(), e1.dot(e2));
      sum += angle * triNormal(t);
    }
    const double len = sum.norm();
    vertex_normal.col(node) = len > 0.0 ? Eigen::Vector3d(sum / len) : Eigen::Vector3d::Zero();
    vertex_normal_epoch[node] = epoch;
  }
  return vertex_normal.col(node);
}

Eigen::Vector3d Collision::Impl::pseudoNormal(const Candidate& cand) {
  const int region = cand.cp.region;
  if (region == kFace) return triNormal(cand.tri);
  if (region < kEdge0) return vertexNormal(surface.triangles[cand.tri][region - kVertex0]);
  const int nb = tri_neighbor[cand.tri][region - kEdge0];
  Eigen::Vector3d n = triNormal(cand.tri);
  if (nb >= 0) n += triNormal(nb);
  return n;
}

}  // namespace tactus::sim
