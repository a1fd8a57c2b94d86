// Contact between tissues and of a tissue with itself (tissue_contact.h).
#include "tactus/sim/tissue_contact.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "collision_impl.h"
#include "moving_surface.h"
#include "tactus/shared/error.h"

namespace tactus::sim {

// (a named namespace, not an anonymous one: TissueContacts::Impl holds these, and the library is
// a unity build, where GCC warns about a class member whose type has internal linkage)
namespace tissue_contact_detail {

// One tissue's surface at the positions of the last refit, with its self-contact neighbourhoods.
struct SurfaceState : collision_detail::MovingSurface {
  bool used = false;
  // self-contact: per surface node, the sorted nodes within two edges (CSR)
  std::vector<int> near_offset;
  std::vector<int> near_nodes;
};

// Nodes within two edges of every surface node, through the tetrahedra (CSR by local index).
void buildNeighbourhoods(SurfaceState& s) {
  const int n = s.mesh->nodeCount();
  std::vector<std::vector<int>> adjacent(static_cast<std::size_t>(n));
  for (const auto& tet : s.mesh->tets) {
    for (int a = 0; a < 4; ++a) {
      for (int b = 0; b < 4; ++b) {
        if (a != b) adjacent[static_cast<std::size_t>(tet[a])].push_back(tet[b]);
      }
    }
  }
  for (auto& list : adjacent) {
    std::sort(list.begin(), list.end());
    list.erase(std::unique(list.begin(), list.end()), list.end());
  }
  s.near_offset.assign(1, 0);
  std::vector<int> ring;
  for (int v : s.surface->nodes) {
    ring.assign(1, v);
    for (int u : adjacent[static_cast<std::size_t>(v)]) {
      ring.push_back(u);
      const auto& second = adjacent[static_cast<std::size_t>(u)];
      ring.insert(ring.end(), second.begin(), second.end());
    }
    std::sort(ring.begin(), ring.end());
    ring.erase(std::unique(ring.begin(), ring.end()), ring.end());
    s.near_nodes.insert(s.near_nodes.end(), ring.begin(), ring.end());
    s.near_offset.push_back(static_cast<int>(s.near_nodes.size()));
  }
}

}  // namespace tissue_contact_detail

struct TissueContacts::Impl {
  std::vector<tissue_contact_detail::SurfaceState> tissues;
  std::vector<TissueContactSpec> specs;
  std::vector<Direction> directions;
  std::vector<std::vector<Contact>> found;   // per direction
  std::vector<int> overflow;

  void detectDirection(int k, const Eigen::VectorXd& qa, const Eigen::VectorXd& qb);
};

TissueContacts::TissueContacts(std::span<const TetMesh* const> meshes,
                               std::span<const SurfaceMesh* const> surfaces,
                               const std::vector<TissueContactSpec>& specs)
    : impl_(std::make_unique<Impl>()) {
  if (meshes.size() != surfaces.size()) throw Error("TissueContacts: one surface per mesh");
  if (specs.size() > static_cast<std::size_t>(kMaxTissueContactPairs)) {
    throw SceneError(fmt::format("tissue_contact: at most {} pairs (got {})",
                                 kMaxTissueContactPairs, specs.size()));
  }
  impl_->specs = specs;
  impl_->tissues.resize(meshes.size());
  for (std::size_t t = 0; t < meshes.size(); ++t) {
    impl_->tissues[t].mesh = meshes[t];
    impl_->tissues[t].surface = surfaces[t];
  }
  for (std::size_t p = 0; p < specs.size(); ++p) {
    const TissueContactSpec& spec = specs[p];
    for (int t : {spec.tissue_a, spec.tissue_b}) {
      if (t < 0 || t >= static_cast<int>(meshes.size())) {
        throw SceneError(fmt::format("{}: no tissue {}", spec.where, t));
      }
      tissue_contact_detail::SurfaceState& s = impl_->tissues[static_cast<std::size_t>(t)];
      if (s.surface->triangles.empty()) {
        throw SceneError(fmt::format("{}: tissue {} has no surface", spec.where, t));
      }
      if (s.mesh->nodeCount() >= (1 << 24)) {
        throw SceneError(fmt::format("{}: tissue {} has {} nodes; tissue contact supports "
                                     "meshes of fewer than 2^24", spec.where, t,
                                     s.mesh->nodeCount()));
      }
      s.used = true;
    }
    const int pair = static_cast<int>(p);
    impl_->directions.push_back({pair, spec.tissue_a, spec.tissue_b, 2 * pair});
    if (spec.tissue_a != spec.tissue_b && spec.two_way) {
      impl_->directions.push_back({pair, spec.tissue_b, spec.tissue_a, 2 * pair + 1});
    }
  }
  std::vector<bool> self(meshes.size(), false);
  for (const auto& spec : specs) {
    if (spec.tissue_a == spec.tissue_b) self[static_cast<std::size_t>(spec.tissue_a)] = true;
  }
  for (std::size_t t = 0; t < impl_->tissues.size(); ++t) {
    tissue_contact_detail::SurfaceState& s = impl_->tissues[t];
    if (!s.used) continue;
    s.init(*s.mesh, *s.surface);
    if (self[t]) tissue_contact_detail::buildNeighbourhoods(s);
  }
  impl_->found.resize(impl_->directions.size());
  impl_->overflow.assign(impl_->directions.size(), 0);
}

TissueContacts::~TissueContacts() = default;
TissueContacts::TissueContacts(TissueContacts&&) noexcept = default;
TissueContacts& TissueContacts::operator=(TissueContacts&&) noexcept = default;

int TissueContacts::directionCount() const { return static_cast<int>(impl_->directions.size()); }
const TissueContacts::Direction& TissueContacts::direction(int k) const {
  return impl_->directions.at(static_cast<std::size_t>(k));
}
const TissueContactSpec& TissueContacts::spec(int pair) const {
  return impl_->specs.at(static_cast<std::size_t>(pair));
}
const std::vector<Contact>& TissueContacts::contacts(int k) const {
  return impl_->found.at(static_cast<std::size_t>(k));
}
int TissueContacts::overflow(int k) const {
  return impl_->overflow.at(static_cast<std::size_t>(k));
}

void TissueContacts::detect(std::span<const Eigen::VectorXd* const> q) {
  for (std::size_t t = 0; t < impl_->tissues.size(); ++t) {
    if (impl_->tissues[t].used) impl_->tissues[t].refit(*q[t]);
  }
  for (int k = 0; k < directionCount(); ++k) {
    const Direction& d = impl_->directions[static_cast<std::size_t>(k)];
    impl_->detectDirection(k, *q[static_cast<std::size_t>(d.vertex_tissue)],
                           *q[static_cast<std::size_t>(d.surface_tissue)]);
  }
}

void TissueContacts::Impl::detectDirection(int k, const Eigen::VectorXd& qa,
                                           const Eigen::VectorXd& qb) {
  const Direction& d = directions[static_cast<std::size_t>(k)];
  const TissueContactSpec& spec = specs[static_cast<std::size_t>(d.pair)];
  const tissue_contact_detail::SurfaceState& a = tissues[static_cast<std::size_t>(d.vertex_tissue)];
  const tissue_contact_detail::SurfaceState& b = tissues[static_cast<std::size_t>(d.surface_tissue)];
  const bool self = d.vertex_tissue == d.surface_tissue;
  const auto slot = static_cast<std::uint64_t>(d.slot);
  const double reach = std::max(spec.alarm_distance_m, spec.depth_m);
  std::vector<Contact>& out = found[static_cast<std::size_t>(k)];
  out.clear();
  const auto& tris = b.surface->triangles;
  for (std::size_t li = 0; li < a.surface->nodes.size(); ++li) {
    const int v = a.surface->nodes[li];
    const Eigen::Vector3d p = qa.segment<3>(3 * v);
    const int* near_begin = self ? b.near_nodes.data() + b.near_offset[li] : nullptr;
    const int* near_end = self ? b.near_nodes.data() + b.near_offset[li + 1] : nullptr;
    const collision_detail::SurfaceClosest found = collision_detail::closestOnSurface(
        b.tree, tris, b.face_normal, p, reach, [&](int i) { return qb.segment<3>(3 * i); },
        [&](const std::array<int, 3>& tri) {   // self-contact: v's own neighbourhood
          return self && std::any_of(tri.begin(), tri.end(), [&](int node) {
                   return std::binary_search(near_begin, near_end, node);
                 });
        });
    if (found.triangle < 0) continue;
    const double best = found.distance;
    const int best_tri = found.triangle;
    const collision_detail::ClosestPoint& best_cp = found.point;
    const bool inside = found.side < 0.0;
    if (inside ? best > spec.depth_m : best > spec.alarm_distance_m) continue;
    const Eigen::Vector3d outward = collision_detail::surfaceOutward(found, p, b.face_normal);
    // A's vertex must face B (its normal against B's outward normal)
    if (!(a.vertex_normal[li].dot(outward) < 0.0)) continue;
    Contact c;
    c.kind = ContactKind::kTissueTissue;
    c.instrument = -1;
    c.feature = v;
    c.element = best_tri;
    c.nodes = tris[static_cast<std::size_t>(best_tri)];
    c.weights = best_cp.bary;
    c.tissue_point_m = best_cp.p;
    c.tool_point_m = p;
    c.tool_local_m = p;
    c.n = outward;
    contactTangents(c.n, c.t1, c.t2);
    c.gap_m = inside ? -best : best;
    c.id = (static_cast<std::uint64_t>(ContactKind::kTissueTissue) << 56) | (slot << 58) |
           (static_cast<std::uint64_t>(v) << 32) | static_cast<std::uint32_t>(best_tri);
    out.push_back(c);
  }
  overflow[static_cast<std::size_t>(k)] = 0;
  const auto cap = static_cast<std::size_t>(spec.max_contacts);
  if (out.size() > cap) {
    overflow[static_cast<std::size_t>(k)] = static_cast<int>(out.size() - cap);
    std::nth_element(out.begin(), out.begin() + static_cast<std::ptrdiff_t>(cap), out.end(),
                     [](const Contact& x, const Contact& y) {
                       return x.gap_m < y.gap_m || (x.gap_m == y.gap_m && x.id < y.id);
                     });
    out.resize(cap);
  }
  std::sort(out.begin(), out.end(), [](const Contact& x, const Contact& y) { return x.id < y.id; });
}

}  // namespace tactus::sim
