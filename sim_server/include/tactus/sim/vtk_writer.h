#pragma once
// The VTK writer (sim_server's output, scene key `output`; tactus::sim_app, an application part:
// the library does not write files of its own).

#include <Eigen/Core>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "tactus/sim/mesh.h"

namespace tactus::sim {

/// A named 3-vector per node for writeVtu's point data (e.g. "reaction_force").
using NamedPointVectors = std::pair<std::string, Eigen::Matrix3Xd>;

/// Writes one VTK XML unstructured grid (.vtu, ASCII): the mesh at positions `positions`
/// (3 x n), with point data "displacement" (3 x n, may be empty) and cell data "von_mises"
/// (one per tet, may be empty). `volume_ratio` (det F per tet, may be empty) adds the cell
/// fields "volume_ratio" and "inverted" (UInt8, 1 where det F <= 0). Throws tactus::Error on
/// I/O failure. `point_vectors` adds more point data (3 x n each).
void writeVtu(const std::filesystem::path& path, const TetMesh& mesh,
              const Eigen::Matrix3Xd& positions, const Eigen::Matrix3Xd& displacement,
              const Eigen::VectorXd& von_mises,
              const Eigen::VectorXd& volume_ratio = Eigen::VectorXd(),
              const std::vector<NamedPointVectors>& point_vectors = {});

/// Writes a ParaView collection (.pvd) listing `files` (relative to the .pvd) at `times_s`.
void writePvd(const std::filesystem::path& path, const std::vector<std::string>& files,
              const std::vector<double>& times_s);

}  // namespace tactus::sim
