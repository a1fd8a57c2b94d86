#pragma once
// Triangle surfaces for static obstacles (scene `obstacles[i].mesh`): Wavefront OBJ and STL
// (ASCII and binary), chosen by content (binary STL: 80-byte header and a triangle count that
// matches the size; ASCII STL: starts with `solid` and has `facet`; otherwise OBJ).
//  * OBJ: `v x y z` and `f a b c ...` lines (polygons fanned into triangles; `a/b/c` forms and
//    negative, relative indices accepted); other lines ignored.
//  * STL: each facet's three vertices; coincident vertices (bit-equal) are merged.
// The triangles' normals (counter-clockwise, right hand) point out of the obstacle.

#include <Eigen/Core>
#include <array>
#include <filesystem>
#include <string>
#include <vector>

namespace tactus::sim {

struct TriangleSurface {
  Eigen::Matrix3Xd vertices;                  ///< one column per vertex
  std::vector<std::array<int, 3>> triangles;  ///< vertex indices
  std::string source;                         ///< file it came from (for messages)
};

/// Reads an OBJ or STL surface. Throws tactus::MeshError naming the file (and line for text
/// formats) on malformed input: a bad number, an index out of range, a non-finite coordinate, a
/// truncated binary file, no triangle at all. Degenerate (zero-area) triangles are dropped.
TriangleSurface loadTriangleSurface(const std::filesystem::path& path);

/// Same from memory; `name` is used in messages.
TriangleSurface parseTriangleSurface(const std::string& content, const std::string& name);

}  // namespace tactus::sim
