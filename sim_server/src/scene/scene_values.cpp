// Scene parsing, the node helpers: typed accessors that check type and range and record every
// problem with file:line:col and the field path (errors), or a value outside its plausible range
// (warnings).

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <tuple>

#include "scene_parser.h"
#include "tactus/shared/error.h"

namespace tactus::sim::scene_detail {

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

SceneSpec SceneParser::parse(const std::string& yaml) {
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

void SceneParser::warning(const YAML::Node& at, const std::string& path, const std::string& what) {
  const YAML::Mark m = at.Mark();
  const int line = std::max(1, m.line + 1);
  const int column = std::max(1, m.column + 1);
  warnings_.push_back({line, column, fmt::format("{}:{}:{}: {}: {}", name_, line, column, path,
                                                 what)});
}

// Warns when a valid value lies outside its plausible range.
void SceneParser::plausible(const YAML::Node& at, const std::string& path, double v, Range usual) {
  if (!usual.contains(v)) {
    warning(at, path, fmt::format("unusual value {} (plausible: {}); check the units", v,
                                  usual.describe().substr(std::string("must be ").size())));
  }
}

void SceneParser::error(const YAML::Node& at, const std::string& path, const std::string& what) {
  const YAML::Mark m = at.Mark();
  const int line = std::max(1, m.line + 1);
  const int column = std::max(1, m.column + 1);
  // messages quote file content: no control bytes, bounded length (shared::printable)
  errors_.push_back({line, column, fmt::format("{}:{}:{}: {}: {}", name_, line, column, path,
                                               shared::printable(what, 1000))});
}

std::string SceneParser::join(const std::string& path, const std::string& key) {
  return path.empty() ? key : path + "." + key;
}

namespace {
// Keys that were scene keys once; a scene that still has one gets told where the setting went.
const char* removedKeyHint(const std::string& field) {
  if (field == "haptics.device") {
    return "no longer a scene key: the device backend is chosen where haptic_server starts "
           "(scripts/start.sh --device NAME|PATH.so, haptic_server --device); delete the line";
  }
  return nullptr;
}
}  // namespace

// Unknown and duplicate keys of a map.
void SceneParser::checkKeys(const YAML::Node& map, const std::string& path,
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
      if (const char* hint = removedKeyHint(join(path, k))) {
        error(key, join(path, k), hint);
        continue;
      }
      std::string list;
      for (const char* a : allowed) list += (list.empty() ? "" : ", ") + std::string(a);
      error(key, join(path, k), "unknown key (expected one of: " + list + ")");
    } else if (!seen.insert(k).second) {
      error(key, join(path, k), "duplicate key");
    }
  }
}

// A sub-map, or nothing. Reports a present non-map value.
bool SceneParser::section(const YAML::Node& map, const std::string& path, const char* key,
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

bool SceneParser::parseNumber(const YAML::Node& n, const std::string& path, double* out) {
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
bool SceneParser::number(const YAML::Node& map, const std::string& path, const char* key,
                         double* out, Range range, Range hard, Range usual) {
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
bool SceneParser::integer(const YAML::Node& map, const std::string& path, const char* key, int* out,
                          int min_value, int max_value, int usual_max) {
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

bool SceneParser::boolean(const YAML::Node& map, const std::string& path, const char* key,
                          bool* out) {
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

bool SceneParser::string(const YAML::Node& map, const std::string& path, const char* key,
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

void SceneParser::require(const YAML::Node& map, const std::string& path, const char* key) {
  if (!map[key].IsDefined()) error(map, join(path, key), "is required");
}

std::filesystem::path SceneParser::resolve(const std::string& p) const {
  std::filesystem::path path(p);
  if (path.is_relative()) path = base_dir_ / path;
  return std::filesystem::absolute(path).lexically_normal();
}

// Orientation from rotation_deg (XYZ Euler) or quaternion [w, x, y, z]; identity if neither.
void SceneParser::orientation(const YAML::Node& map, const std::string& path,
                              Eigen::Quaterniond* out) {
  const bool has_euler = map["rotation_deg"].IsDefined();
  const bool has_quat = map["quaternion"].IsDefined();
  if (has_euler && has_quat) {
    error(map["quaternion"], join(path, "quaternion"),
          "give either rotation_deg or quaternion, not both");
    return;
  }
  Eigen::Vector3d deg;
  // the same ranges as a transform's angles (1e300 degrees is no orientation)
  if (vector<3>(map, path, "rotation_deg", &deg, kSymmetric(1e6), kSymmetric(360.0))) {
    *out = eulerXyzDeg(deg);
  }
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

void SceneParser::readPose(const YAML::Node& map, const std::string& path, PoseSpec* pose) {
  vector<3>(map, path, "position", &pose->position_m, kCoordinate, kUsualCoordinate);
  orientation(map, path, &pose->orientation);
}

}  // namespace tactus::sim::scene_detail
