#pragma once
// Private to collision: the geometric primitives (closest points on a triangle and a segment, the
// grown-box slab test) and Collision::Impl, shared by the collision source files. The primitives
// and the normals are inline: the narrow phases call them per candidate.
//   collision.cpp             construction, refit, detect (the cap), contact records and rows
//   collision_surface.cpp     broad phase upkeep: adjacency, node -> triangle lists, boxes
//   collision_vertex.cpp      narrow phase: tissue vertices against capsules and pads
//   collision_sphere.cpp      narrow phase: spheres against the surface triangles

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "aabb_tree.h"
#include "tactus/sim/collision.h"
#include "tactus/sim/state_archive.h"

namespace tactus::sim::collision_detail {

using Box = Eigen::AlignedBox3d;

// Closest-point regions on a triangle (v0, v1, v2); edge k joins v_k and v_(k+1)%3.
enum Region : int { kFace = 0, kVertex0 = 1, kEdge0 = 4 };

constexpr double kTinyDistance_m = 1e-12;
constexpr double kOpposedCos = -0.1;   // inside: ignore faces whose normal opposes the nearest

struct ClosestPoint {
  Eigen::Vector3d p;
  std::array<double, 3> bary;
  int region;
};

// Closest point of p on triangle (a, b, c) by Voronoi regions (Ericson, Real-Time Collision
// Detection 5.1.5); vertex/edge regions carry exact zero weights.
inline ClosestPoint closestOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                      const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return {a, {1, 0, 0}, kVertex0};
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return {b, {0, 1, 0}, kVertex0 + 1};
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    const double v = d1 / (d1 - d3);
    return {a + v * ab, {1.0 - v, v, 0.0}, kEdge0};
  }
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return {c, {0, 0, 1}, kVertex0 + 2};
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    const double w = d2 / (d2 - d6);
    return {a + w * ac, {1.0 - w, 0.0, w}, kEdge0 + 2};
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return {b + w * (c - b), {0.0, 1.0 - w, w}, kEdge0 + 1};
  }
  const double sum = va + vb + vc;
  if (!(sum > 0.0)) return {a, {1, 0, 0}, kVertex0};   // degenerate triangle
  const double v = vb / sum, w = vc / sum;
  return {a + v * ab + w * ac, {1.0 - v - w, v, w}, kFace};
}

// Parameter in [0, 1] of the closest point of p on segment a..b.
inline double closestOnSegment(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                               const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  if (len2 <= 0.0) return 0.0;
  return std::clamp((p - a).dot(ab) / len2, 0.0, 1.0);
}

// The closest point of p over a triangle surface, among the triangles whose box is within `reach`
// of p (through `tree`, built over the triangles) and that skip(t) keeps. Triangles at the same
// distance (to 1e-12 relative: an edge or vertex they share) add their (p - c) . N_t to `side`,
// an unweighted pseudo-normal whose sign says whether p is outside (> 0) or inside. vertex(i) is
// vertex i's position, normals[t] triangle t's unit outward normal. Used by the mesh obstacles
// and by the contact between tissues.
struct SurfaceClosest {
  double distance = std::numeric_limits<double>::infinity();
  double side = 0.0;
  int triangle = -1;                 // -1: none within reach
  ClosestPoint point{};
};

template <class Vertex, class Skip>
SurfaceClosest closestOnSurface(const detail::AabbTree& tree,
                                const std::vector<std::array<int, 3>>& triangles,
                                const std::vector<Eigen::Vector3d>& normals,
                                const Eigen::Vector3d& p, double reach, Vertex&& vertex,
                                Skip&& skip) {
  SurfaceClosest best;
  tree.query([&](const Box& box) { return box.exteriorDistance(p) <= reach; },
             [&](int t) {
               const auto& tri = triangles[static_cast<std::size_t>(t)];
               if (skip(tri)) return;
               const ClosestPoint c = closestOnTriangle(p, vertex(tri[0]), vertex(tri[1]),
                                                        vertex(tri[2]));
               const double d = (p - c.p).norm();
               const double dot = (p - c.p).dot(normals[static_cast<std::size_t>(t)]);
               const double same = 1e-12 * std::max(1.0, d);
               if (d < best.distance - same) {
                 best.distance = d;
                 best.side = dot;
                 best.triangle = t;
                 best.point = c;
               } else if (d <= best.distance + same) {
                 best.side += dot;
               }
             });
  return best;
}

// The surface's outward unit normal at found's closest point, seen from p: along p - c, turned by
// the side (p inside: from p toward c), or the triangle's normal when p lies on the surface.
inline Eigen::Vector3d surfaceOutward(const SurfaceClosest& found, const Eigen::Vector3d& p,
                                      const std::vector<Eigen::Vector3d>& normals) {
  if (!(found.distance > kTinyDistance_m)) return normals[static_cast<std::size_t>(found.triangle)];
  return (found.side < 0.0 ? -1.0 : 1.0) * (p - found.point.p) / found.distance;
}

// Segment a..b against a box grown by `radius` on every side (slab test): conservative for the
// capsule of that radius.
inline bool segmentHitsGrownBox(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                double radius, const Box& box) {
  double t0 = 0.0, t1 = 1.0;
  const Eigen::Vector3d d = b - a;
  for (int i = 0; i < 3; ++i) {
    const double lo = box.min()[i] - radius, hi = box.max()[i] + radius;
    if (std::abs(d[i]) < 1e-300) {
      if (a[i] < lo || a[i] > hi) return false;
      continue;
    }
    double ta = (lo - a[i]) / d[i], tb = (hi - a[i]) / d[i];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  return true;
}

}  // namespace tactus::sim::collision_detail

namespace tactus::sim {

struct Collision::Impl {
  using Box = collision_detail::Box;
  struct Candidate {
    int tri;
    double dist;
    collision_detail::ClosestPoint cp;
  };

  SurfaceMesh surface;
  CollisionOptions options;
  int node_count = 0;
  Eigen::VectorXd q;
  // normals are computed on demand, once per refit (epoch), only where a query needs them
  int epoch = 1;
  Eigen::Matrix3Xd tri_normal;       // unit outward normals
  Eigen::Matrix3Xd vertex_normal;    // angle-weighted pseudo-normals (unit), per mesh node
  std::vector<int> tri_normal_epoch, vertex_normal_epoch;
  std::vector<int> vt_offset, vt_tri;   // node -> incident triangles (CSR)
  std::vector<std::array<int, 3>> tri_neighbor;   // across edge k, -1 on a border
  std::vector<Box> tri_boxes, vertex_boxes;
  detail::AabbTree tri_tree, vertex_tree;
  std::vector<int> tri_stamp, node_stamp;
  int stamp = 0;
  std::vector<Candidate> candidates;
  std::vector<Contact> contacts;
  CollisionStats stats;
  // side memory: the normal of each sphere feature's closest contact at the previous detect()
  struct FeatureSide {
    int feature;
    Eigen::Vector3d n;
    void transferState(StateArchive& ar) {
      ar("feature", feature);
      ar("n", n);
    }
  };
  std::vector<FeatureSide> side_prev, side_next;
  // pad side memory, per (jaw part & 1, node): the side (+1: the face normal's side) of the
  // vertex's last pad contact and the detect() count it was set at
  std::vector<std::int8_t> pad_side;
  std::vector<long> pad_side_detect;
  long detect_count = 2;   // pad_side_detect starts at 0: nothing remembered


  const Eigen::Vector3d* previousSide(int feature) const {
    for (const FeatureSide& fs : side_prev) {
      if (fs.feature == feature) return &fs.n;
    }
    return nullptr;
  }

  Eigen::Vector3d pos(int node) const { return q.segment<3>(3 * node); }

  // --- collision_surface.cpp ---
  void buildAdjacency();
  void buildVertexTriangles();
  // Boxes of the current positions; normals become stale (new epoch).
  void updateGeometry();

  // --- normals on demand (inline: the narrow phases call them per candidate) ---
  Eigen::Vector3d triNormal(int t) {
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
  Eigen::Vector3d vertexNormal(int node) {
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

  Eigen::Vector3d pseudoNormal(const Candidate& cand) {
    const int region = cand.cp.region;
    if (region == collision_detail::kFace) return triNormal(cand.tri);
    if (region < collision_detail::kEdge0) {
      return vertexNormal(surface.triangles[cand.tri][region - collision_detail::kVertex0]);
    }
    const int nb = tri_neighbor[cand.tri][region - collision_detail::kEdge0];
    Eigen::Vector3d n = triNormal(cand.tri);
    if (nb >= 0) n += triNormal(nb);
    return n;
  }

  // --- collision.cpp ---
  void emit(ContactKind kind, const ToolFeature& f, int element, const std::array<int, 3>& nodes,
            const std::array<double, 3>& weights, const Eigen::Vector3d& tissue_point,
            const Eigen::Vector3d& tool_point, const Eigen::Vector3d& n, double gap,
            const shared::Pose& tool_pose);

  // --- collision_vertex.cpp ---
  void vertexCapsule(const ToolFeature& f, const shared::Pose& tool_pose);
  // Tissue vertices against a pad (collision.h (c)): over the rectangle the normal is the pad's
  // face normal on the side the vertex touched at the previous detect() (so a vertex pushed past
  // the pad's mid-plane is pushed back, not through); at the rim the radial normal of the
  // rounded edge, as for a capsule.
  void vertexPad(const ToolFeature& f, const shared::Pose& tool_pose);

  // --- collision_sphere.cpp ---
  // A triangle contact of another sample at the same tissue point (within 1 nm: the same point
  // of a triangle, or of an edge seen from either of its triangles), among the contacts before
  // `end`.
  bool pointTaken(std::size_t end, const Eigen::Vector3d& p) const;
  void sphereTriangles(const ToolFeature& f, const shared::Pose& tool_pose);
};

}  // namespace tactus::sim
