#pragma once
// FemBody's private state (fem_body.cpp: setup and steps; fem_solve.cpp: the linear solves;
// fem_queries.cpp: queries of the state; fem_assembly.cpp: the element loop and the system
// matrix pattern; fem_scene.cpp: a scene's tissue to the FEM's inputs). Not installed.

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <array>
#include <cstdint>
#include <vector>

#include "fem_internal.h"
#include "tactus/sim/fem.h"

namespace tactus::sim {

using Sparse = fem_detail::CholmodSolver::Sparse;

// Entries of one element's lower-triangular contribution: blocks (a, b) with a >= b, and only
// i >= j inside diagonal blocks: 4 * 6 + 6 * 9.
inline constexpr int kEntriesPerElement = 78;
// The element loop's offsets into A's values: per block (a, b), a >= b, one per column.
inline constexpr int kBlockOffsetsPerElement = 30;

// FemBody's data in three groups, in the manner of the pipeline's SimulationModel /
// SimulationState / StepScratch (docs/design.md, "Model, state, scratch"):
//  * FemModel: what the mesh, material and options define, set by init and not changed by a step
//    (plus the rest-shape factorisation and the surface, derived from them once on demand);
//  * FemState: what a step (or solveStatic) changes and the next step or a query reads;
//  * FemScratch: buffers a step reuses; their values mean nothing between calls.
// FemBody::Impl derives from all three so that its member functions (fem_assembly.cpp,
// fem_solve.cpp, ...) name the members as before; the group a member belongs to is its type's.
struct FemModel {
  TetMesh mesh;
  FemMaterial material;
  FemSolverOptions options;
  bool corotational = true;
  bool has_gravity = false;
  Eigen::Vector3d gravity = Eigen::Vector3d::Zero();
  double lambda = 0.0, mu = 0.0;

  int n = 0;
  std::vector<bool> fixed;
  std::vector<int> dof_base;  // first reduced DOF of each node, -1 when fixed
  int n_free = 0;             // reduced DOFs

  Eigen::VectorXd rest, mass;

  // per element: shape function gradients (columns g_0..g_3) and rest volume
  std::vector<Eigen::Matrix<double, 3, 4>> grad;
  std::vector<double> volume;

  // The element loop's copy of the element data, in assembly order: sorted by their nodes'
  // lowest reduced DOF, then second lowest, ..., so that consecutive elements scatter into
  // nearby memory; the local nodes of each by ascending reduced DOF.
  struct AssemblyElement {
    std::array<int, 4> node;
    int index;                      // in mesh.tets
    bool has_fixed;                 // some block has a fixed node (its offsets are -1)
    Eigen::Matrix<double, 3, 4> g;  // grad[index], columns in the order of `node`
    double vol;                     // = volume[index]
  };
  std::vector<AssemblyElement> assembly_elems;
  // The same elements four at a time for the batched element loop (fem_assembly.cpp): lane l of
  // batch b is assembly element 4 b + l; the last batch's missing lanes repeat its first element
  // (computed, never scattered).
  struct ElementBatch {
    int x[4][4];        // [local node][lane]: 3 * node, the node's first entry in q, v and forces
    double g[3][4][4];  // [component][local node][lane]: the shape gradients
    double vol[4];
  };
  std::vector<ElementBatch> batches;
  // where each element writes into A's fixed pattern: per assembly element and block (a, b),
  // a >= b, in order (0,0), (1,0), (1,1), (2,0), ...: for each column j of the block, the
  // position in A's values of its first entry (row p of column q + j, or row p + j on the
  // diagonal, with p, q the DOFs of nodes a, b); -1: a node is fixed
  std::vector<int> block_offset;
  std::vector<int> diag_offset;  // per reduced DOF

  // The general element loop (fem_domains.cpp) runs instead of the batched corotational one
  // (fem_assembly.cpp) when the material asks for more: the consistent tangent, the invertible
  // law or edge-smoothed strain. It keeps its rotations in `rotation` as the batched loop does
  // (keep_rotations) but does not warm-start from them.
  bool general_loop = false;
  bool rotation_stiffness = false;   // the tangent's rotation modes (B > 0) are kept
  // Edge-smoothed strain: one integration domain per mesh edge (empty for linear tets). Domain d
  // has the nodes dom_node[dom_start[d] .. dom_start[d + 1]) by ascending reduced DOF (fixed,
  // DOF -1, first), their smoothed shape gradients (3 per node in dom_grad) and the volume
  // dom_vol[d]; its blocks (a, b), a >= b, write into A at the three offsets per block from
  // dom_offset[dom_offset_start[d]] on, laid out as block_offset (-1: a node is fixed).
  std::vector<int> dom_start, dom_node;
  std::vector<double> dom_grad, dom_vol;
  std::vector<std::size_t> dom_offset_start;
  std::vector<int> dom_offset;
  int dom_max_nodes = 0;

  // rotation groups: nodes tied by short edges share one node rotation
  std::vector<int> rot_group;   // node -> group index (empty: every node on its own)
  int rot_group_count = 0;

  std::uint64_t hash = 0;       // restHash: identity of mesh, material, fixed nodes

  // Derived from the model on first demand (ensureRestFactor, surfaceNodes), never changed by a
  // step: the rest-shape system matrix and its factorisation for the step rest_h, and the
  // surface nodes.
  Sparse a_rest;
  fem_detail::CholmodSolver chol_rest;
  double rest_h = -1.0;
  std::vector<int> surface;
  bool surface_ready = false;
};

struct FemState {
  Eigen::VectorXd q, v;
  // Per element: the rotation of the last element loop that kept its rotations (freeMotion,
  // solveStatic; the linearisation point q + h v of a step), in the batched loop's layout
  // ([batch].r[row][col][lane]). The element loop starts each element's polar decomposition from
  // it, so it is state: a step continues bit for bit only from the same rotations. The warped
  // compliance and the preconditioner read the node rotations made from it (stepNodeRotations).
  struct RotationBatch {
    double r[3][3][4];
  };
  std::vector<RotationBatch> rotation;
  bool rotation_current = false;   // `rotation` is that of the last freeMotion's linearisation
  // the same per mesh element (FemBody::elementRotations), filled on demand
  std::vector<Eigen::Matrix3d> rotation_by_tet;
  bool rotation_by_tet_stale = true;
  // The system matrix A (lower triangle). Its pattern is the model's (block_offset and
  // diag_offset index it, fixed at init); its values are the last step's A (or solveStatic's K),
  // kept as state because the compliance queries factorise it after the step
  // (ensureCurrentFactor).
  Sparse a;
  // the factor of record and what it holds
  fem_detail::CholmodSolver chol;
  bool chol_current = false;     // chol holds the factor of the current `a`
  bool a_is_step_matrix = false; // `a` is freeMotion's A (not solveStatic's K)
  fem_detail::ReusedFactorSolver reuse{{}};  // LinearSolverKind::kCholmodReuse (factor: chol)
  // kCholmodReuse on a corotational body: node rotations of the factor's step (per free node, in
  // DOF order)
  std::vector<Eigen::Matrix3d> factor_node_rot;
  // background refreshes (background_refactor_lag_steps > 0): the worker, and the node rotations
  // of the step whose A it factorises (they become factor_node_rot when its factor is taken)
  std::unique_ptr<fem_detail::BackgroundFactoriser> background;
  std::vector<Eigen::Matrix3d> background_node_rot;
  // and the values of that A (they become factor_values when its factor is taken)
  Eigen::VectorXd background_factor_values;
  double compliance_scale = 0.0; // C = compliance_scale * A^-1 for the current `a`
  double last_h = 0.0;
  // the last two steps' dv (reduced): the iterative solvers' warm start
  Eigen::VectorXd dv_prev, dv_prev2;
  // kCholmodReuse: the values of the A the factor of record was computed from (copied when the
  // factor is refreshed; a restored state refactorises them, fem_state.cpp)
  Eigen::VectorXd factor_values;
  // prepareFreeMotion: chol's generation when it factorised the A of factor_values before the
  // first step (0: none prepared); the next freeMotion uses it if its A is that one
  std::uint64_t prepared_generation = 0;
  // a contact correction solved with the body's compliance since the last freeMotion
  // (solveCompliance, solveComplianceBatch, solveRestCompliance): the background refresh's lag
  // counts the step it ends as one in contact (FemSolverOptions::background_refactor_free_lag_steps)
  bool compliance_solved = false;
};

struct FemScratch {
  std::vector<Eigen::Vector3d> dom_scratch;          // the general loop's rotated gradients
  // step buffers (reduced or full)
  Eigen::VectorXd f_int, rhs_full, rhs, dv;
  Eigen::VectorXd cg_t, jacobi_inv;
  fem_detail::CgBuffers cg;
  std::vector<Eigen::Matrix3d> node_rot, node_acc;  // warped preconditioner
  // nodeRotations: the element rotations at q (batched layout, then mesh order)
  std::vector<FemState::RotationBatch> query_rotation;
  std::vector<Eigen::Matrix3d> query_element_rot;
  // kCholmodReuse: this step's node rotations relative to the factor's (the preconditioner's warp)
  std::vector<Eigen::Matrix3d> relative_rot;
  std::vector<Eigen::Matrix3d> group_acc;           // sumNodeRotations' per-group sums
  std::vector<double> group_w;
  // finishNodeRotations' smoothing: one pass is acc'_i = sum_j c_ij acc_j with c_ij the number
  // of tets holding both nodes i and j (c_ii: the tets at i), node i's row in smooth_ptr /
  // smooth_node / smooth_count (buildSmoothingRows); the pass's output in smooth_acc, smooth_w
  std::vector<int> smooth_ptr, smooth_node;
  std::vector<double> smooth_count;
  std::vector<Eigen::Matrix3d> smooth_acc;
  std::vector<double> smooth_w;
  std::vector<double> node_w;                       // node weights of the preconditioner's sums
  // the node sums of the last kept element rotations (ensureStepNodeSums) and a working copy
  std::vector<Eigen::Matrix3d> step_acc, work_acc;
  std::vector<double> step_w, work_w;
  bool step_sums_current = false;
  // the element loop's reference-path elements of one call (slots)
  std::vector<int> fallback_slots;
  // the rest factor solved since the last freeMotion (a contact correction); when it was not,
  // the next freeMotion reads its pages (keepRestFactorResident)
  bool rest_solved = false;
  // freeMotion: the step before it was in contact (compliance_solved, taken and cleared)
  bool after_contact = false;
  // solveRestCompliance's reduced right-hand side and solution
  Eigen::VectorXd rest_rhs, rest_x;
};

struct FemBody::Impl : FemModel, FemState, FemScratch {
  // statistics and logging, outside the physics
  Counters counters;
  bool inversion_warned = false;   // "inverted elements" is logged once per body

  void init(const TetMesh& m, const FemMaterial& mat, const std::vector<int>& fixed_nodes,
            const Eigen::Vector3d* g, const FemSolverOptions& opt);
  void buildPattern();
  // Position in A's values of entry (r, c), r >= c, of its fixed pattern.
  int valueOffset(int r, int c) const;
  // fem_domains.cpp: the edge-smoothed domains (before buildPattern, which then takes A's pattern
  // from them: every pair of nodes in a domain), their offsets into A (after it).
  void buildEdgeDomains();
  void buildDomainPattern();
  void buildDomainOffsets();
  // The general element loop: evaluate()'s contract (fem_assembly.cpp calls it when
  // general_loop is set).
  void evaluateGeneral(const Eigen::VectorXd& q, const Eigen::VectorXd* v, double h, double beta,
                       Eigen::VectorXd* f_out, Sparse* target, double c_k, double c_m,
                       bool use_rest_frame, int* inverted_at_q, bool keep_rotations);
  // One integration domain of the general loop (k nodes, gradients 3 per node, volume vol,
  // offsets off): adds its internal force into fd (if non-null) and c_k times its tangent into
  // vals (if non-null); returns the rotation it used (identity without rotation).
  Eigen::Matrix3d domainKernel(int k, const int* node, const double* grad, double vol,
                               const int* off, const double* qd, const double* vd, double h,
                               double beta, double* fd, double* vals, double c_k,
                               bool rotate);
  // Elastic energy of the general loop's domains at positions x.
  double generalEnergy(const Eigen::VectorXd& x) const;
  // Element loop (fem_assembly.cpp) at positions x = q + h v (x = q when v is null):
  //  * f_out (3n, if non-null): internal force (+K u sense) f_el(x) + beta K(x) v, the elastic
  //    force plus the stiffness-proportional damping force (beta = 0 or v null: elastic only);
  //  * target (if non-null): c_k K(x) + c_m M into its fixed pattern;
  //  * inverted_at_q (if non-null): elements with det F <= 0 at q (not x).
  // Element rotations are taken at x, each polar decomposition starting from `rotation`;
  // keep_rotations: they replace `rotation` (a step's or a static solve's linearisation point;
  // queries leave the state alone). use_rest_frame: R = I without rotation extraction (rest
  // tangent). Elements go four at a time through the batched kernel (AVX where the CPU has it,
  // the same operations in SSE2 otherwise: the same bits); those it cannot finish (an
  // ill-conditioned or inverted F, a rotation the warm-started iteration did not reach) go
  // through elementStep, the reference constitutive step.
  void evaluate(const Eigen::VectorXd& q, const Eigen::VectorXd* v, double h, double beta,
                Eigen::VectorXd* f_out, Sparse* target, double c_k, double c_m,
                bool use_rest_frame, int* inverted_at_q = nullptr, bool keep_rotations = false);
  // One element through the reference path (Eigen, the robust polar decomposition of
  // fem_detail::polarRotation): its force and tangent scattered as evaluate describes; returns its
  // rotation.
  Eigen::Matrix3d elementStep(int slot, const double* q, const double* v, double h, double beta,
                              double* f_out, double* vals, double c_k, bool rotate) const;
  // The element rotations at positions x into `out` (the batched layout, slot order), each
  // polar decomposition warm-started from the kept rotations (`rotation`, the last element
  // loop's): the batched kernel's Newton steps on the rotation alone (no force, no tangent), the
  // elements it cannot finish through the reference path. `rotation` is left alone. Not for the
  // general element loop.
  void rotationsAt(const Eigen::VectorXd& x, std::vector<RotationBatch>& out);
  Eigen::Matrix3d slotRotation(int slot) const {
    const RotationBatch& b = rotation[static_cast<std::size_t>(slot / 4)];
    Eigen::Matrix3d r;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) r(i, j) = b.r[i][j][slot % 4];
    return r;
  }
  void setSlotRotation(int slot, const Eigen::Matrix3d& r) {
    RotationBatch& b = rotation[static_cast<std::size_t>(slot / 4)];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) b.r[i][j][slot % 4] = r(i, j);
  }
  Eigen::Matrix3d elementF(int e, const Eigen::VectorXd& x) const {
    const auto& t = mesh.tets[e];
    Eigen::Matrix<double, 3, 4> xe;
    for (int k = 0; k < 4; ++k) xe.col(k) = x.segment<3>(3 * t[k]);
    return xe * grad[e].transpose();
  }
  Eigen::Matrix3d sigma(const Eigen::Matrix3d& eps) const {
    return lambda * eps.trace() * Eigen::Matrix3d::Identity() + 2.0 * mu * eps;
  }
  void reduce(const Eigen::VectorXd& full, double* out) const {
    for (int i = 0; i < n; ++i)
      if (dof_base[i] >= 0)
        for (int c = 0; c < 3; ++c) out[dof_base[i] + c] = full[3 * i + c];
  }
  void expand(const double* red, double scale, double* out) const {
    for (int i = 0; i < n; ++i)
      for (int c = 0; c < 3; ++c)
        out[3 * i + c] = dof_base[i] >= 0 ? scale * red[dof_base[i] + c] : 0.0;
  }
  void buildRotationGroups();
  void buildSmoothingRows();
  // Node rotations from element rotations: volume-weighted sum over the adjacent elements,
  // summed over the node's rotation group, widened by `smoothing_passes` passes over the
  // elements (FemBody::nodeRotations), polar factor. Nodes with no weight get identity.
  // sumNodeRotations fills acc (and w, the same sums of the volumes alone) from per-mesh-element
  // rotations, or (null) from `rotation`, groups included; finishNodeRotations smooths and takes
  // the polar factors.
  void sumNodeRotations(const std::vector<Eigen::Matrix3d>* element_rot,
                        std::vector<Eigen::Matrix3d>& acc, std::vector<double>& w);
  void finishNodeRotations(std::vector<Eigen::Matrix3d>& acc, std::vector<double>& w,
                           std::vector<Eigen::Matrix3d>& out, int smoothing_passes);
  // The same sums of the elements' deformation gradients at positions x, in the mesh's order
  // (FemBody::fittedNodeRotations): no polar decomposition per element.
  void sumNodeGradients(const Eigen::VectorXd& x, std::vector<Eigen::Matrix3d>& acc,
                        std::vector<double>& w);
  // sumNodeRotations' and sumNodeGradients' last part: every member of a rotation group gets the
  // group's sums.
  void sumRotationGroups(std::vector<Eigen::Matrix3d>& acc, std::vector<double>& w);
  // The node sums of `rotation` (step_acc, step_w), computed once per element loop that kept
  // its rotations.
  void ensureStepNodeSums();
  void ensureRestFactor(double h);
  void prepareFreeMotion(double h);   // FemBody::prepareFreeMotion
  // the step's buffers (node rotation sums and rotations, the smoothing's per-tet sums) given
  // the storage the steps size them to, written now (prepareFreeMotion)
  void prepareStepBuffers();
  void ensureCurrentFactor();
  // dv = A^-1 rhs by a fresh CHOLMOD factorisation of `a` (timed into stats); false when A is not
  // positive definite.
  bool factorizeAndSolve(FemStepStats& stats);
  // dv from rhs by the configured strategy; false on failure (dv not finite or no factor).
  bool solveStep(double h, FemStepStats& stats);
  // kCholmodReuse: the factor now holds this step's A; its node rotations are this step's.
  void keepFactorRotations();
  // Reads the rest factor's pages (CholmodSolver::touchPages) when it is factorised and no
  // correction solved with it since the last call: a body out of contact keeps the factor its
  // first contact's correction needs resident, at about 0.1 ms a step on liver_grasp_23k.
  void keepRestFactorResident();
  bool pcg(double tol, int max_iter, FemStepStats& stats);
  // kCholmodReuse: the factor was just computed from `a` (keeps its values, factor_values).
  void noteFactorSource();
  // FemState through the archive, the factor of record rebuilt when reading (fem_state.cpp).
  void transferState(StateArchive& ar);
};

}  // namespace tactus::sim
