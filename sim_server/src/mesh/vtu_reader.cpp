// VTK XML unstructured grid (.vtu) reader: a small XML parser (elements, attributes, text),
// DataArrays in ascii, inline base64 binary (optionally zlib-compressed) and appended (raw or
// base64) formats. Every size read from the file is checked before it is used.
// (Over 500 lines on purpose: one format's reader, whose XML parser and decoders serve only it.)

#include <fmt/format.h>
#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <limits>
#include <map>
#include <memory>

#include "mesh_internal.h"

namespace tactus::sim::detail {
namespace {

constexpr int kMaxXmlDepth = 64;

struct XmlElement {
  std::string name;
  std::map<std::string, std::string> attrs;
  std::size_t pos = 0;                   // offset of '<'
  std::size_t text_begin = 0, text_end = 0;  // first run of character data
  std::vector<std::unique_ptr<XmlElement>> children;

  const std::string* attr(const std::string& key) const {
    auto it = attrs.find(key);
    return it == attrs.end() ? nullptr : &it->second;
  }
  const XmlElement* child(const std::string& child_name) const {
    for (const auto& c : children) {
      if (c->name == child_name) return c.get();
    }
    return nullptr;
  }
};

bool isSpace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; }
bool isNameChar(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
         c == '-' || c == '.' || c == ':';
}

// Minimal XML parser for VTK files: no DTDs, entities are kept verbatim.
class XmlParser {
 public:
  XmlParser(const std::string& text, const std::string& name) : s_(text), name_(name) {}

  std::unique_ptr<XmlElement> parseDocument() {
    skipMisc();
    if (pos_ >= s_.size() || s_[pos_] != '<') failAt(pos_, "expected an XML element");
    auto root = parseElement(0);
    return root;
  }

  std::size_t appendedBegin() const { return appended_begin_; }
  std::size_t appendedEnd() const { return appended_end_; }
  const std::string* appendedEncoding() const {
    return appended_ ? appended_->attr("encoding") : nullptr;
  }
  bool hasAppended() const { return appended_ != nullptr; }

  [[noreturn]] void failAt(std::size_t pos, const std::string& msg) const {
    fail(name_, lineOf(s_, pos), msg);
  }

 private:
  // Skips whitespace, <?...?> declarations, comments and <!DOCTYPE ...>.
  void skipMisc() {
    for (;;) {
      while (pos_ < s_.size() && isSpace(s_[pos_])) ++pos_;
      if (s_.compare(pos_, 4, "<!--") == 0) {
        const std::size_t e = s_.find("-->", pos_ + 4);
        if (e == std::string::npos) failAt(pos_, "unexpected end of file inside a comment");
        pos_ = e + 3;
      } else if (s_.compare(pos_, 2, "<?") == 0) {
        const std::size_t e = s_.find("?>", pos_ + 2);
        if (e == std::string::npos) failAt(pos_, "unexpected end of file inside '<?'");
        pos_ = e + 2;
      } else if (s_.compare(pos_, 2, "<!") == 0) {
        const std::size_t e = s_.find('>', pos_ + 2);
        if (e == std::string::npos) failAt(pos_, "unexpected end of file inside '<!'");
        pos_ = e + 1;
      } else {
        return;
      }
    }
  }

  std::string parseName() {
    const std::size_t start = pos_;
    while (pos_ < s_.size() && isNameChar(s_[pos_])) ++pos_;
    if (pos_ == start) failAt(start, "expected a name");
    return s_.substr(start, pos_ - start);
  }

  std::unique_ptr<XmlElement> parseElement(int depth) {
    if (depth > kMaxXmlDepth) failAt(pos_, "XML nesting too deep");
    auto el = std::make_unique<XmlElement>();
    el->pos = pos_;
    ++pos_;  // '<'
    el->name = parseName();
    // attributes
    for (;;) {
      while (pos_ < s_.size() && isSpace(s_[pos_])) ++pos_;
      if (pos_ >= s_.size()) failAt(el->pos, "unexpected end of file inside <" + el->name + ">");
      if (s_[pos_] == '/') {
        if (s_.compare(pos_, 2, "/>") != 0) failAt(pos_, "expected '/>'");
        pos_ += 2;
        return el;
      }
      if (s_[pos_] == '>') {
        ++pos_;
        break;
      }
      std::string key = parseName();
      while (pos_ < s_.size() && isSpace(s_[pos_])) ++pos_;
      if (pos_ >= s_.size() || s_[pos_] != '=') failAt(pos_, "expected '=' after attribute " + key);
      ++pos_;
      while (pos_ < s_.size() && isSpace(s_[pos_])) ++pos_;
      if (pos_ >= s_.size() || (s_[pos_] != '"' && s_[pos_] != '\'')) {
        failAt(pos_, "expected a quoted value for attribute " + key);
      }
      const char quote = s_[pos_++];
      const std::size_t e = s_.find(quote, pos_);
      if (e == std::string::npos) failAt(pos_, "unexpected end of file inside an attribute value");
      el->attrs[key] = s_.substr(pos_, e - pos_);
      pos_ = e + 1;
    }
    if (el->name == "AppendedData") {
      // raw bytes follow '_' up to the closing tag (searched from the end: the data may hold '<')
      const std::size_t underscore = s_.find('_', pos_);
      const std::size_t close = s_.rfind("</AppendedData>");
      if (underscore == std::string::npos || close == std::string::npos || close < underscore) {
        failAt(el->pos, "AppendedData without '_' marker or closing tag (truncated file?)");
      }
      appended_begin_ = underscore + 1;
      appended_end_ = close;
      // trailing whitespace before the closing tag is not data in base64 mode; raw keeps it
      appended_ = el.get();
      pos_ = close + std::strlen("</AppendedData>");
      return el;
    }
    // content: text and child elements until the matching end tag
    bool have_text = false;
    for (;;) {
      const std::size_t lt = s_.find('<', pos_);
      if (lt == std::string::npos) {
        failAt(el->pos, "unexpected end of file: <" + el->name + "> is not closed");
      }
      if (!have_text) {
        el->text_begin = pos_;
        el->text_end = lt;
        have_text = true;
      }
      pos_ = lt;
      if (s_.compare(pos_, 2, "</") == 0) {
        pos_ += 2;
        const std::string end_name = parseName();
        if (end_name != el->name) {
          failAt(lt, "</" + end_name + "> does not close <" + el->name + ">");
        }
        while (pos_ < s_.size() && isSpace(s_[pos_])) ++pos_;
        if (pos_ >= s_.size() || s_[pos_] != '>') failAt(pos_, "expected '>'");
        ++pos_;
        return el;
      }
      if (s_.compare(pos_, 4, "<!--") == 0 || s_.compare(pos_, 2, "<?") == 0 ||
          s_.compare(pos_, 2, "<!") == 0) {
        skipMisc();
        continue;
      }
      el->children.push_back(parseElement(depth + 1));
    }
  }

  const std::string& s_;
  const std::string& name_;
  std::size_t pos_ = 0;
  XmlElement* appended_ = nullptr;
  std::size_t appended_begin_ = 0, appended_end_ = 0;
};

// Base64, decoded in independent 4-character groups so that separately encoded (padded) header
// and data blocks decode the same as one stream. Whitespace is skipped; stops at any other byte.
std::size_t decodeBase64(std::string_view in, std::vector<unsigned char>* out,
                         std::size_t max_bytes) {
  const auto value = [](char c) -> int {
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    if (c == '+') return 62;
    if (c == '/') return 63;
    if (c == '=') return -2;
    if (isSpace(c)) return -3;
    return -1;
  };
  int group[4];
  int count = 0;
  std::size_t i = 0;
  for (; i < in.size() && out->size() < max_bytes; ++i) {
    const int v = value(in[i]);
    if (v == -3) continue;
    if (v == -1) break;
    group[count++] = v;
    if (count < 4) continue;
    count = 0;
    if (group[0] < 0 || group[1] < 0) break;  // invalid padding position
    out->push_back(static_cast<unsigned char>((group[0] << 2) | (group[1] >> 4)));
    if (group[2] < 0) continue;
    out->push_back(static_cast<unsigned char>(((group[1] & 15) << 4) | (group[2] >> 2)));
    if (group[3] < 0) continue;
    out->push_back(static_cast<unsigned char>(((group[2] & 3) << 6) | group[3]));
  }
  return i;
}

int typeSize(const std::string& type) {
  if (type == "Int8" || type == "UInt8") return 1;
  if (type == "Int16" || type == "UInt16") return 2;
  if (type == "Int32" || type == "UInt32" || type == "Float32") return 4;
  if (type == "Int64" || type == "UInt64" || type == "Float64") return 8;
  return 0;
}

// One little/big-endian value of `type` at `p` as double.
double readValue(const unsigned char* p, const std::string& type, bool big_endian) {
  unsigned char b[8];
  const int n = typeSize(type);
  for (int i = 0; i < n; ++i) b[i] = big_endian ? p[n - 1 - i] : p[i];
  // the host is little-endian (x86-64, aarch64 Linux)
  if (type == "Float64") { double v; std::memcpy(&v, b, 8); return v; }
  if (type == "Float32") { float v; std::memcpy(&v, b, 4); return v; }
  if (type == "Int64") { std::int64_t v; std::memcpy(&v, b, 8); return static_cast<double>(v); }
  if (type == "UInt64") { std::uint64_t v; std::memcpy(&v, b, 8); return static_cast<double>(v); }
  if (type == "Int32") { std::int32_t v; std::memcpy(&v, b, 4); return v; }
  if (type == "UInt32") { std::uint32_t v; std::memcpy(&v, b, 4); return v; }
  if (type == "Int16") { std::int16_t v; std::memcpy(&v, b, 2); return v; }
  if (type == "UInt16") { std::uint16_t v; std::memcpy(&v, b, 2); return v; }
  if (type == "Int8") { return static_cast<std::int8_t>(b[0]); }
  return b[0];
}

class VtuReader {
 public:
  VtuReader(const std::string& content, const std::string& name, RawMesh* raw)
      : s_(content), name_(name), raw_(raw), xml_(content, name) {}

  void run() {
    raw_->format = "vtu";
    raw_->element_word = "cell";
    raw_->node_word = "point";
    auto root = xml_.parseDocument();
    if (root->name != "VTKFile") xml_.failAt(root->pos, "root element is not <VTKFile>");
    const std::string* type = root->attr("type");
    if (type == nullptr || *type != "UnstructuredGrid") {
      xml_.failAt(root->pos, fmt::format("VTKFile type is '{}', expected UnstructuredGrid",
                                         type ? *type : std::string("(none)")));
    }
    const std::string* order = root->attr("byte_order");
    big_endian_ = order != nullptr && *order == "BigEndian";
    const std::string* header = root->attr("header_type");
    header_size_ = 4;
    if (header != nullptr) {
      if (*header == "UInt64") {
        header_size_ = 8;
      } else if (*header != "UInt32") {
        xml_.failAt(root->pos, "header_type must be UInt32 or UInt64, got '" + *header + "'");
      }
    }
    if (const std::string* c = root->attr("compressor"); c != nullptr && !c->empty()) {
      if (*c != "vtkZLibDataCompressor") {
        xml_.failAt(root->pos, "unsupported compressor '" + *c +
                                   "' (only vtkZLibDataCompressor): re-save uncompressed or zlib");
      }
      compressed_ = true;
    }
    const XmlElement* grid = root->child("UnstructuredGrid");
    if (grid == nullptr) xml_.failAt(root->pos, "missing <UnstructuredGrid>");
    int pieces = 0;
    for (const auto& piece : grid->children) {
      if (piece->name != "Piece") continue;
      readPiece(*piece);
      ++pieces;
    }
    if (pieces == 0) xml_.failAt(grid->pos, "<UnstructuredGrid> has no <Piece>");
    raw_->last_line = lineOf(s_, s_.size());
  }

 private:
  std::int64_t intAttr(const XmlElement& el, const std::string& key) {
    const std::string* v = el.attr(key);
    std::int64_t out = 0;
    if (v == nullptr || !parseInt(*v, &out) || out < 0 ||
        out > static_cast<std::int64_t>(std::numeric_limits<int>::max())) {
      xml_.failAt(el.pos, fmt::format("<{}> needs a non-negative integer attribute {}", el.name,
                                      key));
    }
    return out;
  }

  void readPiece(const XmlElement& piece) {
    const std::int64_t n_points = intAttr(piece, "NumberOfPoints");
    const std::int64_t n_cells = intAttr(piece, "NumberOfCells");
    const XmlElement* points = piece.child("Points");
    const XmlElement* cells = piece.child("Cells");
    if (points == nullptr) xml_.failAt(piece.pos, "<Piece> has no <Points>");
    if (cells == nullptr) xml_.failAt(piece.pos, "<Piece> has no <Cells>");
    const XmlElement* parray = firstArray(*points, nullptr);
    if (parray == nullptr) xml_.failAt(points->pos, "<Points> has no <DataArray>");
    const std::vector<double> xyz = readArray(*parray, n_points * 3);
    const XmlElement* conn_el = firstArray(*cells, "connectivity");
    const XmlElement* off_el = firstArray(*cells, "offsets");
    const XmlElement* types_el = firstArray(*cells, "types");
    if (conn_el == nullptr || off_el == nullptr || types_el == nullptr) {
      xml_.failAt(cells->pos, "<Cells> needs DataArrays named connectivity, offsets and types");
    }
    const std::vector<double> offsets = readArray(*off_el, n_cells);
    const std::int64_t n_conn = offsets.empty() ? 0 : checkedIndex(offsets.back(), *off_el);
    const std::vector<double> conn = readArray(*conn_el, n_conn);
    const std::vector<double> types = readArray(*types_el, n_cells);
    // points (ids continue across pieces)
    const auto base = static_cast<std::int64_t>(raw_->node_ids.size());
    const int points_line = lineOf(s_, parray->pos);
    for (std::int64_t i = 0; i < n_points; ++i) {
      raw_->node_ids.push_back(base + i);
      const auto k = static_cast<std::size_t>(3 * i);
      raw_->coords.insert(raw_->coords.end(), {xyz[k], xyz[k + 1], xyz[k + 2]});
      raw_->node_lines.push_back(points_line);
    }
    // cells
    const int conn_line = lineOf(s_, conn_el->pos);
    const auto cell_base = static_cast<std::int64_t>(raw_->tet_ids.size()) + raw_->ignored_elements;
    std::int64_t begin = 0;
    for (std::int64_t c = 0; c < n_cells; ++c) {
      const std::int64_t end = checkedIndex(offsets[static_cast<std::size_t>(c)], *off_el);
      if (end < begin || end > n_conn) {
        xml_.failAt(off_el->pos, fmt::format("offsets must increase and stay within the "
                                             "connectivity (cell {})", c));
      }
      const std::int64_t t = checkedIndex(types[static_cast<std::size_t>(c)], *types_el);
      if (t == 10) {
        if (end - begin != 4) {
          xml_.failAt(conn_el->pos,
                      fmt::format("cell {} is a tetrahedron (type 10) with {} points instead of 4",
                                  c, end - begin));
        }
        std::array<std::int64_t, 4> tet{};
        for (std::size_t k = 0; k < 4; ++k) {
          tet[k] = base + checkedIndex(conn[static_cast<std::size_t>(begin) + k], *conn_el);
          if (tet[k] >= base + n_points) tet[k] = -1 - (tet[k] - base);  // unknown: reported below
        }
        for (std::size_t k = 0; k < 4; ++k) {
          if (tet[k] < 0) {
            fail(name_, conn_line,
                 fmt::format("cell {} refers to point {} which is not defined (the piece has {} "
                             "points)", cell_base + c, -1 - tet[k], n_points));
          }
        }
        raw_->tets.push_back(tet);
        raw_->tet_ids.push_back(cell_base + c);
        raw_->tet_lines.push_back(conn_line);
      } else {
        ++raw_->ignored_elements;
      }
      begin = end;
    }
  }

  const XmlElement* firstArray(const XmlElement& parent, const char* array_name) {
    for (const auto& c : parent.children) {
      if (c->name != "DataArray") continue;
      if (array_name == nullptr) return c.get();
      const std::string* n = c->attr("Name");
      if (n != nullptr && *n == array_name) return c.get();
    }
    return nullptr;
  }

  std::int64_t checkedIndex(double v, const XmlElement& el) {
    if (!(v >= 0) || v > static_cast<double>(std::numeric_limits<int>::max()) ||
        v != static_cast<double>(static_cast<std::int64_t>(v))) {
      xml_.failAt(el.pos, fmt::format("DataArray '{}' holds {} where a non-negative integer "
                                      "index is expected", arrayName(el), v));
    }
    return static_cast<std::int64_t>(v);
  }

  static std::string arrayName(const XmlElement& el) {
    const std::string* n = el.attr("Name");
    return n ? *n : std::string("(unnamed)");
  }

  // Reads exactly `count` values of a DataArray, whatever its format.
  std::vector<double> readArray(const XmlElement& el, std::int64_t count) {
    const std::string* type = el.attr("type");
    if (type == nullptr || typeSize(*type) == 0) {
      xml_.failAt(el.pos, fmt::format("DataArray '{}' has a missing or unknown type",
                                      arrayName(el)));
    }
    const std::string* format = el.attr("format");
    const std::string fmt_name = format ? *format : std::string("ascii");
    // every value takes at least one byte of the file (zlib expands at most ~1032:1)
    const auto bound = static_cast<std::int64_t>(s_.size()) * (compressed_ ? 1100 : 1) + 16;
    if (count > bound) {
      xml_.failAt(el.pos, fmt::format("DataArray '{}' cannot hold {} values in a file of {} bytes",
                                      arrayName(el), count, s_.size()));
    }
    const auto n = static_cast<std::size_t>(count);
    std::vector<double> values;
    if (fmt_name == "ascii") {
      std::vector<std::string_view> tokens;
      splitTokens(std::string_view(s_).substr(el.text_begin, el.text_end - el.text_begin),
                  &tokens);
      if (tokens.size() != n) {
        xml_.failAt(el.pos, fmt::format("DataArray '{}': expected {} values, got {}",
                                        arrayName(el), n, tokens.size()));
      }
      values.resize(n);
      for (std::size_t i = 0; i < n; ++i) {
        if (!parseDouble(tokens[i], &values[i])) {
          xml_.failAt(el.pos, fmt::format("DataArray '{}': '{}' is not a number", arrayName(el),
                                          std::string(tokens[i].substr(0, 40))));
        }
      }
      return values;
    }
    const std::size_t value_size = static_cast<std::size_t>(typeSize(*type));
    const std::size_t want = n * value_size;
    std::vector<unsigned char> bytes;
    if (fmt_name == "binary") {
      std::string_view text =
          std::string_view(s_).substr(el.text_begin, el.text_end - el.text_begin);
      decodeBase64(text, &bytes, std::numeric_limits<std::size_t>::max());
    } else if (fmt_name == "appended") {
      if (!xml_.hasAppended()) xml_.failAt(el.pos, "format=\"appended\" without <AppendedData>");
      std::int64_t offset = intAttr(el, "offset");
      const std::size_t start = xml_.appendedBegin() + static_cast<std::size_t>(offset);
      if (start > xml_.appendedEnd()) {
        xml_.failAt(el.pos, "appended offset beyond the end of <AppendedData>");
      }
      const std::string* enc = xml_.appendedEncoding();
      const std::string_view region =
          std::string_view(s_).substr(start, xml_.appendedEnd() - start);
      if (enc != nullptr && *enc == "base64") {
        decodeBase64(region, &bytes, want + 64 + 8 * (want / 1024 + 16));
        // a base64 region may decode past this array: sizes below come from the header
      } else if (enc == nullptr || *enc == "raw") {
        bytes.assign(region.begin(), region.end());
      } else {
        xml_.failAt(el.pos, "unknown AppendedData encoding '" + *enc + "'");
      }
    } else {
      xml_.failAt(el.pos, "unknown DataArray format '" + fmt_name + "'");
    }
    const std::vector<unsigned char> data =
        compressed_ ? inflateBlocks(bytes, want, el) : plainBlock(bytes, want, el);
    values.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      values[i] = readValue(data.data() + i * value_size, *type, big_endian_);
    }
    return values;
  }

  std::uint64_t headerWord(const std::vector<unsigned char>& b, std::size_t index,
                           const XmlElement& el) {
    const std::size_t at = index * header_size_;
    if (at + header_size_ > b.size()) {
      xml_.failAt(el.pos, fmt::format("DataArray '{}': binary data too short for its header "
                                      "(truncated?)", arrayName(el)));
    }
    return header_size_ == 8 ? static_cast<std::uint64_t>(readValue(b.data() + at, "UInt64",
                                                                    big_endian_))
                             : static_cast<std::uint64_t>(readValue(b.data() + at, "UInt32",
                                                                    big_endian_));
  }

  // Uncompressed: [byte count][data].
  std::vector<unsigned char> plainBlock(const std::vector<unsigned char>& b, std::size_t want,
                                        const XmlElement& el) {
    const std::uint64_t declared = headerWord(b, 0, el);
    if (declared != want) {
      xml_.failAt(el.pos, fmt::format("DataArray '{}': header declares {} bytes, expected {}",
                                      arrayName(el), declared, want));
    }
    if (b.size() - header_size_ < want) {
      xml_.failAt(el.pos, fmt::format("DataArray '{}': {} bytes of data, expected {} "
                                      "(truncated?)", arrayName(el), b.size() - header_size_,
                                      want));
    }
    return std::vector<unsigned char>(b.begin() + static_cast<long>(header_size_),
                                      b.begin() + static_cast<long>(header_size_ + want));
  }

  // zlib: [blocks][block size][last block size][compressed sizes...][compressed blocks...].
  std::vector<unsigned char> inflateBlocks(const std::vector<unsigned char>& b, std::size_t want,
                                           const XmlElement& el) {
    const std::uint64_t blocks = headerWord(b, 0, el);
    const std::uint64_t block_size = headerWord(b, 1, el);
    const std::uint64_t last_size = headerWord(b, 2, el);
    const std::string what = fmt::format("DataArray '{}' (zlib)", arrayName(el));
    if (blocks > b.size() || (blocks > 0 && block_size == 0) || last_size > block_size) {
      xml_.failAt(el.pos, what + ": invalid compression header");
    }
    const std::uint64_t total =
        blocks == 0 ? 0 : (blocks - 1) * block_size + (last_size == 0 ? block_size : last_size);
    if (total != want) {
      xml_.failAt(el.pos, fmt::format("{}: holds {} bytes, expected {}", what, total, want));
    }
    std::size_t at = (3 + static_cast<std::size_t>(blocks)) * header_size_;
    std::vector<std::uint64_t> csizes(static_cast<std::size_t>(blocks));
    std::uint64_t compressed_total = 0;
    for (std::size_t k = 0; k < csizes.size(); ++k) {
      csizes[k] = headerWord(b, 3 + k, el);
      compressed_total += csizes[k];
      if (csizes[k] > b.size() || compressed_total > b.size() - std::min(at, b.size())) {
        xml_.failAt(el.pos, what + ": compressed data truncated");
      }
    }
    // zlib cannot expand more than ~1032:1: refuse absurd sizes before allocating
    if (want > compressed_total * 1100 + 1024) {
      xml_.failAt(el.pos, what + ": declared size inconsistent with the compressed data");
    }
    std::vector<unsigned char> out(want);
    std::size_t written = 0;
    for (std::uint64_t k = 0; k < blocks; ++k) {
      const std::uint64_t csize = csizes[static_cast<std::size_t>(k)];
      const std::uint64_t usize = (k + 1 == blocks && last_size != 0) ? last_size : block_size;
      uLongf dest_len = static_cast<uLongf>(usize);
      const int rc = uncompress(out.data() + written, &dest_len, b.data() + at,
                                static_cast<uLong>(csize));
      if (rc != Z_OK || dest_len != usize) {
        xml_.failAt(el.pos, fmt::format("{}: block {} does not decompress ({})", what, k,
                                        rc == Z_OK ? "wrong size" : zError(rc)));
      }
      written += static_cast<std::size_t>(usize);
      at += static_cast<std::size_t>(csize);
    }
    return out;
  }

  const std::string& s_;
  const std::string& name_;
  RawMesh* raw_;
  XmlParser xml_;
  std::size_t header_size_ = 4;
  bool compressed_ = false;
  bool big_endian_ = false;
};

}  // namespace

void readVtu(const std::string& content, const std::string& name, RawMesh* raw) {
  VtuReader(content, name, raw).run();
}

}  // namespace tactus::sim::detail
