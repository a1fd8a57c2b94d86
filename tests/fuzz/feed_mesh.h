#pragma once
// Fuzz target for the tetrahedral mesh readers (Gmsh 1/2/4, legacy VTK, VTU), shared by the
// libFuzzer harness (mesh_fuzz.cpp) and the regression test (tests/unit/mesh).
//
// Contract checked: parseTetMesh returns a mesh or throws tactus::Error. Anything else (another
// exception type, a sanitizer report, a returned mesh that breaks the documented invariants:
// finite nodes, tet indices in range, at least one tet, group nodes sorted, unique and in range)
// escapes as std::logic_error: a bug.

#include <cmath>
#include <stdexcept>
#include <string>

#include "tactus/shared/error.h"
#include "tactus/sim/mesh.h"

namespace tactus::fuzz {

/// Feeds `bytes` to parseTetMesh (and extractSurface on success). Returns true when the input was
/// accepted, false on a tactus::Error; throws std::logic_error on a broken invariant.
inline bool feedMesh(const std::string& bytes) {
  sim::TetMesh mesh;
  try {
    sim::MeshReport report;
    mesh = sim::parseTetMesh(bytes, "fuzz.msh", &report);
  } catch (const tactus::Error&) {
    return false;
  }
  if (mesh.tets.empty()) throw std::logic_error("mesh accepted without tetrahedra");
  if (!mesh.nodes.allFinite()) throw std::logic_error("mesh accepted with non-finite nodes");
  for (const auto& t : mesh.tets) {
    for (int v : t) {
      if (v < 0 || v >= mesh.nodeCount()) throw std::logic_error("tet index out of range");
    }
  }
  for (const sim::NodeGroup& g : mesh.groups) {
    for (std::size_t i = 0; i < g.nodes.size(); ++i) {
      const bool in_range = g.nodes[i] >= 0 && g.nodes[i] < mesh.nodeCount();
      if (!in_range || (i > 0 && g.nodes[i] <= g.nodes[i - 1])) {
        throw std::logic_error("group nodes out of range, unsorted or repeated");
      }
    }
  }
  const sim::SurfaceMesh surface = sim::extractSurface(mesh);
  for (const auto& tri : surface.triangles) {
    for (int v : tri) {
      if (v < 0 || v >= mesh.nodeCount()) throw std::logic_error("surface index out of range");
    }
  }
  return true;
}

}  // namespace tactus::fuzz
