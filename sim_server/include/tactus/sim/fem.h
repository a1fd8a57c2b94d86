#pragma once
// Tetrahedral FEM body: linear or corotational elasticity, lumped mass, Rayleigh damping,
// gravity, Dirichlet nodes, and implicit Euler free motion (paper eq. 2-7).
//
//   (M/h + B + hK) dv = p - F(q + h v, v),  v_free = v + dv,  q_free = q + h v_free
//
// with F the internal (elastic + damping) force, K its tangent, B = alpha M + beta K.
// Corotational: per element R_e from the deformation gradient (SVD polar decomposition with sign
// correction, robust to inverted elements), f_e = R_e K0_e (R_e^T x_e - X_e), tangent
// R_e K0_e R_e^T. Linear: R_e = I (no rotation extraction at all).
//
// The system matrix keeps a fixed sparsity pattern; CHOLMOD's symbolic analysis runs once in the
// constructor and every step refactorises numerically. Fixed nodes are eliminated (their rows and
// columns are not in the system; their displacement stays zero).
//
// The contact compliance C = (M/h^2 + B/h + K)^-1 = h (M/h + B + hK)^-1 is available from the
// factorisation of the last free motion (`solveCompliance`) and from a rest-shape factorisation
// (`solveRestCompliance`), which compliance.h uses.

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <memory>
#include <vector>

#include "tactus/sim/mesh.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {

struct FemMaterial {
  MaterialLaw law = MaterialLaw::kCorotational;
  double young_pa = 3000.0;
  double poisson = 0.45;
  double density_kgpm3 = 1000.0;
  std::optional<RayleighSpec> damping;          ///< absent: B = 0, no damping terms computed
};

struct FemSolverOptions {
  LinearSolverKind linear = LinearSolverKind::kCholmod;
  double cg_tolerance = 1e-8;                   ///< relative residual
  int cg_max_iterations = 500;
};

/// Per-stage wall times of the last step [s] and solver figures.
struct FemStepStats {
  double assembly_s = 0.0;
  double factorisation_s = 0.0;                 ///< CHOLMOD numeric factorisation (0 for CG)
  double solve_s = 0.0;
  int cg_iterations = 0;                        ///< 0 for CHOLMOD
  bool ok = true;                               ///< false: factorisation/CG failed, state kept
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
  /// Updates positions/velocities to the free state. Leaves the factorisation of
  /// A = M/h + B + hK at the linearisation point available for solveCompliance().
  FemStepStats freeMotion(double h, const Eigen::VectorXd* external_force_n = nullptr);

  /// Internal elastic force at q (3n), rotations updated from q (corotational).
  void elasticForce(const Eigen::VectorXd& q, Eigen::VectorXd& force_out);

  /// x = C r with C = (M/h^2 + B/h + K)^-1 from the last freeMotion's factorisation (h of that
  /// step). Fixed DOFs of x are zero. r and x are 3n.
  void solveCompliance(const Eigen::VectorXd& r, Eigen::VectorXd& x) const;

  /// x = C0 r with C0 the compliance at the rest shape (K0, same h). Factorised on first use
  /// (or when h changes) and kept.
  void solveRestCompliance(double h, const Eigen::VectorXd& r, Eigen::VectorXd& x);

  /// Per-element rotations of the last evaluation (identity for linear material).
  const std::vector<Eigen::Matrix3d>& elementRotations() const;
  /// Per-node rotations rest -> current: volume-weighted average of adjacent element rotations,
  /// re-orthonormalised (polar). Identity for linear material. Recomputed from current positions.
  void nodeRotations(std::vector<Eigen::Matrix3d>& out) const;

  /// Per-element von Mises stress [Pa] at the current positions.
  void vonMises(Eigen::VectorXd& out) const;
  /// Kinetic energy 1/2 v^T M v and elastic energy (corotational strain energy) [J].
  double kineticEnergy() const;
  double elasticEnergy() const;
  /// Gravitational potential energy -sum m_i g . x_i (0 without gravity) [J].
  double gravityEnergy() const;

  /// Counters of the pipeline's "absent = not computed" promise.
  struct Counters {
    long rotation_extractions = 0;              ///< element polar decompositions performed
    long damping_evaluations = 0;               ///< steps that built damping terms
    long factorisations = 0;
  };
  const Counters& counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Applies a scene transform (scale, then XYZ Euler rotation in degrees, then translation).
void transformMesh(TetMesh& mesh, double scale, const Eigen::Vector3d& rotation_deg,
                   const Eigen::Vector3d& translation_m);

/// Node indices whose positions lie inside any of the boxes.
std::vector<int> nodesInBoxes(const TetMesh& mesh, const std::vector<BoxSpec>& boxes);

}  // namespace tactus::sim
