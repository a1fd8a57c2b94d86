#pragma once
// Tetrahedral meshes: the in-memory type, readers for the common file formats, surface
// extraction and VTK output.
//
// Supported inputs (chosen by content, not only by extension):
//  * Gmsh ASCII 1.0 (`$NOD`/`$ELM`), 2.2 and 4.1 (`$MeshFormat`): 4-node tetrahedra are kept
//    (element type 4); other element types are ignored and counted, but every element (of any
//    dimension) still counts for the physical groups it belongs to (TetMesh::groups).
//  * Legacy VTK unstructured grids (`# vtk DataFile`, ASCII, DATASET UNSTRUCTURED_GRID,
//    cell type 10).
//  * VTK XML `.vtu` (ASCII, base64 binary, zlib-compressed base64 where present).
// Node ids in files may be sparse and unordered; they are renumbered densely in file order.
// Nodes not referenced by any tetrahedron are dropped (counted in MeshReport).

#include <Eigen/Core>
#include <array>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace tactus::sim {

/// A Gmsh physical group as a set of nodes: the nodes of every element, of any dimension (points,
/// lines, triangles, tetrahedra...), the file puts in it. Read from `$PhysicalNames` and the
/// elements' physical tags (2.x and 1.0: an element's first tag / reg-phys; 4.1: the physical tags
/// of the `$Entities` entity an element block belongs to). Scenes select them with a region's
/// `group:` selector (scenes/README.md, "Regions"). Malformed group sections are MeshErrors with
/// the line, as is a 4.1 file whose entities are in so many groups that their copies would exceed
/// 16 times the elements' nodes (plus 65536): memory out of proportion to the file.
struct NodeGroup {
  std::string name;        ///< its $PhysicalNames name; the tag as text ("7") when it has none
  int dimension = 0;       ///< 0 point, 1 curve, 2 surface, 3 volume
  int tag = 0;             ///< the physical tag (unique within a dimension)
  /// sorted unique indices into TetMesh::nodes (after the reader's renumbering); nodes that no
  /// tetrahedron uses are dropped from the mesh and so from its groups (may leave it empty)
  std::vector<int> nodes;
};

/// A tetrahedral mesh. Positions in the file's units until a scene transforms them (SI inside).
struct TetMesh {
  Eigen::Matrix3Xd nodes;                 ///< node positions, one column per node
  std::vector<std::array<int, 4>> tets;   ///< node indices; positive orientation after loading
  std::string source;                     ///< file it came from (for messages)
  /// Gmsh physical groups ordered by (dimension, tag), including named groups with no element;
  /// empty for other formats
  std::vector<NodeGroup> groups;

  int nodeCount() const { return static_cast<int>(nodes.cols()); }
  int tetCount() const { return static_cast<int>(tets.size()); }
};

/// What a reader repaired or skipped; every non-zero count is also logged as a warning.
struct MeshReport {
  std::string format;            ///< "gmsh1", "gmsh2", "gmsh4", "vtk-legacy", "vtu"
  int ignored_elements = 0;      ///< non-tetrahedral elements skipped
  int flipped_tets = 0;          ///< negatively oriented tets re-oriented (two nodes swapped)
  int dropped_nodes = 0;         ///< nodes referenced by no tetrahedron
  /// tetrahedra whose mean ratio 12 (3 |V|)^(2/3) / (sum of squared edge lengths) is below 1e-3
  /// (1: the regular tetrahedron; a sliver of height 1e-8 m across 1 cm edges: ~1e-4)
  int sliver_tets = 0;
  double worst_mean_ratio = 1.0; ///< the smallest mean ratio of the mesh
  int worst_mean_ratio_line = 0; ///< the file line of that tetrahedron
};

/// Reads a tetrahedral mesh. Throws tactus::MeshError naming the file and line on malformed input:
/// truncated file, missing section, no tetrahedra at all; and, all of them in one error (the
/// first 20 listed, each with its line, and their count), duplicate ids, non-finite
/// coordinates, an element referring to an unknown node or using one twice, a degenerate
/// (zero-volume, relative to the mesh size) tetrahedron, a face shared by more than two
/// tetrahedra, a tangle (two tetrahedra on the same side of their shared face: a node pushed
/// through a face). Negatively oriented tetrahedra of an untangled mesh are repaired (counted in
/// `report`); near-degenerate ones (slivers, caps, needles) are counted and the worst named in a
/// warning and in `report`. Never crashes on bad input.
TetMesh loadTetMesh(const std::filesystem::path& path, MeshReport* report = nullptr);

/// Same as loadTetMesh but from an in-memory buffer; `name` is used in messages and the format is
/// detected from the content.
TetMesh parseTetMesh(const std::string& content, const std::string& name,
                     MeshReport* report = nullptr);

/// The boundary of a tetrahedral mesh: faces that belong to exactly one tetrahedron, oriented so
/// that their normal (counter-clockwise, right hand) points out of the volume.
struct SurfaceMesh {
  std::vector<std::array<int, 3>> triangles;  ///< indices into TetMesh::nodes
  std::vector<int> triangle_tet;              ///< the tetrahedron each triangle bounds
  std::vector<int> nodes;                     ///< sorted unique surface node indices
};

SurfaceMesh extractSurface(const TetMesh& mesh);

}  // namespace tactus::sim
