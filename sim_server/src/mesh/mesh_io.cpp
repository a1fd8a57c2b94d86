// Mesh input: format detection, Gmsh (1.0, 2.x, 4.1) and legacy VTK readers, and the common
// validation (id resolution, unreferenced nodes, orientation, degeneracy).

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

namespace tactus::sim {
namespace detail {

void fail(const std::string& name, int line, const std::string& message) {
  // the message may quote file content: no control bytes, bounded length
  throw MeshError(fmt::format("{}:{}: {}", name, line, shared::printable(message, 1000)));
}

bool parseDouble(std::string_view token, double* out) {
  if (!token.empty() && token.front() == '+') token.remove_prefix(1);
  if (token.empty()) return false;
  const char* end = token.data() + token.size();
  auto [ptr, ec] = std::from_chars(token.data(), end, *out, std::chars_format::general);
  return ec == std::errc() && ptr == end;
}

bool parseInt(std::string_view token, std::int64_t* out) {
  if (!token.empty() && token.front() == '+') token.remove_prefix(1);
  if (token.empty()) return false;
  const char* end = token.data() + token.size();
  auto [ptr, ec] = std::from_chars(token.data(), end, *out);
  return ec == std::errc() && ptr == end;
}

void splitTokens(std::string_view line, std::vector<std::string_view>* tokens) {
  tokens->clear();
  std::size_t i = 0;
  const auto is_space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n' ||
                                            c == '\v' || c == '\f'; };
  while (i < line.size()) {
    while (i < line.size() && is_space(line[i])) ++i;
    const std::size_t start = i;
    while (i < line.size() && !is_space(line[i])) ++i;
    if (i > start) tokens->push_back(line.substr(start, i - start));
  }
}

int lineOf(std::string_view text, std::size_t pos) {
  pos = std::min(pos, text.size());
  const auto end = text.begin() + static_cast<long>(pos);
  return 1 + static_cast<int>(std::count(text.begin(), end, '\n'));
}

namespace {

// A printable excerpt of a token for messages (bounded, no control characters).
std::string excerpt(std::string_view s) { return shared::printable(s, 40); }

// Signed 6 x volume of the tetrahedron (a, b, c, d).
double sixVolume(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                 const Eigen::Vector3d& d) {
  return (b - a).dot((c - a).cross(d - a));
}

}  // namespace

TetMesh finalizeMesh(RawMesh&& raw, const std::string& name, MeshReport* report) {
  const std::size_t n = raw.node_ids.size();
  const std::string& ew = raw.element_word;
  const std::string& nw = raw.node_word;
  // file id -> position in file order; duplicates are ambiguous
  std::unordered_map<std::int64_t, int> index_of;
  index_of.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    auto [it, inserted] = index_of.emplace(raw.node_ids[i], static_cast<int>(i));
    if (!inserted) {
      fail(name, raw.node_lines[i],
           fmt::format("{} {} is defined twice (first at line {})", nw, raw.node_ids[i],
                       raw.node_lines[static_cast<std::size_t>(it->second)]));
    }
    for (int k = 0; k < 3; ++k) {
      if (!std::isfinite(raw.coords[3 * i + static_cast<std::size_t>(k)])) {
        fail(name, raw.node_lines[i],
             fmt::format("{} {} has a non-finite coordinate", nw, raw.node_ids[i]));
      }
    }
  }
  if (raw.tets.empty()) {
    fail(name, raw.last_line,
         fmt::format("no tetrahedra (4-node elements) in the file ({} other elements ignored)",
                     raw.ignored_elements));
  }
  // resolve node ids; element ids must be unique too
  std::unordered_map<std::int64_t, int> tet_index_of;
  tet_index_of.reserve(raw.tets.size());
  std::vector<std::array<int, 4>> tets(raw.tets.size());
  std::vector<char> referenced(n, 0);
  for (std::size_t t = 0; t < raw.tets.size(); ++t) {
    auto [it, inserted] = tet_index_of.emplace(raw.tet_ids[t], static_cast<int>(t));
    if (!inserted) {
      fail(name, raw.tet_lines[t],
           fmt::format("{} {} is defined twice (first at line {})", ew, raw.tet_ids[t],
                       raw.tet_lines[static_cast<std::size_t>(it->second)]));
    }
    for (int k = 0; k < 4; ++k) {
      const std::int64_t id = raw.tets[t][static_cast<std::size_t>(k)];
      auto found = index_of.find(id);
      if (found == index_of.end()) {
        fail(name, raw.tet_lines[t],
             fmt::format("{} {} refers to {} {} which is not defined", ew, raw.tet_ids[t], nw, id));
      }
      tets[t][static_cast<std::size_t>(k)] = found->second;
      referenced[static_cast<std::size_t>(found->second)] = 1;
    }
    for (int a = 0; a < 4; ++a) {
      for (int b = a + 1; b < 4; ++b) {
        if (tets[t][static_cast<std::size_t>(a)] == tets[t][static_cast<std::size_t>(b)]) {
          fail(name, raw.tet_lines[t],
               fmt::format("{} {} is degenerate: it uses {} {} twice", ew, raw.tet_ids[t], nw,
                           raw.tets[t][static_cast<std::size_t>(a)]));
        }
      }
    }
  }
  // dense renumbering of the referenced nodes, in file order
  std::vector<int> new_index(n, -1);
  int kept = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (referenced[i]) new_index[i] = kept++;
  }
  TetMesh mesh;
  mesh.source = name;
  mesh.nodes.resize(3, kept);
  for (std::size_t i = 0; i < n; ++i) {
    if (new_index[i] < 0) continue;
    mesh.nodes.col(new_index[i]) =
        Eigen::Vector3d(raw.coords[3 * i], raw.coords[3 * i + 1], raw.coords[3 * i + 2]);
  }
  const Eigen::Vector3d lo = mesh.nodes.rowwise().minCoeff();
  const Eigen::Vector3d hi = mesh.nodes.rowwise().maxCoeff();
  const double size = (hi - lo).norm();
  // |6V| below this is a zero volume at the scale of the mesh
  const double tol = 1e-12 * size * size * size;
  int flipped = 0;
  int first_flipped_line = 0;
  mesh.tets.resize(tets.size());
  for (std::size_t t = 0; t < tets.size(); ++t) {
    std::array<int, 4> tet;
    for (std::size_t k = 0; k < 4; ++k) {
      tet[k] = new_index[static_cast<std::size_t>(tets[t][k])];
    }
    const double v6 = sixVolume(mesh.nodes.col(tet[0]), mesh.nodes.col(tet[1]),
                                mesh.nodes.col(tet[2]), mesh.nodes.col(tet[3]));
    if (!(std::abs(v6) > tol)) {
      fail(name, raw.tet_lines[t],
           fmt::format("{} {} is degenerate: volume {:.3g} is zero at the mesh size {:.3g} "
                       "(its nodes are coplanar)",
                       ew, raw.tet_ids[t], v6 / 6.0, size));
    }
    if (v6 < 0) {
      std::swap(tet[2], tet[3]);
      if (flipped == 0) first_flipped_line = raw.tet_lines[t];
      ++flipped;
    }
    mesh.tets[t] = tet;
  }
  const int dropped = static_cast<int>(n) - kept;
  if (raw.ignored_elements > 0) {
    spdlog::warn("{}: {} non-tetrahedral elements ignored", name, raw.ignored_elements);
  }
  if (flipped > 0) {
    spdlog::warn("{}: {} negatively oriented tetrahedra re-oriented (first at line {})", name,
                 flipped, first_flipped_line);
  }
  if (dropped > 0) {
    spdlog::warn("{}: {} nodes referenced by no tetrahedron dropped", name, dropped);
  }
  if (report != nullptr) {
    report->format = raw.format;
    report->ignored_elements = raw.ignored_elements;
    report->flipped_tets = flipped;
    report->dropped_nodes = dropped;
  }
  return mesh;
}

// ------------------------------------------------------------------------------------------------
// Gmsh

namespace {

bool equalsNoCase(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const auto lower = [](char c) {
      return (c >= 'A' && c <= 'Z') ? static_cast<char>(c + 32) : c;
    };
    if (lower(a[i]) != lower(b[i])) return false;
  }
  return true;
}

std::string_view trim(std::string_view s) {
  const auto is_space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' ||
                                            c == '\f'; };
  while (!s.empty() && is_space(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_space(s.back())) s.remove_suffix(1);
  return s;
}

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

// ------------------------------------------------------------------------------------------------
// Legacy VTK

namespace {

// Whitespace-separated tokens with the line each starts on.
class TokenCursor {
 public:
  explicit TokenCursor(std::string_view text) : text_(text) {}
  bool next(std::string_view* tok) {
    skipSpace();
    if (pos_ >= text_.size()) return false;
    const std::size_t start = pos_;
    tok_line_ = line_;
    while (pos_ < text_.size() && !isSpace(text_[pos_])) ++pos_;
    *tok = text_.substr(start, pos_ - start);
    return true;
  }
  // Skips the rest of the current line.
  void skipLine() {
    while (pos_ < text_.size() && text_[pos_] != '\n') ++pos_;
  }
  // Skips lines until an empty one (end of a METADATA block).
  void skipToBlankLine() {
    skipLine();
    while (pos_ < text_.size()) {
      ++pos_;
      ++line_;
      std::size_t e = pos_;
      while (e < text_.size() && text_[e] != '\n' && isSpace(text_[e])) ++e;
      if (e >= text_.size() || text_[e] == '\n') return;
      skipLine();
    }
  }
  int line() const { return tok_line_; }
  int currentLine() const { return line_; }

 private:
  static bool isSpace(char c) {
    return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\v' || c == '\f';
  }
  void skipSpace() {
    while (pos_ < text_.size() && isSpace(text_[pos_])) {
      if (text_[pos_] == '\n') ++line_;
      ++pos_;
    }
  }
  std::string_view text_;
  std::size_t pos_ = 0;
  int line_ = 1;
  int tok_line_ = 1;
};

class VtkLegacyReader {
 public:
  VtkLegacyReader(const std::string& content, const std::string& name, RawMesh* raw)
      : content_(content), name_(name), raw_(raw), cur_(content) {}

  void run() {
    raw_->format = "vtk-legacy";
    raw_->element_word = "cell";
    raw_->node_word = "point";
    // header: version line and title line, then tokens: ASCII|BINARY, DATASET ...
    if (content_.rfind("# vtk DataFile", 0) != 0) {
      fail(name_, 1, "not a legacy VTK file (first line must be '# vtk DataFile Version x.x')");
    }
    const std::size_t nl = content_.find('\n');
    const std::size_t nl2 = nl == std::string::npos ? nl : content_.find('\n', nl + 1);
    if (nl2 == std::string::npos) fail(name_, 2, "unexpected end of file after the title line");
    cur_ = TokenCursor(std::string_view(content_).substr(nl2 + 1));
    line_offset_ = 2;
    std::string_view tok;
    if (!nextTok(&tok)) fail(name_, line(), "unexpected end of file: expected ASCII or BINARY");
    if (equalsNoCase(tok, "BINARY")) {
      fail(name_, line(), "binary legacy VTK is not supported: save as ASCII or as .vtu");
    }
    if (!equalsNoCase(tok, "ASCII")) {
      fail(name_, line(), fmt::format("expected ASCII or BINARY, got '{}'", excerpt(tok)));
    }
    if (!nextTok(&tok) || !equalsNoCase(tok, "DATASET")) {
      fail(name_, line(), "expected 'DATASET UNSTRUCTURED_GRID'");
    }
    if (!nextTok(&tok) || !equalsNoCase(tok, "UNSTRUCTURED_GRID")) {
      fail(name_, line(),
           fmt::format("unsupported dataset '{}' (only UNSTRUCTURED_GRID holds tetrahedra)",
                       excerpt(tok)));
    }
    bool have_points = false, have_cells = false, have_types = false;
    while (nextTok(&tok)) {
      if (equalsNoCase(tok, "POINTS")) {
        readPoints();
        have_points = true;
      } else if (equalsNoCase(tok, "CELLS")) {
        readCells();
        have_cells = true;
      } else if (equalsNoCase(tok, "CELL_TYPES")) {
        readTypes();
        have_types = true;
      } else if (equalsNoCase(tok, "METADATA")) {
        cur_.skipToBlankLine();
      } else if (equalsNoCase(tok, "POINT_DATA") || equalsNoCase(tok, "CELL_DATA") ||
                 equalsNoCase(tok, "FIELD")) {
        break;  // attributes are not needed
      } else {
        fail(name_, line(), fmt::format("unexpected keyword '{}'", excerpt(tok)));
      }
    }
    raw_->last_line = std::max(1, cur_.currentLine() + line_offset_);
    if (!have_points) fail(name_, raw_->last_line, "no POINTS section in the file");
    if (!have_cells) fail(name_, raw_->last_line, "no CELLS section in the file");
    if (!have_types) fail(name_, raw_->last_line, "no CELL_TYPES section in the file");
    buildTets();
  }

 private:
  int line() const { return cur_.line() + line_offset_; }

  bool nextTok(std::string_view* tok) { return cur_.next(tok); }

  std::string_view need(const char* what) {
    std::string_view tok;
    if (!cur_.next(&tok)) {
      fail(name_, std::max(1, cur_.currentLine() + line_offset_),
           fmt::format("unexpected end of file while reading {}", what));
    }
    return tok;
  }
  std::int64_t needInt(const char* what) {
    const std::string_view tok = need(what);
    std::int64_t v = 0;
    if (!parseInt(tok, &v)) {
      fail(name_, line(), fmt::format("expected an integer ({}), got '{}'", what, excerpt(tok)));
    }
    return v;
  }
  std::int64_t needCount(const char* what) {
    const std::int64_t v = needInt(what);
    // each counted item needs at least two bytes of text
    if (v < 0 || v > static_cast<std::int64_t>(content_.size())) {
      fail(name_, line(), fmt::format("invalid {} {}", what, v));
    }
    return v;
  }
  double needDouble(const char* what) {
    const std::string_view tok = need(what);
    double v = 0;
    if (!parseDouble(tok, &v)) {
      fail(name_, line(), fmt::format("expected a number ({}), got '{}'", what, excerpt(tok)));
    }
    return v;
  }

  void readPoints() {
    if (!raw_->node_ids.empty()) fail(name_, line(), "second POINTS section");
    const std::int64_t n = needCount("point count");
    need("point data type");
    raw_->coords.reserve(static_cast<std::size_t>(n) * 3);
    for (std::int64_t i = 0; i < n; ++i) {
      const double x = needDouble("point x");
      const int l = line();
      const double y = needDouble("point y");
      const double z = needDouble("point z");
      raw_->node_ids.push_back(i);
      raw_->coords.insert(raw_->coords.end(), {x, y, z});
      raw_->node_lines.push_back(l);
    }
  }

  void readCells() {
    if (!cell_sizes_.empty()) fail(name_, line(), "second CELLS section");
    cells_line_ = line();
    const std::int64_t n = needCount("cell count");
    const std::int64_t size = needCount("cell list size");
    // VTK 5.x layout: CELLS n_offsets n_connectivity / OFFSETS type ... / CONNECTIVITY type ...
    TokenCursor peek = cur_;
    std::string_view tok;
    if (peek.next(&tok) && equalsNoCase(tok, "OFFSETS")) {
      cur_ = peek;
      const std::int64_t n_off = n;
      const std::int64_t n_conn = size;
      need("offset data type");
      std::vector<std::int64_t> offsets;
      for (std::int64_t i = 0; i < n_off; ++i) offsets.push_back(needInt("offset"));
      tok = need("CONNECTIVITY");
      if (!equalsNoCase(tok, "CONNECTIVITY")) fail(name_, line(), "expected CONNECTIVITY");
      need("connectivity data type");
      for (std::int64_t i = 0; i < n_conn; ++i) conn_.push_back(needInt("point index"));
      if (offsets.empty() || offsets.front() != 0 || offsets.back() != n_conn) {
        fail(name_, cells_line_, "OFFSETS must start at 0 and end at the connectivity size");
      }
      for (std::size_t i = 0; i + 1 < offsets.size(); ++i) {
        if (offsets[i + 1] < offsets[i]) fail(name_, cells_line_, "OFFSETS must not decrease");
        cell_sizes_.push_back(offsets[i + 1] - offsets[i]);
        cell_lines_.push_back(cells_line_);
      }
      return;
    }
    std::int64_t used = 0;
    for (std::int64_t i = 0; i < n; ++i) {
      const std::int64_t k = needInt("cell point count");
      const int l = line();
      if (k < 0 || k > size - used - 1) {
        fail(name_, l, fmt::format("cell {} has an invalid point count {} (list size {})", i, k,
                                   size));
      }
      for (std::int64_t j = 0; j < k; ++j) conn_.push_back(needInt("point index"));
      used += k + 1;
      cell_sizes_.push_back(k);
      cell_lines_.push_back(l);
    }
    if (used != size) {
      fail(name_, line(),
           fmt::format("CELLS declares a list size of {} but its cells use {}", size, used));
    }
  }

  void readTypes() {
    if (!types_.empty()) fail(name_, line(), "second CELL_TYPES section");
    const std::int64_t n = needCount("cell type count");
    types_line_ = line();
    for (std::int64_t i = 0; i < n; ++i) {
      types_.push_back(needInt("cell type"));
      type_lines_.push_back(line());
    }
  }

  void buildTets() {
    if (types_.size() != cell_sizes_.size()) {
      fail(name_, types_line_,
           fmt::format("CELL_TYPES lists {} types for {} cells", types_.size(),
                       cell_sizes_.size()));
    }
    std::size_t at = 0;
    for (std::size_t c = 0; c < cell_sizes_.size(); ++c) {
      const auto k = static_cast<std::size_t>(cell_sizes_[c]);
      if (types_[c] == 10) {
        if (k != 4) {
          fail(name_, cell_lines_[c],
               fmt::format("cell {} is a tetrahedron (type 10) with {} points instead of 4", c, k));
        }
        raw_->tets.push_back({conn_[at], conn_[at + 1], conn_[at + 2], conn_[at + 3]});
        raw_->tet_ids.push_back(static_cast<std::int64_t>(c));
        raw_->tet_lines.push_back(cell_lines_[c]);
      } else {
        ++raw_->ignored_elements;
      }
      at += k;
    }
  }

  const std::string& content_;
  const std::string& name_;
  RawMesh* raw_;
  TokenCursor cur_;
  int line_offset_ = 0;
  std::vector<std::int64_t> conn_;
  std::vector<std::int64_t> cell_sizes_;
  std::vector<int> cell_lines_;
  std::vector<std::int64_t> types_;
  std::vector<int> type_lines_;
  int cells_line_ = 0;
  int types_line_ = 0;
};

}  // namespace

void readVtkLegacy(const std::string& content, const std::string& name, RawMesh* raw) {
  VtkLegacyReader(content, name, raw).run();
}

}  // namespace detail

// ------------------------------------------------------------------------------------------------
// Entry points

namespace {

enum class MeshFormat { kUnknown, kGmsh, kVtkLegacy, kVtu };

// The format from the first bytes; `start` is where the content begins (after a UTF-8 byte order
// mark and white space). kUnknown also when `head` holds only white space.
MeshFormat sniffMeshFormat(std::string_view head, std::size_t* start) {
  std::size_t i = 0;
  if (head.substr(0, 3) == "\xEF\xBB\xBF") i = 3;  // UTF-8 byte order mark
  while (i < head.size() && std::isspace(static_cast<unsigned char>(head[i]))) ++i;
  *start = i;
  const std::string_view h = head.substr(i);
  if (!h.empty() && h.front() == '$') return MeshFormat::kGmsh;
  if (h.rfind("# vtk DataFile", 0) == 0) return MeshFormat::kVtkLegacy;
  if (h.rfind("<?xml", 0) == 0 || h.rfind("<VTKFile", 0) == 0) return MeshFormat::kVtu;
  return MeshFormat::kUnknown;
}

[[noreturn]] void failUnrecognised(std::string_view content, std::size_t start,
                                   const std::string& name) {
  detail::fail(name, detail::lineOf(content, start),
               "unrecognised mesh format (expected Gmsh .msh, legacy VTK .vtk or VTK XML .vtu)");
}

}  // namespace

TetMesh parseTetMesh(const std::string& content, const std::string& name, MeshReport* report) {
  std::size_t start = 0;
  const MeshFormat format = sniffMeshFormat(content, &start);
  detail::RawMesh raw;
  switch (format) {
    case MeshFormat::kGmsh: detail::readGmsh(content, name, &raw); break;
    case MeshFormat::kVtkLegacy: detail::readVtkLegacy(content.substr(start), name, &raw); break;
    case MeshFormat::kVtu: detail::readVtu(content, name, &raw); break;
    case MeshFormat::kUnknown: failUnrecognised(content, start, name);
  }
  return detail::finalizeMesh(std::move(raw), name, report);
}

TetMesh loadTetMesh(const std::filesystem::path& path, MeshReport* report) {
  try {
    shared::InputFile file(path, "mesh file", shared::kMaxMeshBytes);
    // sniff the format from the first bytes before reading the whole file
    std::string content(static_cast<std::size_t>(std::min<std::uint64_t>(file.size(), 4096)), '\0');
    content.resize(file.read(content.data(), content.size()));
    std::size_t start = 0;
    const bool all_blank = content.find_first_not_of(" \t\r\n\v\f") == std::string::npos;
    if (!all_blank && sniffMeshFormat(content, &start) == MeshFormat::kUnknown) {
      failUnrecognised(content, start, file.name());
    }
    content += file.readRest();
    return parseTetMesh(content, file.name(), report);
  } catch (const FileError& e) {
    throw MeshError(e.what());
  }
}

}  // namespace tactus::sim
