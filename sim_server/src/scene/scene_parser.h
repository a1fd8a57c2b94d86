#pragma once
// Private to the scene module: the scene parser shared by its source files.
//   scene_values.cpp      YAML node helpers: typed accessors with range checks, errors, warnings
//   scene_tissue.cpp      the tissues section
//   scene_instrument.cpp  the instrument section (tool, grasper, pose, trajectory, workspace)
//   scene_regions.cpp     node regions (fixed.regions, loads)
//   scene_obstacles.cpp   the obstacles and obstacle_contact sections
//   scene_loader.cpp      the root, solver, haptics and output sections; parseScene, loadScene
// Every problem is collected with file:line:col and field path and reported at once.

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <initializer_list>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "tactus/shared/file_io.h"
#include "tactus/sim/scene.h"

namespace tactus::sim::scene_detail {

constexpr double kInf = std::numeric_limits<double>::infinity();
/// Largest shared-memory segment / contact problem sim_server sets up (W is rows x rows doubles).
constexpr std::size_t kMaxContactProblemBytes = std::size_t{2} << 30;
constexpr double kDegToRad = 3.14159265358979323846 / 180.0;

/// Allowed interval of a number; open ends are strict.
struct Range {
  double lo = -kInf;
  double hi = kInf;
  bool lo_open = false;
  bool hi_open = false;

  bool contains(double v) const {
    return (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
  }
  std::string describe() const {
    if (std::isinf(hi)) return fmt::format("must be {} {}", lo_open ? ">" : ">=", lo);
    if (std::isinf(lo)) return fmt::format("must be {} {}", hi_open ? "<" : "<=", hi);
    return fmt::format("must be in {}{}, {}{}", lo_open ? "(" : "[", lo, hi, hi_open ? ")" : "]");
  }
};
constexpr Range kPositive{0.0, kInf, true, false};
constexpr Range kNonNegative{0.0, kInf, false, false};
constexpr Range kAny{};
/// A friction coefficient's hard range (the obstacles' and the tissue pairs').
constexpr Range kFriction{0.0, 100.0};

// Physical sanity (scenes/README.md "Value ranges"): a value outside its hard range is an error
// (impossible, or it would exhaust memory or time); outside its plausible range, a warning.
constexpr Range kAtMost(double hi) { return Range{-kInf, hi, false, false}; }
constexpr Range kPositiveUpTo(double hi) { return Range{0.0, hi, true, false}; }
constexpr Range kNonNegativeUpTo(double hi) { return Range{0.0, hi, false, false}; }
constexpr Range kSymmetric(double bound) { return Range{-bound, bound, false, false}; }
constexpr double kMaxCoordinateM = 1e3;      ///< any position or length in a scene [m]
constexpr double kUsualCoordinateM = 10.0;   ///< a surgical scene fits in a few metres
constexpr Range kCoordinate = kSymmetric(kMaxCoordinateM);
constexpr Range kUsualCoordinate = kSymmetric(kUsualCoordinateM);

/// How a node is shown in a message ("a map", "'text'", ...).
std::string kindOf(const YAML::Node& n);

/// Rotation from XYZ Euler angles in degrees: R = Rz * Ry * Rx (x applied first).
Eigen::Quaterniond eulerXyzDeg(const Eigen::Vector3d& deg);

class SceneParser {
 public:
  SceneParser(std::string name, std::filesystem::path base_dir)
      : name_(shared::printable(name, 256)), base_dir_(std::move(base_dir)) {}

  SceneSpec parse(const std::string& yaml);

 private:
  struct Problem {
    int line;
    int column;
    std::string text;
  };

  // --- node helpers (scene_values.cpp) ---
  void warning(const YAML::Node& at, const std::string& path, const std::string& what);
  // Warns when a valid value lies outside its plausible range.
  void plausible(const YAML::Node& at, const std::string& path, double v, Range usual);
  void error(const YAML::Node& at, const std::string& path, const std::string& what);
  static std::string join(const std::string& path, const std::string& key);
  // Unknown and duplicate keys of a map.
  void checkKeys(const YAML::Node& map, const std::string& path,
                 std::initializer_list<const char*> allowed);
  // A sub-map, or nothing. Reports a present non-map value.
  bool section(const YAML::Node& map, const std::string& path, const char* key,
               YAML::Node* out);
  bool parseNumber(const YAML::Node& n, const std::string& path, double* out);
  // Optional number with a range; `out` is left unchanged when absent or invalid.
  // `usual`: the plausible range (a warning outside it).
  // `range`: what the field means; `hard`: physically possible (both errors outside).
  bool number(const YAML::Node& map, const std::string& path, const char* key, double* out,
              Range range = kAny, Range hard = kAny, Range usual = kAny);
  // At most `max_value` (error above), plausible up to `usual_max` (warning above).
  bool integer(const YAML::Node& map, const std::string& path, const char* key, int* out,
               int min_value, int max_value = std::numeric_limits<int>::max(),
               int usual_max = std::numeric_limits<int>::max());
  bool boolean(const YAML::Node& map, const std::string& path, const char* key, bool* out);
  bool string(const YAML::Node& map, const std::string& path, const char* key,
              std::string* out);
  template <class Enum>
  bool choice(const YAML::Node& map, const std::string& path, const char* key, Enum* out,
              std::initializer_list<std::pair<const char*, Enum>> options) {
    std::string s;
    const YAML::Node n = map[key];
    if (!n.IsDefined()) return false;
    std::string list;
    for (const auto& [text, value] : options) {
      list += (list.empty() ? "" : ", ") + std::string(text);
      if (n.IsScalar() && n.Scalar() == text) {
        *out = value;
        return true;
      }
    }
    error(n, join(path, key), "must be one of " + list + " (got " + kindOf(n) + ")");
    return false;
  }

  // Each component within `range` (error) and `usual` (warning).
  template <int N>
  bool vector(const YAML::Node& map, const std::string& path, const char* key,
              Eigen::Matrix<double, N, 1>* out, Range range = kAny, Range usual = kAny) {
    const YAML::Node n = map[key];
    if (!n.IsDefined()) return false;
    if (!n.IsSequence() || n.size() != N) {
      error(n, join(path, key), fmt::format("must be a list of {} numbers (got {})", N,
                                            n.IsSequence() ? fmt::format("{} items", n.size())
                                                           : kindOf(n)));
      return false;
    }
    Eigen::Matrix<double, N, 1> v;
    bool ok = true;
    for (int i = 0; i < N; ++i) {
      const YAML::Node item = n[static_cast<std::size_t>(i)];
      const std::string item_path = fmt::format("{}[{}]", join(path, key), i);
      if (!parseNumber(item, item_path, &v[i])) {
        ok = false;
      } else if (!range.contains(v[i])) {
        error(item, item_path, fmt::format("{} (got {}): not a physically sensible value",
                                           range.describe(), v[i]));
        ok = false;
      } else {
        plausible(item, item_path, v[i], usual);
      }
    }
    if (ok) *out = v;
    return ok;
  }

  void require(const YAML::Node& map, const std::string& path, const char* key);
  std::filesystem::path resolve(const std::string& p) const;
  // Orientation from rotation_deg (XYZ Euler) or quaternion [w, x, y, z]; identity if neither.
  void orientation(const YAML::Node& map, const std::string& path, Eigen::Quaterniond* out);
  void readPose(const YAML::Node& map, const std::string& path, PoseSpec* pose);

  // --- sections ---
  void readRoot(const YAML::Node& root, SceneSpec* spec);                        // scene_loader.cpp
  void readTissues(const YAML::Node& root, SceneSpec* spec);                     // scene_tissue.cpp
  void readTissue(const YAML::Node& t, const std::string& path, TissueSpec* tissue);
  void readFixed(const YAML::Node& f, const std::string& path, TissueSpec* tissue);
  // scene_regions.cpp: node regions; "file:line:col: path" of a node; a non-zero vector, normalised
  void readRegions(const YAML::Node& list, const std::string& path, std::vector<RegionSpec>* out);
  void readRegion(const YAML::Node& r, const std::string& path, RegionSpec* region);
  void readLoads(const YAML::Node& list, const std::string& path, std::vector<LoadSpec>* out);
  std::string where(const YAML::Node& at, const std::string& path) const;
  bool unitVector(const YAML::Node& map, const std::string& path, const char* key,
                  Eigen::Vector3d* out);
  void readObstacles(const YAML::Node& root, SceneSpec* spec);              // scene_obstacles.cpp
  void readTissueContacts(const YAML::Node& root, SceneSpec* spec);    // scene_tissue_contact.cpp
  bool tissueIndex(const YAML::Node& n, const std::string& p, const SceneSpec& spec, int* out);
  // The instruments' and the obstacles' contacts together must fit the segment's 2 GiB.
  void checkObstacleCapacity(const YAML::Node& root, const SceneSpec& spec);
  void readInstrument(const YAML::Node& n, const std::string& p,          // scene_instrument.cpp
                      InstrumentSpec* in);
  void readInstruments(const YAML::Node& root, SceneSpec* spec);
  void readTrajectory(const YAML::Node& list, const std::string& path, InstrumentSpec* in);
  void readSolver(const YAML::Node& n, SolverSpec* s, int instruments);        // scene_loader.cpp
  void readHaptics(const YAML::Node& n, HapticsSpec* h, int instruments);
  void readWorkspaces(const YAML::Node& n, HapticsSpec* h, int instruments);
  void readWorkspace(const YAML::Node& n, const std::string& p,
                     shared::WorkspaceMappingParams* w);
  void readOutput(const YAML::Node& n, OutputSpec* o);

  std::string name_;
  std::filesystem::path base_dir_;
  std::vector<Problem> errors_;
  std::vector<Problem> warnings_;
};

}  // namespace tactus::sim::scene_detail
