// The Gmsh reader (ASCII 1.0, 2.x and 4.1).

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <limits>
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
  }

 private:
  // Next non-empty line split into tokens; fails at end of input.
  void nextTokens(const char* what) {
    std::string_view line;
    while (cur_.next(&line)) {
      splitTokens(line, &tok_);
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
      if (v1) {
        // id type reg-phys reg-elem number-of-nodes nodes...
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
      const std::int64_t type = intToken(2, "element type");
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
      }
      seen += m;
    }
    if (seen != total) {
      fail(name_, cur_.line(),
           fmt::format("$Elements declares {} elements but its blocks hold {}", total, seen));
    }
    expectEnd("$EndElements");
  }

  LineCursor cur_;
  const std::string& name_;
  RawMesh* raw_;
  std::vector<std::string_view> tok_;
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
