#pragma once
// Collision detection between the instrument and the deformed tissue surface, and the contact
// rows of the contact problem (docs/design.md, "Collision detection" and "The contact problem").
//
// Two AABB trees over the tissue surface (one over triangles, one over surface vertices) are
// built once from the topology and refit every step from the FEM state q (3n, node-major xyz).
// Queries return every contact whose gap is within the alarm distance.
//
// Contact frame convention: n points from the tissue toward the tool, i.e. the direction in
// which the tool must move (relative to the tissue) to separate. The gap
//     gap = distance - radius - contact_distance      (< 0: penetration)
// grows when the tool moves along +n and shrinks when the tissue point moves along +n.
// (t1, t2) complete n to an orthonormal right-handed frame (n x t1 = t2): t1 is the normalised
// projection of the world x axis on the tangent plane (of the world y axis when |n.x| > 0.9).
//
// (a) kVertexCapsule: surface vertex v vs tool capsule (axis a..b, radius r). c = closest axis
//     point, n = (c - v)/|c - v| (the capsule's outward normal at v, reversed), gap = |v - c| -
//     r - contact_distance. Contact at the vertex: nodes (v, -1, -1), weights (1, 0, 0); tool
//     point c - r n. Rules: a vertex that does not face the tool (n . vertex_normal <= 0,
//     angle-weighted vertex normal) is skipped (far side of a thin part, or pushed through the
//     axis); with skip_cap_a, vertices whose closest axis point is the end a are skipped.
//     If v lies on the axis, n = the vertex normal.
//     A sphere feature with query_vertices (the probe tip) is also queried as a degenerate
//     capsule (a == b), so every surface vertex near it is held out, not only the local minima
//     of (b).
// (b) kSphereTriangle: tool sphere (centre c, radius r) vs surface triangles. Per sphere:
//     1. candidates: triangles within r + contact_distance + alarm of c; closest point s
//        (barycentric weights), its region (face interior, edge, vertex) and distance d.
//     2. keep only local minima of the distance over the surface: candidates are visited by
//        increasing (d, triangle index); a candidate whose closest point lies on an edge/vertex
//        of an already visited triangle is dropped (the neighbour is at least as close), so one
//        contact remains per distinct closest point (a sphere over a flat patch gives one).
//     3. side: the nearest candidate decides whether c is outside or inside the tissue, by the
//        sign of (c - s) . N with N the angle-weighted pseudo-normal of its closest element
//        (face normal, sum of the two edge normals, angle-weighted vertex normals).
//        Outside: keep front-facing candidates ((c - s) . N >= 0); n = (c - s)/d,
//                 gap = d - r - contact_distance.
//        Inside:  keep back-facing candidates whose N is not opposed to the nearest one's
//                 (N . N0 > -0.1, so the far side of a thin slab is ignored); n = N,
//                 gap = (c - s) . N - r - contact_distance (signed distance to the plane).
//        Side memory: when the nearest candidate says inside but its N opposes the normal of
//        the feature's closest contact at the previous detect() (the sphere entered from the
//        other side of a thin part, or the surface folded under it), the nearest candidate
//        whose N agrees with that normal decides inside/outside and N0 instead.
//     Tissue point s, tool point c - r n.
// (c) pad (FeatureShape::kPad, a flat jaw pad: rectangle a + s (b - a) + x e, s in [0, 1],
//     x in [-1, 1], swept by radius r) vs surface vertices, one contact per vertex and pad, of
//     kind kVertexCapsule. Over the rectangle (s and x inside) the normal is the pad's face
//     normal N = (b - a) x e / |..| on the vertex's side: n = -side N, gap = side (v - a).N - r
//     - contact_distance, tool point = the vertex's projection on the mid-plane - r n. The side
//     is the one of the vertex's contact with this jaw at the previous detect() (so a vertex
//     squeezed past the mid-plane is pushed back, not through), else the side it lies on, and a
//     new contact must face the pad (n . vertex_normal > 0). Beyond the rectangle's rim: the
//     radial normal of the rounded edge, as for a capsule.
//     Pad samples (spheres with face_only) are queried as in (b) but keep only interior and
//     edge points, and drop a point that an earlier feature's triangle contact already uses
//     (within 1 nm): a vertex belongs to the pad's own query, so no tissue point gets two
//     contacts.
// Contact compliance (instrument.contact_compliance, the pipeline adds it to W's diagonal, see
// docs/design.md, "Contact compliance"): a contact carrying f penetrates by c f_n; W + c I is positive definite even
// where the pads' rows are linearly dependent (a face point under a flat pad is an affine
// combination of its triangle's vertices, which the pad also holds).
// Every contact gets a stable id: (kind << 56) | (feature id << 32) | (vertex or triangle
// index); it does not change while the same feature touches the same vertex/triangle, so warm
// starts can be matched across steps. Contacts are returned sorted by id. When there are more
// than max_contacts, the max_contacts smallest gaps (ties: smaller id) are kept and the rest
// counted as overflow.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "tactus/shared/pose.h"
#include "tactus/sim/compliance.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim {

class StateArchive;

/// kObstacleVertex: a tissue surface vertex against a static obstacle (obstacles.h);
/// kTissueTissue: a tissue's surface vertex against a tissue's surface (tissue_contact.h).
enum class ContactKind : std::uint8_t {
  kVertexCapsule = 0,
  kSphereTriangle = 1,
  kObstacleVertex = 2,
  kTissueTissue = 3,
};

struct Contact {
  std::uint64_t id = 0;                   ///< stable identity, see above
  ContactKind kind = ContactKind::kVertexCapsule;
  int feature = -1;                       ///< tool feature id
  int element = -1;                       ///< tissue node (a) or surface triangle index (b)
  std::array<int, 3> nodes{-1, -1, -1};   ///< tissue nodes (TetMesh indices), unused: -1
  std::array<double, 3> weights{0, 0, 0}; ///< barycentric weights of the tissue point
  Eigen::Vector3d tissue_point_m = Eigen::Vector3d::Zero();
  Eigen::Vector3d tool_point_m = Eigen::Vector3d::Zero();   ///< world
  Eigen::Vector3d tool_local_m = Eigen::Vector3d::Zero();   ///< tool frame
  Eigen::Vector3d n = Eigen::Vector3d::UnitZ();             ///< tissue -> tool
  Eigen::Vector3d t1 = Eigen::Vector3d::UnitX();
  Eigen::Vector3d t2 = Eigen::Vector3d::UnitY();
  double gap_m = 0.0;
  /// The instrument the tool feature belongs to (SceneSpec's order). Collision::detect leaves 0;
  /// with several instruments the pipeline sets it and ors it into the id's bits 58-63 (the kind
  /// takes bits 56-57), so contacts of different instruments, and obstacles' contacts, never
  /// share an id. -1: an obstacle's contact (kObstacleVertex) or a contact between tissues
  /// (kTissueTissue), which belong to no instrument.
  int instrument = 0;
};

/// The contact's tissue point at the positions q (3n, node-major): sum_k w_k q[node_k].
inline Eigen::Vector3d tissuePointAt(const Contact& contact, const Eigen::VectorXd& q) {
  Eigen::Vector3d x = Eigen::Vector3d::Zero();
  for (int j = 0; j < 3; ++j) {
    const int node = contact.nodes[static_cast<std::size_t>(j)];
    if (node < 0 || contact.weights[static_cast<std::size_t>(j)] == 0.0) continue;
    x += contact.weights[static_cast<std::size_t>(j)] * q.segment<3>(3 * node);
  }
  return x;
}

struct CollisionOptions {
  double alarm_distance_m = 0.004;     ///< contacts are reported while gap <= this
  double contact_distance_m = 0.0;     ///< subtracted from every gap
  int max_contacts = 300;              ///< cap (the smallest gaps are kept)
  bool vertex_vs_capsule = true;       ///< kind (a)
  bool sphere_vs_triangle = true;      ///< kind (b)
  bool brute_force = false;            ///< skip the trees (reference for tests)
};

struct CollisionStats {
  int candidates = 0;                  ///< exact primitive tests in the last detect()
  int contacts = 0;                    ///< returned by the last detect()
  int overflow = 0;                    ///< dropped by the cap in the last detect()
  std::int64_t overflow_total = 0;     ///< since construction
  int max_contacts_seen = 0;           ///< high-water mark before capping
};

/// Deterministic tangents (t1, t2) for a unit normal (see the header comment).
void contactTangents(const Eigen::Vector3d& n, Eigen::Vector3d& t1, Eigen::Vector3d& t2);

class Collision {
 public:
  /// `q` (3n) gives the initial positions the trees are built from; triangles must index nodes
  /// of q. Throws tactus::Error on inconsistent sizes/indices or bad options.
  Collision(const SurfaceMesh& surface, const Eigen::VectorXd& q, const CollisionOptions& options);
  ~Collision();
  Collision(Collision&&) noexcept;
  Collision& operator=(Collision&&) noexcept;

  const CollisionOptions& options() const;
  void setOptions(const CollisionOptions& options);   ///< throws tactus::Error on bad values

  /// Updates positions, normals and both trees (topology kept). q must have the size given at
  /// construction (throws tactus::Error otherwise).
  void refit(const Eigen::VectorXd& q);

  /// Contacts of the features against the surface at the last refit. `tool_pose` gives the tool
  /// frame for tool_local_m. Buffers are reused (no allocation once warmed up).
  const std::vector<Contact>& detect(std::span<const ToolFeature> features,
                                     const shared::Pose& tool_pose);
  const std::vector<Contact>& detect(const Instrument& tool) {
    return detect(tool.features(), tool.pose());
  }

  const std::vector<Contact>& contacts() const;
  const CollisionStats& stats() const;
  const SurfaceMesh& surface() const;   ///< triangles as given; nodes = those they use

  /// Writes or reads what one detect() leaves for the next (state_archive.h): the sphere
  /// features' and the pads' side memory and the detect() count it is dated by. The trees,
  /// normals and contacts are rebuilt by refit() and detect(). Throws StateError.
  void transferState(StateArchive& ar);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The rows of the contact problem for a set of contacts.
struct ContactRows {
  std::vector<int> row_offset;                         ///< contacts + 1 entries
  std::vector<TissueRow> tissue;                       ///< one per row
  Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor> tool;  ///< H_tool, rows x 6
  std::vector<double> delta_free;                      ///< n row: gap; t1, t2 rows: 0
  int rows() const { return static_cast<int>(delta_free.size()); }
};

/// One row per contact (n) when mu == 0, else three (n, t1, t2). Tissue rows carry negated
/// weights: (H dq)_dir = -sum_k w_k dir . dq[node_k] (a tissue motion along n closes the gap);
/// tool rows: dir^T [I, -[r]x], r = tool point - tool origin (a tool twist along n opens it).
void buildContactRows(std::span<const Contact> contacts, double mu,
                      const Eigen::Vector3d& tool_origin_m, ContactRows& out);
/// The same for contacts of several instruments: contact c uses the friction mu[i] and the tool
/// origin tool_origin_m[i] of its instrument i = contacts[c].instrument (each < mu.size()).
void buildContactRows(std::span<const Contact> contacts, std::span<const double> mu,
                      std::span<const Eigen::Vector3d> tool_origin_m, ContactRows& out);

}  // namespace tactus::sim
