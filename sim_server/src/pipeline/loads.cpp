// Loads on a tissue: nodal forces, pressures, prescribed displacements (loads.h).
#include "loads.h"

#include <fmt/format.h>

#include <algorithm>

#include "tactus/shared/error.h"
#include "tactus/sim/node_regions.h"

namespace tactus::sim {

std::vector<TissueLoad> buildTissueLoads(const TetMesh& mesh, const TissueSpec& tissue,
                                         const std::string& fallback_where) {
  std::vector<TissueLoad> out;
  SurfaceMesh surface;
  for (std::size_t i = 0; i < tissue.loads.size(); ++i) {
    TissueLoad load;
    load.spec = tissue.loads[i];
    RegionSpec region = load.spec.region;
    if (region.where.empty()) region.where = load.spec.where;
    const std::string where = fmt::format("{}.loads[{}]", fallback_where, i);
    load.nodes = requireRegionNodes(mesh, region, tissue.name, "load", where);
    if (load.spec.kind == LoadKind::kPressure) {
      if (surface.triangles.empty()) surface = extractSurface(mesh);
      std::vector<bool> in(static_cast<std::size_t>(mesh.nodeCount()), false);
      for (int n : load.nodes) in[static_cast<std::size_t>(n)] = true;
      for (const auto& t : surface.triangles) {
        if (in[static_cast<std::size_t>(t[0])] && in[static_cast<std::size_t>(t[1])] &&
            in[static_cast<std::size_t>(t[2])]) {
          load.triangles.push_back(t);
        }
      }
      if (load.triangles.empty()) {
        throw SceneError(fmt::format(
            "{}: the pressure load's region selects {} nodes of tissue '{}' but no boundary "
            "triangle (all three nodes of a surface triangle must be in it)",
            region.where.empty() ? where : region.where, load.nodes.size(), tissue.name));
      }
    }
    out.push_back(std::move(load));
  }
  return out;
}

std::vector<int> prescribedNodes(const std::vector<TissueLoad>& loads) {
  std::vector<int> out;
  for (const TissueLoad& l : loads) {
    if (l.spec.kind == LoadKind::kDisplacement) out.insert(out.end(), l.nodes.begin(), l.nodes.end());
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

Eigen::Vector3d pathOffset(const std::vector<DisplacementKey>& path, double t_s) {
  if (path.empty()) return Eigen::Vector3d::Zero();
  if (t_s <= path.front().t_s) return path.front().offset_m;
  for (std::size_t k = 1; k < path.size(); ++k) {
    if (t_s <= path[k].t_s) {
      const double s = (t_s - path[k - 1].t_s) / (path[k].t_s - path[k - 1].t_s);
      return (1.0 - s) * path[k - 1].offset_m + s * path[k].offset_m;
    }
  }
  return path.back().offset_m;
}

const Eigen::VectorXd* applyLoadsBeforeFreeMotion(const std::vector<TissueLoad>& loads,
                                                  FemBody& body, double t_end_s, double h_s,
                                                  Eigen::VectorXd& force_n) {
  bool any_force = false;
  force_n.setZero(body.dofCount());
  const Eigen::VectorXd& q = body.positions();
  for (const TissueLoad& l : loads) {
    const double ramp =
        l.spec.ramp_s > 0.0 ? std::min(1.0, t_end_s / l.spec.ramp_s) : 1.0;
    switch (l.spec.kind) {
      case LoadKind::kForce: {
        const Eigen::Vector3d each = ramp * l.spec.force_n / static_cast<double>(l.nodes.size());
        for (int n : l.nodes) force_n.segment<3>(3 * n) += each;
        any_force = true;
        break;
      }
      case LoadKind::kPressure:
        for (const auto& t : l.triangles) {
          const Eigen::Vector3d a = q.segment<3>(3 * t[0]);
          // (b - a) x (c - a) / 2 = A N (outward): each node gets -p A N / 3
          const Eigen::Vector3d area_normal =
              0.5 * (q.segment<3>(3 * t[1]) - a).cross(q.segment<3>(3 * t[2]) - a);
          const Eigen::Vector3d each = -ramp * l.spec.pressure_pa * area_normal / 3.0;
          for (int n : t) force_n.segment<3>(3 * n) += each;
        }
        any_force = true;
        break;
      case LoadKind::kDisplacement: {
        const Eigen::Vector3d offset = pathOffset(l.spec.path, t_end_s);
        const Eigen::VectorXd& rest = body.restPositions();
        for (int n : l.nodes) {
          body.velocities().segment<3>(3 * n) =
              (rest.segment<3>(3 * n) + offset - q.segment<3>(3 * n)) / h_s;
        }
        break;
      }
    }
  }
  return any_force ? &force_n : nullptr;
}

void applyLoadsAfterFreeMotion(const std::vector<TissueLoad>& loads, FemBody& body,
                               double t_end_s) {
  for (const TissueLoad& l : loads) {
    if (l.spec.kind != LoadKind::kDisplacement) continue;
    const Eigen::Vector3d offset = pathOffset(l.spec.path, t_end_s);
    const Eigen::VectorXd& rest = body.restPositions();
    for (int n : l.nodes) body.positions().segment<3>(3 * n) = rest.segment<3>(3 * n) + offset;
  }
}

}  // namespace tactus::sim
