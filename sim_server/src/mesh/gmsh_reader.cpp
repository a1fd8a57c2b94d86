// The Gmsh reader (ASCII 1.0, 2.x and 4.1), with the physical groups ($PhysicalNames, the
// elements' physical tags, 4.1's $Entities); mesh_groups.cpp turns them into node sets.

#include <spdlog/spdlog.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <limits>
#include <map>
#include <unordered_map>

#include "mesh_internal.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim::detail {

namespace {

// Reads Gmsh sections line by line; every read is checked against the end of the input.
class GmshReader {
 public:
  GmshReader(const std::string& content, const std::string& name, RawMesh* raw)
      : cur_(content), name_(name), raw_(raw) {}

  void run() {
    std::string_view line;
    while (cur_.next(&line)) {
      line = trim(line);
      if (line.empty()) continue;
      if (line.front() != '$') {
        fail(name_, cur_.line(),
             fmt::format("unexpected text '{}' outside a section (expected a $Section line)",
                         excerpt(line)));
      }
      const std::string_view section = line;
      section_line_ = cur_.line();
      section_ = std::string(section);
      if (section == "$MeshFormat") {
        readFormat();
      } else if (section == "$NOD" || section == "$Nodes") {
        if (section == "$Nodes" && !have_format_) {
          fail(name_, cur_.line(), "$Nodes section before $MeshFormat");
        }
        if (section == "$NOD") version_ = 1.0;
        if (have_nodes_) fail(name_, cur_.line(), "second node section");
        have_nodes_ = true;
        if (version_ >= 4.0) {
          readNodes4();
        } else {
          readNodes12(section == "$NOD" ? "$ENDNOD" : "$EndNodes");
        }
      } else if (section == "$PhysicalNames") {
        readPhysicalNames();
      } else if (section == "$Entities" && version_ >= 4.0) {
        readEntities4();
      } else if (section == "$ELM" || section == "$Elements") {
        if (section == "$Elements" && !have_format_) {
          fail(name_, cur_.line(), "$Elements section before $MeshFormat");
        }
        if (section == "$ELM") version_ = 1.0;
        if (have_elements_) fail(name_, cur_.line(), "second element section");
        have_elements_ = true;
        if (version_ >= 4.0) {
          readElements4();
        } else {
          readElements12(section == "$ELM" ? "$ENDELM" : "$EndElements", version_ < 2.0);
        }
      } else {
        skipSection(section);
      }
    }
    raw_->last_line = std::max(1, cur_.line());
    if (!have_nodes_) fail(name_, raw_->last_line, "no node section ($Nodes or $NOD) in the file");
    if (!have_elements_) {
      fail(name_, raw_->last_line, "no element section ($Elements or $ELM) in the file");
    }
    raw_->format = version_ < 2.0 ? "gmsh1" : (version_ < 4.0 ? "gmsh2" : "gmsh4");
    collectGroups();
  }

 private:
  // Next non-empty line split into tokens; fails at end of input.
  void nextTokens(const char* what) {
    std::string_view line;
    while (cur_.next(&line)) {
      splitTokens(line, &tok_);
      line_ = line;
      if (!tok_.empty()) return;
    }
    fail(name_, std::max(1, cur_.line()),
         fmt::format("unexpected end of file while reading {} in {} (started at line {})", what,
                     section_, section_line_));
  }

  std::int64_t intToken(std::size_t i, const char* what) {
    std::int64_t v = 0;
    if (i >= tok_.size() || !parseInt(tok_[i], &v)) {
      fail(name_, cur_.line(),
           fmt::format("expected an integer ({}), got '{}'", what,
                       i < tok_.size() ? excerpt(tok_[i]) : std::string("end of line")));
    }
    return v;
  }

  double doubleToken(std::size_t i, const char* what) {
    double v = 0;
    if (i >= tok_.size() || !parseDouble(tok_[i], &v)) {
      fail(name_, cur_.line(),
           fmt::format("expected a number ({}), got '{}'", what,
                       i < tok_.size() ? excerpt(tok_[i]) : std::string("end of line")));
    }
    return v;
  }

  // A Gmsh tag (entity or physical group): an int.
  int tagToken(std::size_t i, const char* what) {
    const std::int64_t v = intToken(i, what);
    if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max()) {
      fail(name_, cur_.line(), fmt::format("{} {} is out of range", what, v));
    }
    return static_cast<int>(v);
  }

  // A count on its own; bounded by what the input could possibly hold.
  std::int64_t count(std::int64_t v, const char* what) {
    if (v < 0 || v > static_cast<std::int64_t>(std::numeric_limits<int>::max())) {
      fail(name_, cur_.line(), fmt::format("invalid {} count {}", what, v));
    }
    return v;
  }

  void expectEnd(std::string_view end) {
    std::string_view line;
    while (cur_.next(&line)) {
      line = trim(line);
      if (line.empty()) continue;
      if (equalsNoCase(line, end)) return;
      fail(name_, cur_.line(),
           fmt::format("expected {} to close {} (started at line {}), got '{}' (wrong count?)",
                       end, section_, section_line_, excerpt(line)));
    }
    fail(name_, std::max(1, cur_.line()),
         fmt::format("unexpected end of file: missing {} to close {} (started at line {})", end,
                     section_, section_line_));
  }

  void skipSection(std::string_view section) {
    const std::string end = "$End" + std::string(section.substr(1));
    std::string_view line;
    while (cur_.next(&line)) {
      if (equalsNoCase(trim(line), end)) return;
    }
    fail(name_, std::max(1, cur_.line()),
         fmt::format("unexpected end of file: missing {} to close {} (started at line {})", end,
                     section, section_line_));
  }

  void readFormat() {
    nextTokens("the format line");
    version_ = doubleToken(0, "version");
    const std::int64_t file_type = intToken(1, "file type");
    if (file_type != 0) {
      fail(name_, cur_.line(),
           "binary Gmsh files are not supported: re-save the mesh as ASCII (gmsh -save "
           "-format msh22 or msh41)");
    }
    if (version_ < 2.0 || version_ >= 5.0 || (version_ >= 4.0 && version_ < 4.1)) {
      fail(name_, cur_.line(),
           fmt::format("unsupported Gmsh version {} (supported: 1.0, 2.x, 4.1)", version_));
    }
    have_format_ = true;
    expectEnd("$EndMeshFormat");
  }

  void addNode(std::int64_t id, double x, double y, double z) {
    raw_->node_ids.push_back(id);
    raw_->coords.insert(raw_->coords.end(), {x, y, z});
    raw_->node_lines.push_back(cur_.line());
  }

  void addTet(std::int64_t id, std::size_t first) {
    std::array<std::int64_t, 4> t{};
    for (std::size_t k = 0; k < 4; ++k) t[k] = intToken(first + k, "node id");
    raw_->tets.push_back(t);
    raw_->tet_ids.push_back(id);
    raw_->tet_lines.push_back(cur_.line());
  }

  void readNodes12(std::string_view end) {
    nextTokens("the node count");
    const std::int64_t n = count(intToken(0, "node count"), "node");
    for (std::int64_t i = 0; i < n; ++i) {
      nextTokens("a node");
      if (tok_.size() != 4) {
        fail(name_, cur_.line(),
             fmt::format("a node line needs 4 values (id x y z), got {}", tok_.size()));
      }
      addNode(intToken(0, "node id"), doubleToken(1, "x"), doubleToken(2, "y"),
              doubleToken(3, "z"));
    }
    expectEnd(end);
  }

  void readElements12(std::string_view end, bool v1) {
    nextTokens("the element count");
    const std::int64_t n = count(intToken(0, "element count"), "element");
    for (std::int64_t i = 0; i < n; ++i) {
      nextTokens("an element");
      const std::int64_t id = intToken(0, "element id");
      const std::int64_t type = intToken(1, "element type");
      std::size_t first = 0;
      std::int64_t nodes = 0;
      int physical = 0;   // 0: in no physical group
      if (v1) {
        // id type reg-phys reg-elem number-of-nodes nodes...
        physical = tagToken(2, "physical tag");
        nodes = intToken(4, "number of nodes");
        first = 5;
      } else {
        // id type number-of-tags tags... nodes...
        const std::int64_t tags = intToken(2, "number of tags");
        if (tags < 0 || tags > static_cast<std::int64_t>(tok_.size()) - 3) {
          fail(name_, cur_.line(), fmt::format("element {} has an invalid tag count {}", id, tags));
        }
        first = 3 + static_cast<std::size_t>(tags);
        nodes = static_cast<std::int64_t>(tok_.size() - first);
        if (tags > 0) physical = tagToken(3, "physical tag");
      }
      const auto listed =
          static_cast<std::int64_t>(tok_.size()) - static_cast<std::int64_t>(first);
      if (nodes < 0 || listed != nodes) {
        fail(name_, cur_.line(),
             fmt::format("element {} declares {} nodes but lists {}", id, nodes, listed));
      }
      if (type == 4) {
        if (nodes != 4) {
          fail(name_, cur_.line(),
               fmt::format("element {} is a tetrahedron (type 4) with {} nodes instead of 4", id,
                           nodes));
        }
        addTet(id, first);
      } else {
        ++raw_->ignored_elements;
      }
      if (physical != 0) {
        const int dim = gmshElementDimension(type);
        if (dim < 0) {
          ++unknown_type_grouped_;
        } else {
          addGroupElement(&rawGroup(&groups_, dim, physical), type, first);
        }
      }
    }
    expectEnd(end);
  }

  void readNodes4() {
    nextTokens("the $Nodes header");
    const std::int64_t blocks = count(intToken(0, "number of entity blocks"), "block");
    const std::int64_t total = count(intToken(1, "number of nodes"), "node");
    std::int64_t seen = 0;
    for (std::int64_t b = 0; b < blocks; ++b) {
      nextTokens("a node block header");
      const std::int64_t dim = intToken(0, "entity dimension");
      const std::int64_t parametric = intToken(2, "parametric flag");
      const std::int64_t m = count(intToken(3, "nodes in block"), "node");
      if (dim < 0 || dim > 3 || parametric < 0 || parametric > 1) {
        fail(name_, cur_.line(), "invalid node block header (entity dimension or parametric)");
      }
      if (m > total - seen) {
        fail(name_, cur_.line(),
             fmt::format("node blocks hold more nodes than the {} declared", total));
      }
      const std::size_t first = raw_->node_ids.size();
      std::vector<int> tag_lines;
      for (std::int64_t i = 0; i < m; ++i) {
        nextTokens("a node tag");
        raw_->node_ids.push_back(intToken(0, "node tag"));
      }
      const std::size_t values = 3 + static_cast<std::size_t>(parametric ? dim : 0);
      for (std::int64_t i = 0; i < m; ++i) {
        nextTokens("node coordinates");
        if (tok_.size() != values) {
          fail(name_, cur_.line(),
               fmt::format("node coordinates need {} values, got {}", values, tok_.size()));
        }
        raw_->coords.insert(raw_->coords.end(),
                            {doubleToken(0, "x"), doubleToken(1, "y"), doubleToken(2, "z")});
        raw_->node_lines.push_back(cur_.line());
      }
      (void)first;
      seen += m;
    }
    if (seen != total) {
      fail(name_, cur_.line(),
           fmt::format("$Nodes declares {} nodes but its blocks hold {}", total, seen));
    }
    expectEnd("$EndNodes");
  }

  void readElements4() {
    nextTokens("the $Elements header");
    const std::int64_t blocks = count(intToken(0, "number of entity blocks"), "block");
    const std::int64_t total = count(intToken(1, "number of elements"), "element");
    std::int64_t seen = 0;
    for (std::int64_t b = 0; b < blocks; ++b) {
      nextTokens("an element block header");
      const std::int64_t dim = intToken(0, "entity dimension");
      const int entity = tagToken(1, "entity tag");
      const std::int64_t type = intToken(2, "element type");
      if (dim < 0 || dim > 3) {
        fail(name_, cur_.line(), "invalid element block header (entity dimension)");
      }
      // the entity's elements, kept while its physical groups are unknown or if it has some
      RawGroup* entity_nodes = nullptr;
      const auto physicals = entity_physicals_.find({static_cast<int>(dim), entity});
      if (!have_entities_ ||
          (physicals != entity_physicals_.end() && !physicals->second.empty())) {
        entity_nodes = &rawGroup(&entity_nodes_, static_cast<int>(dim), entity);
      }
      const std::int64_t m = count(intToken(3, "elements in block"), "element");
      if (m > total - seen) {
        fail(name_, cur_.line(),
             fmt::format("element blocks hold more elements than the {} declared", total));
      }
      for (std::int64_t i = 0; i < m; ++i) {
        nextTokens("an element");
        const std::int64_t id = intToken(0, "element tag");
        if (type == 4) {
          if (tok_.size() != 5) {
            fail(name_, cur_.line(),
                 fmt::format("element {} is a tetrahedron (type 4) with {} nodes instead of 4", id,
                             tok_.size() - 1));
          }
          addTet(id, 1);
        } else {
          ++raw_->ignored_elements;
        }
        if (entity_nodes != nullptr) addGroupElement(entity_nodes, type, 1);
      }
      seen += m;
    }
    if (seen != total) {
      fail(name_, cur_.line(),
           fmt::format("$Elements declares {} elements but its blocks hold {}", total, seen));
    }
    expectEnd("$EndElements");
  }

  // $PhysicalNames: count, then `dimension tag "name"` lines.
  void readPhysicalNames() {
    nextTokens("the number of physical names");
    const std::int64_t n = count(intToken(0, "number of physical names"), "physical name");
    for (std::int64_t i = 0; i < n; ++i) {
      nextTokens("a physical name");
      RawPhysicalName entry;
      const std::int64_t dim = intToken(0, "physical dimension");
      entry.tag = tagToken(1, "physical tag");
      entry.line = cur_.line();
      if (dim < 0 || dim > 3) {
        fail(name_, cur_.line(), fmt::format("physical dimension must be 0 to 3, got {}", dim));
      }
      entry.dimension = static_cast<int>(dim);
      // the name: the rest of the line, in double quotes (it may hold spaces)
      const std::string_view rest =
          tok_.size() < 3 ? std::string_view()
                          : trim(line_.substr(static_cast<std::size_t>(tok_[2].data() -
                                                                       line_.data())));
      if (rest.size() < 2 || rest.front() != '"' || rest.back() != '"') {
        fail(name_, cur_.line(),
             fmt::format("a physical name line needs: dimension tag \"name\" (the name in double "
                         "quotes), got '{}'",
                         excerpt(trim(line_))));
      }
      entry.name = std::string(rest.substr(1, rest.size() - 2));
      const auto [first, inserted] =
          name_lines_.emplace(std::pair(entry.dimension, entry.tag), entry.line);
      if (!inserted) {
        fail(name_, cur_.line(),
             fmt::format("physical group (dimension {}, tag {}) is named twice (first at line {})",
                         entry.dimension, entry.tag, first->second));
      }
      raw_->physical_names.push_back(std::move(entry));
    }
    expectEnd("$EndPhysicalNames");
  }

  // 4.1 $Entities: the physical tags of every point, curve, surface and volume.
  void readEntities4() {
    if (have_entities_) fail(name_, cur_.line(), "second $Entities section");
    have_entities_ = true;
    entities_line_ = section_line_;
    nextTokens("the $Entities header");
    std::array<std::int64_t, 4> counts{};
    for (std::size_t d = 0; d < 4; ++d) {
      counts[d] = count(intToken(d, "number of entities"), "entity");
    }
    for (std::size_t d = 0; d < 4; ++d) {
      for (std::int64_t i = 0; i < counts[d]; ++i) {
        nextTokens("an entity");
        const int entity = tagToken(0, "entity tag");
        // a point: tag x y z; others: tag and a bounding box; then the physical tags
        const std::size_t at = d == 0 ? 4 : 7;
        const std::int64_t m = intToken(at, "number of physical tags");
        if (m < 0 || m > static_cast<std::int64_t>(tok_.size() - at - 1)) {
          fail(name_, cur_.line(),
               fmt::format("entity {} declares {} physical tags but its line holds {} values "
                           "after the count",
                           entity, m, tok_.size() - at - 1));
        }
        std::vector<int> physicals;
        for (std::int64_t k = 0; k < m; ++k) {
          physicals.push_back(tagToken(at + 1 + static_cast<std::size_t>(k), "physical tag"));
        }
        if (!entity_physicals_.emplace(std::pair(static_cast<int>(d), entity), physicals).second) {
          fail(name_, cur_.line(),
               fmt::format("entity (dimension {}, tag {}) is defined twice", d, entity));
        }
      }
    }
    expectEnd("$EndEntities");
  }

  // The current element line (its nodes from token `first` on) into `group`: a tetrahedron,
  // just read by addTet, by its index, another element by its node ids.
  void addGroupElement(RawGroup* group, std::int64_t type, std::size_t first) {
    if (type == 4) {
      group->tets.push_back(static_cast<int>(raw_->tets.size() - 1));
      return;
    }
    for (std::size_t k = first; k < tok_.size(); ++k) {
      group->node_ids.push_back(intToken(k, "node id"));
      group->node_lines.push_back(cur_.line());
    }
  }

  // 4.1: each entity's elements go to the entity's physical groups; then all groups to raw_.
  void collectGroups() {
    addEntityGroups(entity_nodes_, entity_physicals_, &groups_, name_, entities_line_);
    for (auto& [key, g] : groups_) raw_->groups.push_back(std::move(g));
    if (unknown_type_grouped_ > 0) {
      spdlog::warn("{}: {} elements of unknown type (hence dimension) left out of their physical "
                   "groups",
                   name_, unknown_type_grouped_);
    }
  }

  LineCursor cur_;
  const std::string& name_;
  RawMesh* raw_;
  std::vector<std::string_view> tok_;
  std::string_view line_;   // the line tok_ comes from
  RawGroupMap groups_;                                       // (dimension, physical tag)
  RawGroupMap entity_nodes_;                                 // 4.1: (dimension, entity tag)
  std::map<std::pair<int, int>, std::vector<int>> entity_physicals_;
  std::map<std::pair<int, int>, int> name_lines_;            // $PhysicalNames: line of each
  bool have_entities_ = false;
  int entities_line_ = 0;                                    // where $Entities starts
  int unknown_type_grouped_ = 0;
  std::string section_;
  int section_line_ = 0;
  double version_ = 0.0;
  bool have_format_ = false;
  bool have_nodes_ = false;
  bool have_elements_ = false;
};

}  // namespace

void readGmsh(const std::string& content, const std::string& name, RawMesh* raw) {
  GmshReader(content, name, raw).run();
}

}  // namespace tactus::sim::detail
