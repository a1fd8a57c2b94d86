#pragma once
// Contact compliance models of a tissue (paper 3.2 "Contact Compliance Warping";
// docs/design.md, "Compliance models").
//
// A contact row acts on the tissue through H: row r maps the DOF displacement dq to a relative
// displacement   (H dq)_r = sum_k weight[k] * dir . dq[node[k]]   (up to 3 nodes: a triangle
// point in barycentric form; signs are carried by `weight`/`dir`, chosen by the caller).
//
// Models:
//  * exact     : C from the current tangent (FemBody::solveCompliance): one solve per DOF of the
//                nodes the rows touch (3|U| solves, batched), then W = P^T C_UU P.
//  * warped    : C ~ R C0 R^T (eq. 12) with C0 precomputed for the surface DOFs (dense block,
//                CHOLMOD: one factorisation, one solve per surface DOF, progress shown),
//                cached on disk (header: magic, version, hash of mesh+material+h, sizes; a stale
//                or corrupt file is rebuilt, never trusted). R: per-node rotations
//                (FemBody::fittedNodeRotations at the free state: the polar factor of each
//                node's sum of v_e F_e, no second polar decomposition per element; the
//                linearisation point's rotations crushed the finite grip; nodes tied by very
//                short edges share one).
//  * rest      : C0 without rotation.
//  * uncoupled : diagonal per-node compliance (diag of C0, isotropic 3x3 per node).
// Constrained motion (paper 3.3): r0 = (H R)^T f, dq0 = C0 r0 (all DOFs, one solve with the
// rest factorisation), dq = R dq0 (exact: dq = C H^T f).
//
// W build (warped/rest/uncoupled): P (3|U| x m, U = nodes the rows touch) has at most 9 nonzeros
// per column (w_k R_a^T dir); G = C0_UU P is formed column by column from 3x3 blocks and
// W += P^T G, so the cost is O(m |U|) + O(m^2), independent of the mesh size.
// C0 is stored dense (3s x 3s for s surface nodes), double by default, float on request:
// liver2 (s = 432) 13.4 MB in double; liver_23k (s = 4795) 1.66 GB double / 0.83 GB float.
// The memory figure of each model is memoryBytes().

#include <Eigen/Core>
#include <array>
#include <filesystem>
#include <memory>
#include <span>
#include <string>

#include "tactus/sim/fem.h"

namespace tactus::sim {

class StateArchive;

/// One contact row on a tissue.
struct TissueRow {
  std::array<int, 3> node{-1, -1, -1};   ///< node indices (unused: -1)
  std::array<double, 3> weight{0, 0, 0};
  Eigen::Vector3d dir = Eigen::Vector3d::Zero();
};

/// Largest ComplianceOptions::rotation_smoothing_passes (the scene's bound too).
inline constexpr int kMaxRotationSmoothingPasses = 10;

struct ComplianceOptions {
  double h_s = 0.01;                       ///< time step the compliance is built for
  std::filesystem::path cache_dir;         ///< empty: no disk cache
  bool show_progress = true;               ///< progress bar on stderr for the precomputation
  /// Cache file stem inside cache_dir (file `<name>.c0.bin`). Empty: the mesh source's stem, or
  /// "tissue". Give each tissue of a scene its own name. A file left by another configuration
  /// (mesh, material, h, fixed nodes) is detected by its header hash and rebuilt.
  std::string cache_name;
  int solve_batch = 64;                    ///< right-hand sides per CHOLMOD call in the precompute
  /// Store C0 in float: half the memory (liver_23k: 4795 surface nodes, 0.83 GB instead of
  /// 1.66 GB). Each entry then carries a relative rounding error <= 6e-8, so W and the
  /// correction differ from the double model by ~1e-7 relative, far below the warping error
  /// itself (~1e-3 under large rotations). Double (default) is preferred for small meshes.
  bool c0_single_precision = false;
  /// Constrained motion with the exact compliance of the free motion (dq = C H^T f, one solve
  /// with the factorisation freeMotion left) whatever the model used for W. With it the
  /// corrected state is exactly the implicit Euler step under the contact force f, so a held
  /// contact cannot feed energy in through the model's error (measured on the slivers hard case:
  /// warped correction +1.05e-5 J while holding, exact correction 0 J); the price is one
  /// back-substitution per solve, and the linearised gap after the correction is no longer
  /// exactly what W predicted (it differs by H (C - C_model) H^T f; contact passes re-solve
  /// it). Off by default: the paper's scheme corrects with the model itself (R C0 R^T).
  bool exact_correction = false;
  /// Warped model's bound (0: off). Its W error grows like the squared spread of the element
  /// rotations between the contact nodes (FemBody::nodeRotations' coherence), which jaws that
  /// crush elements make large (liver2 pinch: W errors of 16-35 % where the nodes nearest the
  /// jaws reach coherence 0.94-0.97 and det F 0.2-0.4, docs/measurements.md, "Accuracy against time"). The
  /// contact nodes themselves stay more coherent, so the bound is an empirical threshold on
  /// them: when some node the rows touch has a coherence below this value, that step's W and
  /// correction use the exact compliance instead (3|U| solves with the free motion's
  /// factorisation); ComplianceBuildInfo::exact_fallbacks counts those calls. 0.9995 keeps
  /// liver2's grasp under 7 % (probe W error).
  double exact_below_coherence = 0.0;
  /// Warped model: smoothing passes of the node rotations R (FemBody::fittedNodeRotations; 0: the
  /// rotation of each node's own elements, the paper's scheme). The warp is exact only where R
  /// is uniform; where jaws crush elements their polar factors scatter from one element to the
  /// next, and the correction R_i dq0_i moves neighbours apart by |R_i - R_j| |dq0|. On
  /// liver_grasp_23k (1.8 mm surface elements) that spurious strain
  /// inverted tets under the pads at every step although the free motion left them at 0.7-1.0 of
  /// their volume; with two passes (the rotation averaged over about four element layers) the
  /// smallest tet in the jaws rose from -13.1 to -0.006 (docs/measurements.md, "Grasps"). W and the
  /// correction use the same rotations.
  int rotation_smoothing_passes = 0;
};

/// How the model was built (for logs and tests).
struct ComplianceBuildInfo {
  bool loaded_from_cache = false;          ///< C0 read from a valid cache file
  bool cache_rejected = false;             ///< a cache file existed but was stale/corrupt/truncated
  std::string cache_message;               ///< why it was rejected (empty otherwise)
  double precompute_s = 0.0;               ///< C0 factorisation + solves (0 when loaded)
  int surface_nodes = 0;                   ///< nodes whose C0 block is stored
  long skipped_row_nodes = 0;              ///< row nodes ignored because not on the surface
  /// warped with exact_below_coherence: addW calls that used the exact compliance
  long exact_fallbacks = 0;
};

/// What TissueCompliance::setWLower calls after each group of columns it completes: `call(context,
/// first, count)` once columns first .. first + count - 1 hold their final values from their
/// diagonal down. Empty (call null): nothing is called.
struct WColumnsDone {
  void (*call)(void* context, int first, int count) = nullptr;
  void* context = nullptr;
};

/// A tissue's compliance model. Model, state and scratch (docs/design.md, "Model, state,
/// scratch"): the model is what makeCompliance builds (the kind, the options, C0 on the surface
/// or its diagonal) and does not change afterwards; the state is what update() refreshes once a
/// step (the warped model's node rotations, the body whose factor the exact model uses); addW and
/// correction only use scratch reused from call to call (compliance.cpp lists the members by
/// group).
class TissueCompliance {
 public:
  virtual ~TissueCompliance() = default;
  virtual ComplianceKind kind() const = 0;
  /// Once per step, after free motion: refresh rotations (warped: FemBody::fittedNodeRotations
  /// at the free state, one pass over the elements and a polar factor per node; with
  /// exact_below_coherence also FemBody::nodeRotations for the coherence) / nothing (rest).
  virtual void update(FemBody& body) = 0;
  /// W += H C H^T for the given rows (W is rows.size() square, row-major or column-major alike:
  /// the result is symmetric).
  virtual void addW(std::span<const TissueRow> rows, Eigen::Ref<Eigen::MatrixXd> W) = 0;
  /// The lower triangle (diagonal included) of W, column-major rows.size() square, set to that
  /// of H C H^T: the values addW adds into a zero W, bit for bit, written once and in place
  /// (buildW's assembly: no m x m scratch, no mirror; the caller mirrors the triangle it
  /// completes). The strict upper triangle is left unspecified. `done` is called as groups of
  /// columns are completed, each column once, in order, while they are still in cache (buildW
  /// adds the instrument's terms there rather than in a second pass over W). By default through
  /// addW, then `done` for all columns at once.
  virtual void setWLower(std::span<const TissueRow> rows, Eigen::Ref<Eigen::MatrixXd> W,
                         WColumnsDone done = {}) {
    W.setZero();
    addW(rows, W);
    if (done.call != nullptr) done.call(done.context, 0, static_cast<int>(rows.size()));
  }
  /// dq = C H^T f (3n; fixed DOFs zero). `f` has rows.size() entries.
  virtual void correction(FemBody& body, std::span<const TissueRow> rows, const double* f,
                          Eigen::VectorXd& dq) = 0;
  /// Bytes held by the model (C0 block etc.), for the log.
  virtual std::size_t memoryBytes() const = 0;
  /// Sizes (and writes once) addW's scratch for problems of up to `rows` rows, so that the
  /// steps' calls neither allocate nor touch memory new to the process while the contacts grow
  /// (a first touch of a page cost ~18 us on the VM measured in docs/measurements.md, "The
  /// simulation step at organ scale"). The Simulation calls it with the largest problem's rows.
  /// Nothing by default.
  virtual void reserve(int rows) { (void)rows; }
  /// How the model was built; skipped_row_nodes is cumulative over addW/correction calls
  /// (warped/rest/uncoupled only know the surface nodes: a row node inside the volume contributes
  /// zero compliance and is counted here).
  virtual ComplianceBuildInfo buildInfo() const { return {}; }
  /// Writes or reads the model's state (state_archive.h; the rotations of the last update()).
  virtual void transferState(StateArchive& ar) = 0;
};

/// Cache file used for `body` under `options` (empty path when options.cache_dir is empty).
std::filesystem::path complianceCachePath(const FemBody& body, const ComplianceOptions& options);

/// Builds the model. `warped`/`rest`/`uncoupled` precompute C0 (or load it from the cache).
std::unique_ptr<TissueCompliance> makeCompliance(ComplianceKind kind, FemBody& body,
                                                 const ComplianceOptions& options);

}  // namespace tactus::sim
