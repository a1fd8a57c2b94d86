// Scene parsing: the instrument section (mass, coupling, probe or grasper geometry, initial pose,
// scripted trajectory, workspace).

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>

#include "scene_parser.h"
#include "tactus/shared/messages.h"

namespace tactus::sim::scene_detail {

void SceneParser::readInstrument(const YAML::Node& n, const std::string& p, InstrumentSpec* in) {
  in->present = true;
  checkKeys(n, p, {"name", "type", "mass", "inertia", "coupling", "friction", "alarm_distance",
                   "contact_distance", "face_contacts", "contact_compliance", "probe",
                   "grasper", "initial_pose", "trajectory", "workspace"});
  if (string(n, p, "name", &in->name)) {
    const auto allowed = [](char c) {
      return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_' || c == '-';
    };
    const bool ok =
        in->name.size() <= 32 && std::all_of(in->name.begin(), in->name.end(), allowed);
    if (!ok) error(n["name"], join(p, "name"), "must be 1 to 32 letters, digits, _ or -");
  }
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
                     "grip_inertia", "grip_squeeze", "grip_hold_open_stop"});
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
    number(s, q, "grip_squeeze", &in->grip_squeeze_nm, kNonNegative, kAtMost(100.0),
           kNonNegativeUpTo(1.0));
    boolean(s, q, "grip_hold_open_stop", &in->grip_hold_open_stop);
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

// `instruments:` (a list of instrument maps, the first one becoming SceneSpec::instrument) or
// the single `instrument:` map; not both.
void SceneParser::readInstruments(const YAML::Node& root, SceneSpec* spec) {
  const YAML::Node list = root["instruments"];
  YAML::Node n;
  if (!list.IsDefined()) {
    if (section(root, "", "instrument", &n)) readInstrument(n, "instrument", &spec->instrument);
    return;
  }
  if (root["instrument"].IsDefined()) {
    error(root["instrument"], "instrument",
          "give either `instrument:` (one) or `instruments:` (a list), not both");
    return;
  }
  if (!list.IsSequence() || list.size() == 0 ||
      list.size() > static_cast<std::size_t>(shared::kMaxInstruments)) {
    error(list, "instruments",
          fmt::format("must be a list of 1 to {} instrument maps (got {})",
                      shared::kMaxInstruments,
                      list.IsSequence() ? fmt::format("{} items", list.size()) : kindOf(list)));
    return;
  }
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string p = fmt::format("instruments[{}]", i);
    if (!list[i].IsMap()) {
      error(list[i], p, "must be a map (an instrument: type, coupling, ...; got " +
                            kindOf(list[i]) + ")");
      continue;
    }
    InstrumentSpec* in = &spec->instrument;
    if (i > 0) in = &spec->additional_instruments.emplace_back();
    readInstrument(list[i], p, in);
  }
  for (std::size_t i = 1; i < list.size(); ++i) {
    const std::string& name = spec->additional_instruments[i - 1].name;
    for (std::size_t j = 0; j < i && !name.empty(); ++j) {
      if (name == (j == 0 ? spec->instrument : spec->additional_instruments[j - 1]).name) {
        error(list[i]["name"], fmt::format("instruments[{}].name", i),
              fmt::format("'{}' is already the name of instruments[{}]", name, j));
      }
    }
  }
}

void SceneParser::readTrajectory(const YAML::Node& list, const std::string& path,
                                 InstrumentSpec* in) {
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

}  // namespace tactus::sim::scene_detail
