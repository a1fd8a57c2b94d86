#include "tactus/sim/collision.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "aabb_tree.h"
#include "tactus/shared/error.h"

namespace tactus::sim {
namespace {

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
double closestOnSegment(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                        const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  if (len2 <= 0.0) return 0.0;
  return std::clamp((p - a).dot(ab) / len2, 0.0, 1.0);
}

// Segment a..b against a box grown by `radius` on every side (slab test): conservative for the
// capsule of that radius.
bool segmentHitsGrownBox(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double radius,
                         const Box& box) {
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

std::uint64_t contactId(ContactKind kind, int feature, int element) {
  return (static_cast<std::uint64_t>(kind) << 56) |
         (static_cast<std::uint64_t>(static_cast<std::uint32_t>(feature) & 0xFFFFFFu) << 32) |
         static_cast<std::uint64_t>(static_cast<std::uint32_t>(element));
}

void validateOptions(const CollisionOptions& o) {
  if (!(o.alarm_distance_m >= 0.0) || !std::isfinite(o.alarm_distance_m)) {
    throw Error("collision: alarm_distance_m must be finite and >= 0 (got " +
                std::to_string(o.alarm_distance_m) + ")");
  }
  if (!(o.contact_distance_m >= 0.0) || !std::isfinite(o.contact_distance_m)) {
    throw Error("collision: contact_distance_m must be finite and >= 0 (got " +
                std::to_string(o.contact_distance_m) + ")");
  }
  if (o.max_contacts < 0) {
    throw Error("collision: max_contacts must be >= 0 (got " + std::to_string(o.max_contacts) +
                ")");
  }
}

}  // namespace

void contactTangents(const Eigen::Vector3d& n, Eigen::Vector3d& t1, Eigen::Vector3d& t2) {
  const Eigen::Vector3d ref =
      std::abs(n.x()) > 0.9 ? Eigen::Vector3d::UnitY() : Eigen::Vector3d::UnitX();
  t1 = (ref - ref.dot(n) * n).normalized();
  t2 = n.cross(t1);
}

struct Collision::Impl {
  struct Candidate {
    int tri;
    double dist;
    ClosestPoint cp;
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

  void buildAdjacency() {
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

  void buildVertexTriangles() {
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
  void updateGeometry() {
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
    if (region == kFace) return triNormal(cand.tri);
    if (region < kEdge0) return vertexNormal(surface.triangles[cand.tri][region - kVertex0]);
    const int nb = tri_neighbor[cand.tri][region - kEdge0];
    Eigen::Vector3d n = triNormal(cand.tri);
    if (nb >= 0) n += triNormal(nb);
    return n;
  }

  void emit(ContactKind kind, const ToolFeature& f, int element, const std::array<int, 3>& nodes,
            const std::array<double, 3>& weights, const Eigen::Vector3d& tissue_point,
            const Eigen::Vector3d& tool_point, const Eigen::Vector3d& n, double gap,
            const shared::Pose& tool_pose) {
    Contact c;
    c.id = contactId(kind, f.id, element);
    c.kind = kind;
    c.feature = f.id;
    c.element = element;
    c.nodes = nodes;
    c.weights = weights;
    c.tissue_point_m = tissue_point;
    c.n = n;
    contactTangents(n, c.t1, c.t2);
    c.gap_m = gap;
    c.tool_point_m = tool_point;
    c.tool_local_m = tool_pose.rot.conjugate() * (c.tool_point_m - tool_pose.pos_m);
    contacts.push_back(c);
  }

  // A triangle contact of another sample at the same tissue point (within 1 nm: the same point
  // of a triangle, or of an edge seen from either of its triangles), among the contacts before
  // `end`.
  bool pointTaken(std::size_t end, const Eigen::Vector3d& p) const {
    for (std::size_t i = 0; i < end; ++i) {
      const Contact& c = contacts[i];
      if (c.kind == ContactKind::kSphereTriangle && (c.tissue_point_m - p).squaredNorm() < 1e-18) {
        return true;
      }
    }
    return false;
  }

  void vertexCapsule(const ToolFeature& f, const shared::Pose& tool_pose) {
    const double cd = options.contact_distance_m;
    const double reach = f.radius_m + cd + options.alarm_distance_m;
    auto visit = [&](int prim) {
      ++stats.candidates;
      const int node = surface.nodes[prim];
      const Eigen::Vector3d v = pos(node);
      const double t = closestOnSegment(v, f.a_m, f.b_m);
      if (f.skip_cap_a && t <= 0.0) return;
      const Eigen::Vector3d axis_point = f.a_m + t * (f.b_m - f.a_m);
      const Eigen::Vector3d diff = axis_point - v;
      const double d = diff.norm();
      if (d > reach) return;
      const Eigen::Vector3d nv = vertexNormal(node);
      const Eigen::Vector3d n = d > kTinyDistance_m ? Eigen::Vector3d(diff / d) : nv;
      if (!(n.dot(nv) > 0.0)) return;   // vertex does not face the tool
      const double gap = d - f.radius_m - cd;
      if (gap > options.alarm_distance_m) return;
      emit(ContactKind::kVertexCapsule, f, node, {node, -1, -1}, {1.0, 0.0, 0.0}, v,
           axis_point - f.radius_m * n, n, gap, tool_pose);
    };
    if (options.brute_force) {
      for (int i = 0; i < static_cast<int>(surface.nodes.size()); ++i) visit(i);
    } else {
      vertex_tree.query(
          [&](const Box& box) { return segmentHitsGrownBox(f.a_m, f.b_m, reach, box); }, visit);
    }
  }

  // Tissue vertices against a pad (collision.h (c)): over the rectangle the normal is the pad's
  // face normal on the side the vertex touched at the previous detect() (so a vertex pushed past
  // the pad's mid-plane is pushed back, not through); at the rim the radial normal of the
  // rounded edge, as for a capsule.
  void vertexPad(const ToolFeature& f, const shared::Pose& tool_pose) {
    const double cd = options.contact_distance_m;
    const double reach = f.radius_m + cd + options.alarm_distance_m;
    const Eigen::Vector3d len = f.b_m - f.a_m;
    const double len2 = len.squaredNorm(), hw2 = f.half_width_m.squaredNorm();
    if (!(len2 > 0.0) || !(hw2 > 0.0)) return;
    const Eigen::Vector3d face_n = len.cross(f.half_width_m).normalized();
    const std::size_t slot_base = static_cast<std::size_t>(f.part & 1) * static_cast<std::size_t>(node_count);
    auto visit = [&](int prim) {
      ++stats.candidates;
      const int node = surface.nodes[prim];
      const Eigen::Vector3d v = pos(node);
      const Eigen::Vector3d rel = v - f.a_m;
      const double t = rel.dot(len) / len2, x = rel.dot(f.half_width_m) / hw2;
      const double height = rel.dot(face_n);   // signed, from the mid-plane
      const std::size_t slot = slot_base + static_cast<std::size_t>(node);
      const bool remembered = pad_side_detect[slot] == detect_count - 1;
      Eigen::Vector3d n;
      double gap;
      Eigen::Vector3d tool_point;
      if (t >= 0.0 && t <= 1.0 && std::abs(x) <= 1.0) {
        const double side = remembered ? pad_side[slot] : (height >= 0.0 ? 1.0 : -1.0);
        gap = side * height - f.radius_m - cd;
        if (gap > options.alarm_distance_m) return;
        n = -side * face_n;
        if (!remembered && !(n.dot(vertexNormal(node)) > 0.0)) return;   // not facing the pad
        tool_point = v - height * face_n - f.radius_m * n;
      } else {
        const Eigen::Vector3d c = f.a_m + std::clamp(t, 0.0, 1.0) * len +
                                  std::clamp(x, -1.0, 1.0) * f.half_width_m;
        const Eigen::Vector3d diff = c - v;
        const double d = diff.norm();
        if (d > reach) return;
        const Eigen::Vector3d nv = vertexNormal(node);
        n = d > kTinyDistance_m ? Eigen::Vector3d(diff / d) : nv;
        if (!(n.dot(nv) > 0.0)) return;
        gap = d - f.radius_m - cd;
        if (gap > options.alarm_distance_m) return;
        tool_point = c - f.radius_m * n;
      }
      pad_side[slot] = static_cast<std::int8_t>(n.dot(face_n) < 0.0 ? 1 : -1);
      pad_side_detect[slot] = detect_count;
      emit(ContactKind::kVertexCapsule, f, node, {node, -1, -1}, {1.0, 0.0, 0.0}, v, tool_point,
           n, gap, tool_pose);
    };
    const double grown = reach + std::sqrt(hw2);
    if (options.brute_force) {
      for (int i = 0; i < static_cast<int>(surface.nodes.size()); ++i) visit(i);
    } else {
      vertex_tree.query(
          [&](const Box& box) { return segmentHitsGrownBox(f.a_m, f.b_m, grown, box); }, visit);
    }
  }

  void sphereTriangles(const ToolFeature& f, const shared::Pose& tool_pose) {
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
};

Collision::Collision(const SurfaceMesh& surface, const Eigen::VectorXd& q,
                     const CollisionOptions& options)
    : impl_(std::make_unique<Impl>()) {
  validateOptions(options);
  if (q.size() % 3 != 0) {
    throw Error("collision: the state vector has " + std::to_string(q.size()) +
                " entries, not a multiple of 3 (expected 3 per node, node-major)");
  }
  Impl& s = *impl_;
  s.options = options;
  s.node_count = static_cast<int>(q.size() / 3);
  s.surface.triangles = surface.triangles;
  s.surface.triangle_tet = surface.triangle_tet;
  // surface nodes: always the nodes the triangles use (sorted, unique)
  for (std::size_t t = 0; t < surface.triangles.size(); ++t) {
    for (int node : surface.triangles[t]) {
      if (node < 0 || node >= s.node_count) {
        throw Error("collision: surface triangle " + std::to_string(t) + " refers to node " +
                    std::to_string(node) + " but the state has " +
                    std::to_string(s.node_count) + " nodes");
      }
      s.surface.nodes.push_back(node);
    }
  }
  std::sort(s.surface.nodes.begin(), s.surface.nodes.end());
  s.surface.nodes.erase(std::unique(s.surface.nodes.begin(), s.surface.nodes.end()),
                        s.surface.nodes.end());
  const int nt = static_cast<int>(s.surface.triangles.size());
  s.q = q;
  s.tri_normal.setZero(3, nt);
  s.vertex_normal.setZero(3, s.node_count);
  s.tri_normal_epoch.assign(nt, 0);
  s.vertex_normal_epoch.assign(s.node_count, 0);
  s.buildVertexTriangles();
  s.tri_boxes.resize(nt);
  s.vertex_boxes.resize(s.surface.nodes.size());
  s.tri_stamp.assign(nt, 0);
  s.pad_side.assign(2 * static_cast<std::size_t>(s.node_count), 0);
  s.pad_side_detect.assign(2 * static_cast<std::size_t>(s.node_count), 0);
  s.node_stamp.assign(s.node_count, 0);
  s.buildAdjacency();
  s.updateGeometry();
  s.tri_tree.build(s.tri_boxes);
  s.vertex_tree.build(s.vertex_boxes);
  s.contacts.reserve(static_cast<std::size_t>(options.max_contacts) + 64);
  s.side_prev.reserve(256);
  s.side_next.reserve(256);
}

Collision::~Collision() = default;
Collision::Collision(Collision&&) noexcept = default;
Collision& Collision::operator=(Collision&&) noexcept = default;

const CollisionOptions& Collision::options() const { return impl_->options; }

void Collision::setOptions(const CollisionOptions& options) {
  validateOptions(options);
  impl_->options = options;
}

void Collision::refit(const Eigen::VectorXd& q) {
  Impl& s = *impl_;
  if (q.size() != s.q.size()) {
    throw Error("collision: refit with " + std::to_string(q.size()) +
                " state entries, the surface was built for " + std::to_string(s.q.size()));
  }
  s.q = q;
  s.updateGeometry();
  s.tri_tree.refit(s.tri_boxes);
  s.vertex_tree.refit(s.vertex_boxes);
}

const std::vector<Contact>& Collision::detect(std::span<const ToolFeature> features,
                                              const shared::Pose& tool_pose) {
  Impl& s = *impl_;
  s.contacts.clear();
  s.stats.candidates = 0;
  s.side_next.clear();
  for (const ToolFeature& f : features) {
    if (f.shape == FeatureShape::kPad) {
      if (s.options.vertex_vs_capsule) s.vertexPad(f, tool_pose);
    } else if (f.shape == FeatureShape::kCapsule) {
      if (s.options.vertex_vs_capsule) s.vertexCapsule(f, tool_pose);
    } else {
      if (s.options.sphere_vs_triangle) s.sphereTriangles(f, tool_pose);
      if (f.query_vertices && s.options.vertex_vs_capsule) s.vertexCapsule(f, tool_pose);
    }
  }
  std::swap(s.side_prev, s.side_next);
  ++s.detect_count;
  // cap: keep the smallest gaps (ties: smaller id), count the rest
  const int found = static_cast<int>(s.contacts.size());
  s.stats.max_contacts_seen = std::max(s.stats.max_contacts_seen, found);
  s.stats.overflow = 0;
  if (found > s.options.max_contacts) {
    const auto by_gap = [](const Contact& a, const Contact& b) {
      return a.gap_m < b.gap_m || (a.gap_m == b.gap_m && a.id < b.id);
    };
    std::nth_element(s.contacts.begin(), s.contacts.begin() + s.options.max_contacts,
                     s.contacts.end(), by_gap);
    s.contacts.resize(s.options.max_contacts);
    s.stats.overflow = found - s.options.max_contacts;
    s.stats.overflow_total += s.stats.overflow;
  }
  std::sort(s.contacts.begin(), s.contacts.end(),
            [](const Contact& a, const Contact& b) { return a.id < b.id; });
  s.stats.contacts = static_cast<int>(s.contacts.size());
  return s.contacts;
}

const std::vector<Contact>& Collision::contacts() const { return impl_->contacts; }
const CollisionStats& Collision::stats() const { return impl_->stats; }
const SurfaceMesh& Collision::surface() const { return impl_->surface; }

void buildContactRows(std::span<const Contact> contacts, double mu,
                      const Eigen::Vector3d& tool_origin_m, ContactRows& out) {
  const int nc = static_cast<int>(contacts.size());
  const int per = mu > 0.0 ? 3 : 1;
  const int rows = nc * per;
  out.row_offset.resize(nc + 1);
  out.tissue.resize(rows);
  out.tool.resize(rows, 6);
  out.delta_free.resize(rows);
  out.row_offset[0] = 0;
  for (int i = 0; i < nc; ++i) {
    const Contact& c = contacts[i];
    const Eigen::Matrix<double, 3, 6> jac = shared::pointJacobian(tool_origin_m, c.tool_point_m);
    for (int d = 0; d < per; ++d) {
      const int r = i * per + d;
      const Eigen::Vector3d& dir = d == 0 ? c.n : (d == 1 ? c.t1 : c.t2);
      TissueRow& row = out.tissue[r];
      row.node = c.nodes;
      for (int k = 0; k < 3; ++k) row.weight[k] = c.nodes[k] >= 0 ? -c.weights[k] : 0.0;
      row.dir = dir;
      out.tool.row(r) = dir.transpose() * jac;
      out.delta_free[r] = d == 0 ? c.gap_m : 0.0;
    }
    out.row_offset[i + 1] = (i + 1) * per;
  }
}

}  // namespace tactus::sim
