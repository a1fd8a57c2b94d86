// Static obstacles and their contacts with tissue surface vertices (obstacles.h).
#include "tactus/sim/obstacles.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "collision_impl.h"
#include "moving_surface.h"
#include "tactus/shared/error.h"

namespace tactus::sim {

// An obstacle's edge points: its corners and the points along its sharp edges.
using EdgePoints = std::vector<Eigen::Vector3d>;

struct EdgeCandidate {
  int point = 0;                           // index into the obstacle's EdgePoints
  collision_detail::SurfaceClosest closest;
};

// Appends to `keep` the indices in [first, end) of the corners of the convex hull of the
// candidates' (w1, w2) (sorted by w1, then w2: Andrew's monotone chain; points on a hull edge
// are not corners; coincident points count once).
void convexHullCorners(const std::vector<EdgeCandidate>& c, std::size_t first, std::size_t end,
                       std::vector<std::size_t>& hull, std::vector<std::size_t>& keep) {
  const auto u = [&](std::size_t i) { return c[i].closest.point.bary[1]; };
  const auto v = [&](std::size_t i) { return c[i].closest.point.bary[2]; };
  const auto cross = [&](std::size_t o, std::size_t a, std::size_t b) {
    return (u(a) - u(o)) * (v(b) - v(o)) - (v(a) - v(o)) * (u(b) - u(o));
  };
  constexpr double kFlat = 1e-12;   // in barycentric units: collinear below this
  if (end - first <= 2) {
    for (std::size_t i = first; i < end; ++i) {
      if (i == first || std::abs(u(i) - u(first)) + std::abs(v(i) - v(first)) > kFlat) keep.push_back(i);
    }
    return;
  }
  hull.clear();
  for (std::size_t i = first; i < end; ++i) {   // lower chain
    while (hull.size() >= 2 && cross(hull[hull.size() - 2], hull.back(), i) <= kFlat) hull.pop_back();
    hull.push_back(i);
  }
  const std::size_t lower = hull.size() + 1;
  for (std::size_t i = end - 1; i-- > first;) {   // upper chain
    while (hull.size() >= lower && cross(hull[hull.size() - 2], hull.back(), i) <= kFlat) hull.pop_back();
    hull.push_back(i);
  }
  hull.pop_back();   // the first point again
  if (hull.size() < 2) {
    keep.push_back(first);   // all points coincide
    if (std::abs(u(end - 1) - u(first)) + std::abs(v(end - 1) - v(first)) > kFlat) keep.push_back(end - 1);
    return;
  }
  keep.insert(keep.end(), hull.begin(), hull.end());
}

struct Obstacles::Impl {
  struct Placed {
    ObstacleSpec spec;
    TriangleSurface surface;                 // mesh: placed vertices
    std::vector<Eigen::Vector3d> normals;    // mesh: unit triangle normals
    detail::AabbTree tree;                   // mesh: over the triangles
    EdgePoints edges;                        // edges: corners and points along sharp edges
  };
  std::vector<Placed> obstacles;
  ObstacleContactSpec options;
  TriangleSurface empty;
  // detectEdges' scratch: the edge points of one obstacle that touch the tissue, the hull in
  // construction and the candidates kept
  std::vector<EdgeCandidate> candidates;
  std::vector<std::size_t> hull;
  std::vector<std::size_t> keep;
  // edges: the tissues' surfaces, and per tissue node a mark of the obstacle its vertex touches
  std::vector<collision_detail::MovingSurface> tissues;
  std::vector<std::vector<int>> touching;

  bool queryMesh(const Placed& o, const Eigen::Vector3d& p, double max_gap, double& gap,
                 Eigen::Vector3d& closest, Eigen::Vector3d& outward) const;
};

namespace {

Eigen::Matrix3d eulerXyz(const Eigen::Vector3d& deg) {
  const double k = M_PI / 180.0;
  return (Eigen::AngleAxisd(deg.z() * k, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(deg.y() * k, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(deg.x() * k, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

// Keeps the `cap` deepest contacts (smallest gaps; ties: smaller id), sorted by id; returns how
// many were dropped.
int keepDeepest(std::vector<Contact>& out, int cap_contacts) {
  const auto deeper = [](const Contact& a, const Contact& b) {
    return a.gap_m < b.gap_m || (a.gap_m == b.gap_m && a.id < b.id);
  };
  const auto cap = static_cast<std::size_t>(std::max(1, cap_contacts));
  int dropped = 0;
  if (out.size() > cap) {
    std::nth_element(out.begin(), out.begin() + static_cast<std::ptrdiff_t>(cap), out.end(),
                     deeper);
    dropped = static_cast<int>(out.size() - cap);
    out.resize(cap);
  }
  std::sort(out.begin(), out.end(), [](const Contact& a, const Contact& b) { return a.id < b.id; });
  return dropped;
}

// At most this many edge points per obstacle (edge_spacing is checked by the parser; a huge
// mesh with many sharp edges is refused here).
constexpr std::size_t kMaxEdgePoints = 200000;

// The points strictly between p0 and p1, evenly, at most `spacing` apart (the ends are added as
// corners by the callers).
void sampleEdge(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1, double spacing,
                EdgePoints& out) {
  const double length = (p1 - p0).norm();
  // (a length that is a whole number of spacings up to rounding is cut in that many pieces)
  const auto pieces = static_cast<long>(std::ceil(length / spacing - 1e-9));
  for (long j = 1; j < pieces && out.size() <= kMaxEdgePoints; ++j) {
    out.push_back(p0 + (p1 - p0) * (static_cast<double>(j) / static_cast<double>(pieces)));
  }
}

EdgePoints boxEdgePoints(const ObstacleSpec& box, double spacing) {
  EdgePoints out;
  const auto corner = [&](int bits) {
    return Eigen::Vector3d((bits & 1) ? box.max_m.x() : box.min_m.x(),
                           (bits & 2) ? box.max_m.y() : box.min_m.y(),
                           (bits & 4) ? box.max_m.z() : box.min_m.z());
  };
  for (int c = 0; c < 8; ++c) out.push_back(corner(c));
  for (int c = 0; c < 8; ++c) {
    for (int axis = 0; axis < 3; ++axis) {
      if (!(c & (1 << axis))) sampleEdge(corner(c), corner(c | (1 << axis)), spacing, out);
    }
  }
  return out;
}

// Boundary edges and convex edges sharper than 30 deg, their end vertices and points along them.
EdgePoints meshEdgePoints(const TriangleSurface& s,
                                            const std::vector<Eigen::Vector3d>& normals,
                                            double spacing) {
  struct Edge {
    int a, b, triangle;
    bool operator<(const Edge& o) const { return a != o.a ? a < o.a : b < o.b; }
  };
  std::vector<Edge> edges;
  for (std::size_t t = 0; t < s.triangles.size(); ++t) {
    const auto& tri = s.triangles[t];
    for (int k = 0; k < 3; ++k) {
      const int a = tri[k], b = tri[(k + 1) % 3];
      edges.push_back({std::min(a, b), std::max(a, b), static_cast<int>(t)});
    }
  }
  std::sort(edges.begin(), edges.end());
  const double sharp_cos = std::cos(30.0 * M_PI / 180.0);
  std::vector<char> corner(static_cast<std::size_t>(s.vertices.cols()), 0);
  EdgePoints out;
  for (std::size_t i = 0; i < edges.size();) {
    std::size_t j = i;
    while (j < edges.size() && edges[j].a == edges[i].a && edges[j].b == edges[i].b) ++j;
    bool sharp = j - i != 2;   // a boundary edge, or more than two triangles (non-manifold)
    if (!sharp) {
      const Eigen::Vector3d& n1 = normals[static_cast<std::size_t>(edges[i].triangle)];
      const Eigen::Vector3d& n2 = normals[static_cast<std::size_t>(edges[i + 1].triangle)];
      const auto& t2 = s.triangles[static_cast<std::size_t>(edges[i + 1].triangle)];
      int opposite = t2[0];
      for (int v : t2) {
        if (v != edges[i].a && v != edges[i].b) opposite = v;
      }
      const bool convex = (s.vertices.col(opposite) - s.vertices.col(edges[i].a)).dot(n1) < 0.0;
      sharp = convex && n1.dot(n2) < sharp_cos;
    }
    if (sharp) {
      corner[static_cast<std::size_t>(edges[i].a)] = 1;
      corner[static_cast<std::size_t>(edges[i].b)] = 1;
      sampleEdge(s.vertices.col(edges[i].a), s.vertices.col(edges[i].b), spacing, out);
    }
    i = j;
  }
  for (std::size_t v = 0; v < corner.size(); ++v) {
    if (corner[v]) out.push_back(s.vertices.col(static_cast<Eigen::Index>(v)));
  }
  return out;
}

}  // namespace

Obstacles::Obstacles(const std::vector<ObstacleSpec>& specs, const ObstacleContactSpec& options)
    : impl_(std::make_unique<Impl>()) {
  impl_->options = options;
  if (specs.size() >= (std::size_t{1} << 16)) throw SceneError("more than 65535 obstacles");
  for (const ObstacleSpec& spec : specs) {
    Impl::Placed o;
    o.spec = spec;
    if (spec.kind == ObstacleKind::kMesh) {
      try {
        o.surface = loadTriangleSurface(spec.mesh_path);
      } catch (const MeshError& e) {
        throw MeshError(fmt::format("{}: obstacle '{}': {}", spec.where, spec.name, e.what()));
      }
      const Eigen::Matrix3d r = eulerXyz(spec.rotation_deg);
      o.surface.vertices =
          ((r * (spec.scale * o.surface.vertices)).colwise() + spec.translation_m).eval();
      std::vector<Eigen::AlignedBox3d> boxes;
      for (const auto& t : o.surface.triangles) {
        const Eigen::Vector3d a = o.surface.vertices.col(t[0]);
        const Eigen::Vector3d b = o.surface.vertices.col(t[1]);
        const Eigen::Vector3d c = o.surface.vertices.col(t[2]);
        o.normals.push_back((b - a).cross(c - a).normalized());
        Eigen::AlignedBox3d box(a);
        box.extend(b);
        box.extend(c);
        boxes.push_back(box);
      }
      o.tree.build(boxes);
    }
    if (options.edges) {
      if (spec.kind == ObstacleKind::kBox) {
        o.edges = boxEdgePoints(spec, options.edge_spacing_m);
      } else if (spec.kind == ObstacleKind::kMesh) {
        o.edges = meshEdgePoints(o.surface, o.normals, options.edge_spacing_m);
      }
      if (o.edges.size() > kMaxEdgePoints) {
        throw SceneError(fmt::format(
            "{}: obstacle '{}': more than {} edge points at obstacle_contact.edge_spacing {} m; "
            "raise edge_spacing or turn obstacle_contact.edges off",
            spec.where, spec.name, kMaxEdgePoints, options.edge_spacing_m));
      }
    }
    impl_->obstacles.push_back(std::move(o));
  }
}

Obstacles::~Obstacles() = default;
Obstacles::Obstacles(Obstacles&&) noexcept = default;
Obstacles& Obstacles::operator=(Obstacles&&) noexcept = default;

int Obstacles::count() const { return static_cast<int>(impl_->obstacles.size()); }
const ObstacleSpec& Obstacles::spec(int i) const { return impl_->obstacles.at(i).spec; }
const TriangleSurface& Obstacles::surface(int i) const {
  const auto& o = impl_->obstacles.at(i);
  return o.spec.kind == ObstacleKind::kMesh ? o.surface : impl_->empty;
}

bool Obstacles::Impl::queryMesh(const Placed& o, const Eigen::Vector3d& p, double max_gap,
                                double& gap, Eigen::Vector3d& closest,
                                Eigen::Vector3d& outward) const {
  const double reach = std::max(max_gap, o.spec.thickness_m);
  const collision_detail::SurfaceClosest found = collision_detail::closestOnSurface(
      o.tree, o.surface.triangles, o.normals, p, reach,
      [&](int i) { return o.surface.vertices.col(i); },
      [](const std::array<int, 3>&) { return false; });
  const double best = found.distance;
  if (!(best <= reach)) return false;
  const bool inside = found.side < 0.0;
  gap = inside ? -best : best;
  if (inside ? best > o.spec.thickness_m : best > max_gap) return false;
  closest = found.point.p;
  outward = collision_detail::surfaceOutward(found, p, o.normals);
  return true;
}

bool Obstacles::query(int i, const Eigen::Vector3d& p, double max_gap_m, double& gap_m,
                      Eigen::Vector3d& closest_m, Eigen::Vector3d& outward) const {
  const Impl::Placed& o = impl_->obstacles.at(static_cast<std::size_t>(i));
  switch (o.spec.kind) {
    case ObstacleKind::kPlane: {
      gap_m = (p - o.spec.point_m).dot(o.spec.normal);
      outward = o.spec.normal;
      closest_m = p - gap_m * outward;
      return gap_m <= max_gap_m;
    }
    case ObstacleKind::kBox: {
      const Eigen::Vector3d c = p.cwiseMax(o.spec.min_m).cwiseMin(o.spec.max_m);
      const double d = (p - c).norm();
      if (d > 0.0) {
        gap_m = d;
        outward = (p - c) / d;
        closest_m = c;
        return gap_m <= max_gap_m;
      }
      // inside: the face of least depth
      double depth = std::numeric_limits<double>::infinity();
      for (int a = 0; a < 3; ++a) {
        for (int s = 0; s < 2; ++s) {
          const double di = s == 0 ? p[a] - o.spec.min_m[a] : o.spec.max_m[a] - p[a];
          if (di < depth) {
            depth = di;
            outward = Eigen::Vector3d::Zero();
            outward[a] = s == 0 ? -1.0 : 1.0;
            closest_m = p;
            closest_m[a] = s == 0 ? o.spec.min_m[a] : o.spec.max_m[a];
          }
        }
      }
      gap_m = -depth;
      return true;
    }
    case ObstacleKind::kMesh:
      return impl_->queryMesh(o, p, max_gap_m, gap_m, closest_m, outward);
  }
  return false;
}

void Obstacles::detect(int tissue, std::span<const int> nodes, const Eigen::VectorXd& q,
                       std::vector<Contact>& out, int& overflow) const {
  out.clear();
  overflow = 0;
  const double alarm = impl_->options.alarm_distance_m;
  for (int i = 0; i < count(); ++i) {
    for (int node : nodes) {
      const Eigen::Vector3d v = q.segment<3>(3 * node);
      double gap = 0.0;
      Eigen::Vector3d closest, outward;
      if (!query(i, v, alarm, gap, closest, outward)) continue;
      Contact c;
      c.id = (std::uint64_t{static_cast<std::uint8_t>(ContactKind::kObstacleVertex)} << 56) |
             (static_cast<std::uint64_t>(tissue & 0xff) << 48) |
             (static_cast<std::uint64_t>(i) << 32) | static_cast<std::uint32_t>(node);
      c.kind = ContactKind::kObstacleVertex;
      c.instrument = -1;   // no instrument's
      c.feature = i;
      c.element = node;
      c.nodes = {node, -1, -1};
      c.weights = {1.0, 0.0, 0.0};
      c.tissue_point_m = v;
      c.tool_point_m = closest;
      c.tool_local_m = closest;
      c.n = -outward;
      contactTangents(c.n, c.t1, c.t2);
      c.gap_m = gap;
      out.push_back(c);
    }
  }
  overflow = keepDeepest(out, impl_->options.max_contacts);
}

const std::vector<Eigen::Vector3d>& Obstacles::edgePoints(int i) const {
  return impl_->obstacles.at(static_cast<std::size_t>(i)).edges;
}

void Obstacles::attachTissues(std::span<const TetMesh* const> meshes,
                              std::span<const SurfaceMesh* const> surfaces) {
  if (!impl_->options.edges) return;
  if (meshes.size() != surfaces.size()) throw Error("Obstacles::attachTissues: one surface per mesh");
  impl_->tissues.assign(meshes.size(), collision_detail::MovingSurface{});
  impl_->touching.resize(meshes.size());
  for (std::size_t t = 0; t < meshes.size(); ++t) {
    impl_->tissues[t].init(*meshes[t], *surfaces[t]);
    impl_->touching[t].assign(static_cast<std::size_t>(meshes[t]->nodeCount()), -1);
  }
}

void Obstacles::detectEdges(int tissue, const Eigen::VectorXd& q, std::vector<Contact>& out,
                            int& overflow) {
  Impl& m = *impl_;
  if (!m.options.edges || tissue < 0 || tissue >= static_cast<int>(m.tissues.size())) return;
  collision_detail::MovingSurface& s = m.tissues[static_cast<std::size_t>(tissue)];
  if (s.surface->triangles.empty()) return;
  s.refit(q);
  std::vector<int>& touching = m.touching[static_cast<std::size_t>(tissue)];
  const double alarm = m.options.alarm_distance_m;
  const double depth = m.options.edge_depth_m;
  const double reach = std::max(alarm, depth);
  const std::size_t vertex_contacts = out.size();
  const auto& tris = s.surface->triangles;
  std::vector<EdgeCandidate>& found_points = m.candidates;
  for (int i = 0; i < count(); ++i) {
    const EdgePoints& points = m.obstacles[static_cast<std::size_t>(i)].edges;
    if (points.empty()) continue;
    // the tissue vertices this obstacle already holds (detect()'s contacts)
    std::fill(touching.begin(), touching.end(), -1);
    for (std::size_t k = 0; k < vertex_contacts; ++k) {
      if (out[k].feature == i) touching[static_cast<std::size_t>(out[k].nodes[0])] = i;
    }
    found_points.clear();
    for (std::size_t e = 0; e < points.size(); ++e) {
      const Eigen::Vector3d& p = points[e];
      const collision_detail::SurfaceClosest found = collision_detail::closestOnSurface(
          s.tree, tris, s.face_normal, p, reach, [&](int n) { return q.segment<3>(3 * n); },
          [](const std::array<int, 3>&) { return false; });
      if (found.triangle < 0) continue;
      const bool inside = found.side < 0.0;
      if (inside ? found.distance > depth : found.distance > alarm) continue;
      // at a tissue vertex: that vertex's own contact holds it
      if (found.point.region >= collision_detail::kVertex0 &&
          found.point.region < collision_detail::kEdge0) {
        continue;
      }
      const auto& tri = tris[static_cast<std::size_t>(found.triangle)];
      if (std::all_of(tri.begin(), tri.end(), [&](int n) {
            return touching[static_cast<std::size_t>(n)] == i;
          })) {
        continue;   // the face is held by its vertices on this obstacle
      }
      found_points.push_back({static_cast<int>(e), found});
    }
    // On one (flat) triangle a point's row is the affine combination of its barycentric
    // weights, so holding the points at the corners of their convex hull holds every point
    // inside it: keep only those (points along one straight edge: its first and last). The hull
    // is taken in the barycentric coordinates (w1, w2), an affine image of the triangle's plane.
    std::sort(found_points.begin(), found_points.end(),
              [](const EdgeCandidate& a, const EdgeCandidate& b) {
                if (a.closest.triangle != b.closest.triangle) {
                  return a.closest.triangle < b.closest.triangle;
                }
                const auto& x = a.closest.point.bary;
                const auto& y = b.closest.point.bary;
                return x[1] != y[1] ? x[1] < y[1] : x[2] < y[2];
              });
    m.keep.clear();
    for (std::size_t first = 0; first < found_points.size();) {
      std::size_t end = first;
      while (end < found_points.size() &&
             found_points[end].closest.triangle == found_points[first].closest.triangle) {
        ++end;
      }
      convexHullCorners(found_points, first, end, m.hull, m.keep);
      first = end;
    }
    for (std::size_t k : m.keep) {
      const EdgeCandidate& cand = found_points[k];
      const collision_detail::SurfaceClosest& found = cand.closest;
      const Eigen::Vector3d& p = points[static_cast<std::size_t>(cand.point)];
      Contact c;
      c.id = (std::uint64_t{static_cast<std::uint8_t>(ContactKind::kObstacleVertex)} << 56) |
             (std::uint64_t{1} << 58) | (static_cast<std::uint64_t>(tissue & 0xff) << 48) |
             (static_cast<std::uint64_t>(i) << 32) | static_cast<std::uint32_t>(cand.point);
      c.kind = ContactKind::kObstacleVertex;
      c.instrument = -1;
      c.feature = i;
      c.element = cand.point;
      c.nodes = tris[static_cast<std::size_t>(found.triangle)];
      c.weights = found.point.bary;
      c.tissue_point_m = found.point.p;
      c.tool_point_m = p;
      c.tool_local_m = p;
      // the tissue's outward normal: from the tissue toward the obstacle
      c.n = collision_detail::surfaceOutward(found, p, s.face_normal);
      contactTangents(c.n, c.t1, c.t2);
      c.gap_m = found.side < 0.0 ? -found.distance : found.distance;
      out.push_back(c);
    }
  }
  overflow += keepDeepest(out, m.options.max_contacts);
}

}  // namespace tactus::sim
