// Scene loading: YAML -> SceneSpec with complete validation. Every problem is collected (with
// file, line, column and field path) and reported at once in one SceneError. This file: the root,
// solver, haptics and output sections and the entry points; the parser and the other sections are
// in scene_parser.h and scene_{values,tissue,instrument}.cpp.

#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <limits>
#include <string>

#include "scene_parser.h"
#include "tactus/shared/haptic_limits.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/scene.h"
// the contact problem's size limit (max_contacts)
#include "tactus/shared/segment.h"

namespace tactus::sim {
namespace scene_detail {

void SceneParser::readRoot(const YAML::Node& root, SceneSpec* spec) {
  checkKeys(root, "", {"time_step", "duration", "gravity", "tissues", "instrument", "instruments",
                       "solver", "haptics", "output", "obstacles", "obstacle_contact",
                       "tissue_contact"});
  require(root, "", "time_step");
  number(root, "", "time_step", &spec->time_step_s, kPositive, kAtMost(1.0), Range{1e-5, 0.05});
  number(root, "", "duration", &spec->duration_s, kNonNegative, kAtMost(1e7), Range{0.0, 86400.0});
  Eigen::Vector3d g;
  if (vector<3>(root, "", "gravity", &g, kSymmetric(1e3), kSymmetric(20.0))) {
    spec->gravity_mps2 = g;
  }
  readTissues(root, spec);
  readObstacles(root, spec);   // scene_obstacles.cpp
  readTissueContacts(root, spec);   // scene_tissue_contact.cpp
  YAML::Node n;
  readInstruments(root, spec);
  if (section(root, "", "solver", &n)) readSolver(n, &spec->solver, instrumentCount(*spec));
  if (section(root, "", "haptics", &n)) readHaptics(n, &spec->haptics, instrumentCount(*spec));
  if (section(root, "", "output", &n)) readOutput(n, &spec->output);
  checkObstacleCapacity(root, *spec);   // scene_obstacles.cpp
}

void SceneParser::readSolver(const YAML::Node& n, SolverSpec* s, int instruments) {
  const std::string p = "solver";
  checkKeys(n, p, {"linear", "cg_tolerance", "cg_max_iterations", "refactor_iterations",
                   "refactor_every_steps", "background_refactor_lag_steps",
                   "background_refactor_free_lag_steps",
                   "background_refactor_when_ready", "preconditioner_precision",
                   "single_precision_preconditioner",
                   "pcg_local_correction_threshold",
                   "nsgs_tolerance",
                   "nsgs_max_sweeps", "nsgs_sor", "nsgs_anderson_depth", "split_contact_groups", "max_contacts", "contact_iterations",
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
  integer(n, p, "background_refactor_lag_steps", &s->background_refactor_lag_steps, 0, 1000, 100);
  integer(n, p, "background_refactor_free_lag_steps", &s->background_refactor_free_lag_steps, 0,
          1000, 100);
  boolean(n, p, "background_refactor_when_ready", &s->background_refactor_when_ready);
  choice(n, p, "preconditioner_precision", &s->preconditioner_precision,
         {{"double", PreconditionerPrecision::kDouble},
          {"float", PreconditionerPrecision::kFloat},
          {"half", PreconditionerPrecision::kHalf}});
  if (n["single_precision_preconditioner"].IsDefined())
    error(n["single_precision_preconditioner"], join(p, "single_precision_preconditioner"),
          "replaced by solver.preconditioner_precision (double, float or half): write "
          "`preconditioner_precision: float` for `true`, or leave both out for `false`");
  number(n, p, "pcg_local_correction_threshold", &s->pcg_local_correction_threshold,
         Range{0.0, 1.0});
  number(n, p, "nsgs_tolerance", &s->nsgs_tolerance, kPositive, Range{-kInf, 1.0, false, true},
         kPositiveUpTo(1e-2));
  integer(n, p, "nsgs_max_sweeps", &s->nsgs_max_sweeps, 1, 10'000'000, 100'000);
  number(n, p, "nsgs_sor", &s->nsgs_sor, Range{0.0, 2.0, true, true});
  integer(n, p, "nsgs_anderson_depth", &s->nsgs_anderson_depth, 0, shared::kMaxAndersonDepth,
          shared::kMaxAndersonDepth);
  boolean(n, p, "split_contact_groups", &s->split_contact_groups);
  // the contact problem's W (rows x rows doubles, 3 rows per frictional contact) lives in
  // the shared segment's triple buffer: refuse what cannot be allocated, before trying
  if (integer(n, p, "max_contacts", &s->max_contacts, 1, std::numeric_limits<int>::max(),
              2000)) {
    // (the layout is computed only for counts whose row count fits an int); the problem holds
    // max_contacts per instrument
    const long contacts = static_cast<long>(s->max_contacts) * std::max(1, instruments);
    const std::size_t bytes =
        contacts > 1'000'000
            ? std::numeric_limits<std::size_t>::max()
            : shared::SegmentLayout::forCapacity(
                  shared::SegmentCapacity::forContacts(static_cast<std::int32_t>(contacts)))
                  .total_bytes;
    if (bytes > kMaxContactProblemBytes) {
      error(n["max_contacts"], join(p, "max_contacts"),
            fmt::format("{} contacts need {} MiB for the contact problem (W is rows x rows "
                        "doubles, 3 rows per contact; max_contacts per instrument), more than "
                        "the {} MiB limit: lower it (at most about 3000 in all)",
                        contacts,
                        contacts > 1'000'000 ? std::string("too many")
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

void SceneParser::readHaptics(const YAML::Node& n, HapticsSpec* h, int instruments) {
  // the hard ranges are haptic_server's own (a scene value reaches it through start.sh)
  using L = shared::HapticLimits;
  const std::string p = "haptics";
  checkKeys(n, p, {"enabled", "rate", "force_scale", "max_force", "watchdog_ms",
                   "max_sweeps_per_tick", "nsgs_tolerance", "nsgs_anderson_depth",
                   "snapshot_blend_ms", "local_model", "workspace", "workspaces"});
  h->enabled = true;  // a haptics section turns haptics on unless it says otherwise
  boolean(n, p, "enabled", &h->enabled);
  number(n, p, "rate", &h->rate_hz, kPositive, Range{L::kMinRateHz, L::kMaxRateHz},
         Range{100.0, L::kMaxRateHz});
  number(n, p, "force_scale", &h->force_scale, kNonNegative, kAtMost(L::kMaxForceScale),
         kNonNegativeUpTo(L::kMaxForceScale));
  number(n, p, "max_force", &h->max_force_n, kPositive, kAtMost(L::kMaxForceN), kPositiveUpTo(40.0));
  number(n, p, "watchdog_ms", &h->watchdog_ms, kPositive, kAtMost(L::kMaxWatchdogMs),
         kPositiveUpTo(1e3));
  integer(n, p, "max_sweeps_per_tick", &h->max_sweeps_per_tick, 1, L::kMaxSweeps, 10'000);
  number(n, p, "nsgs_tolerance", &h->nsgs_tolerance, kPositive, Range{-kInf, 1.0, false, true},
         kPositiveUpTo(1e-2));
  integer(n, p, "nsgs_anderson_depth", &h->nsgs_anderson_depth, 0, shared::kMaxAndersonDepth,
          shared::kMaxAndersonDepth);
  number(n, p, "snapshot_blend_ms", &h->snapshot_blend_ms, kNonNegative,
         kAtMost(L::kMaxSnapshotBlendMs), kNonNegativeUpTo(L::kMaxSnapshotBlendMs));
  choice(n, p, "local_model", &h->local_model,
         {{"automatic", HapticLocalModel::kAutomatic},
          {"full", HapticLocalModel::kFull},
          {"linearized", HapticLocalModel::kLinearized}});
  YAML::Node w;
  if (section(n, p, "workspace", &w)) readWorkspace(w, p + ".workspace", &h->workspace);
  readWorkspaces(n, h, instruments);
}

// `haptics.workspaces:` one mapping per device (entry i for instrument/device i), instead of the
// one `workspace:` every device shares.
void SceneParser::readWorkspaces(const YAML::Node& n, HapticsSpec* h, int instruments) {
  const YAML::Node list = n["workspaces"];
  if (!list.IsDefined()) return;
  if (n["workspace"].IsDefined()) {
    error(list, "haptics.workspaces",
          "give either `workspace:` (every device) or `workspaces:` (one per device), not both");
    return;
  }
  const std::size_t most = static_cast<std::size_t>(std::max(1, instruments));
  if (!list.IsSequence() || list.size() == 0 || list.size() > most) {
    error(list, "haptics.workspaces",
          fmt::format("must be a list of 1 to {} workspace maps, one per instrument (got {})",
                      most, list.IsSequence() ? fmt::format("{} items", list.size())
                                              : kindOf(list)));
    return;
  }
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string p = fmt::format("haptics.workspaces[{}]", i);
    shared::WorkspaceMappingParams& w = h->workspaces.emplace_back();
    if (!list[i].IsMap()) {
      error(list[i], p, "must be a map (scale, offset, rotation_deg or quaternion, "
                        "clutch_button; got " + kindOf(list[i]) + ")");
      continue;
    }
    readWorkspace(list[i], p, &w);
  }
}

// The device -> scene mapping (shared::WorkspaceMappingLimits are the hard ranges).
void SceneParser::readWorkspace(const YAML::Node& n, const std::string& p,
                                shared::WorkspaceMappingParams* w) {
  using L = shared::WorkspaceMappingLimits;
  checkKeys(n, p, {"scale", "offset", "rotation_deg", "quaternion", "clutch_button"});
  number(n, p, "scale", &w->scale, kPositive, Range{L::kMinScale, L::kMaxScale},
         Range{0.1, 10.0});
  Eigen::Vector3d offset;
  if (vector<3>(n, p, "offset", &offset, Range{-L::kMaxOffsetM, L::kMaxOffsetM},
                Range{-2.0, 2.0})) {
    w->offset_m = {offset.x(), offset.y(), offset.z()};
  }
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
  orientation(n, p, &q);
  w->rotation_wxyz = {q.w(), q.x(), q.y(), q.z()};
  integer(n, p, "clutch_button", &w->clutch_button, -1, L::kMaxButton);
}

void SceneParser::readOutput(const YAML::Node& n, OutputSpec* o) {
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

}  // namespace scene_detail

using scene_detail::SceneParser;

SceneSpec parseScene(const std::string& yaml, const std::string& name,
                     const std::filesystem::path& base_dir) {
  SceneSpec spec = SceneParser(name, base_dir).parse(yaml);
  std::uint64_t hash = 0xcbf29ce484222325ull;   // FNV-1a
  for (const char c : yaml) {
    hash ^= static_cast<unsigned char>(c);
    hash *= 0x100000001b3ull;
  }
  spec.text_hash = hash;
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

int instrumentCount(const SceneSpec& spec) {
  return spec.instrument.present ? 1 + static_cast<int>(spec.additional_instruments.size()) : 0;
}

const InstrumentSpec& instrumentSpec(const SceneSpec& spec, int i) {
  return i == 0 ? spec.instrument : spec.additional_instruments.at(static_cast<std::size_t>(i - 1));
}

InstrumentSpec& instrumentSpec(SceneSpec& spec, int i) {
  return i == 0 ? spec.instrument : spec.additional_instruments.at(static_cast<std::size_t>(i - 1));
}

int problemContactCapacity(const SceneSpec& spec) {
  return std::max(1, instrumentCount(spec)) * spec.solver.max_contacts;
}

bool anyFriction(const SceneSpec& spec) {
  for (int i = 0; i < instrumentCount(spec); ++i) {
    if (instrumentSpec(spec, i).friction_mu > 0.0) return true;
  }
  return false;
}

namespace {
int tissueContactDirections(const TissueContactSpec& p) {
  return p.tissue_a != p.tissue_b && p.two_way ? 2 : 1;
}
}  // namespace

int tissueContactCapacity(const SceneSpec& spec) {
  int total = 0;
  for (const TissueContactSpec& p : spec.tissue_contacts) {
    total += tissueContactDirections(p) * p.max_contacts;
  }
  return total;
}

int tissueContactRowCapacity(const SceneSpec& spec) {
  int total = 0;
  for (const TissueContactSpec& p : spec.tissue_contacts) {
    total += tissueContactDirections(p) * p.max_contacts * (p.friction_mu > 0.0 ? 3 : 1);
  }
  return total;
}

bool anyTissueContactFriction(const SceneSpec& spec) {
  return std::any_of(spec.tissue_contacts.begin(), spec.tissue_contacts.end(),
                     [](const TissueContactSpec& p) { return p.friction_mu > 0.0; });
}

}  // namespace tactus::sim
