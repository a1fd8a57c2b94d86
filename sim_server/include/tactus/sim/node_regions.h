#pragma once
// Node regions of a tissue (scene_regions.h's RegionSpec): the nodes a selector chooses, and the
// check that it chooses some (scenes/README.md, "Regions").

#include <string>
#include <vector>

#include "tactus/sim/mesh.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {

/// The region's nodes (sorted indices into mesh.nodes), possibly none (a group region naming no
/// group of the mesh throws, see groupRegionNodes). A node on the selector's
/// boundary (a box face, the plane) counts as inside: every test is widened by 1e-9 of the mesh's
/// bounding-box diagonal, so rounding in the transform does not drop it.
std::vector<int> selectRegionNodes(const TetMesh& mesh, const RegionSpec& region);

/// As selectRegionNodes, but a region that selects no node throws tactus::SceneError naming it
/// (region.where, else `fallback_where`), what it selects for (`use`, e.g. "fixed") and the span
/// of the placed mesh, so a region in the wrong units or frame is found at once.
std::vector<int> requireRegionNodes(const TetMesh& mesh, const RegionSpec& region,
                                    const std::string& tissue_name, const std::string& use,
                                    const std::string& fallback_where);

/// A group region's nodes (RegionKind::kGroup): the one physical group of mesh.groups named
/// region.group, else, when the selector is an integer, the one with that physical tag. No match,
/// or several (a name or tag in several dimensions), throws tactus::SceneError naming the region
/// (region.where, else `fallback_where`), the group, the tissue and listing the mesh's groups. In
/// group_regions.cpp.
const std::vector<int>& groupRegionNodes(const TetMesh& mesh, const RegionSpec& region,
                                         const std::string& tissue_name,
                                         const std::string& fallback_where);

/// A fixed box (TissueSpec::fixed_boxes) as a region.
RegionSpec boxRegion(const BoxSpec& box);

}  // namespace tactus::sim
