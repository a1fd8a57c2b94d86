// Collision between the tissue surface and the tool's features (collision.h): construction,
// refit, detect (dispatch per feature shape, the contact cap) and the contact rows. The surface
// upkeep and the narrow phases are in collision_{surface,vertex,sphere}.cpp.
#include "tactus/sim/collision.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "collision_impl.h"
#include "tactus/shared/error.h"

namespace tactus::sim {
namespace {

using namespace collision_detail;

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

void Collision::Impl::emit(ContactKind kind, const ToolFeature& f, int element,
                           const std::array<int, 3>& nodes, const std::array<double, 3>& weights,
                           const Eigen::Vector3d& tissue_point, const Eigen::Vector3d& tool_point,
                           const Eigen::Vector3d& n, double gap, const shared::Pose& tool_pose) {
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
  buildContactRows(contacts, std::span<const double>(&mu, 1),
                   std::span<const Eigen::Vector3d>(&tool_origin_m, 1), out);
}

void buildContactRows(std::span<const Contact> contacts, std::span<const double> mu,
                      std::span<const Eigen::Vector3d> tool_origin_m, ContactRows& out) {
  const int nc = static_cast<int>(contacts.size());
  int rows = 0;
  for (const Contact& c : contacts) {
    rows += mu[static_cast<std::size_t>(c.instrument)] > 0.0 ? 3 : 1;
  }
  out.row_offset.resize(nc + 1);
  out.tissue.resize(rows);
  out.tool.resize(rows, 6);
  out.delta_free.resize(rows);
  out.row_offset[0] = 0;
  for (int i = 0; i < nc; ++i) {
    const Contact& c = contacts[i];
    const auto inst = static_cast<std::size_t>(c.instrument);
    const int per = mu[inst] > 0.0 ? 3 : 1;
    const Eigen::Matrix<double, 3, 6> jac =
        shared::pointJacobian(tool_origin_m[inst], c.tool_point_m);
    for (int d = 0; d < per; ++d) {
      const int r = out.row_offset[i] + d;
      const Eigen::Vector3d& dir = d == 0 ? c.n : (d == 1 ? c.t1 : c.t2);
      TissueRow& row = out.tissue[r];
      row.node = c.nodes;
      for (int k = 0; k < 3; ++k) row.weight[k] = c.nodes[k] >= 0 ? -c.weights[k] : 0.0;
      row.dir = dir;
      out.tool.row(r) = dir.transpose() * jac;
      out.delta_free[r] = d == 0 ? c.gap_m : 0.0;
    }
    out.row_offset[i + 1] = out.row_offset[i] + per;
  }
}

}  // namespace tactus::sim
