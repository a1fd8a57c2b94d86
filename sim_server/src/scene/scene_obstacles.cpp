// Scene parsing: the obstacles and obstacle_contact sections (static obstacles).

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <filesystem>
#include <limits>
#include <set>

#include "scene_parser.h"
#include "tactus/shared/segment.h"

namespace tactus::sim::scene_detail {

void SceneParser::readObstacles(const YAML::Node& root, SceneSpec* spec) {
  YAML::Node c;
  if (section(root, "", "obstacle_contact", &c)) {
    const std::string p = "obstacle_contact";
    checkKeys(c, p, {"alarm_distance", "max_contacts", "edges", "edge_spacing", "edge_depth"});
    number(c, p, "alarm_distance", &spec->obstacle_contact.alarm_distance_m, kNonNegative,
           kAtMost(1.0), kNonNegativeUpTo(0.05));
    integer(c, p, "max_contacts", &spec->obstacle_contact.max_contacts, 1, 1'000'000, 3000);
    boolean(c, p, "edges", &spec->obstacle_contact.edges);
    // (below 0.1 mm the points of a long edge would exhaust memory: Obstacles caps their count)
    number(c, p, "edge_spacing", &spec->obstacle_contact.edge_spacing_m, kPositive,
           Range{1e-4, 1.0}, Range{2e-4, 0.05});
    number(c, p, "edge_depth", &spec->obstacle_contact.edge_depth_m, kNonNegative, kAtMost(1.0),
           kNonNegativeUpTo(0.05));
  }
  const YAML::Node list = root["obstacles"];
  if (!list.IsDefined()) return;
  if (!list.IsSequence()) {
    error(list, "obstacles", "must be a list of obstacles (got " + kindOf(list) + ")");
    return;
  }
  std::set<std::string> names;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YAML::Node o = list[i];
    const std::string p = fmt::format("obstacles[{}]", i);
    if (!o.IsMap()) {
      error(o, p, "must be a map with one shape (plane, box, mesh) (got " + kindOf(o) + ")");
      continue;
    }
    checkKeys(o, p, {"name", "plane", "box", "mesh", "friction"});
    ObstacleSpec ob;
    ob.name = fmt::format("obstacle{}", i);
    ob.where = where(o, p);
    string(o, p, "name", &ob.name);
    if (!names.insert(ob.name).second) {
      error(o["name"].IsDefined() ? o["name"] : o, join(p, "name"),
            "duplicate obstacle name '" + ob.name + "'");
    }
    number(o, p, "friction", &ob.friction_mu, kFriction, kAny, Range{0.0, 2.0});
    int shapes = 0;
    for (const char* k : {"plane", "box", "mesh"}) shapes += o[k].IsDefined() ? 1 : 0;
    if (shapes != 1) {
      error(o, p, fmt::format("must have exactly one shape of plane, box, mesh (got {})", shapes));
      continue;
    }
    YAML::Node n;
    if (section(o, p, "plane", &n)) {
      const std::string sp = join(p, "plane");
      ob.kind = ObstacleKind::kPlane;
      checkKeys(n, sp, {"point", "normal"});
      require(n, sp, "point");
      require(n, sp, "normal");
      vector<3>(n, sp, "point", &ob.point_m, kCoordinate, kUsualCoordinate);
      unitVector(n, sp, "normal", &ob.normal);
    } else if (section(o, p, "box", &n)) {
      const std::string sp = join(p, "box");
      ob.kind = ObstacleKind::kBox;
      checkKeys(n, sp, {"min", "max"});
      require(n, sp, "min");
      require(n, sp, "max");
      const bool ok_min = vector<3>(n, sp, "min", &ob.min_m, kCoordinate, kUsualCoordinate);
      const bool ok_max = vector<3>(n, sp, "max", &ob.max_m, kCoordinate, kUsualCoordinate);
      if (ok_min && ok_max && !(ob.min_m.array() < ob.max_m.array()).all()) {
        error(n["max"], join(sp, "max"), "must be > min in every coordinate");
      }
    } else if (section(o, p, "mesh", &n)) {
      const std::string sp = join(p, "mesh");
      ob.kind = ObstacleKind::kMesh;
      checkKeys(n, sp, {"file", "scale", "rotation_deg", "translation", "thickness"});
      require(n, sp, "file");
      std::string file;
      if (string(n, sp, "file", &file)) {
        ob.mesh_path = resolve(file);
        std::error_code ec;
        const auto status = std::filesystem::status(ob.mesh_path, ec);
        const std::string shown = shared::printable(ob.mesh_path.string(), 256);
        if (std::filesystem::is_directory(status)) {
          error(n["file"], join(sp, "file"), "surface file " + shown + " is a directory");
        } else if (std::filesystem::exists(status) &&
                   !std::filesystem::is_regular_file(status)) {
          error(n["file"], join(sp, "file"),
                "surface file " + shown + " is not a regular file (a FIFO, socket or device)");
        } else if (!std::filesystem::is_regular_file(status)) {
          error(n["file"], join(sp, "file"),
                "surface file not found: " + shown +
                    " (relative paths are resolved against the scene file's folder)");
        }
      }
      number(n, sp, "scale", &ob.scale, kPositive, Range{1e-9, 1e6}, Range{1e-4, 1e3});
      vector<3>(n, sp, "rotation_deg", &ob.rotation_deg, kSymmetric(1e6), kSymmetric(360.0));
      vector<3>(n, sp, "translation", &ob.translation_m, kCoordinate, kUsualCoordinate);
      number(n, sp, "thickness", &ob.thickness_m, kNonNegative, kAtMost(kMaxCoordinateM),
             kNonNegativeUpTo(0.1));
    }
    spec->obstacles.push_back(ob);
  }
}

void SceneParser::checkObstacleCapacity(const YAML::Node& root, const SceneSpec& spec) {
  if (spec.obstacles.empty() && spec.tissue_contacts.empty()) return;
  // the instruments' contacts (max_contacts each), the obstacles' (per tissue) and those between
  // tissues (per pair and direction)
  const long long between = tissueContactCapacity(spec);
  bool friction = anyFriction(spec) || anyTissueContactFriction(spec);
  const long long per_tissue = spec.obstacles.empty() ? 0 : spec.obstacle_contact.max_contacts;
  const long long total = static_cast<long long>(problemContactCapacity(spec)) +
                          per_tissue * static_cast<long long>(spec.tissues.size()) + between;
  friction = friction || std::any_of(spec.obstacles.begin(), spec.obstacles.end(),
                                     [](const ObstacleSpec& o) { return o.friction_mu > 0.0; });
  const std::size_t bytes =
      total > 1'000'000 ? std::numeric_limits<std::size_t>::max()
                        : shared::SegmentLayout::forCapacity(
                              shared::SegmentCapacity::forContacts(static_cast<int>(total),
                                                                   friction))
                              .total_bytes;
  if (bytes <= kMaxContactProblemBytes) return;
  const int tools = instrumentCount(spec);
  const std::string instruments =
      tools > 1 ? fmt::format("solver.max_contacts {} x {} instruments", spec.solver.max_contacts,
                              tools)
                : fmt::format("solver.max_contacts {}", spec.solver.max_contacts);
  const std::string limit = fmt::format(
      "need more than the {} MiB the contact problem may take (W is rows x rows doubles, 3 rows "
      "per frictional contact): lower them (about 3000 in all)", kMaxContactProblemBytes >> 20);
  std::string parts = instruments;
  if (per_tissue > 0) {
    parts += fmt::format(" + obstacle_contact.max_contacts {} per tissue x {} tissues", per_tissue,
                         spec.tissues.size());
  }
  if (between > 0) parts += fmt::format(" + {} between tissues (tissue_contact)", between);
  const std::string what = fmt::format("{} contacts in all ({}) {}", total, parts, limit);
  // the error goes where the largest part is set (a key absent from the file: its section)
  const long long by_tools = problemContactCapacity(spec);
  const long long by_obstacles = per_tissue * static_cast<long long>(spec.tissues.size());
  auto child = [](const YAML::Node& map, const char* key) {
    return map.IsDefined() && map.IsMap() && map[key].IsDefined() ? map[key] : map;
  };
  if (between >= by_obstacles && between >= by_tools) {
    // the largest pair of tissue_contact
    const YAML::Node list = root["tissue_contact"];
    std::size_t largest = 0;
    for (std::size_t k = 1; k < spec.tissue_contacts.size(); ++k) {
      if (spec.tissue_contacts[k].max_contacts > spec.tissue_contacts[largest].max_contacts) {
        largest = k;
      }
    }
    if (list.IsDefined() && list.IsSequence() && list.size() == spec.tissue_contacts.size()) {
      error(child(list[largest], "max_contacts"),
            fmt::format("tissue_contact[{}].max_contacts", largest), what);
    } else {
      error(list.IsDefined() ? list : root, "tissue_contact", what);
    }
  } else if (by_obstacles >= by_tools) {
    const YAML::Node c = root["obstacle_contact"];
    error(c.IsDefined() ? child(c, "max_contacts") : root["obstacles"],
          c.IsDefined() ? "obstacle_contact.max_contacts" : "obstacles", what);
  } else {
    const YAML::Node solver = root["solver"];
    error(solver.IsDefined() ? child(solver, "max_contacts") : root, "solver.max_contacts", what);
  }
}

}  // namespace tactus::sim::scene_detail
