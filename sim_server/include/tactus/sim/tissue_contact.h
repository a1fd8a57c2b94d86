#pragma once
// Contact between two tissues, and of a tissue with itself (scene `tissue_contact:`, scene_regions.h
// TissueContactSpec; docs/design.md, "Tissue against tissue").
//
// Detection, for a directed pair (A's vertices against B's surface): every surface vertex v of A,
// at the current positions, looks for the closest point s over B's surface triangles within
// reach = max(alarm, depth) (an AABB tree over B's triangles, refit at every detection). The side
// is the sign of the sum of (v - s) . N_k over the triangles sharing that closest point (N_k their
// outward face normals; an unweighted pseudo-normal, exact on faces and convex or concave edges):
//   outside: gap = |v - s|, kept while gap <= alarm;
//   inside:  gap = -|v - s|, kept while -gap <= depth (a deeper vertex is taken to be past a thin
//            part of B, not in it);
//   outward  = +-(v - s)/|v - s| (B's face normal when v lies on the surface).
// A vertex whose angle-weighted normal does not face B (vertex normal . outward >= 0) is skipped:
// it lies beside B's surface, not against it.
// Self-contact (A == B): the triangles with a node within two edges of v in the tetrahedral mesh
// are skipped (v's own neighbourhood, through the thickness too), so only the surface folding
// onto itself is found. Two tissues: both directions by default (two_way), so neither tissue's
// vertices pass through the other's faces; self-contact is both ways by construction.
//
// The contact (collision.h conventions, B in the tissue's role and A's vertex in the tool's):
// kind kTissueTissue, instrument -1 (no instrument), n = outward (from B toward v), gap as above,
// nodes/weights = B's triangle and the barycentric weights of s, feature = v, element = B's
// triangle, tissue_point = s, tool_point = v. Its rows act on both tissues: on B the usual
// -w_k dir at the triangle's nodes, on A +dir at v, so W = H_A C_A H_A^T + H_B C_B H_B^T.
// id = (kTissueTissue << 56) | (slot << 58) | (v << 32) | triangle, slot = 2 pair + direction:
// stable while the same vertex touches the same triangle (warm starts). At most max_contacts per
// direction are kept (the smallest gaps; ties: smaller id), the rest counted as overflow.

#include <Eigen/Core>
#include <memory>
#include <span>
#include <vector>

#include "tactus/sim/collision.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/scene_regions.h"

namespace tactus::sim {

class TissueContacts {
 public:
  /// One directed pair: the vertices of `vertex_tissue` against the surface of `surface_tissue`.
  struct Direction {
    int pair = 0;             ///< index into the specs
    int vertex_tissue = 0;    ///< A
    int surface_tissue = 0;   ///< B (== A: self-contact)
    int slot = 0;             ///< 2 pair + 0 (A's vertices on B) or 1 (two-way: B's on A): the id's
  };

  /// `meshes[t]` and `surfaces[t]` of every tissue (rest positions; surfaces outward oriented),
  /// `specs` the scene's pairs (tissue indices < meshes.size()). Throws tactus::SceneError naming
  /// the pair on a tissue without surface, more than kMaxTissueContactPairs pairs or a mesh whose
  /// node indices do not fit the contact id (2^24).
  TissueContacts(std::span<const TetMesh* const> meshes,
                 std::span<const SurfaceMesh* const> surfaces,
                 const std::vector<TissueContactSpec>& specs);
  ~TissueContacts();
  TissueContacts(TissueContacts&&) noexcept;
  TissueContacts& operator=(TissueContacts&&) noexcept;

  /// Refits the surfaces of the tissues that take part (q[t]: tissue t's positions, 3n) and
  /// detects every direction. Buffers are reused (no allocation once warmed up).
  void detect(std::span<const Eigen::VectorXd* const> q);

  int directionCount() const;
  const Direction& direction(int k) const;
  const TissueContactSpec& spec(int pair) const;
  /// Contacts of direction k at the last detect(), sorted by id.
  const std::vector<Contact>& contacts(int k) const;
  /// Contacts direction k dropped by its cap at the last detect().
  int overflow(int k) const;
  /// The pair (index into the specs) of a kTissueTissue contact id.
  static int pairOfId(std::uint64_t id) { return static_cast<int>((id >> 58) / 2); }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tactus::sim
