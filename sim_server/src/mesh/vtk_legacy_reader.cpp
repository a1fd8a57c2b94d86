// The legacy VTK reader (ASCII and binary unstructured grids).

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

}  // namespace tactus::sim::detail
