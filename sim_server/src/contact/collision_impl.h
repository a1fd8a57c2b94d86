#pragma once
// Private to collision: the helpers and Collision::Impl shared by the collision source files.
//   collision.cpp             construction, refit, detect (the cap), contact records and rows
//   collision_surface.cpp     broad phase upkeep: adjacency, boxes, normals on demand
//   collision_primitives.cpp  closest points (triangle, segment) and the grown-box slab test
//   collision_vertex.cpp      narrow phase: tissue vertices against capsules and pads
//   collision_sphere.cpp      narrow phase: spheres against the surface triangles

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <vector>

#include "aabb_tree.h"
#include "tactus/sim/collision.h"

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
ClosestPoint closestOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                               const Eigen::Vector3d& b, const Eigen::Vector3d& c);
// Parameter in [0, 1] of the closest point of p on segment a..b.
double closestOnSegment(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                        const Eigen::Vector3d& b);
// Segment a..b against a box grown by `radius` on every side (slab test): conservative for the
// capsule of that radius.
bool segmentHitsGrownBox(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double radius,
                         const Box& box);

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
  Eigen::Vector3d triNormal(int t);
  // Angle-weighted pseudo-normal of a surface node (unit; zero if degenerate).
  Eigen::Vector3d vertexNormal(int node);
  Eigen::Vector3d pseudoNormal(const Candidate& cand);

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
