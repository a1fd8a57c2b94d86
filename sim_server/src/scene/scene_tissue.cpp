// Scene parsing: the tissues section (mesh, transform, material, damping, fixed nodes, compliance).

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <limits>
#include <set>

#include "scene_parser.h"
#include "tactus/sim/compliance.h"

namespace tactus::sim::scene_detail {

void SceneParser::readTissues(const YAML::Node& root, SceneSpec* spec) {
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

void SceneParser::readTissue(const YAML::Node& t, const std::string& path, TissueSpec* tissue) {
  checkKeys(t, path, {"name", "mesh", "transform", "material", "element", "damping", "fixed",
                      "compliance", "loads", "strain_limit"});
  if (t["loads"].IsDefined()) readLoads(t["loads"], join(path, "loads"), &tissue->loads);
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
    checkKeys(n, p, {"law", "tangent", "young_modulus", "poisson_ratio", "density"});
    choice(n, p, "law", &tissue->law,
           {{"linear", MaterialLaw::kLinear}, {"corotational", MaterialLaw::kCorotational},
            {"invertible_neo_hookean", MaterialLaw::kInvertibleNeoHookean}});
    if (choice(n, p, "tangent", &tissue->tangent,
               {{"corotated", TangentKind::kCorotated},
                {"consistent", TangentKind::kConsistent}}) &&
        tissue->tangent == TangentKind::kConsistent &&
        tissue->law != MaterialLaw::kCorotational) {
      error(n["tangent"], join(p, "tangent"),
            "'consistent' is a linearisation of the corotational law only (the linear law's "
            "tangent is exact, invertible_neo_hookean always uses its full tangent)");
    }
    number(n, p, "young_modulus", &tissue->young_pa, kPositive, kAtMost(1e12), Range{10.0, 1e9});
    number(n, p, "poisson_ratio", &tissue->poisson, Range{-1.0, 0.5, true, true});
    number(n, p, "density", &tissue->density_kgpm3, kPositive, kAtMost(1e5), Range{100.0, 1e4});
  }
  choice(t, path, "element", &tissue->element,
         {{"linear_tet", ElementKind::kLinearTet},
          {"edge_smoothed_tet", ElementKind::kEdgeSmoothedTet}});
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
                     "exact_below_coherence", "rotation_smoothing"});
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
    integer(n, p, "rotation_smoothing", &tissue->rotation_smoothing_passes, 0,
            kMaxRotationSmoothingPasses, 4);
  }
  if (section(t, path, "strain_limit", &n)) {
    const std::string p = join(path, "strain_limit");
    checkKeys(n, p, {"min_volume_ratio"});
    number(n, p, "min_volume_ratio", &tissue->min_volume_ratio, kNonNegative, kAtMost(0.95),
           kNonNegativeUpTo(0.9));
  }
}

void SceneParser::readFixed(const YAML::Node& f, const std::string& path, TissueSpec* tissue) {
  checkKeys(f, path, {"nodes", "boxes", "regions"});
  if (f["regions"].IsDefined()) readRegions(f["regions"], join(path, "regions"), &tissue->fixed_regions);
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
      box.where = where(b, p);
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

}  // namespace tactus::sim::scene_detail
