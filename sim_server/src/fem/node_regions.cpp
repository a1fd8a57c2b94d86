// Node regions: the selectors of scene_regions.h over a placed mesh.
#include "tactus/sim/node_regions.h"

#include <fmt/format.h>

#include <Eigen/Geometry>

#include "tactus/shared/error.h"

namespace tactus::sim {
namespace {

std::string describe(const RegionSpec& r) {
  const char* axis = r.axis == 0 ? "x" : r.axis == 1 ? "y" : "z";
  switch (r.kind) {
    case RegionKind::kBox:
      return fmt::format("the box [{:g}, {:g}, {:g}]..[{:g}, {:g}, {:g}] m", r.min_m.x(),
                         r.min_m.y(), r.min_m.z(), r.max_m.x(), r.max_m.y(), r.max_m.z());
    case RegionKind::kPlaneSide:
      return fmt::format("the side of the plane through [{:g}, {:g}, {:g}] m along normal "
                         "[{:g}, {:g}, {:g}] (tolerance {:g} m)",
                         r.point_m.x(), r.point_m.y(), r.point_m.z(), r.normal.x(), r.normal.y(),
                         r.normal.z(), r.tolerance_m);
    case RegionKind::kLowest:
      return fmt::format("the lowest nodes along {} (tolerance {:g} m)", axis, r.tolerance_m);
    case RegionKind::kHighest:
      return fmt::format("the highest nodes along {} (tolerance {:g} m)", axis, r.tolerance_m);
    case RegionKind::kGroup: return fmt::format("the physical group '{}'", r.group);
  }
  return "the region";
}

}  // namespace

std::vector<int> selectRegionNodes(const TetMesh& mesh, const RegionSpec& r) {
  if (r.kind == RegionKind::kGroup) return groupRegionNodes(mesh, r, "", "region");
  std::vector<int> out;
  const int n = mesh.nodeCount();
  if (n == 0) return out;
  // positions on a selector's boundary count as inside despite rounding (1e-9 of the mesh's size)
  const double eps =
      1e-9 * (mesh.nodes.rowwise().maxCoeff() - mesh.nodes.rowwise().minCoeff()).norm();
  const double tol = r.tolerance_m + eps;
  double extreme = 0.0;
  if (r.kind == RegionKind::kLowest) extreme = mesh.nodes.row(r.axis).minCoeff();
  if (r.kind == RegionKind::kHighest) extreme = mesh.nodes.row(r.axis).maxCoeff();
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d p = mesh.nodes.col(i);
    bool in = false;
    switch (r.kind) {
      case RegionKind::kBox:
        in = (p.array() >= r.min_m.array() - eps).all() && (p.array() <= r.max_m.array() + eps).all();
        break;
      case RegionKind::kPlaneSide: in = (p - r.point_m).dot(r.normal) >= -tol; break;
      case RegionKind::kLowest: in = p[r.axis] <= extreme + tol; break;
      case RegionKind::kHighest: in = p[r.axis] >= extreme - tol; break;
      case RegionKind::kGroup: break;   // handled above
    }
    if (in) out.push_back(i);
  }
  return out;
}

std::vector<int> requireRegionNodes(const TetMesh& mesh, const RegionSpec& region,
                                    const std::string& tissue_name, const std::string& use,
                                    const std::string& fallback_where) {
  std::vector<int> nodes = region.kind == RegionKind::kGroup
                               ? groupRegionNodes(mesh, region, tissue_name, fallback_where)
                               : selectRegionNodes(mesh, region);
  if (!nodes.empty()) return nodes;
  Eigen::AlignedBox3d bounds;
  for (Eigen::Index i = 0; i < mesh.nodes.cols(); ++i) bounds.extend(mesh.nodes.col(i));
  const Eigen::Vector3d lo = bounds.min();
  const Eigen::Vector3d hi = bounds.max();
  throw SceneError(fmt::format(
      "{}: the {} region, {}, selects no node of tissue '{}' (its placed mesh spans "
      "[{:g}, {:g}, {:g}]..[{:g}, {:g}, {:g}] m)",
      region.where.empty() ? fallback_where : region.where, use, describe(region), tissue_name,
      lo.x(), lo.y(), lo.z(), hi.x(), hi.y(), hi.z()));
}

RegionSpec boxRegion(const BoxSpec& box) {
  RegionSpec r;
  r.kind = RegionKind::kBox;
  r.min_m = box.min_m;
  r.max_m = box.max_m;
  r.where = box.where;
  return r;
}

}  // namespace tactus::sim
