// Scene parsing: the tissue_contact section (contact between tissues and self-contact).

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <set>

#include "scene_parser.h"

namespace tactus::sim::scene_detail {

bool SceneParser::tissueIndex(const YAML::Node& n, const std::string& p, const SceneSpec& spec,
                              int* out) {
  if (!n.IsScalar()) {
    error(n, p, "must be a tissue's name (got " + kindOf(n) + ")");
    return false;
  }
  const std::string name = n.Scalar();
  std::string known;
  for (std::size_t t = 0; t < spec.tissues.size(); ++t) {
    if (spec.tissues[t].name == name) {
      *out = static_cast<int>(t);
      return true;
    }
    known += (t == 0 ? "" : ", ") + spec.tissues[t].name;
  }
  error(n, p, "no tissue named '" + shared::printable(name, 64) + "' (the tissues: " + known + ")");
  return false;
}

void SceneParser::readTissueContacts(const YAML::Node& root, SceneSpec* spec) {
  const YAML::Node list = root["tissue_contact"];
  if (!list.IsDefined()) return;
  if (!list.IsSequence()) {
    error(list, "tissue_contact",
          "must be a list of pairs ({between: [a, b]} or {self: a}) (got " + kindOf(list) + ")");
    return;
  }
  if (list.size() > static_cast<std::size_t>(kMaxTissueContactPairs)) {
    error(list, "tissue_contact",
          fmt::format("at most {} pairs (got {})", kMaxTissueContactPairs, list.size()));
    return;
  }
  std::set<std::pair<int, int>> seen;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YAML::Node c = list[i];
    const std::string p = fmt::format("tissue_contact[{}]", i);
    if (!c.IsMap()) {
      error(c, p, "must be a map with `between: [a, b]` or `self: a` (got " + kindOf(c) + ")");
      continue;
    }
    checkKeys(c, p, {"between", "self", "friction", "alarm_distance", "depth",
                     "contact_compliance", "max_contacts", "two_way"});
    TissueContactSpec pair;
    pair.where = where(c, p);
    const bool between = c["between"].IsDefined();
    if (between == c["self"].IsDefined()) {
      error(c, p, "must have exactly one of `between: [a, b]` (two tissues) and `self: a` "
                  "(self-contact)");
      continue;
    }
    bool ok = true;
    if (between) {
      const YAML::Node b = c["between"];
      const std::string bp = join(p, "between");
      if (!b.IsSequence() || b.size() != 2) {
        error(b, bp, "must be a list of two tissue names (got " + kindOf(b) + ")");
        continue;
      }
      ok = tissueIndex(b[0], bp + "[0]", *spec, &pair.tissue_a) &&
           tissueIndex(b[1], bp + "[1]", *spec, &pair.tissue_b);
      if (ok && pair.tissue_a == pair.tissue_b) {
        error(b, bp, "names one tissue twice: use `self: " + spec->tissues[static_cast<std::size_t>(
                         pair.tissue_a)].name + "` for self-contact");
        ok = false;
      }
    } else {
      ok = tissueIndex(c["self"], join(p, "self"), *spec, &pair.tissue_a);
      pair.tissue_b = pair.tissue_a;
    }
    number(c, p, "friction", &pair.friction_mu, kFriction, kAny, Range{0.0, 2.0});
    number(c, p, "alarm_distance", &pair.alarm_distance_m, kNonNegative, kAtMost(1.0),
           kNonNegativeUpTo(0.05));
    number(c, p, "depth", &pair.depth_m, kNonNegative, kAtMost(1.0), kNonNegativeUpTo(0.1));
    number(c, p, "contact_compliance", &pair.contact_compliance_mpn, kNonNegative, kAtMost(1.0),
           kNonNegativeUpTo(1e-2));
    integer(c, p, "max_contacts", &pair.max_contacts, 1, 1'000'000, 3000);
    boolean(c, p, "two_way", &pair.two_way);
    if (!ok) continue;
    const std::pair<int, int> key = std::minmax(pair.tissue_a, pair.tissue_b);
    if (!seen.insert(key).second) {
      error(c, p, "the same pair of tissues twice");
      continue;
    }
    spec->tissue_contacts.push_back(pair);
  }
}

}  // namespace tactus::sim::scene_detail
