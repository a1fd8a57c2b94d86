#pragma once
// Contact compliance models of a tissue (paper 3.2 "Contact Compliance Warping", DESIGN 3.4).
//
// A contact row acts on the tissue through H: row r maps the DOF displacement dq to a relative
// displacement   (H dq)_r = sum_k weight[k] * dir . dq[node[k]]   (up to 3 nodes: a triangle
// point in barycentric form; signs are carried by `weight`/`dir`, chosen by the caller).
//
// Models:
//  * exact     : C from the current tangent (FemBody::solveCompliance), one solve per row.
//  * warped    : C ~ R C0 R^T (eq. 12) with C0 precomputed for the surface DOFs (dense block,
//                CHOLMOD: one factorisation, one solve per surface DOF, progress shown),
//                cached on disk (header: magic, version, hash of mesh+material+h, sizes; a stale
//                or corrupt file is rebuilt, never trusted). R: per-node rotations.
//  * rest      : C0 without rotation.
//  * uncoupled : diagonal per-node compliance (diag of C0, isotropic 3x3 per node).
// Constrained motion (paper 3.3): r0 = (H R)^T f, dq0 = C0 r0 (all DOFs, one solve with the
// rest factorisation), dq = R dq0 (exact: dq = C H^T f).

#include <Eigen/Core>
#include <array>
#include <filesystem>
#include <memory>
#include <span>

#include "tactus/sim/fem.h"

namespace tactus::sim {

/// One contact row on a tissue.
struct TissueRow {
  std::array<int, 3> node{-1, -1, -1};   ///< node indices (unused: -1)
  std::array<double, 3> weight{0, 0, 0};
  Eigen::Vector3d dir = Eigen::Vector3d::Zero();
};

struct ComplianceOptions {
  double h_s = 0.01;                       ///< time step the compliance is built for
  std::filesystem::path cache_dir;         ///< empty: no disk cache
  bool show_progress = true;               ///< progress bar on stderr for the precomputation
};

class TissueCompliance {
 public:
  virtual ~TissueCompliance() = default;
  virtual ComplianceKind kind() const = 0;
  /// Once per step, after free motion: refresh rotations (warped) / nothing (rest).
  virtual void update(FemBody& body) = 0;
  /// W += H C H^T for the given rows (W is rows.size() square, row-major or column-major alike:
  /// the result is symmetric).
  virtual void addW(std::span<const TissueRow> rows, Eigen::Ref<Eigen::MatrixXd> W) = 0;
  /// dq = C H^T f (3n; fixed DOFs zero). `f` has rows.size() entries.
  virtual void correction(FemBody& body, std::span<const TissueRow> rows, const double* f,
                          Eigen::VectorXd& dq) = 0;
  /// Bytes held by the model (C0 block etc.), for the log and the README.
  virtual std::size_t memoryBytes() const = 0;
};

/// Builds the model. `warped`/`rest`/`uncoupled` precompute C0 (or load it from the cache).
std::unique_ptr<TissueCompliance> makeCompliance(ComplianceKind kind, FemBody& body,
                                                 const ComplianceOptions& options);

}  // namespace tactus::sim
