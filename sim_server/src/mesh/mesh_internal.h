#pragma once
// Private helpers shared by the mesh readers: a raw (file-id) mesh every reader fills, the
// validation that turns it into a TetMesh, a line-aware text cursor and number parsing.

#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "tactus/shared/file_io.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim::detail {

/// The file node ids of the elements of one physical group (gmsh), before ids are resolved.
struct RawGroup {
  int dimension = 0;
  int tag = 0;
  std::vector<int> tets;                ///< its tetrahedra: indices into RawMesh::tets
  std::vector<std::int64_t> node_ids;   ///< its other elements' nodes, with repetitions
  std::vector<int> node_lines;          ///< line of the element each id comes from
};

/// Raw groups by (dimension, tag).
using RawGroupMap = std::map<std::pair<int, int>, RawGroup>;

/// The entry of `groups` for (dimension, tag), created empty when missing. In mesh_groups.cpp.
RawGroup& rawGroup(RawGroupMap* groups, int dimension, int tag);

/// Gmsh 4.1: each entity's elements (`entity_nodes`, by (dimension, entity tag)) into every
/// physical group `entity_physicals` lists for it, in `groups` (by (dimension, physical tag)). An
/// entity is copied once per group: copies beyond 16 times the elements' nodes (a file asking for
/// far more memory than its size) fail at `line`. In mesh_groups.cpp.
void addEntityGroups(const RawGroupMap& entity_nodes,
                     const std::map<std::pair<int, int>, std::vector<int>>& entity_physicals,
                     RawGroupMap* groups, const std::string& name, int line);

/// A `$PhysicalNames` entry.
struct RawPhysicalName {
  int dimension = 0;
  int tag = 0;
  std::string name;
  int line = 0;
};

/// What a reader collected, before ids are resolved and tets are checked.
struct RawMesh {
  std::string format;                           ///< MeshReport::format
  std::string element_word = "element";         ///< "element" (gmsh) or "cell" (VTK) in messages
  std::string node_word = "node";               ///< "node" (gmsh) or "point" (VTK) in messages
  std::vector<std::int64_t> node_ids;           ///< file ids, file order
  std::vector<double> coords;                   ///< x y z per node
  std::vector<int> node_lines;                  ///< line of each node (for messages)
  std::vector<std::array<std::int64_t, 4>> tets;  ///< file node ids
  std::vector<std::int64_t> tet_ids;            ///< file element ids
  std::vector<int> tet_lines;                   ///< line of each tet
  std::vector<RawGroup> groups;                 ///< gmsh physical groups, any order
  std::vector<RawPhysicalName> physical_names;  ///< gmsh $PhysicalNames
  int ignored_elements = 0;
  int last_line = 1;                            ///< where "no tetrahedra" is reported
};

/// Throws MeshError "name:line: message".
[[noreturn]] void fail(const std::string& name, int line, const std::string& message);

/// At most this many problems of one mesh are listed in its MeshError (all are counted).
inline constexpr int kListedMeshProblems = 20;
/// Tetrahedra of a mean ratio below this are reported as near-degenerate (a warning).
inline constexpr double kSliverMeanRatio = 1e-3;

/// Resolves ids, drops unreferenced nodes, flips negatively oriented tets and checks the result:
/// duplicate ids, unknown nodes, non-finite coordinates, repeated nodes, zero volumes, faces
/// shared by more than two tets and tangles (two tets on the same side of their shared face) are
/// errors, all reported together (MeshProblems in mesh_validate.cpp); near-degenerate tets are
/// counted and the worst one named in a warning.
TetMesh finalizeMesh(RawMesh&& raw, const std::string& name, MeshReport* report);

/// The physical groups of `raw` on `mesh` (whose tets are raw.tets resolved, in the same order),
/// other elements' node ids resolved through `index_of` (file id -> position in file order) and
/// `new_index` (position -> mesh index, -1 when dropped); fails on an element of a group that
/// refers to an unknown node. `dropped` counts the group nodes no tetrahedron uses (left out). In
/// mesh_groups.cpp.
std::vector<NodeGroup> resolveGroups(const RawMesh& raw, const TetMesh& mesh,
                                     const std::unordered_map<std::int64_t, int>& index_of,
                                     const std::vector<int>& new_index, const std::string& name,
                                     int* dropped);

/// The dimension (0 to 3) of a Gmsh element type (the MSH format's elm-type table), -1 when unknown.
int gmshElementDimension(std::int64_t type);

/// Parses a whole token as a number; false on any trailing garbage, overflow or empty input.
bool parseDouble(std::string_view token, double* out);
bool parseInt(std::string_view token, std::int64_t* out);

/// A printable excerpt of a token for messages (bounded, no control characters).
std::string excerpt(std::string_view s);
/// ASCII case-insensitive equality (format keywords).
bool equalsNoCase(std::string_view a, std::string_view b);
/// `s` without leading and trailing blanks (space, tab, CR, VT, FF).
std::string_view trim(std::string_view s);

/// Splits a line into whitespace-separated tokens (views into the line).
void splitTokens(std::string_view line, std::vector<std::string_view>* tokens);

/// Readers, one per format. `content` is the whole file.
void readGmsh(const std::string& content, const std::string& name, RawMesh* raw);
void readVtkLegacy(const std::string& content, const std::string& name, RawMesh* raw);
void readVtu(const std::string& content, const std::string& name, RawMesh* raw);

/// A cursor over text lines with 1-based line numbers.
class LineCursor {
 public:
  explicit LineCursor(std::string_view text) : text_(text) {}
  /// Next line (without the end-of-line characters); false at end of input.
  bool next(std::string_view* line) {
    if (pos_ >= text_.size()) return false;
    const std::size_t end = text_.find('\n', pos_);
    const std::size_t stop = end == std::string_view::npos ? text_.size() : end;
    std::string_view l = text_.substr(pos_, stop - pos_);
    if (!l.empty() && l.back() == '\r') l.remove_suffix(1);
    pos_ = end == std::string_view::npos ? text_.size() : end + 1;
    ++line_;
    if ((line_ & 0xFFFFF) == 0) shared::throwIfStopRequested("reading a mesh");
    *line = l;
    return true;
  }
  /// Line number of the line last returned by next() (0 before the first call).
  int line() const { return line_; }
  bool atEnd() const { return pos_ >= text_.size(); }

 private:
  std::string_view text_;
  std::size_t pos_ = 0;
  int line_ = 0;
};

/// 1-based line number of byte offset `pos` in `text`.
int lineOf(std::string_view text, std::size_t pos);

}  // namespace tactus::sim::detail
