// Gmsh physical groups: from the file's node ids to sorted node sets of the mesh (NodeGroup).

#include <fmt/format.h>

#include <algorithm>
#include <map>
#include <utility>

#include "mesh_internal.h"

namespace tactus::sim::detail {

int gmshElementDimension(std::int64_t type) {
  switch (type) {
    case 15: return 0;                                                    // point
    case 1: case 8: case 26: case 27: case 28: return 1;                  // lines
    case 2: case 3: case 9: case 10: case 16: case 20: case 21: case 22:  // triangles, quads
    case 23: case 24: case 25: return 2;
    case 4: case 5: case 6: case 7: case 11: case 12: case 13: case 14:   // tets, hexes, prisms,
    case 17: case 18: case 19: case 29: case 30: case 31: case 92: case 93: return 3;  // pyramids
    default: return -1;
  }
}

RawGroup& rawGroup(RawGroupMap* groups, int dimension, int tag) {
  RawGroup& g = (*groups)[{dimension, tag}];
  g.dimension = dimension;
  g.tag = tag;
  return g;
}

void addEntityGroups(const RawGroupMap& entity_nodes,
                     const std::map<std::pair<int, int>, std::vector<int>>& entity_physicals,
                     RawGroupMap* groups, const std::string& name, int line) {
  std::size_t listed = 0;
  for (const auto& [entity, part] : entity_nodes) {
    listed += 4 * part.tets.size() + part.node_ids.size();
  }
  const std::size_t bound = 16 * listed + (std::size_t{1} << 16);
  std::size_t copied = 0;
  for (const auto& [entity, part] : entity_nodes) {
    const auto physicals = entity_physicals.find(entity);
    if (physicals == entity_physicals.end()) continue;
    std::vector<int> tags = physicals->second;   // a tag listed twice counts once
    std::sort(tags.begin(), tags.end());
    tags.erase(std::unique(tags.begin(), tags.end()), tags.end());
    for (const int tag : tags) {
      copied += 4 * part.tets.size() + part.node_ids.size();
      if (copied > bound) {
        fail(name, line,
             fmt::format("the physical groups of $Entities would hold over {} element nodes, "
                         "16 times those of the elements: too many groups per entity",
                         bound));
      }
      RawGroup& g = rawGroup(groups, entity.first, tag);
      g.tets.insert(g.tets.end(), part.tets.begin(), part.tets.end());
      g.node_ids.insert(g.node_ids.end(), part.node_ids.begin(), part.node_ids.end());
      g.node_lines.insert(g.node_lines.end(), part.node_lines.begin(), part.node_lines.end());
    }
  }
}

std::vector<NodeGroup> resolveGroups(const RawMesh& raw, const TetMesh& mesh,
                                     const std::unordered_map<std::int64_t, int>& index_of,
                                     const std::vector<int>& new_index, const std::string& name,
                                     int* dropped) {
  std::map<std::pair<int, int>, NodeGroup> by_key;   // ordered by (dimension, tag)
  const auto group = [&by_key](int dimension, int tag) -> NodeGroup& {
    auto [it, inserted] = by_key.try_emplace({dimension, tag});
    if (inserted) {
      it->second.dimension = dimension;
      it->second.tag = tag;
      it->second.name = std::to_string(tag);
    }
    return it->second;
  };
  for (const RawPhysicalName& n : raw.physical_names) {
    if (!n.name.empty()) group(n.dimension, n.tag).name = n.name;
  }
  std::vector<int> dropped_positions;
  // nodes are marked as they join a group (each once), then sorted and the marks cleared
  std::vector<char> in(static_cast<std::size_t>(mesh.nodeCount()), 0);
  for (const RawGroup& rg : raw.groups) {
    NodeGroup& g = group(rg.dimension, rg.tag);
    for (int node : g.nodes) in[static_cast<std::size_t>(node)] = 1;
    const auto mark = [&in, &g](int node) {
      if (in[static_cast<std::size_t>(node)] == 0) {
        in[static_cast<std::size_t>(node)] = 1;
        g.nodes.push_back(node);
      }
    };
    for (int t : rg.tets) {
      for (int node : mesh.tets[static_cast<std::size_t>(t)]) mark(node);
    }
    for (std::size_t k = 0; k < rg.node_ids.size(); ++k) {
      const auto found = index_of.find(rg.node_ids[k]);
      if (found == index_of.end()) {
        fail(name, rg.node_lines[k],
             fmt::format("an element of physical group '{}' (dimension {}, tag {}) refers to "
                         "{} {} which is not defined",
                         g.name, g.dimension, g.tag, raw.node_word, rg.node_ids[k]));
      }
      const int index = new_index[static_cast<std::size_t>(found->second)];
      if (index < 0) {
        dropped_positions.push_back(found->second);
      } else {
        mark(index);
      }
    }
    std::sort(g.nodes.begin(), g.nodes.end());
    for (int node : g.nodes) in[static_cast<std::size_t>(node)] = 0;
  }
  std::sort(dropped_positions.begin(), dropped_positions.end());
  *dropped = static_cast<int>(std::unique(dropped_positions.begin(), dropped_positions.end()) -
                              dropped_positions.begin());
  std::vector<NodeGroup> out;
  out.reserve(by_key.size());
  for (auto& [key, g] : by_key) out.push_back(std::move(g));
  return out;
}

}  // namespace tactus::sim::detail
