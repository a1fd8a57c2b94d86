// Static obstacles and their contacts with tissue surface vertices (obstacles.h).
#include "tactus/sim/obstacles.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "collision_impl.h"
#include "tactus/shared/error.h"

namespace tactus::sim {

struct Obstacles::Impl {
  struct Placed {
    ObstacleSpec spec;
    TriangleSurface surface;                 // mesh: placed vertices
    std::vector<Eigen::Vector3d> normals;    // mesh: unit triangle normals
    detail::AabbTree tree;                   // mesh: over the triangles
  };
  std::vector<Placed> obstacles;
  ObstacleContactSpec options;
  TriangleSurface empty;

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
  const Eigen::Vector3d best_point = found.point.p;
  const Eigen::Vector3d& best_normal = o.normals[static_cast<std::size_t>(found.triangle)];
  closest = best_point;
  outward = best > collision_detail::kTinyDistance_m ? Eigen::Vector3d((inside ? -1.0 : 1.0) *
                                                                       (p - best_point) / best)
                                                     : best_normal;
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
  const auto deeper = [](const Contact& a, const Contact& b) {
    return a.gap_m < b.gap_m || (a.gap_m == b.gap_m && a.id < b.id);
  };
  const std::size_t cap = static_cast<std::size_t>(std::max(1, impl_->options.max_contacts));
  if (out.size() > cap) {
    std::nth_element(out.begin(), out.begin() + static_cast<std::ptrdiff_t>(cap), out.end(),
                     deeper);
    overflow = static_cast<int>(out.size() - cap);
    out.resize(cap);
  }
  std::sort(out.begin(), out.end(), [](const Contact& a, const Contact& b) { return a.id < b.id; });
}

}  // namespace tactus::sim
