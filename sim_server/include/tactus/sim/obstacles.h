#pragma once
// Static obstacles (scene `obstacles:`, scene_regions.h ObstacleSpec) and their contacts with the
// tissues' surface vertices (docs/design.md, "Obstacles").
//
// Each obstacle is rigid and fixed in the world: a half-space bounded by a plane, an axis-aligned
// box, or a triangle surface (OBJ/STL, surface_io.h) whose triangle normals point out of it.
// For every surface vertex v of a tissue and every obstacle the closest point c of the obstacle's
// boundary gives one contact when the signed distance is within the alarm distance:
//   plane: gap = (v - p) . N, c = v - gap N, outward normal N;
//   box:   outside: c = v clamped to the box, gap = |v - c|, outward normal (v - c)/gap;
//          inside:  the face of least penetration: gap = -(its depth), outward normal the face's;
//   mesh:  c the closest point over the triangles (AABB tree), |gap| = |v - c|; the side is the
//          sign of the sum of (v - c) . N_k over the triangles that share that closest point (an
//          unweighted pseudo-normal: exact on faces and on convex or concave edges), outward
//          normal +-(v - c)/|v - c| (N on the surface). A vertex behind the surface deeper than
//          the obstacle's thickness is taken to be past a thin wall and ignored.
// The contact's n points from the tissue toward the obstacle (the collision.h convention with
// the obstacle as the tool): n = -outward normal; tissue row -n at the vertex, no tool row.
// id = (kObstacleVertex << 56) | (tissue << 48) | (obstacle << 32) | node: stable while the same
// vertex touches the same obstacle (warm starts). Per tissue at most max_contacts are kept (the
// smallest gaps; ties: smaller id), the rest counted as overflow.
//
// Edges (obstacle_contact.edges): a box's edge or a rib's ridge pressed into a tissue face whose
// vertices lie on either side of it would pass between them, since only vertices are tested. With
// edges on, each box and mesh obstacle also has feature points: a box's 8 corners and points
// along its 12 edges; a mesh's boundary edges and its convex edges sharper than 30 deg (dihedral
// angle between the two triangles' normals), their end vertices and points along them; at most
// edge_spacing apart (a plane has none). Each feature point p finds the closest point s on the
// tissue's surface triangles at the current positions (an AABB tree refit at every detection;
// side from the pseudo-normal, as for a mesh obstacle); it is a contact while p is within the
// alarm distance outside the tissue or within edge_depth inside it, unless s is a tissue vertex
// (that vertex's own contact holds it) or the triangle's three vertices already touch the same
// obstacle (the face is held by them: a face point there would only repeat their rows). On one
// tissue triangle a point's row is the affine combination of its barycentric weights, so only
// the points at the corners of the convex hull of that triangle's points are kept (along one
// straight edge: the first and the last): they hold every point between them, and the rows
// stay few (a 2 cm face on a bar gets 2 per bar edge and triangle, not one per 2 mm). The
// contact: kObstacleVertex, feature = the obstacle, element = the feature point, nodes/weights
// = the triangle and the barycentric weights of s, n = the tissue's outward normal at s (from
// the tissue toward the obstacle), gap = +-|p - s|; its rows act on the triangle's nodes with
// -w_k dir. id as above with bit 58 set and the feature point's index in place of the node.

#include <Eigen/Core>
#include <memory>
#include <span>
#include <vector>

#include "tactus/sim/collision.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/scene.h"
#include "tactus/sim/surface_io.h"

namespace tactus::sim {

class Obstacles {
 public:
  /// Places the obstacles (mesh surfaces read, scaled, rotated, translated, their trees built).
  /// Throws tactus::MeshError / SceneError naming the obstacle on a bad surface.
  Obstacles(const std::vector<ObstacleSpec>& specs, const ObstacleContactSpec& options);
  ~Obstacles();
  Obstacles(Obstacles&&) noexcept;
  Obstacles& operator=(Obstacles&&) noexcept;

  int count() const;
  const ObstacleSpec& spec(int i) const;
  /// The placed surface of a mesh obstacle (empty for planes and boxes).
  const TriangleSurface& surface(int i) const;

  /// Signed distance of p to obstacle i (< 0 inside), its closest boundary point and outward
  /// normal; false when p is further than `max_gap_m` outside, or (mesh) deeper than the
  /// thickness inside.
  bool query(int i, const Eigen::Vector3d& p, double max_gap_m, double& gap_m,
             Eigen::Vector3d& closest_m, Eigen::Vector3d& outward) const;

  /// The contacts of the given tissue nodes (positions in q, 3n node-major) with every obstacle,
  /// sorted by id, at most options.max_contacts (deepest kept); `overflow` counts the rest.
  void detect(int tissue, std::span<const int> nodes, const Eigen::VectorXd& q,
              std::vector<Contact>& out, int& overflow) const;

  /// Edges: the feature points of obstacle i (empty without obstacle_contact.edges).
  const std::vector<Eigen::Vector3d>& edgePoints(int i) const;
  /// Edges: the tissues whose faces the edge points are tested against (their meshes and
  /// outward surfaces; kept by pointer). Without it, or without edges, detectEdges adds nothing.
  void attachTissues(std::span<const TetMesh* const> meshes,
                     std::span<const SurfaceMesh* const> surfaces);
  /// Edges: adds to `out` (detect()'s contacts of this tissue, at the same q) the edge points'
  /// contacts with the tissue's faces, then keeps at most max_contacts of all (deepest), sorted
  /// by id; `overflow` grows by what is dropped.
  void detectEdges(int tissue, const Eigen::VectorXd& q, std::vector<Contact>& out,
                   int& overflow);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tactus::sim
