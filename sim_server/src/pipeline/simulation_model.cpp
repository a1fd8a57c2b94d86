// The model of a scene: meshes placed, fixed nodes collected, solver settings derived.
#include "simulation_model.h"

#include <fmt/format.h>

#include <algorithm>
#include <iterator>

#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/node_regions.h"
#include "obstacle_stage.h"
#include "strain_limit.h"
#include "tissue_contact_stage.h"

namespace tactus::sim {
namespace {

TissueModel buildTissueModel(const SceneSpec& spec, const TissueSpec& ts) {
  TissueModel tissue;
  tissue.name = ts.name;
  MeshReport mesh_report;
  tissue.mesh = loadTetMesh(ts.mesh_path, &mesh_report);
  transformMesh(tissue.mesh, ts.scale, ts.rotation_deg, ts.translation_m);
  std::vector<int> fixed = ts.fixed_nodes;
  for (int n : fixed) {
    if (n < 0 || n >= tissue.mesh.nodeCount()) {
      throw SceneError(fmt::format("{}: tissue '{}': fixed node {} is not in the mesh ({} nodes)",
                                   spec.source.string(), ts.name, n, tissue.mesh.nodeCount()));
    }
  }
  // a region that catches no node is a mistake in the scene (a box in the wrong units or frame)
  const std::string scene_where = fmt::format("{}: tissues '{}'", spec.source.string(), ts.name);
  std::vector<RegionSpec> regions;
  for (const BoxSpec& box : ts.fixed_boxes) regions.push_back(boxRegion(box));
  regions.insert(regions.end(), ts.fixed_regions.begin(), ts.fixed_regions.end());
  for (const RegionSpec& region : regions) {
    const std::vector<int> nodes =
        requireRegionNodes(tissue.mesh, region, ts.name, "fixed", scene_where + ": fixed");
    fixed.insert(fixed.end(), nodes.begin(), nodes.end());
  }
  tissue.loads = buildTissueLoads(tissue.mesh, ts, scene_where);
  const std::vector<int> prescribed = prescribedNodes(tissue.loads);
  // a node is either held at rest or moved along a path, not both
  std::sort(fixed.begin(), fixed.end());
  fixed.erase(std::unique(fixed.begin(), fixed.end()), fixed.end());
  std::vector<int> both;
  std::set_intersection(fixed.begin(), fixed.end(), prescribed.begin(), prescribed.end(),
                        std::back_inserter(both));
  if (!both.empty()) {
    throw SceneError(fmt::format(
        "{}: {} node(s) are both fixed and given a prescribed displacement (the first: node {}): "
        "a node is either held at rest or moved along its path; take them out of the fixed "
        "nodes/boxes/regions or out of the displacement load's region",
        scene_where, both.size(), both.front()));
  }
  fixed.insert(fixed.end(), prescribed.begin(), prescribed.end());
  std::sort(fixed.begin(), fixed.end());
  fixed.erase(std::unique(fixed.begin(), fixed.end()), fixed.end());
  tissue.fixed_nodes = std::move(fixed);
  if (spec.instrument.present || !spec.obstacles.empty() || !spec.tissue_contacts.empty()) {
    tissue.surface = extractSurface(tissue.mesh);
  }
  tissue.min_volume_ratio = ts.min_volume_ratio;
  if (ts.min_volume_ratio > 0.0) tissue.rest_volume6 = restVolumes6(tissue.mesh);
  return tissue;
}

}  // namespace

SimulationModel buildModel(const SceneSpec& spec) {
  if (!(spec.time_step_s > 0.0)) throw SceneError("time_step must be > 0");
  SimulationModel model;
  model.spec = spec;
  model.h_s = spec.time_step_s;
  for (const TissueSpec& ts : spec.tissues) model.tissues.push_back(buildTissueModel(spec, ts));
  // a box obstacle pushes out what enters it through its faces: a tissue that starts inside it
  // entirely has nothing pushing it out and falls through
  for (const ObstacleSpec& o : spec.obstacles) {
    if (o.kind != ObstacleKind::kBox) continue;
    for (const TissueModel& t : model.tissues) {
      const Eigen::Matrix3Xd& x = t.mesh.nodes;
      bool all_inside = x.cols() > 0;
      for (Eigen::Index i = 0; i < x.cols() && all_inside; ++i) {
        all_inside = (x.col(i).array() > o.min_m.array()).all() &&
                     (x.col(i).array() < o.max_m.array()).all();
      }
      if (all_inside) {
        throw SceneError(fmt::format(
            "{}: the box encloses all of tissue '{}' at rest: a box obstacle pushes out only "
            "what enters it through its faces, so the tissue would fall through it; place the "
            "box beside or under the tissue",
            o.where.empty() ? "obstacles '" + o.name + "'" : o.where, t.name));
      }
    }
  }
  model.has_instrument = spec.instrument.present;
  model.instrument_count = instrumentCount(spec);
  model.has_contacts =
      model.has_instrument || !spec.obstacles.empty() || !spec.tissue_contacts.empty();
  if (!model.has_contacts) return model;
  model.nsgs.tolerance = spec.solver.nsgs_tolerance;
  model.nsgs.max_sweeps = spec.solver.nsgs_max_sweeps;
  model.nsgs.sor = spec.solver.nsgs_sor;
  model.nsgs.anderson_depth = spec.solver.nsgs_anderson_depth;
  model.nsgs.coupling = shared::NsgsCoupling::kSymmetricRowUpdate;   // buildW keeps W symmetric
  // obstacle rows (3 per contact with friction) come after the instruments', per tissue
  model.max_rows = obstacleRowCapacity(spec) + tissueContactRowCapacity(spec);
  if (!model.has_instrument) return model;
  // the device target stays within a box around the scene at rest (instrument.h "Workspace")
  Eigen::AlignedBox3d bounds;
  for (const TissueModel& tissue : model.tissues) {
    for (Eigen::Index i = 0; i < tissue.mesh.nodes.cols(); ++i) bounds.extend(tissue.mesh.nodes.col(i));
  }
  for (int i = 0; i < model.instrument_count; ++i) {
    const InstrumentSpec& in = instrumentSpec(spec, i);
    model.instrument_workspaces.push_back(instrumentWorkspace(in, bounds));
    model.max_rows += (in.friction_mu > 0.0 ? 3 : 1) * spec.solver.max_contacts;
  }
  return model;
}

}  // namespace tactus::sim
