// Scene loading: YAML -> SceneSpec with complete validation. Every problem is collected (with
// file, line, column and field path) and reported at once in one SceneError.

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <set>
#include <sstream>
#include <tuple>

#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/scene.h"
// the contact problem's size limit (max_contacts)
#include "tactus/shared/segment.h"

namespace tactus::sim {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
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
/// Largest shared-memory segment / contact problem sim_server sets up (W is rows x rows doubles).
constexpr std::size_t kMaxContactProblemBytes = std::size_t{2} << 30;

std::string kindOf(const YAML::Node& n) {
  switch (n.Type()) {
    case YAML::NodeType::Map: return "a map";
    case YAML::NodeType::Sequence: return "a list";
    case YAML::NodeType::Null: return "nothing";
    case YAML::NodeType::Scalar: return "'" + shared::printable(n.Scalar()) + "'";
    default: return "nothing";
  }
}

/// Rotation from XYZ Euler angles in degrees: R = Rz * Ry * Rx (x applied first).
Eigen::Quaterniond eulerXyzDeg(const Eigen::Vector3d& deg) {
  const Eigen::Vector3d r = deg * kDegToRad;
  return Eigen::Quaterniond(Eigen::AngleAxisd(r.z(), Eigen::Vector3d::UnitZ()) *
                            Eigen::AngleAxisd(r.y(), Eigen::Vector3d::UnitY()) *
                            Eigen::AngleAxisd(r.x(), Eigen::Vector3d::UnitX()));
}

class SceneParser {
 public:
  SceneParser(std::string name, std::filesystem::path base_dir)
      : name_(shared::printable(name, 256)), base_dir_(std::move(base_dir)) {}

  SceneSpec parse(const std::string& yaml) {
    SceneSpec spec;
    spec.source = name_;
    YAML::Node root;
    try {
      root = YAML::Load(yaml);
    } catch (const YAML::Exception& e) {
      throw SceneError(fmt::format("{}:{}:{}: YAML syntax error: {}", name_,
                                   std::max(1, e.mark.line + 1), std::max(1, e.mark.column + 1),
                                   shared::printable(e.msg, 200)));
    }
    if (!root.IsMap()) {
      throw SceneError(fmt::format("{}:1:1: scene: must be a map of settings (got {})", name_,
                                   kindOf(root)));
    }
    try {
      readRoot(root, &spec);
    } catch (const YAML::Exception& e) {
      // defensive: accessors above check types first, so this means a yaml-cpp surprise
      error(root, "scene", "cannot be read: " + shared::printable(e.what(), 200));
    }
    if (!errors_.empty()) {
      std::stable_sort(errors_.begin(), errors_.end(), [](const Problem& a, const Problem& b) {
        return std::tie(a.line, a.column) < std::tie(b.line, b.column);
      });
      std::string message;
      for (const Problem& p : errors_) {
        if (!message.empty()) message += '\n';
        message += p.text;
      }
      throw SceneError(message);
    }
    std::stable_sort(warnings_.begin(), warnings_.end(), [](const Problem& a, const Problem& b) {
      return std::tie(a.line, a.column) < std::tie(b.line, b.column);
    });
    for (const Problem& p : warnings_) spec.warnings.push_back(p.text);
    return spec;
  }

 private:
  struct Problem {
    int line;
    int column;
    std::string text;
  };

  void warning(const YAML::Node& at, const std::string& path, const std::string& what) {
    const YAML::Mark m = at.Mark();
    const int line = std::max(1, m.line + 1);
    const int column = std::max(1, m.column + 1);
    warnings_.push_back({line, column, fmt::format("{}:{}:{}: {}: {}", name_, line, column, path,
                                                   what)});
  }

  // Warns when a valid value lies outside its plausible range.
  void plausible(const YAML::Node& at, const std::string& path, double v, Range usual) {
    if (!usual.contains(v)) {
      warning(at, path, fmt::format("unusual value {} (plausible: {}); check the units", v,
                                    usual.describe().substr(std::string("must be ").size())));
    }
  }

  void error(const YAML::Node& at, const std::string& path, const std::string& what) {
    const YAML::Mark m = at.Mark();
    const int line = std::max(1, m.line + 1);
    const int column = std::max(1, m.column + 1);
    // messages quote file content: no control bytes, bounded length (shared::printable)
    errors_.push_back({line, column, fmt::format("{}:{}:{}: {}: {}", name_, line, column, path,
                                                 shared::printable(what, 1000))});
  }

  static std::string join(const std::string& path, const std::string& key) {
    return path.empty() ? key : path + "." + key;
  }

  // Unknown and duplicate keys of a map.
  void checkKeys(const YAML::Node& map, const std::string& path,
                 std::initializer_list<const char*> allowed) {
    std::set<std::string> seen;
    for (const auto& entry : map) {
      const YAML::Node key = entry.first;  // a copy: the iterator's pair is a temporary
      if (!key.IsScalar()) {
        error(key, path, "keys must be plain names");
        continue;
      }
      const std::string k = shared::printable(key.Scalar());
      if (std::find_if(allowed.begin(), allowed.end(),
                       [&](const char* a) { return k == a; }) == allowed.end()) {
        std::string list;
        for (const char* a : allowed) list += (list.empty() ? "" : ", ") + std::string(a);
        error(key, join(path, k), "unknown key (expected one of: " + list + ")");
      } else if (!seen.insert(k).second) {
        error(key, join(path, k), "duplicate key");
      }
    }
  }

  // A sub-map, or nothing. Reports a present non-map value.
  bool section(const YAML::Node& map, const std::string& path, const char* key,
               YAML::Node* out) {
    const YAML::Node n = map[key];
    if (!n.IsDefined()) return false;
    if (!n.IsMap()) {
      error(n, join(path, key), "must be a map (got " + kindOf(n) + ")");
      return false;
    }
    *out = n;
    return true;
  }

  bool parseNumber(const YAML::Node& n, const std::string& path, double* out) {
    double v = 0.0;
    if (!n.IsScalar() || !YAML::convert<double>::decode(n, v) || !std::isfinite(v)) {
      error(n, path, "must be a number (got " + kindOf(n) + ")");
      return false;
    }
    *out = v;
    return true;
  }

  // Optional number with a range; `out` is left unchanged when absent or invalid.
  // `usual`: the plausible range (a warning outside it).
  // `range`: what the field means; `hard`: physically possible (both errors outside).
  bool number(const YAML::Node& map, const std::string& path, const char* key, double* out,
              Range range = kAny, Range hard = kAny, Range usual = kAny) {
    const YAML::Node n = map[key];
    if (!n.IsDefined()) return false;
    double v = 0.0;
    if (!parseNumber(n, join(path, key), &v)) return false;
    if (!range.contains(v)) {
      error(n, join(path, key), fmt::format("{} (got {})", range.describe(), v));
      return false;
    }
    if (!hard.contains(v)) {
      error(n, join(path, key), fmt::format("{} (got {}): not a physically sensible value",
                                            hard.describe(), v));
      return false;
    }
    plausible(n, join(path, key), v, usual);
    *out = v;
    return true;
  }

  // At most `max_value` (error above), plausible up to `usual_max` (warning above).
  bool integer(const YAML::Node& map, const std::string& path, const char* key, int* out,
               int min_value, int max_value = std::numeric_limits<int>::max(),
               int usual_max = std::numeric_limits<int>::max()) {
    const YAML::Node n = map[key];
    if (!n.IsDefined()) return false;
    long long v = 0;
    if (!n.IsScalar() || !YAML::convert<long long>::decode(n, v)) {
      error(n, join(path, key), "must be an integer (got " + kindOf(n) + ")");
      return false;
    }
    if (v < min_value) {
      error(n, join(path, key), fmt::format("must be >= {} (got {})", min_value, v));
      return false;
    }
    if (v > max_value) {
      error(n, join(path, key), fmt::format("must be in [{}, {}] (got {})", min_value, max_value, v));
      return false;
    }
    if (v > usual_max) {
      warning(n, join(path, key), fmt::format("unusual value {} (plausible: [{}, {}])", v,
                                              min_value, usual_max));
    }
    *out = static_cast<int>(v);
    return true;
  }

  bool boolean(const YAML::Node& map, const std::string& path, const char* key, bool* out) {
    const YAML::Node n = map[key];
    if (!n.IsDefined()) return false;
    bool v = false;
    if (!n.IsScalar() || !YAML::convert<bool>::decode(n, v)) {
      error(n, join(path, key), "must be true or false (got " + kindOf(n) + ")");
      return false;
    }
    *out = v;
    return true;
  }

  bool string(const YAML::Node& map, const std::string& path, const char* key,
              std::string* out) {
    const YAML::Node n = map[key];
    if (!n.IsDefined()) return false;
    if (!n.IsScalar() || n.Scalar().empty()) {
      error(n, join(path, key), "must be a non-empty string (got " + kindOf(n) + ")");
      return false;
    }
    *out = n.Scalar();
    return true;
  }

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

  void require(const YAML::Node& map, const std::string& path, const char* key) {
    if (!map[key].IsDefined()) error(map, join(path, key), "is required");
  }

  std::filesystem::path resolve(const std::string& p) const {
    std::filesystem::path path(p);
    if (path.is_relative()) path = base_dir_ / path;
    return std::filesystem::absolute(path).lexically_normal();
  }

  // Orientation from rotation_deg (XYZ Euler) or quaternion [w, x, y, z]; identity if neither.
  void orientation(const YAML::Node& map, const std::string& path, Eigen::Quaterniond* out) {
    const bool has_euler = map["rotation_deg"].IsDefined();
    const bool has_quat = map["quaternion"].IsDefined();
    if (has_euler && has_quat) {
      error(map["quaternion"], join(path, "quaternion"),
            "give either rotation_deg or quaternion, not both");
      return;
    }
    Eigen::Vector3d deg;
    if (vector<3>(map, path, "rotation_deg", &deg)) *out = eulerXyzDeg(deg);
    Eigen::Vector4d q;
    if (vector<4>(map, path, "quaternion", &q)) {
      const double norm = q.norm();
      if (std::abs(norm - 1.0) > 1e-3) {
        error(map["quaternion"], join(path, "quaternion"),
              fmt::format("must be a unit quaternion [w, x, y, z] (norm is {:.6g})", norm));
      } else {
        *out = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized();
      }
    }
  }

  void readRoot(const YAML::Node& root, SceneSpec* spec) {
    checkKeys(root, "", {"time_step", "duration", "gravity", "tissues", "instrument", "solver",
                         "haptics", "output"});
    require(root, "", "time_step");
    number(root, "", "time_step", &spec->time_step_s, kPositive, kAtMost(1.0), Range{1e-5, 0.05});
    number(root, "", "duration", &spec->duration_s, kNonNegative, kAtMost(1e7), Range{0.0, 86400.0});
    Eigen::Vector3d g;
    if (vector<3>(root, "", "gravity", &g, kSymmetric(1e3), kSymmetric(20.0))) {
      spec->gravity_mps2 = g;
    }
    readTissues(root, spec);
    YAML::Node n;
    if (section(root, "", "instrument", &n)) readInstrument(n, &spec->instrument);
    if (section(root, "", "solver", &n)) readSolver(n, &spec->solver);
    if (section(root, "", "haptics", &n)) readHaptics(n, &spec->haptics);
    if (section(root, "", "output", &n)) readOutput(n, &spec->output);
  }

  void readTissues(const YAML::Node& root, SceneSpec* spec) {
    const YAML::Node list = root["tissues"];
    if (!list.IsDefined()) {
      error(root, "tissues", "is required (a list with at least one tissue)");
      return;
    }
    if (!list.IsSequence() || list.size() == 0) {
      error(list, "tissues", "must be a list with at least one tissue (got " +
                                 (list.IsSequence() ? std::string("an empty list")
                                                    : kindOf(list)) + ")");
      return;
    }
    std::set<std::string> names;
    for (std::size_t i = 0; i < list.size(); ++i) {
      const YAML::Node t = list[i];
      const std::string path = fmt::format("tissues[{}]", i);
      if (!t.IsMap()) {
        error(t, path, "must be a map (got " + kindOf(t) + ")");
        continue;
      }
      TissueSpec tissue;
      if (list.size() > 1) tissue.name = fmt::format("tissue{}", i);
      readTissue(t, path, &tissue);
      if (!names.insert(tissue.name).second) {
        error(t["name"].IsDefined() ? t["name"] : t, join(path, "name"),
              "duplicate tissue name '" + tissue.name + "'");
      }
      spec->tissues.push_back(std::move(tissue));
    }
  }

  void readTissue(const YAML::Node& t, const std::string& path, TissueSpec* tissue) {
    checkKeys(t, path, {"name", "mesh", "transform", "material", "damping", "fixed",
                        "compliance"});
    string(t, path, "name", &tissue->name);
    require(t, path, "mesh");
    std::string mesh;
    if (string(t, path, "mesh", &mesh)) {
      tissue->mesh_path = resolve(mesh);
      std::error_code ec;
      const auto status = std::filesystem::status(tissue->mesh_path, ec);
      const std::string shown = shared::printable(tissue->mesh_path.string(), 256);
      if (std::filesystem::is_directory(status)) {
        error(t["mesh"], join(path, "mesh"), "mesh file " + shown + " is a directory");
      } else if (std::filesystem::exists(status) && !std::filesystem::is_regular_file(status)) {
        error(t["mesh"], join(path, "mesh"),
              "mesh file " + shown + " is not a regular file (a FIFO, socket or device)");
      } else if (!std::filesystem::is_regular_file(status)) {
        error(t["mesh"], join(path, "mesh"),
              "mesh file not found: " + shown +
                  " (relative paths are resolved against the scene file's folder)");
      }
    }
    YAML::Node n;
    if (section(t, path, "transform", &n)) {
      const std::string p = join(path, "transform");
      checkKeys(n, p, {"scale", "rotation_deg", "translation"});
      number(n, p, "scale", &tissue->scale, kPositive, Range{1e-9, 1e6}, Range{1e-4, 1e3});
      vector<3>(n, p, "rotation_deg", &tissue->rotation_deg, kSymmetric(1e6), kSymmetric(360.0));
      vector<3>(n, p, "translation", &tissue->translation_m, kCoordinate, kUsualCoordinate);
    }
    if (section(t, path, "material", &n)) {
      const std::string p = join(path, "material");
      checkKeys(n, p, {"law", "young_modulus", "poisson_ratio", "density"});
      choice(n, p, "law", &tissue->law,
             {{"linear", MaterialLaw::kLinear}, {"corotational", MaterialLaw::kCorotational}});
      number(n, p, "young_modulus", &tissue->young_pa, kPositive, kAtMost(1e12), Range{10.0, 1e9});
      number(n, p, "poisson_ratio", &tissue->poisson, Range{-1.0, 0.5, true, true});
      number(n, p, "density", &tissue->density_kgpm3, kPositive, kAtMost(1e5), Range{100.0, 1e4});
    }
    if (section(t, path, "damping", &n)) {
      const std::string p = join(path, "damping");
      checkKeys(n, p, {"rayleigh_mass", "rayleigh_stiffness"});
      RayleighSpec r;
      number(n, p, "rayleigh_mass", &r.mass_alpha_per_s, kNonNegative, kAtMost(1e6),
             kNonNegativeUpTo(1e3));
      number(n, p, "rayleigh_stiffness", &r.stiffness_beta_s, kNonNegative, kAtMost(10.0),
             kNonNegativeUpTo(1.0));
      tissue->damping = r;
    }
    if (section(t, path, "fixed", &n)) readFixed(n, join(path, "fixed"), tissue);
    if (section(t, path, "compliance", &n)) {
      const std::string p = join(path, "compliance");
      checkKeys(n, p, {"model", "cache_dir", "correction", "c0_precision",
                       "exact_below_coherence"});
      choice(n, p, "model", &tissue->compliance,
             {{"exact", ComplianceKind::kExact}, {"warped", ComplianceKind::kWarped},
              {"rest", ComplianceKind::kRest}, {"uncoupled", ComplianceKind::kUncoupled}});
      std::string dir;
      if (string(n, p, "cache_dir", &dir)) tissue->compliance_cache_dir = resolve(dir);
      choice(n, p, "correction", &tissue->exact_correction, {{"model", false}, {"exact", true}});
      choice(n, p, "c0_precision", &tissue->c0_single_precision,
             {{"double", false}, {"float", true}});
      number(n, p, "exact_below_coherence", &tissue->exact_below_coherence, kNonNegative,
             kAtMost(1.0), kNonNegativeUpTo(1.0));
    }
  }

  void readFixed(const YAML::Node& f, const std::string& path, TissueSpec* tissue) {
    checkKeys(f, path, {"nodes", "boxes"});
    const YAML::Node nodes = f["nodes"];
    if (nodes.IsDefined()) {
      if (!nodes.IsSequence()) {
        error(nodes, join(path, "nodes"), "must be a list of node indices (got " +
                                              kindOf(nodes) + ")");
      } else {
        for (std::size_t i = 0; i < nodes.size(); ++i) {
          const YAML::Node v = nodes[i];
          long long idx = 0;
          const std::string p = fmt::format("{}.nodes[{}]", path, i);
          if (!v.IsScalar() || !YAML::convert<long long>::decode(v, idx)) {
            error(v, p, "must be an integer node index (got " + kindOf(v) + ")");
          } else if (idx < 0 || idx > std::numeric_limits<int>::max()) {
            error(v, p, fmt::format("must be >= 0 (got {})", idx));
          } else {
            tissue->fixed_nodes.push_back(static_cast<int>(idx));
          }
        }
      }
    }
    const YAML::Node boxes = f["boxes"];
    if (boxes.IsDefined()) {
      if (!boxes.IsSequence()) {
        error(boxes, join(path, "boxes"), "must be a list of {min, max} boxes (got " +
                                              kindOf(boxes) + ")");
        return;
      }
      for (std::size_t i = 0; i < boxes.size(); ++i) {
        const YAML::Node b = boxes[i];
        const std::string p = fmt::format("{}.boxes[{}]", path, i);
        if (!b.IsMap()) {
          error(b, p, "must be a map {min: [x, y, z], max: [x, y, z]} (got " + kindOf(b) + ")");
          continue;
        }
        checkKeys(b, p, {"min", "max"});
        require(b, p, "min");
        require(b, p, "max");
        BoxSpec box;
        const bool ok_min = vector<3>(b, p, "min", &box.min_m, kCoordinate);
        const bool ok_max = vector<3>(b, p, "max", &box.max_m, kCoordinate);
        if (ok_min && ok_max) {
          if ((box.min_m.array() > box.max_m.array()).any()) {
            error(b["max"], join(p, "max"), "must be >= min in every coordinate");
          } else {
            tissue->fixed_boxes.push_back(box);
          }
        }
      }
    }
  }

  void readPose(const YAML::Node& map, const std::string& path, PoseSpec* pose) {
    vector<3>(map, path, "position", &pose->position_m, kCoordinate, kUsualCoordinate);
    orientation(map, path, &pose->orientation);
  }

  void readInstrument(const YAML::Node& n, InstrumentSpec* in) {
    const std::string p = "instrument";
    in->present = true;
    checkKeys(n, p, {"type", "mass", "inertia", "coupling", "friction", "alarm_distance",
                     "contact_distance", "face_contacts", "contact_compliance", "probe",
                     "grasper", "initial_pose", "trajectory", "workspace"});
    choice(n, p, "type", &in->kind,
           {{"probe", InstrumentKind::kProbe}, {"grasper", InstrumentKind::kGrasper}});
    number(n, p, "mass", &in->mass_kg, kPositive, kAtMost(1e3), Range{1e-4, 10.0});
    number(n, p, "inertia", &in->inertia_kgm2, kPositive, kAtMost(1e3), kPositiveUpTo(1.0));
    number(n, p, "friction", &in->friction_mu, kNonNegative, kAtMost(100.0), kNonNegativeUpTo(2.0));
    number(n, p, "alarm_distance", &in->alarm_distance_m, kNonNegative, kAtMost(1.0),
           kNonNegativeUpTo(0.05));
    number(n, p, "contact_distance", &in->contact_distance_m, kNonNegative, kAtMost(1.0),
           kNonNegativeUpTo(0.01));
    boolean(n, p, "face_contacts", &in->face_contacts);
    number(n, p, "contact_compliance", &in->contact_compliance_mpn, kNonNegative, kAtMost(1.0),
           kNonNegativeUpTo(1e-2));
    YAML::Node s;
    if (section(n, p, "coupling", &s)) {
      const std::string q = join(p, "coupling");
      checkKeys(s, q, {"stiffness", "damping", "rotational_stiffness", "rotational_damping"});
      number(s, q, "stiffness", &in->coupling_k_npm, kPositive, kAtMost(1e9), Range{1.0, 1e6});
      number(s, q, "damping", &in->coupling_b_nspm, kNonNegative, kAtMost(1e7), kNonNegativeUpTo(1e4));
      number(s, q, "rotational_stiffness", &in->coupling_k_rot_nmprad, kNonNegative, kAtMost(1e7),
             kNonNegativeUpTo(1e4));
      number(s, q, "rotational_damping", &in->coupling_b_rot_nmsprad, kNonNegative, kAtMost(1e5),
             kNonNegativeUpTo(1e2));
    }
    if (section(n, p, "probe", &s)) {
      const std::string q = join(p, "probe");
      checkKeys(s, q, {"tip_radius", "shaft_length"});
      number(s, q, "tip_radius", &in->tip_radius_m, kPositive, kAtMost(1.0), Range{1e-5, 0.05});
      number(s, q, "shaft_length", &in->shaft_length_m, kNonNegative, kAtMost(10.0),
             kNonNegativeUpTo(1.0));
    }
    if (section(n, p, "grasper", &s)) {
      const std::string q = join(p, "grasper");
      checkKeys(s, q, {"jaw_length", "jaw_radius", "max_opening_deg", "samples", "width",
                       "width_samples", "pad_width", "pad_columns", "grip_stiffness", "grip_damping",
                       "grip_inertia"});
      number(s, q, "jaw_length", &in->jaw_length_m, kPositive, kAtMost(1.0), Range{1e-4, 0.2});
      number(s, q, "jaw_radius", &in->jaw_radius_m, kPositive, kAtMost(0.5), Range{1e-5, 0.02});
      double deg = 0.0;
      if (number(s, q, "max_opening_deg", &deg, Range{0.0, 90.0, true, false})) {
        in->max_opening_rad = deg * kDegToRad;
      }
      integer(s, q, "samples", &in->jaw_samples, 1, 10000, 200);
      number(s, q, "width", &in->jaw_width_m, kNonNegative, kAtMost(1.0), kNonNegativeUpTo(0.05));
      integer(s, q, "width_samples", &in->jaw_rows, 1, 1000, 20);
      number(s, q, "pad_width", &in->pad_width_m, kNonNegative, kAtMost(1.0), kNonNegativeUpTo(0.05));
      integer(s, q, "pad_columns", &in->pad_columns, 1, 1000, 20);
      number(s, q, "grip_stiffness", &in->grip_k_nmprad, kNonNegative, kAtMost(1e6),
             kNonNegativeUpTo(1e3));
      number(s, q, "grip_damping", &in->grip_b_nmsprad, kNonNegative, kAtMost(1e4),
             kNonNegativeUpTo(10.0));
      number(s, q, "grip_inertia", &in->grip_inertia_kgm2, kPositive, kAtMost(1.0),
             kPositiveUpTo(1e-2));
    }
    if (section(n, p, "initial_pose", &s)) {
      const std::string q = join(p, "initial_pose");
      checkKeys(s, q, {"position", "rotation_deg", "quaternion"});
      readPose(s, q, &in->initial_pose);
    }
    const YAML::Node traj = n["trajectory"];
    if (traj.IsDefined()) readTrajectory(traj, join(p, "trajectory"), in);
    if (section(n, p, "workspace", &s)) {
      const std::string q = join(p, "workspace");
      checkKeys(s, q, {"min", "max"});
      require(s, q, "min");
      require(s, q, "max");
      BoxSpec box;
      const bool ok_min = vector<3>(s, q, "min", &box.min_m, kCoordinate, kUsualCoordinate);
      const bool ok_max = vector<3>(s, q, "max", &box.max_m, kCoordinate, kUsualCoordinate);
      if (ok_min && ok_max) {
        if ((box.min_m.array() > box.max_m.array()).any()) {
          error(s["max"], join(q, "max"), "must be >= min in every coordinate");
        } else {
          in->workspace = box;
        }
      }
    }
  }

  void readTrajectory(const YAML::Node& list, const std::string& path, InstrumentSpec* in) {
    if (!list.IsSequence()) {
      error(list, path, "must be a list of keys {t, position, ...} (got " + kindOf(list) + ")");
      return;
    }
    double previous_t = -kInf;
    for (std::size_t i = 0; i < list.size(); ++i) {
      const YAML::Node k = list[i];
      const std::string p = fmt::format("{}[{}]", path, i);
      if (!k.IsMap()) {
        error(k, p, "must be a map {t, position, rotation_deg|quaternion, gripper} (got " +
                        kindOf(k) + ")");
        continue;
      }
      checkKeys(k, p, {"t", "position", "rotation_deg", "quaternion", "gripper"});
      require(k, p, "t");
      require(k, p, "position");
      TrajectoryKey key;
      if (number(k, p, "t", &key.t_s, kNonNegative, kAtMost(1e7), Range{0.0, 86400.0})) {
        if (key.t_s <= previous_t) {
          error(k["t"], join(p, "t"),
                fmt::format("must be greater than the previous key's t ({})", previous_t));
        }
        previous_t = key.t_s;
      }
      readPose(k, p, &key.pose);
      number(k, p, "gripper", &key.gripper_opening, Range{0.0, 1.0, false, false});
      in->trajectory.push_back(key);
    }
  }

  void readSolver(const YAML::Node& n, SolverSpec* s) {
    const std::string p = "solver";
    checkKeys(n, p, {"linear", "cg_tolerance", "cg_max_iterations", "refactor_iterations",
                     "refactor_every_steps", "nsgs_tolerance",
                     "nsgs_max_sweeps", "nsgs_sor", "max_contacts", "contact_iterations",
                     "penetration_tolerance", "contact_detection"});
    choice(n, p, "linear", &s->linear,
           {{"cholmod", LinearSolverKind::kCholmod},
            {"pcg", LinearSolverKind::kPcg},
            {"cholmod_reuse", LinearSolverKind::kCholmodReuse}});
    number(n, p, "cg_tolerance", &s->cg_tolerance, kPositive, Range{-kInf, 1.0, false, true},
           kPositiveUpTo(1e-2));
    integer(n, p, "cg_max_iterations", &s->cg_max_iterations, 1, 100'000'000, 1'000'000);
    integer(n, p, "refactor_iterations", &s->refactor_iterations, 1, 10'000, 1'000);
    integer(n, p, "refactor_every_steps", &s->refactor_every_steps, 0, 100'000'000, 1'000'000);
    number(n, p, "nsgs_tolerance", &s->nsgs_tolerance, kPositive, Range{-kInf, 1.0, false, true},
           kPositiveUpTo(1e-2));
    integer(n, p, "nsgs_max_sweeps", &s->nsgs_max_sweeps, 1, 10'000'000, 100'000);
    number(n, p, "nsgs_sor", &s->nsgs_sor, Range{0.0, 2.0, true, true});
    // the contact problem's W (rows x rows doubles, 3 rows per frictional contact) lives in
    // the shared segment's triple buffer: refuse what cannot be allocated, before trying
    if (integer(n, p, "max_contacts", &s->max_contacts, 1, std::numeric_limits<int>::max(),
                2000)) {
      // (the layout is computed only for counts whose row count fits an int)
      const std::size_t bytes =
          s->max_contacts > 1'000'000
              ? std::numeric_limits<std::size_t>::max()
              : shared::SegmentLayout::forCapacity(
                    shared::SegmentCapacity::forContacts(s->max_contacts))
                    .total_bytes;
      if (bytes > kMaxContactProblemBytes) {
        error(n["max_contacts"], join(p, "max_contacts"),
              fmt::format("{} contacts need {} MiB for the contact problem (W is rows x rows "
                          "doubles, 3 rows per contact), more than the {} MiB limit: lower it "
                          "(at most about 3000)",
                          s->max_contacts,
                          s->max_contacts > 1'000'000 ? std::string("too many")
                                                      : std::to_string(bytes >> 20),
                          kMaxContactProblemBytes >> 20));
        s->max_contacts = SolverSpec{}.max_contacts;
      }
    }
    integer(n, p, "contact_iterations", &s->contact_iterations, 1, 1000, 20);
    number(n, p, "penetration_tolerance", &s->penetration_tolerance_m, kPositive, kAtMost(1.0),
           kPositiveUpTo(0.01));
    choice(n, p, "contact_detection", &s->contact_detection,
           {{"free_state", ContactDetection::kFreeState},
            {"step_start", ContactDetection::kStepStart}});
  }

  void readHaptics(const YAML::Node& n, HapticsSpec* h) {
    const std::string p = "haptics";
    checkKeys(n, p, {"enabled", "rate", "device", "force_scale", "max_force", "watchdog_ms",
                     "max_sweeps_per_tick", "nsgs_tolerance"});
    h->enabled = true;  // a haptics section turns haptics on unless it says otherwise
    boolean(n, p, "enabled", &h->enabled);
    number(n, p, "rate", &h->rate_hz, kPositive, kAtMost(1e5), Range{100.0, 1e4});
    string(n, p, "device", &h->device);
    number(n, p, "force_scale", &h->force_scale, kNonNegative, kAtMost(1e3), kNonNegativeUpTo(10.0));
    number(n, p, "max_force", &h->max_force_n, kPositive, kAtMost(1e3), kPositiveUpTo(40.0));
    number(n, p, "watchdog_ms", &h->watchdog_ms, kPositive, kAtMost(1e5), kPositiveUpTo(1e3));
    integer(n, p, "max_sweeps_per_tick", &h->max_sweeps_per_tick, 1, 1'000'000, 10'000);
    number(n, p, "nsgs_tolerance", &h->nsgs_tolerance, kPositive, Range{-kInf, 1.0, false, true},
           kPositiveUpTo(1e-2));
  }

  void readOutput(const YAML::Node& n, OutputSpec* o) {
    const std::string p = "output";
    checkKeys(n, p, {"vtk", "every"});
    require(n, p, "vtk");
    std::string dir;
    if (string(n, p, "vtk", &dir)) {
      o->enabled = true;
      o->directory = dir;
    }
    integer(n, p, "every", &o->every_n_steps, 1, std::numeric_limits<int>::max(), 1'000'000);
  }

  std::string name_;
  std::filesystem::path base_dir_;
  std::vector<Problem> errors_;
  std::vector<Problem> warnings_;
};

}  // namespace

SceneSpec parseScene(const std::string& yaml, const std::string& name,
                     const std::filesystem::path& base_dir) {
  SceneSpec spec = SceneParser(name, base_dir).parse(yaml);
  for (const std::string& w : spec.warnings) spdlog::warn("{}", w);
  return spec;
}

SceneSpec loadScene(const std::filesystem::path& path) {
  std::string text;
  try {
    text = shared::readTextFileChecked(path, "scene file", shared::kMaxSceneBytes);
  } catch (const FileError& e) {
    throw SceneError(e.what());
  }
  const std::filesystem::path dir =
      path.has_parent_path() ? path.parent_path() : std::filesystem::path(".");
  SceneSpec spec = parseScene(text, path.string(), dir);
  spec.source = path;
  return spec;
}

}  // namespace tactus::sim
