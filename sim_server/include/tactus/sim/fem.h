#pragma once
// Tetrahedral FEM body: linear or corotational elasticity, lumped mass, Rayleigh damping,
// gravity, Dirichlet nodes, and implicit Euler free motion (paper eq. 2-7).
//
//   (M/h + B + hK) dv = p - F(q + h v, v),  v_free = v + dv,  q_free = q + h v_free
//
// with F the internal (elastic + damping) force, K its tangent, B = alpha M + beta K.
// Corotational: per element R_e from the deformation gradient (SVD polar decomposition with sign
// correction, robust to inverted elements), f_e = R_e K0_e (R_e^T x_e - X_e), tangent
// R_e K0_e R_e^T (TangentKind::kConsistent: plus the rotation's own stiffness where positive).
// Linear: R_e = I (no rotation extraction at all). Invertible neo-Hookean: the law in the
// principal stretches of the rotation-valued SVD, with its full tangent projected positive
// semi-definite (fem_constitutive.h). ElementKind::kEdgeSmoothedTet: the same laws on one
// smoothed strain per mesh edge instead of one per tetrahedron (docs/design.md, "Element
// choice"); the system matrix's pattern then couples every pair of nodes of the tetrahedra
// around an edge.
//
// Element loops: linear and corotational tetrahedra with the corotated tangent (the default,
// every shipped scene) go four elements at a time through a vector kernel whose polar
// decompositions start from each element's last rotation (femElementKernelName). The tissue
// options (kConsistent, the invertible neo-Hookean law, kEdgeSmoothedTet) take the reference
// element loop instead, one element or domain at a time with a fresh SVD polar decomposition:
// the batched kernel computes only the corotated linear stress and tangent.
//
// The system matrix keeps a fixed sparsity pattern; CHOLMOD's symbolic analysis runs once in the
// constructor and every step refactorises numerically (LinearSolverKind::kCholmod), or a
// recent factorisation preconditions a PCG (kCholmodReuse, see FemSolverOptions). Fixed nodes are eliminated (their rows and
// columns are not in the system; their displacement stays zero).
//
// The contact compliance C = (M/h^2 + B/h + K)^-1 = h (M/h + B + hK)^-1 is available from the
// factorisation of the last free motion (`solveCompliance`) and from a rest-shape factorisation
// (`solveRestCompliance`), which compliance.h uses.

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "tactus/sim/mesh.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {

class StateArchive;

struct FemMaterial {
  MaterialLaw law = MaterialLaw::kCorotational;
  /// kConsistent: the corotational law's tangent with the rotation's own stiffness where it is
  /// positive (corotational law only; the other laws ignore it)
  TangentKind tangent = TangentKind::kCorotated;
  /// kEdgeSmoothedTet: one strain per mesh edge instead of one per tetrahedron (bending without
  /// the linear tetrahedron's locking; docs/design.md, "Element choice")
  ElementKind element = ElementKind::kLinearTet;
  double young_pa = 3000.0;
  double poisson = 0.45;
  double density_kgpm3 = 1000.0;
  std::optional<RayleighSpec> damping;          ///< absent: B = 0, no damping terms computed
};

/// Preconditioner of the PCG solver.
enum class PcgPreconditioner {
  kJacobi,        ///< diagonal of A (cheap, many iterations on large meshes)
  kRestCholesky,  ///< CHOLMOD factor of the rest-shape A0 = M/h + B0 + h K0 (factorised once
                  ///< per h; few iterations while the rotations stay moderate)
  kWarpedCholesky,  ///< R A0^-1 R^T with R the per-node rotations of the step (the warped
                    ///< rest factor, as in the paper's eq. 12): few iterations even under large
                    ///< rotations; one CHOLMOD solve per iteration
};

/// Linear solve of the step, A dv = b with A = M/h + B + hK:
///  * kCholmod: CHOLMOD factorises A every step and solves directly.
///  * kPcg: PCG (cg_tolerance, cg_max_iterations) with `pcg_preconditioner`.
///  * kCholmodReuse: PCG warm-started from the previous step's dv and preconditioned by the
///    CHOLMOD factor of a recent A (the factor is that of an earlier step's A_f, or of the current
///    one after solveCompliance refreshed it). Corotational material: the preconditioner is
///    warped, T A_f^-1 T^T with T the per-node rotations since A_f's step (node rotations as in
///    nodeRotations(), from the step's element rotations), so the factor follows the tissue's
///    rotations (the liver scenes' tissue settling under gravity: 14-21 % of the steps
///    factorise instead of 47-57 % unwarped, docs/measurements.md, "Soft tissue"). The warm start is
///    extrapolated from the last two steps' dv. The factor is refreshed synchronously (the
///    current A is factorised and solved directly) when PCG does not reach cg_tolerance within
///    refactor_iterations iterations, when the previous step needed more than half of them,
///    and every refactor_every_steps steps when that is > 0. Every step's dv meets cg_tolerance
///    (relative residual) or comes from a fresh factorisation. cg_max_iterations is not used.
///    With background_refactor_lag_steps > 0 (scene key solver.background_refactor_lag_steps,
///    2 in liver_grasp_20k and liver_grasp_23k; the default 0 refreshes synchronously, which the
///    small scenes keep, docs/design.md) the schedule and the drift refresh
///    off the step's critical path: a worker thread factorises the step's A while the steps go
///    on with PCG on the old factor (up to 3 x refactor_iterations), and the new factor takes
///    over background_refactor_lag_steps steps later (that step waits for the worker only if
///    it has not finished: FemStepStats::factor_wait_s). Only the first step, and a PCG that
///    misses 3 x refactor_iterations, factorise on the step's thread. The steps at which the
///    factor changes do not depend on the worker's speed: the results do not depend on timing
///    (the step's solves run CHOLMOD's supernodal sweeps without BLAS, the same bits whatever
///    the worker does), and a state saved with a factorisation in flight restarts it.
///    With background_refactor_when_ready as well (scene key
///    solver.background_refactor_when_ready) no step waits for the worker: the new factor takes
///    over at the first step, background_refactor_lag_steps or more after its start, at which the
///    worker has finished (Counters::background_not_ready counts the steps that went on with the
///    old factor instead); each step still meets cg_tolerance, but which factor preconditions
///    which step then depends on the worker's timing (the solves are the BLAS-free sweeps as
///    above: none waits for the worker's BLAS either).
struct FemSolverOptions {
  LinearSolverKind linear = LinearSolverKind::kCholmod;
  double cg_tolerance = 1e-8;                   ///< relative residual ||A dv - b|| / ||b||
  int cg_max_iterations = 500;
  PcgPreconditioner pcg_preconditioner = PcgPreconditioner::kJacobi;
  int refactor_iterations = 8;                  ///< kCholmodReuse: PCG iteration bound (>= 1)
  int refactor_every_steps = 0;                 ///< kCholmodReuse: refresh schedule (0: none)
  /// kCholmodReuse: steps between a background factorisation's start and the step that takes
  /// its factor (0, the default: refresh synchronously, on the step's thread; liver_grasp_20k
  /// and liver_grasp_23k set 2)
  int background_refactor_lag_steps = 0;
  /// kCholmodReuse in the background, the lagged takeover: the lag over steps without contact.
  /// The steps since a job's start are added up, a step in which a contact correction solved
  /// with the body's compliance (solveCompliance, solveComplianceBatch, solveRestCompliance)
  /// counting 1 / background_refactor_lag_steps and one without 1 / this, and the new factor
  /// takes over at the step at which they reach 1: a step out of contact costs about half of one
  /// in contact on the grasp scenes, the factorisation the same, so fewer steps would wait for
  /// it out of contact (liver_grasp_23k sets 4 with the lag 2). Which steps count how much
  /// follows from the contacts, never from the worker's speed: reproducible bit for bit.
  /// 0 (the default): background_refactor_lag_steps, every step counting alike. With
  /// background_refactor_when_ready the same count is the least age at which a job is taken.
  int background_refactor_free_lag_steps = 0;
  /// kCholmodReuse in the background: the new factor takes over as soon as it is ready (no step
  /// waits for the worker; timing-dependent results) instead of exactly
  /// background_refactor_lag_steps steps after its start (reproducible; waits if not ready)
  bool background_refactor_when_ready = false;
  /// kCholmodReuse in the background (background_refactor_lag_steps > 0, the supernodal factor
  /// solved without BLAS): the precision of PCG's preconditioner solves. kFloat and kHalf sweep
  /// a reduced copy of the factor that the worker makes after its factorisation, so a step
  /// never pays the conversion; the sweeps read the whole factor and are bound by memory, so
  /// fewer bytes are a faster solve. PCG itself stays in double and meets cg_tolerance as
  /// before. Scene key solver.preconditioner_precision (liver_grasp_20k and liver_grasp_23k:
  /// half; docs/design.md, "Free motion")
  PreconditionerPrecision preconditioner_precision = PreconditionerPrecision::kDouble;
  /// kCholmodReuse, corotational: > 0 corrects the warped factor exactly at the nodes where it
  /// is furthest from the current A: those whose diagonal 3x3 block of A differs from the warped
  /// factor's by more than this fraction (Frobenius norms; at most
  /// pcg_local_correction_max_nodes of them, the furthest off), solved together with a dense
  /// Cholesky factor inside each preconditioner application (a deflated PCG; the tets crushed
  /// between a grasper's jaws deform unlike their nodes' rotations, and PCG spent most of its
  /// iterations there). 0, the default: none. Scene key solver.pcg_local_correction_threshold
  /// (liver_grasp_20k sets 0.03, liver_grasp_23k 0.05; docs/design.md, "Free motion")
  double pcg_local_correction_threshold = 0.0;
  int pcg_local_correction_max_nodes = 96;
};

/// Per-stage wall times of the last step [s] and solver figures. freeMotion allocates nothing
/// in our code after the first step (CHOLMOD allocates internally during factorisation).
struct FemStepStats {
  double assembly_s = 0.0;
  /// CHOLMOD numeric factorisation (PCG: the rest factor when it is refreshed; kCholmodReuse:
  /// the steps that refresh, and the wait for a background factor, factor_wait_s)
  double factorisation_s = 0.0;
  double solve_s = 0.0;
  int cg_iterations = 0;                        ///< 0 for kCholmod
  /// kCholmodReuse: nodes in the PCG's local correction (pcg_local_correction_threshold)
  int pcg_local_nodes = 0;
  /// false: the factorisation failed or dv was not finite (state kept), or CG stopped above its
  /// tolerance (its last finite iterate is applied; cg_residual says how far it got).
  bool ok = true;
  double cg_residual = 0.0;                     ///< final relative residual (CG only)
  /// kCholmodReuse: the step factorised its current A (then cg_iterations counts the PCG
  /// iterations of an attempt that did not converge within the bound, if any).
  bool factor_refreshed = false;
  /// kCholmodReuse in the background: the step started factorising its A on the worker thread,
  /// took a finished background factor, and waited this long for the worker (0: it had finished)
  bool background_factorisation_started = false;
  bool background_factor_taken = false;
  double factor_wait_s = 0.0;
  /// kCholmodReuse: the refresh (factor_refreshed) solved directly with the factor
  /// prepareFreeMotion made from this step's A: no factorisation on the step's thread
  bool factor_prepared = false;
  /// Tetrahedra inverted at the start of the step (det F <= 0 at the positions the step starts
  /// from). The corotational force pushes an inverted element back (see polarRotation); a count
  /// that stays up at equilibrium means the mesh or material cannot carry the load.
  int inverted_elements = 0;
};

class FemBody {
 public:
  /// `mesh` positions are in metres (the scene transform already applied). `fixed_nodes` are node
  /// indices. `gravity_mps2` null: no gravity. Throws tactus::NumericalError / tactus::Error.
  FemBody(const TetMesh& mesh, const FemMaterial& material, const std::vector<int>& fixed_nodes,
          const Eigen::Vector3d* gravity_mps2, const FemSolverOptions& options = {});
  ~FemBody();
  FemBody(const FemBody&) = delete;
  FemBody& operator=(const FemBody&) = delete;

  const TetMesh& mesh() const;
  int nodeCount() const;
  int dofCount() const;                          ///< 3 * nodeCount()
  const std::vector<bool>& fixedMask() const;   ///< per node

  // State (3n vectors, node-major xyz). Users may write q/v (e.g. constrained motion), keeping
  // fixed nodes at rest.
  const Eigen::VectorXd& restPositions() const;
  Eigen::VectorXd& positions();
  Eigen::VectorXd& velocities();
  const Eigen::VectorXd& positions() const;
  const Eigen::VectorXd& velocities() const;
  const Eigen::VectorXd& lumpedMass() const;    ///< per DOF [kg]

  /// Implicit Euler free motion over `h` seconds with optional external force p (3n, may be null).
  /// Updates positions/velocities to the free state. Leaves A = M/h + B + hK at the
  /// linearisation point (and with kCholmod its factorisation) for solveCompliance(). The
  /// linearisation point is q + h v: element rotations, elastic force and tangent K are taken
  /// there, and the damping force is B v with the same K (eq. 7 with F(q + h v, v)).
  FemStepStats freeMotion(double h, const Eigen::VectorXd* external_force_n = nullptr);

  /// Elastic force the material applies to the nodes at positions q (3n): the restoring force,
  /// i.e. minus the elastic part of F in eq. 7, so that M a = p + force_out (no damping).
  /// Element rotations are updated from q (corotational). Fixed nodes get their reaction too.
  void elasticForce(const Eigen::VectorXd& q, Eigen::VectorXd& force_out);

  /// Static equilibrium under gravity and `external_force_n` (3n, may be null) by Newton
  /// iterations on f_el(q) + f_ext = 0 through the same assembly (K only: no mass, no damping),
  /// CHOLMOD. Linear material: one iteration is exact. Stops when ||residual|| <= tol_n or after
  /// `max_iterations`. Velocities are set to zero. Returns the stats of the last iteration.
  FemStepStats solveStatic(const Eigen::VectorXd* external_force_n = nullptr,
                           int max_iterations = 20, double tol_n = 1e-10);

  /// x = C r with C = (M/h^2 + B/h + K)^-1 from the last freeMotion's factorisation (h of that
  /// step). Fixed DOFs of x are zero. r and x are 3n.
  /// With the PCG solvers the current A is factorised by CHOLMOD on the first call after a step
  /// when the step did not (kCholmodReuse then preconditions the next steps with that factor).
  void solveCompliance(const Eigen::VectorXd& r, Eigen::VectorXd& x) const;
  /// Same for the columns of r (3n x k) at once (one CHOLMOD call).
  void solveComplianceBatch(const Eigen::MatrixXd& r, Eigen::MatrixXd& x) const;

  /// x = C0 r with C0 the compliance at the rest shape (K0, same h). Factorised on first use
  /// (or when h changes) and kept.
  void solveRestCompliance(double h, const Eigen::VectorXd& r, Eigen::VectorXd& x);
  /// Same for the columns of r (3n x k) at once.
  void solveRestComplianceBatch(double h, const Eigen::MatrixXd& r, Eigen::MatrixXd& x);
  /// Factorises the rest-shape matrix for h now (nothing when it is already), so that the first
  /// solveRestCompliance does not: the warped and rest compliance models call it when they are
  /// built, whose C0 loaded from a cache would otherwise leave the factorisation (its analysis
  /// and numeric factorisation, about 0.4 s of CPU on liver_grasp_23k) to the first step in
  /// contact.
  void prepareRestCompliance(double h);
  /// kCholmodReuse, before the first step (no factor of record yet): assembles the system
  /// matrix the next freeMotion(h) will assemble from the current state and factorises it now
  /// (with the symbolic analysis), so that the first step does not: that step checks that its
  /// A is the prepared one to the bit and then solves directly with the prepared factor (the
  /// same factor and the same results as factorising there); any other A (the state changed in
  /// between, another h) is factorised by the step as before. Nothing to do for the other
  /// solvers or once a factor of record exists. On liver_grasp_23k the first step's
  /// factorisation was 0.5 s of the step (docs/measurements.md, "The simulation step at organ
  /// scale").
  void prepareFreeMotion(double h);
  /// Time step of the last freeMotion (0 before the first).
  double lastStepH() const;

  /// Per-element rotations of the last evaluation (identity for linear material).
  const std::vector<Eigen::Matrix3d>& elementRotations() const;
  /// Per-node rotations rest -> current: volume-weighted average of adjacent element rotations,
  /// re-orthonormalised (polar). Identity for linear material. Recomputed from current positions.
  ///
  /// Rotation groups: nodes joined by an edge shorter than 5 % of the longest edge of an element
  /// containing it (transitively) share one rotation, the polar factor of the sum of their
  /// members' volume-weighted element rotations. Such an element is flat across that edge and
  /// stiff in proportion to 1/length, so the rest compliance C0 moves the two nodes (almost)
  /// together; the warped correction dq_i = R_i dq0_i then keeps them together only if
  /// R_i = R_j. Without the groups, a node that belongs only to flat elements (a 5 um cell layer
  /// under a surface) takes its rotation from their ill-conditioned polar factors (measured:
  /// 0.29 rad away from the node 5 um below it), and rotating a ~0.4 mm dq0 by the two
  /// rotations moved the nodes 0.12 mm apart across the 5 um layer: 22 elements inverted in one
  /// correction, 289 later. A mesh without such edges has no groups (nothing changes); the
  /// constructor logs the groups it finds. Slivers without a short edge (a node near the plane
  /// of the opposite face) are not grouped; volume weighting keeps their rotation's influence
  /// small wherever a node also has well-shaped elements. The warped PCG preconditioner uses the
  /// same groups.
  ///
  /// Smoothing (`smoothing_passes` > 0; the warped compliance's
  /// ComplianceOptions::rotation_smoothing_passes): each pass replaces every node's sum by the
  /// sum, over its elements, of their four nodes' sums, so one pass averages over the elements
  /// within two element layers of the node, and each further pass adds one layer on each side.
  /// Under a rigid rotation nothing changes; where a grasp crushes elements their polar factors
  /// scatter from one element to the next, and the warped correction R_i dq0_i then moves
  /// neighbouring nodes apart by |R_i - R_j| |dq0| (docs/design.md, "Rotation smoothing").
  ///
  /// `coherence` (optional): per node, |sum v_e R_e|_F / (sqrt(3) sum v_e) over the elements
  /// (group, smoothing passes) the average uses: 1 when they all rotate alike, smaller as their
  /// rotations spread (about 1 - theta^2/3 for a spread of theta rad). The warped compliance's
  /// error grows like the spread squared (docs/measurements.md, "Accuracy against time": elements crushed by a
  /// grasp). Throws tactus::Error when smoothing_passes < 0. Each element's polar factor is
  /// taken by the element loop's Newton steps from the rotation the last step kept (a cold
  /// decomposition on the general element loop or before any step): the same factors to
  /// rounding. Works in the body's scratch: not for concurrent calls on one body.
  void nodeRotations(std::vector<Eigen::Matrix3d>& out,
                     std::vector<double>* coherence = nullptr, int smoothing_passes = 0) const;
  /// The same node rotations from the element rotations of the last free motion's element loop,
  /// i.e. at its linearisation point q + h v, where the step's system matrix A (and so the exact
  /// compliance C = h A^-1) was taken: no second polar decomposition per element. Before the
  /// first free motion, or after solveStatic, nodeRotations at the current positions. The
  /// cholmod_reuse preconditioner's warp uses them (not the warped compliance: see design.md).
  void stepNodeRotations(std::vector<Eigen::Matrix3d>& out,
                         std::vector<double>* coherence = nullptr, int smoothing_passes = 0) const;
  /// Node rotations without a polar decomposition per element: per node the rotation closest to
  /// its elements' deformation gradients at the current positions, i.e. the polar factor of
  /// sum v_e F_e (which minimises sum v_e |F_e - R|_F^2), over the same elements (rotation
  /// group, `smoothing_passes` passes) as nodeRotations. Where the elements rotate alike
  /// (F_e = R S_e, S_e symmetric positive definite) it is that R whatever their stretch, as
  /// nodeRotations; where they scatter, elements weigh with their stretch (a crushed element
  /// less along its crushed axis). One pass over the elements (F_e and the node sums) and one
  /// polar factor per node. The warped compliance's rotations at the free state (docs/design.md,
  /// "The warped compliance's rotations from the deformation gradients"). Throws tactus::Error
  /// when smoothing_passes < 0. Works in the body's scratch: not for concurrent calls on one
  /// body.
  void fittedNodeRotations(std::vector<Eigen::Matrix3d>& out, int smoothing_passes = 0) const;

  /// Per-element volume ratio det F = current signed volume / rest volume at the current
  /// positions (<= 0: inverted).
  void volumeRatios(Eigen::VectorXd& out) const;
  /// Elements with det F <= 0 at the current positions.
  int invertedElementCount() const;

  /// Per-element von Mises stress [Pa] at the current positions.
  void vonMises(Eigen::VectorXd& out) const;
  /// Per-element stress tensor [Pa] at the current positions: the corotated linear stress
  /// R sigma(eps) R^T with eps = sym(R^T F) - I (linear material: R = I, eps = sym(F) - I);
  /// invertible neo-Hookean: P R^T = U diag(P^) U^T, the same measure for that law. From each
  /// tetrahedron's own F, also for edge-smoothed strain (whose domains straddle elements).
  void stresses(std::vector<Eigen::Matrix3d>& out) const;
  /// Kinetic energy 1/2 v^T M v and elastic energy (the law's strain energy over the
  /// integration domains: tetrahedra or edge-smoothed domains) [J].
  double kineticEnergy() const;
  double elasticEnergy() const;
  /// Gravitational potential energy -sum m_i g . x_i (0 without gravity) [J].
  double gravityEnergy() const;

  /// Counters of the pipeline's "absent = not computed" promise.
  struct Counters {
    long rotation_extractions = 0;              ///< element polar decompositions performed
    long damping_evaluations = 0;               ///< steps that built damping terms
    long factorisations = 0;                    ///< on the step's thread
    long background_factorisations = 0;         ///< taken from the worker thread
    /// steps that waited more than 0.1 ms for the worker (factor_wait_s), and the longest wait
    long background_waits = 0;
    double background_wait_max_s = 0.0;
    double background_wait_s = 0.0;             ///< all the steps' waits for the worker
    /// made before the first step (prepareFreeMotion) and used by it instead of a factorisation
    /// on the step's thread (not in `factorisations`)
    long prepared_factorisations = 0;
    /// background_refactor_when_ready: steps at which a background factor was due and not
    /// ready (they went on with the factor they had instead of waiting)
    long background_not_ready = 0;
    /// integration domains evaluated by the general element loop: 0 unless the material asks
    /// for the consistent tangent, the invertible law or edge-smoothed strain
    long general_domain_evaluations = 0;
    /// elements the element loop's batched kernel left to its reference path (an
    /// ill-conditioned or inverted F, a rotation its warm-started Newton steps did not reach)
    long fallback_elements = 0;
  };
  const Counters& counters() const;

  /// Unknowns of the reduced system (free DOFs) and nonzeros of the CHOLMOD factor of the
  /// system matrix (0 before the first factorisation).
  int freeDofCount() const;
  std::size_t factorNonzeros() const;
  /// kCholmodReuse in the background: a factorisation started on the worker thread and not yet
  /// taken (a state saved now holds it: the restore starts it again)
  bool backgroundFactorisationInFlight() const;
  /// Sorted unique boundary nodes (faces that belong to one tetrahedron), computed once.
  const std::vector<int>& surfaceNodes() const;
  /// Hash of everything the rest compliance depends on except h: node positions at rest, tets,
  /// material (law, E, nu, rho, damping) and fixed nodes.
  std::uint64_t restHash() const;

  /// Writes or reads what a step changes and the next step reads (q, v, the element rotations,
  /// A, the factor of record and what it was computed from, the warm starts; state_archive.h).
  /// Reading rebuilds the factor from what it was computed from, so the next freeMotion gives
  /// the same bits as it would have after the step that wrote the state. Throws StateError.
  void transferState(StateArchive& ar);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The element loop's kernel this process runs: "avx" or "generic" (the same operations in the
/// x86-64 baseline: both give the same bits), or "reference" (every element through the
/// reference constitutive step, for tests). Chosen once from the CPU (AVX when it has it);
/// TACTUS_FEM_KERNEL names another. setFemElementKernel switches (false: unknown or not
/// supported by this CPU; nothing changes); not while an element loop runs.
const char* femElementKernelName();
bool setFemElementKernel(const char* name);

/// Threads of the numeric libraries CHOLMOD brings into the process.
struct NumericThreads {
  int blas_threads = -1;            ///< openblas_get_num_threads(); -1: OpenBLAS not loaded
  std::string blas_config;          ///< openblas_get_config() (e.g. "... SINGLE_THREADED ...")
  int omp_max_active_levels = -1;   ///< omp_get_max_active_levels(); -1: libgomp not loaded
};

/// Runs CHOLMOD's numeric libraries on the calling process's thread only: OpenMP parallel
/// regions off (omp_set_max_active_levels(0)) and OpenBLAS at one thread
/// (openblas_set_num_threads(1)), both looked up with dlsym so neither is a link dependency.
/// Setting OPENBLAS_NUM_THREADS from the program cannot work: OpenBLAS is loaded with CHOLMOD and
/// reads it in its load-time constructor, before main. The first call applies the limit and logs
/// it ("numeric threads: BLAS 1 (...)"); every CholmodSolver makes that call before CHOLMOD's
/// first BLAS call. Later calls return the state it left.
NumericThreads limitNumericThreads();

/// The current state, without changing it.
NumericThreads queryNumericThreads();

/// The CHOLMOD calls that use BLAS (supernodal factorisations and solves, of every FemBody in the
/// process) hold one process-wide lock: the serial OpenBLAS that Debian installs keeps one work
/// buffer per process, so two threads must not run BLAS at once. Nothing else is serialised:
/// the library defines no BLAS routine of its own. With the background refresh on
/// (FemSolverOptions::background_refactor_lag_steps > 0) a worker thread runs BLAS, under this
/// lock, between and during steps, and the body's step-thread solves make no BLAS call (the
/// supernodal factor's sweeps by Eigen's kernels). A program that calls BLAS itself on other threads meanwhile (numpy included) must take
/// lockCholmodBlas() around those calls, or use a BLAS that is safe to call from several threads
/// (an OpenBLAS built with threads or with USE_LOCKING), or keep the background refresh off.
/// Calls that found the lock taken, and their total wait [s].
struct BlasLockFigures {
  long contended_calls = 0;
  double waited_s = 0.0;
};
BlasLockFigures blasLockFigures();

/// The lock above, for a program's own BLAS calls (see BlasLockFigures).
std::unique_lock<std::mutex> lockCholmodBlas();

/// A scene tissue's material and the scene's linear solver settings as the FemBody takes them.
FemMaterial femMaterial(const TissueSpec& tissue);
FemSolverOptions femSolverOptions(const SolverSpec& solver);

/// Applies a scene transform (scale, then XYZ Euler rotation in degrees, then translation).
/// The rotation is extrinsic x, then y, then z: R = Rz(rz) Ry(ry) Rx(rx).
void transformMesh(TetMesh& mesh, double scale, const Eigen::Vector3d& rotation_deg,
                   const Eigen::Vector3d& translation_m);

/// Node indices whose positions lie inside any of the boxes.
std::vector<int> nodesInBoxes(const TetMesh& mesh, const std::vector<BoxSpec>& boxes);

}  // namespace tactus::sim
