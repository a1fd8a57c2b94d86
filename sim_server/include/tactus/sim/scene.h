#pragma once
// Scene description: the YAML file a user writes, parsed into plain structs (spec -> pipeline).
//
// A scene names only the effects it wants; everything optional is std::optional or has a
// `present`/`enabled` flag, and an absent effect is never computed (see pipeline.h). Units are
// SI everywhere (metres, seconds, kilograms, pascals, newtons, radians) except where a field name
// says otherwise (`*_deg`). The full schema with defaults is documented in scenes/README.md.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "tactus/shared/workspace_mapping.h"
#include "tactus/sim/scene_regions.h"

namespace tactus::sim {

/// The elastic law of a tissue (scenes/README.md, material.law; docs/design.md, "Free motion").
enum class MaterialLaw {
  kLinear,                ///< small-strain linear elasticity (no rotation extraction)
  kCorotational,          ///< linear elasticity in each element's rotated frame (the paper's)
  /// Neo-Hookean in principal stretches after Irving, Teran and Fedkiw (2004): inverted elements
  /// keep a rotation and one negative stretch; below kInvertibleStretchFloor a stretch's stress is
  /// extrapolated linearly, so the stress pushes harder the deeper an element is compressed or
  /// inverted. Always linearised with the full tangent projected positive semi-definite.
  kInvertibleNeoHookean,
};
/// How the corotational law is linearised in the implicit step (material.tangent).
enum class TangentKind {
  kCorotated,    ///< R K0 R^T: the rotation held fixed (the paper's; cheapest)
  /// R K0 R^T plus the stiffness of the rotation itself where the element's stress makes it
  /// positive (the corotational energy's Hessian with its negative part left out)
  kConsistent,
};
/// How the strain of a tissue is sampled (tissues[i].element).
enum class ElementKind {
  kLinearTet,      ///< constant strain per tetrahedron
  /// edge-based smoothed strain on the same tetrahedra: one strain per mesh edge, the volume
  /// average of the strains of the tetrahedra around it (a sixth of each one's volume)
  kEdgeSmoothedTet,
};
enum class ComplianceKind { kExact, kWarped, kRest, kUncoupled };
/// How the implicit Euler step solves its linear system (FemSolverOptions, scenes/README.md).
enum class LinearSolverKind {
  kCholmod,        ///< CHOLMOD factorises A every step (exact)
  kPcg,            ///< PCG with a fixed preconditioner (FemSolverOptions::pcg_preconditioner)
  kCholmodReuse,   ///< PCG preconditioned by the CHOLMOD factor of a recent A, refreshed when
                   ///< PCG needs more than refactor_iterations (or on a schedule)
};
/// The precision of the factor-reuse PCG's preconditioner solves (FemSolverOptions::
/// preconditioner_precision). PCG's residual, products and convergence test stay in double
/// whichever it is, so every step still meets cg_tolerance; only the preconditioner, already
/// inexact by the factor's age, is less exact.
enum class PreconditionerPrecision {
  kDouble,  ///< the factor's own values
  kFloat,   ///< a float copy of the factor (half the bytes per sweep of the double)
  /// the factor as L D^-1 in IEEE half precision and D^-2 in float, packed (5.4 MB on
  /// liver_23k against the float copy's 12.9; fem_detail::HalfFactor): 11 significant bits,
  /// the sweeps accumulate in float. Needs F16C or AVX-512F to be faster than kFloat: on a CPU
  /// with neither the float copy is used instead (FemBody logs it once)
  kHalf,
};
enum class InstrumentKind { kProbe, kGrasper };
/// Where the first contact pass of a step detects its contacts (SolverSpec::contact_detection).
enum class ContactDetection {
  kFreeState,   ///< after the free motion, at the free state (the paper's scheme)
  kStepStart,   ///< before the free motion, at the start-of-step state; gaps carried to the free
                ///< state along the rows (gap + n . (x_free - x_start) relative motion)
};

/// Axis-aligned box in scene coordinates (after the mesh transform) [m].
struct BoxSpec {
  Eigen::Vector3d min_m = Eigen::Vector3d::Zero();
  Eigen::Vector3d max_m = Eigen::Vector3d::Zero();
  /// Where the scene defines it ("file:line:col: path"), for messages; empty when built in code.
  std::string where;
};

/// Rayleigh damping B = alpha M + beta K.
struct RayleighSpec {
  double mass_alpha_per_s = 0.0;    ///< alpha [1/s]
  double stiffness_beta_s = 0.0;    ///< beta [s]
};

/// One deformable object.
struct TissueSpec {
  std::string name = "tissue";
  std::filesystem::path mesh_path;                 ///< absolute, resolved against the scene file
  double scale = 1.0;                              ///< applied first (file units -> metres)
  Eigen::Vector3d rotation_deg = Eigen::Vector3d::Zero();  ///< then rotation, XYZ Euler [deg]
  Eigen::Vector3d translation_m = Eigen::Vector3d::Zero(); ///< then translation [m]
  MaterialLaw law = MaterialLaw::kCorotational;
  TangentKind tangent = TangentKind::kCorotated;  ///< material.tangent (corotational law only)
  ElementKind element = ElementKind::kLinearTet;   ///< element
  double young_pa = 3000.0;
  double poisson = 0.45;
  double density_kgpm3 = 1000.0;
  std::optional<RayleighSpec> damping;             ///< absent: no damping terms at all
  std::vector<int> fixed_nodes;                    ///< node indices (file order, 0-based)
  std::vector<BoxSpec> fixed_boxes;                ///< nodes inside any box are fixed too
  std::vector<RegionSpec> fixed_regions;           ///< and the nodes of every region
  std::vector<LoadSpec> loads;                     ///< forces, pressures, displacements
  ComplianceKind compliance = ComplianceKind::kWarped;
  std::filesystem::path compliance_cache_dir;      ///< empty: no on-disk cache
  /// compliance.correction: exact -> ComplianceOptions::exact_correction
  bool exact_correction = false;
  /// compliance.c0_precision: float -> ComplianceOptions::c0_single_precision
  bool c0_single_precision = false;
  /// compliance.exact_below_coherence -> ComplianceOptions::exact_below_coherence (0: off)
  double exact_below_coherence = 0.0;
  /// compliance.rotation_smoothing -> ComplianceOptions::rotation_smoothing_passes (0: off)
  int rotation_smoothing_passes = 0;
  /// strain_limit.min_volume_ratio: after the constrained motion no tet keeps less than this
  /// share of its rest volume (docs/design.md, "Strain limiting"; 0: off)
  double min_volume_ratio = 0.0;
};

/// A pose: position [m] and orientation (unit quaternion), world frame.
struct PoseSpec {
  Eigen::Vector3d position_m = Eigen::Vector3d::Zero();
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
};

/// One key of a scripted instrument trajectory (linear/slerp interpolation between keys).
struct TrajectoryKey {
  double t_s = 0.0;
  PoseSpec pose;
  double gripper_opening = 1.0;   ///< 0 closed .. 1 fully open
};

/// An instrument (god object) and its coupling to its device. A scene has none, one
/// (`instrument:`) or several (`instruments:`, at most shared::kMaxInstruments): instrument i is
/// driven by haptic device i (haptic_server's i-th `--device`) or by its own script.
struct InstrumentSpec {
  bool present = false;
  std::string name;                             ///< for messages and status ("" : by index)
  InstrumentKind kind = InstrumentKind::kProbe;
  double mass_kg = 0.05;
  double inertia_kgm2 = 1e-5;                   ///< isotropic rotational inertia
  double coupling_k_npm = 500.0;                ///< translational PD stiffness
  double coupling_b_nspm = 5.0;                 ///< translational PD damping
  double coupling_k_rot_nmprad = 0.5;           ///< rotational PD stiffness
  double coupling_b_rot_nmsprad = 0.005;        ///< rotational PD damping
  double friction_mu = 0.0;                     ///< Coulomb coefficient tool/tissue (0: no tangential rows)
  double alarm_distance_m = 0.004;              ///< collision query radius beyond contact
  double contact_distance_m = 0.0;              ///< gap offset treated as contact
  /// Sphere-vs-triangle contacts (collision.h kind (b)) of the tool's spheres. false: only the
  /// surface vertices are held out of the tool (kind (a); a probe tip is also queried as a
  /// degenerate capsule), so the surface between held vertices may dip into a sphere of radius
  /// r by about l^2 / (8 r) for edges of length l: for tools much larger than the elements. On a
  /// surface that wraps a sphere the face contacts' closest points (projections of the centre on
  /// nearly equidistant triangles) jump between steps and the contact set never settles.
  bool face_contacts = true;
  // probe: a capsule from the tool origin along -z (shaft) with a spherical tip
  double tip_radius_m = 0.003;
  double shaft_length_m = 0.0;
  // grasper: two jaws hinged at the tool origin, opening about the tool x axis, pointing along -z
  double jaw_length_m = 0.02;
  double jaw_radius_m = 0.002;
  double max_opening_rad = 0.6;                 ///< half-angle of each jaw when fully open
  int jaw_samples = 8;                          ///< capsules (segments) per jaw
  /// Jaw pads: `jaw_rows` parallel rows of samples spread over `jaw_width_m` along the hinge
  /// axis (tool x), each row a capsule plus jaw_samples spheres. 1 row: a round jaw (default).
  int jaw_rows = 1;
  double jaw_width_m = 0.0;                     ///< centre-to-centre span of the rows
  /// Flat jaw pads (grasper.pad_width > 0): each jaw is a rounded box, the rectangle of
  /// jaw_length x pad_width_m swept by a sphere of jaw_radius (so 2 jaw_radius thick), with one
  /// pad feature (tissue vertices against the rectangle) and jaw_samples x pad_columns sample
  /// points on it (tissue triangles' interiors; see instrument.h). 0: round jaws (rows above).
  double pad_width_m = 0.0;
  int pad_columns = 3;                          ///< sample points across the pad's width
  /// Contact compliance [m/N]: added to the normal and tangential diagonal of W (collision.h,
  /// "Contact compliance"): the local compliance of the pad's serrations and of the tissue's
  /// surface layer under one contact point. A contact carrying f_n penetrates by c f_n.
  double contact_compliance_mpn = 0.0;
  /// Grip: 0 (default) = kinematic jaws (the opening follows the device's gripper value);
  /// > 0 = the jaw angle is a DOF pulled toward the device's value by this PD (see instrument.h).
  double grip_k_nmprad = 0.0;                   ///< grip stiffness [N m / rad]
  double grip_b_nmsprad = 0.0;                  ///< grip damping [N m s / rad]
  double grip_inertia_kgm2 = 1e-6;              ///< inertia of the jaw angle [kg m^2]
  /// The closing torque on the jaw angle of a fully closed handle beyond the spring's pull
  /// [N m]: (1 - gripper) times it is added, so a closed handle squeezes a thin bite too (the
  /// spring alone pulls with k phi, which vanishes as the jaws close); with grip_k_nmprad > 0
  double grip_squeeze_nm = 0.0;
  /// The open stop holds the jaws in the solve (instrument.h) instead of clamping them after
  /// it; with grip_k_nmprad > 0 (grasper.grip_hold_open_stop)
  bool grip_hold_open_stop = false;
  PoseSpec initial_pose;
  std::vector<TrajectoryKey> trajectory;        ///< scripted device target when no device drives it
  /// Where the device target may be (instrument.workspace {min, max}); absent: a box around the
  /// scene (instrumentWorkspace in instrument.h).
  std::optional<BoxSpec> workspace;
};

struct SolverSpec {
  LinearSolverKind linear = LinearSolverKind::kCholmod;
  double cg_tolerance = 1e-8;
  int cg_max_iterations = 500;
  int refactor_iterations = 8;                  ///< kCholmodReuse: PCG iteration bound
  int refactor_every_steps = 0;                 ///< kCholmodReuse: refresh schedule (0: none)
  /// kCholmodReuse: > 0 refreshes the factor on a worker thread, the new factor taking over this
  /// many steps later (FemSolverOptions::background_refactor_lag_steps); 0: on the step's thread
  int background_refactor_lag_steps = 0;
  /// kCholmodReuse in the background: the lag over steps without contact (a step whose
  /// contact correction did not solve with the body counts background_refactor_lag_steps / this
  /// of a step; FemSolverOptions::background_refactor_free_lag_steps); 0: the same lag
  int background_refactor_free_lag_steps = 0;
  /// kCholmodReuse: the PCG's local correction (FemSolverOptions::pcg_local_correction_threshold)
  double pcg_local_correction_threshold = 0.0;
  /// kCholmodReuse in the background: the new factor takes over as soon as the worker has
  /// finished, no step waiting for it (FemSolverOptions::background_refactor_when_ready)
  bool background_refactor_when_ready = false;
  /// kCholmodReuse in the background: the precision of PCG's preconditioner solves
  /// (FemSolverOptions::preconditioner_precision)
  PreconditionerPrecision preconditioner_precision = PreconditionerPrecision::kDouble;
  double nsgs_tolerance = 1e-6;
  int nsgs_max_sweeps = 500;
  double nsgs_sor = 1.0;                        ///< over-relaxation factor in (0, 2)
  /// Anderson acceleration of the NSGS sweeps: how many past sweeps it combines (0: off; at most
  /// shared::kMaxAndersonDepth; shared/nsgs.h, NsgsSettings::anderson_depth)
  int nsgs_anderson_depth = 0;
  /// Solve each group of bodies that share no contact (no tissue, no instrument in common) as a
  /// problem of its own (docs/design.md, "Bodies that do not couple"); false: one NSGS over the
  /// whole W
  bool split_contact_groups = true;
  int max_contacts = 300;
  /// Contact passes per step: after the constrained motion, contacts are detected again at the
  /// corrected state and, while some gap is below -penetration_tolerance_m, the contact problem
  /// is linearised there and solved again from the free motion (1: the paper's single pass).
  /// With a contact compliance c a contact's gap counts as gap + c f_n (f_n its normal force in
  /// the pass just solved): the penetration the compliance allows is not a linearisation error.
  int contact_iterations = 1;
  double penetration_tolerance_m = 1e-4;        ///< geometric gap accepted by the passes [m]
  /// Where the first pass detects its contacts. kFreeState (default): at the free state, so the
  /// rows are linearised where the free motion put the tissue (when it springs deep into the
  /// tool, far from where the constraint holds). kStepStart: at the start of the step (gaps ~0
  /// on a resting contact, normals and contact points of the constrained state), each gap
  /// carried to the free state along its row: delta_free = gap - n . ((p_tool - p_tool_free) -
  /// (p_tissue - p_tissue_free)). At rest the linearisation point is then the constrained
  /// equilibrium itself. The alarm distance must cover the relative motion of one step (contacts
  /// that start further apart are found only at the next step). Later passes
  /// (contact_iterations > 1) detect at the corrected state in both modes.
  ContactDetection contact_detection = ContactDetection::kFreeState;
};

/// haptics.local_model: the model haptic_server's tick solves (haptic_server --local-model;
/// haptic_server/include/tactus/haptic/local_model.h).
enum class HapticLocalModel { kAutomatic, kFull, kLinearized };

struct HapticsSpec {
  bool enabled = false;
  double rate_hz = 1000.0;
  double force_scale = 1.0;
  double max_force_n = 8.0;
  double watchdog_ms = 50.0;
  int max_sweeps_per_tick = 50;
  double nsgs_tolerance = 1e-6;
  /// haptic_server --nsgs-anderson-depth: Anderson acceleration of the tick's NSGS (0: off)
  int nsgs_anderson_depth = 0;
  /// haptic_server --snapshot-blend-ms: each new snapshot's force blended in over this time
  /// [ms] (0: off)
  double snapshot_blend_ms = 0.0;
  /// haptic_server --local-model: full re-solve, linearised with fallback, or automatic by size
  HapticLocalModel local_model = HapticLocalModel::kAutomatic;
  /// device -> scene mapping and clutch button (haptics.workspace; docs/design.md)
  shared::WorkspaceMappingParams workspace;
  /// haptics.workspaces: device i's own mapping (entry i for instrument/device i; at most the
  /// instrument count; empty: `workspace` for every device). Exclusive with `workspace`.
  std::vector<shared::WorkspaceMappingParams> workspaces;
};

/// haptic_server's options for the scene's haptics section, one per item (`--rate=R`,
/// `--max-force=F`, `--force-scale`, `--watchdog-ms`, `--max-sweeps`, `--tolerance`, then the
/// workspace mapping `--workspace-scale=S`, ... when it is not the identity, and each device's own
/// `--workspace-option=I:key=value`, one per field, from haptics.workspaces); none when haptics
/// is off. scripts/start.sh passes them on (sim_server --print-haptic-options), so the clamp a
/// scene sets is the one the device gets.
std::vector<std::string> hapticServerOptions(const HapticsSpec& haptics);

struct OutputSpec {
  bool enabled = false;
  std::filesystem::path directory;              ///< resolved against the working directory
  int every_n_steps = 1;
};

struct SceneSpec {
  std::filesystem::path source;                 ///< the YAML file (for messages)
  /// FNV-1a of the YAML text it was parsed from (part of the model identity a saved state is
  /// tied to; a program that edits the spec after parsing keeps it)
  std::uint64_t text_hash = 0;
  double time_step_s = 0.01;
  std::optional<Eigen::Vector3d> gravity_mps2;  ///< absent: no gravity
  std::vector<TissueSpec> tissues;
  std::vector<ObstacleSpec> obstacles;          ///< static obstacles (scene_regions.h)
  ObstacleContactSpec obstacle_contact;
  /// Contact between tissues and self-contact (`tissue_contact:`, tissue_contact.h)
  std::vector<TissueContactSpec> tissue_contacts;
  /// The first instrument (`instrument:`, or `instruments[0]`); present == false: none.
  InstrumentSpec instrument;
  /// `instruments[1..]`: the others, in order (empty with the single `instrument:` form). Every
  /// instrument's contacts go into the one contact problem of the step (pipeline.h).
  std::vector<InstrumentSpec> additional_instruments;
  SolverSpec solver;
  HapticsSpec haptics;
  OutputSpec output;
  double duration_s = 0.0;                      ///< scripted length (0: until stopped)
  /// Values outside their plausible range (scenes/README.md "Value ranges"), one line each as
  /// `file:line:col: field: unusual value ...`; also logged as warnings by parseScene/loadScene.
  std::vector<std::string> warnings;
};

/// Instruments of the scene: 0 without one, else 1 + additional_instruments.size().
int instrumentCount(const SceneSpec& spec);
/// Instrument i (0 = spec.instrument), 0 <= i < instrumentCount(spec).
const InstrumentSpec& instrumentSpec(const SceneSpec& spec, int i);
InstrumentSpec& instrumentSpec(SceneSpec& spec, int i);
/// Contacts the step's contact problem may hold: solver.max_contacts per instrument.
int problemContactCapacity(const SceneSpec& spec);
/// Whether some instrument has friction (3 rows per contact; else 1).
bool anyFriction(const SceneSpec& spec);
/// Contacts the tissue_contact pairs may add: max_contacts per direction (two per two-way pair).
int tissueContactCapacity(const SceneSpec& spec);
/// Rows they may add: 3 per contact on a pair with friction, else 1.
int tissueContactRowCapacity(const SceneSpec& spec);
/// Whether some tissue_contact pair has friction.
bool anyTissueContactFriction(const SceneSpec& spec);

/// Reads and validates a scene file. Throws tactus::SceneError listing every problem found
/// (unknown keys, wrong types, out-of-range values, missing mesh), each with file, line, column
/// and the field path (e.g. `scene.yaml:12:5: tissues[0].material.poisson: must be < 0.5`).
/// Every number has a hard range (impossible or memory-exhausting values are errors) and a
/// plausible one (outside it: a warning in SceneSpec::warnings, also logged).
SceneSpec loadScene(const std::filesystem::path& path);

/// Same from a string; relative paths resolve against `base_dir`, `name` is used in messages.
SceneSpec parseScene(const std::string& yaml, const std::string& name,
                     const std::filesystem::path& base_dir);

}  // namespace tactus::sim

