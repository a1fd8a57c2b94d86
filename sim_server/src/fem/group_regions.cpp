// Node regions by physical group (RegionKind::kGroup): the group a region names, or an error
// listing the mesh's groups.
#include <fmt/format.h>

#include <charconv>

#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/node_regions.h"

namespace tactus::sim {
namespace {

const char* dimensionWord(int dimension) {
  switch (dimension) {
    case 0: return "point";
    case 1: return "curve";
    case 2: return "surface";
    default: return "volume";
  }
}

std::string describeGroup(const NodeGroup& g) {
  return fmt::format("'{}' ({} {}, {} nodes)", shared::printable(g.name, 80),
                     dimensionWord(g.dimension), g.tag, g.nodes.size());
}

std::string listGroups(const std::vector<const NodeGroup*>& groups) {
  std::string out;
  for (const NodeGroup* g : groups) out += (out.empty() ? "" : ", ") + describeGroup(*g);
  return out;
}

}  // namespace

const std::vector<int>& groupRegionNodes(const TetMesh& mesh, const RegionSpec& region,
                                         const std::string& tissue_name,
                                         const std::string& fallback_where) {
  // by name first; a selector no name matches that reads as an integer is a physical tag
  std::vector<const NodeGroup*> matches;
  for (const NodeGroup& g : mesh.groups) {
    if (g.name == region.group) matches.push_back(&g);
  }
  int tag = 0;
  const char* end = region.group.data() + region.group.size();
  const auto [ptr, ec] = std::from_chars(region.group.data(), end, tag);
  if (matches.empty() && !region.group.empty() && ec == std::errc() && ptr == end) {
    for (const NodeGroup& g : mesh.groups) {
      if (g.tag == tag) matches.push_back(&g);
    }
  }
  if (matches.size() == 1) return matches.front()->nodes;
  const std::string where = region.where.empty() ? fallback_where : region.where;
  const std::string tissue = tissue_name.empty() ? "" : fmt::format(" of tissue '{}'", tissue_name);
  if (matches.size() > 1) {
    throw SceneError(fmt::format("{}: the group '{}' is ambiguous in the mesh{} ({}): it matches "
                                 "{}; give the name or tag of just one",
                                 where, region.group, tissue, mesh.source, listGroups(matches)));
  }
  std::vector<const NodeGroup*> all;
  for (const NodeGroup& g : mesh.groups) all.push_back(&g);
  throw SceneError(fmt::format(
      "{}: the group '{}' is not a physical group of the mesh{} ({}): {}", where, region.group,
      tissue, mesh.source,
      all.empty() ? std::string("it has no physical groups (only Gmsh meshes carry them, in "
                                "$PhysicalNames and the elements' physical tags)")
                  : "its groups are " + listGroups(all)));
}

}  // namespace tactus::sim
