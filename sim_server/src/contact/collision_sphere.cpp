// Collision, narrow phase: sphere features against the surface triangles (local minima of the
// distance, inside/outside from pseudo-normals, the side remembered between queries).

#include <algorithm>
#include <cmath>

#include "collision_impl.h"

namespace tactus::sim {

using namespace collision_detail;

// A triangle contact of another sample at the same tissue point (within 1 nm: the same point
// of a triangle, or of an edge seen from either of its triangles), among the contacts before
// `end`.
bool Collision::Impl::pointTaken(std::size_t end, const Eigen::Vector3d& p) const {
  for (std::size_t i = 0; i < end; ++i) {
    const Contact& c = contacts[i];
    if (c.kind == ContactKind::kSphereTriangle && (c.tissue_point_m - p).squaredNorm() < 1e-18) {
      return true;
    }
  }
  return false;
}

void Collision::Impl::sphereTriangles(const ToolFeature& f, const shared::Pose& tool_pose) {
  const double cd = options.contact_distance_m;
  const double reach = f.radius_m + cd + options.alarm_distance_m;
  const Eigen::Vector3d c = f.a_m;
  candidates.clear();
  // 1. candidate triangles within reach
  auto visit = [&](int t) {
    ++stats.candidates;
    const auto& tri = surface.triangles[t];
    const ClosestPoint cp = closestOnTriangle(c, pos(tri[0]), pos(tri[1]), pos(tri[2]));
    const double d = (c - cp.p).norm();
    if (d <= reach) candidates.push_back({t, d, cp});
  };
  if (options.brute_force) {
    for (int t = 0; t < static_cast<int>(surface.triangles.size()); ++t) visit(t);
  } else {
    const double reach2 = reach * reach;
    tri_tree.query([&](const Box& box) { return box.squaredExteriorDistance(c) <= reach2; },
                   visit);
  }
  if (candidates.empty()) return;
  std::sort(candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) {
    return a.dist < b.dist || (a.dist == b.dist && a.tri < b.tri);
  });
  // 3. inside/outside from the nearest candidate's pseudo-normal
  Eigen::Vector3d n0 = pseudoNormal(candidates.front());
  bool inside = (c - candidates.front().cp.p).dot(n0) < 0.0;
  // Inside a thin part the nearest face may be the far one, and a surface folded under the
  // tool may put a flipped face nearest: keep the side the sphere touched at the previous
  // query (the nearest candidate facing that way decides inside/outside).
  const Eigen::Vector3d* prev = previousSide(f.id);
  if (inside && prev != nullptr && n0.dot(*prev) < 0.0) {
    for (const Candidate& cand : candidates) {
      const Eigen::Vector3d pn = pseudoNormal(cand);
      if (pn.dot(*prev) > 0.0) {
        n0 = pn;
        inside = (c - cand.cp.p).dot(pn) < 0.0;
        break;
      }
    }
  }
  const Eigen::Vector3d n0_unit = n0.normalized();
  const std::size_t first_contact = contacts.size();
  ++stamp;
  for (const Candidate& cand : candidates) {
    const auto& tri = surface.triangles[cand.tri];
    // 2. local minima only: an edge/vertex point shared with a visited (closer) triangle is
    //    a duplicate
    bool duplicate = false;
    if (cand.cp.region != kFace) {
      if (cand.cp.region < kEdge0) {
        duplicate = node_stamp[tri[cand.cp.region - kVertex0]] == stamp;
      } else {
        const int nb = tri_neighbor[cand.tri][cand.cp.region - kEdge0];
        duplicate = nb >= 0 && tri_stamp[nb] == stamp;
      }
    }
    tri_stamp[cand.tri] = stamp;
    for (int k = 0; k < 3; ++k) node_stamp[tri[k]] = stamp;
    if (duplicate) continue;
    // pad samples: no vertex (the pad feature's), one contact per tissue point
    if (f.face_only && ((cand.cp.region != kFace && cand.cp.region < kEdge0) ||
                        pointTaken(first_contact, cand.cp.p))) {
      continue;
    }
    // 3. side filter, normal and gap
    const Eigen::Vector3d pn = pseudoNormal(cand);
    const double pn_len = pn.norm();
    if (!(pn_len > 0.0)) continue;
    const Eigen::Vector3d pn_unit = pn / pn_len;
    const Eigen::Vector3d diff = c - cand.cp.p;
    const bool facing = diff.dot(pn) >= 0.0;
    Eigen::Vector3d n;
    double gap;
    if (!inside) {
      if (!facing) continue;
      n = cand.dist > kTinyDistance_m ? Eigen::Vector3d(diff / cand.dist) : pn_unit;
      gap = cand.dist - f.radius_m - cd;
    } else {
      if (facing || pn_unit.dot(n0_unit) <= kOpposedCos) continue;
      n = pn_unit;
      gap = diff.dot(n) - f.radius_m - cd;
    }
    if (gap > options.alarm_distance_m) continue;
    emit(ContactKind::kSphereTriangle, f, cand.tri, tri, cand.cp.bary, cand.cp.p,
         c - f.radius_m * n, n, gap, tool_pose);
  }
  // remember the side of the closest contact for the next query
  const Contact* closest = nullptr;
  for (std::size_t i = first_contact; i < contacts.size(); ++i) {
    if (closest == nullptr || contacts[i].gap_m < closest->gap_m) closest = &contacts[i];
  }
  if (closest != nullptr) side_next.push_back({f.id, closest->n});
}

}  // namespace tactus::sim
