#pragma once
// A compiled model, in the manner of MuJoCo's mjModel (docs/api.md): a scene read, validated and
// compiled once (meshes loaded, scaled and placed; fixed nodes, loads and the solver settings
// derived), then never changed. Any number of Simulations run from one Model; copying a Model
// is cheap (it is shared). A saved State is tied to its model's identity.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <string_view>

namespace tactus {

namespace detail {
struct ModelData;
}

class Model {
 public:
  /// Reads, validates and compiles a scene file (scenes/README.md). Relative paths in it (meshes,
  /// compliance caches) are relative to its folder. Throws tactus::SceneError (file, line,
  /// column and field of every problem), MeshError or FileError.
  static Model fromFile(const std::filesystem::path& scene);
  /// The same from YAML text: relative paths resolve against `base_dir`; `name` stands for the
  /// file in messages and in saved states.
  static Model fromString(std::string_view yaml, const std::filesystem::path& base_dir = ".",
                          std::string_view name = "scene.yaml");

  /// The scene's file name (or the name given to fromString).
  const std::string& name() const;
  /// What a State saved from this model is tied to: a hash of the scene's text, the time step
  /// and each tissue's placed rest mesh and fixed nodes.
  std::uint64_t identity() const;
  double timeStep() const;                  ///< [s]
  double duration() const;                  ///< the scene's scripted length [s] (0: none)

  int tissueCount() const;
  const std::string& tissueName(int tissue) const;
  int nodeCount(int tissue) const;
  /// Rest positions of tissue's nodes, 3 x nodeCount [m] (placed as the scene says).
  Eigen::Map<const Eigen::Matrix3Xd> restPositions(int tissue) const;
  /// The tetrahedra, as node indices.
  std::span<const std::array<int, 4>> tetrahedra(int tissue) const;
  /// The boundary triangles (outward, counter-clockwise), as node indices: what a renderer draws.
  std::span<const std::array<int, 3>> surfaceTriangles(int tissue) const;
  /// The nodes held fixed (Dirichlet), sorted.
  std::span<const int> fixedNodes(int tissue) const;

  int instrumentCount() const;
  const std::string& instrumentName(int instrument) const;

  /// Throws std::out_of_range naming the index when a tissue or instrument does not exist.

 private:
  explicit Model(std::shared_ptr<const detail::ModelData> data);
  std::shared_ptr<const detail::ModelData> data_;
  friend class Simulation;
};

}  // namespace tactus
