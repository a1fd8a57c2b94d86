#pragma once
// A tissue's surface triangles at its current positions, for closest-point queries against it
// (collision_impl.h closestOnSurface): unit outward face normals, angle-weighted vertex normals
// and an AABB tree over the triangles, refit at every detection. Used by the contact between
// tissues (tissue_contact.cpp) and by the obstacles' edges against tissue faces (obstacles.cpp).

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <vector>

#include "aabb_tree.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim::collision_detail {

struct MovingSurface {
  const TetMesh* mesh = nullptr;
  const SurfaceMesh* surface = nullptr;
  std::vector<Eigen::Vector3d> face_normal;      // unit, outward, per triangle
  std::vector<Eigen::Vector3d> vertex_normal;    // angle-weighted, unit, per surface node (local)
  std::vector<int> local;                        // TetMesh node -> index in surface->nodes, or -1
  std::vector<Eigen::AlignedBox3d> boxes;        // per triangle
  detail::AabbTree tree;

  /// Sizes everything for `m`'s surface `s` and builds the tree at the rest positions.
  void init(const TetMesh& m, const SurfaceMesh& s) {
    mesh = &m;
    surface = &s;
    const std::size_t nt = s.triangles.size();
    face_normal.resize(nt);
    boxes.resize(nt);
    vertex_normal.resize(s.nodes.size());
    local.assign(static_cast<std::size_t>(m.nodeCount()), -1);
    for (std::size_t i = 0; i < s.nodes.size(); ++i) {
      local[static_cast<std::size_t>(s.nodes[i])] = static_cast<int>(i);
    }
    Eigen::VectorXd q(3 * m.nodeCount());
    for (int i = 0; i < m.nodeCount(); ++i) q.segment<3>(3 * i) = m.nodes.col(i);
    refit(q);
    tree.build(boxes);
  }

  /// Normals, boxes and tree at the positions q (3n, node-major).
  void refit(const Eigen::VectorXd& q) {
    const auto& tris = surface->triangles;
    std::fill(vertex_normal.begin(), vertex_normal.end(), Eigen::Vector3d::Zero());
    for (std::size_t t = 0; t < tris.size(); ++t) {
      const auto& tri = tris[t];
      const Eigen::Vector3d p[3] = {q.segment<3>(3 * tri[0]), q.segment<3>(3 * tri[1]),
                                    q.segment<3>(3 * tri[2])};
      const Eigen::Vector3d cross = (p[1] - p[0]).cross(p[2] - p[0]);
      const double norm = cross.norm();
      const Eigen::Vector3d normal =
          norm > 0.0 ? Eigen::Vector3d(cross / norm) : Eigen::Vector3d::Zero();
      face_normal[t] = normal;
      Eigen::AlignedBox3d box(p[0]);
      box.extend(p[1]);
      box.extend(p[2]);
      boxes[t] = box;
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector3d e1 = p[(k + 1) % 3] - p[k];
        const Eigen::Vector3d e2 = p[(k + 2) % 3] - p[k];
        const double denominator = e1.norm() * e2.norm();
        if (!(denominator > 0.0)) continue;
        const double angle = std::acos(std::clamp(e1.dot(e2) / denominator, -1.0, 1.0));
        vertex_normal[static_cast<std::size_t>(local[static_cast<std::size_t>(tri[k])])] +=
            angle * normal;
      }
    }
    for (Eigen::Vector3d& n : vertex_normal) {
      const double norm = n.norm();
      if (norm > 0.0) n /= norm;
    }
    tree.refit(boxes);
  }
};

}  // namespace tactus::sim::collision_detail
