// Scene parsing: node regions (fixed.regions; the selectors of scene_regions.h).

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include "scene_parser.h"

namespace tactus::sim::scene_detail {

std::string SceneParser::where(const YAML::Node& at, const std::string& path) const {
  const YAML::Mark m = at.Mark();
  return fmt::format("{}:{}:{}: {}", name_, std::max(1, m.line + 1), std::max(1, m.column + 1),
                     path);
}

bool SceneParser::unitVector(const YAML::Node& map, const std::string& path, const char* key,
                             Eigen::Vector3d* out) {
  Eigen::Vector3d v;
  if (!vector<3>(map, path, key, &v, kSymmetric(1e6))) return false;
  const double norm = v.norm();
  if (!(norm > 1e-12)) {
    error(map[key], join(path, key), "must not be the zero vector");
    return false;
  }
  *out = v / norm;
  return true;
}

void SceneParser::readRegion(const YAML::Node& r, const std::string& p, RegionSpec* region) {
  checkKeys(r, p, {"box", "plane", "lowest", "highest", "group", "tolerance"});
  region->where = where(r, p);
  int selectors = 0;
  for (const char* k : {"box", "plane", "lowest", "highest", "group"}) {
    selectors += r[k].IsDefined() ? 1 : 0;
  }
  if (selectors != 1) {
    error(r, p, fmt::format("must have exactly one selector of box, plane, lowest, highest, group "
                            "(got {})", selectors));
    return;
  }
  if (r["group"].IsDefined()) {
    // resolved against the mesh's physical groups when the model is built (node_regions.cpp)
    region->kind = RegionKind::kGroup;
    string(r, p, "group", &region->group);
    if (r["tolerance"].IsDefined()) {
      error(r["tolerance"], join(p, "tolerance"), "has no meaning for a group region");
    }
    return;
  }
  number(r, p, "tolerance", &region->tolerance_m, kNonNegative, kAtMost(kMaxCoordinateM),
         kNonNegativeUpTo(1.0));
  YAML::Node n;
  if (section(r, p, "box", &n)) {
    const std::string bp = join(p, "box");
    region->kind = RegionKind::kBox;
    checkKeys(n, bp, {"min", "max"});
    require(n, bp, "min");
    require(n, bp, "max");
    const bool ok_min = vector<3>(n, bp, "min", &region->min_m, kCoordinate);
    const bool ok_max = vector<3>(n, bp, "max", &region->max_m, kCoordinate);
    if (ok_min && ok_max && (region->min_m.array() > region->max_m.array()).any()) {
      error(n["max"], join(bp, "max"), "must be >= min in every coordinate");
    }
  } else if (section(r, p, "plane", &n)) {
    const std::string pp = join(p, "plane");
    region->kind = RegionKind::kPlaneSide;
    checkKeys(n, pp, {"point", "normal"});
    require(n, pp, "point");
    require(n, pp, "normal");
    vector<3>(n, pp, "point", &region->point_m, kCoordinate, kUsualCoordinate);
    unitVector(n, pp, "normal", &region->normal);
  } else {
    const bool lowest = r["lowest"].IsDefined();
    region->kind = lowest ? RegionKind::kLowest : RegionKind::kHighest;
    choice(r, p, lowest ? "lowest" : "highest", &region->axis, {{"x", 0}, {"y", 1}, {"z", 2}});
  }
}

void SceneParser::readRegions(const YAML::Node& list, const std::string& path,
                              std::vector<RegionSpec>* out) {
  if (!list.IsSequence()) {
    error(list, path, "must be a list of regions ({box: ...}, {plane: ...}, {lowest: z}, "
                      "{highest: z}, {group: name}) (got " + kindOf(list) + ")");
    return;
  }
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YAML::Node r = list[i];
    const std::string p = fmt::format("{}[{}]", path, i);
    if (!r.IsMap()) {
      error(r, p, "must be a map with one selector (box, plane, lowest, highest, group) (got " +
                      kindOf(r) + ")");
      continue;
    }
    RegionSpec region;
    readRegion(r, p, &region);
    out->push_back(region);
  }
}

void SceneParser::readLoads(const YAML::Node& list, const std::string& path,
                            std::vector<LoadSpec>* out) {
  if (!list.IsSequence()) {
    error(list, path, "must be a list of loads (got " + kindOf(list) + ")");
    return;
  }
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YAML::Node l = list[i];
    const std::string p = fmt::format("{}[{}]", path, i);
    if (!l.IsMap()) {
      error(l, p, "must be a map {region, force | pressure | displacement} (got " + kindOf(l) +
                      ")");
      continue;
    }
    checkKeys(l, p, {"region", "force", "pressure", "displacement", "ramp"});
    LoadSpec load;
    load.where = where(l, p);
    int kinds = 0;
    for (const char* k : {"force", "pressure", "displacement"}) kinds += l[k].IsDefined() ? 1 : 0;
    if (kinds != 1) {
      error(l, p, fmt::format("must have exactly one of force, pressure, displacement (got {})",
                              kinds));
      continue;
    }
    require(l, p, "region");
    const YAML::Node r = l["region"];
    if (r.IsDefined() && !r.IsMap()) {
      error(r, join(p, "region"), "must be a map with one selector (got " + kindOf(r) + ")");
    } else if (r.IsDefined()) {
      readRegion(r, join(p, "region"), &load.region);
    }
    number(l, p, "ramp", &load.ramp_s, kNonNegative, kAtMost(1e7), kNonNegativeUpTo(3600.0));
    if (l["force"].IsDefined()) {
      load.kind = LoadKind::kForce;
      vector<3>(l, p, "force", &load.force_n, kSymmetric(1e6), kSymmetric(1e3));
    } else if (l["pressure"].IsDefined()) {
      load.kind = LoadKind::kPressure;
      number(l, p, "pressure", &load.pressure_pa, kAny, kSymmetric(1e9), kSymmetric(1e6));
    } else {
      load.kind = LoadKind::kDisplacement;
      if (l["ramp"].IsDefined()) error(l["ramp"], join(p, "ramp"), "has no meaning for a displacement (its path sets the timing)");
      const YAML::Node keys = l["displacement"];
      const std::string dp = join(p, "displacement");
      if (!keys.IsSequence() || keys.size() == 0) {
        error(keys, dp, "must be a non-empty list of {t, offset} keys (got " + kindOf(keys) + ")");
      } else {
        for (std::size_t k = 0; k < keys.size(); ++k) {
          const YAML::Node key = keys[k];
          const std::string kp = fmt::format("{}[{}]", dp, k);
          if (!key.IsMap()) {
            error(key, kp, "must be a map {t, offset} (got " + kindOf(key) + ")");
            continue;
          }
          checkKeys(key, kp, {"t", "offset"});
          require(key, kp, "t");
          require(key, kp, "offset");
          DisplacementKey d;
          number(key, kp, "t", &d.t_s, kNonNegative, kAtMost(1e7));
          vector<3>(key, kp, "offset", &d.offset_m, kCoordinate, Range{-1.0, 1.0});
          if (!load.path.empty() && !(d.t_s > load.path.back().t_s)) {
            error(key["t"].IsDefined() ? key["t"] : key, join(kp, "t"),
                  "must be greater than the previous key's t");
          }
          load.path.push_back(d);
        }
      }
    }
    out->push_back(load);
  }
}

}  // namespace tactus::sim::scene_detail
