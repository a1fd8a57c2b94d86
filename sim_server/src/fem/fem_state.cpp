// FemBody's state through the state archive (state_archive.h; docs/design.md, "State: copy, save,
// restore"): every FemState member is either written here or named with the reason it is not.
#include "fem_body_impl.h"
#include "tactus/shared/error.h"

namespace tactus::sim {

// A member added to FemState must be added below (or to the list of members rebuilt from
// others): this stops the build until it is.
static_assert(kAggregateFields<FemState> == 22,
              "FemState gained or lost a member: walk it in FemBody::Impl::transferState "
              "(fem_state.cpp) and update this count");

static_assert(sizeof(FemState::RotationBatch) == 36 * sizeof(double),
              "transferState writes the rotations as 36 doubles per batch");

void FemBody::Impl::noteFactorSource() {
  if (options.linear != LinearSolverKind::kCholmodReuse) return;
  factor_values = Eigen::Map<const Eigen::VectorXd>(a.valuePtr(), a.nonZeros());
}

void FemBody::Impl::transferState(StateArchive& ar) {
  ar("q", q);
  ar("v", v);
  // the kept element rotations, the element loop's warm starts (batched layout: 36 doubles per
  // batch of four elements), and whether they are the last free motion's linearisation point
  ar.block("rotation", reinterpret_cast<double*>(rotation.data()), rotation.size() * 36);
  ar("rotation_current", rotation_current);
  ar.block("a", a.valuePtr(), static_cast<std::size_t>(a.nonZeros()));
  ar("chol_current", chol_current);
  ar("a_is_step_matrix", a_is_step_matrix);
  ar("reuse", reuse);
  ar.resizable("factor_node_rot", factor_node_rot, static_cast<std::size_t>(n_free / 3));
  ar("compliance_scale", compliance_scale);
  ar("last_h", last_h);
  ar("dv_prev", dv_prev);
  ar("dv_prev2", dv_prev2);
  // A scratch member that is state between steps: kCholmodReuse's node rotations of the last
  // free motion, which a factorisation after the step (solveCompliance, the exact compliance)
  // keeps as the factor's (keepFactorRotations).
  ar.resizable("node_rot", node_rot, static_cast<std::size_t>(n));
  // The factor of record (chol) is not bytes but what it was computed from: the current `a`
  // when chol_current, else (kCholmodReuse, a factor some steps old preconditioning the PCG) the
  // values kept by noteFactorSource. Only a factor a later step or query reads is rebuilt.
  const bool reuse_mode = options.linear == LinearSolverKind::kCholmodReuse;
  const bool old_factor_read = reuse_mode && reuse.ageSteps() >= 0 && !chol_current;
  Eigen::VectorXd none;
  ar.resizable("factor_values", old_factor_read ? factor_values : none,
               static_cast<std::size_t>(a.nonZeros()));
  // background refreshes: the node rotations and values of the A of a job started and not yet
  // taken; a loaded job in flight is started again from them (below)
  ar.resizable("background_node_rot", background_node_rot, static_cast<std::size_t>(n_free / 3));
  ar.resizable("background_factor_values", background_factor_values,
               static_cast<std::size_t>(a.nonZeros()));
  // whether the last step's contact correction solved with the body: the next step's adoptDue
  // weighs the running job's age by it
  ar("compliance_solved", compliance_solved);
  if (!ar.loading()) return;
  // rebuilt from the rotations on demand: FemBody::elementRotations' per-tet copy and the node sums
  rotation_by_tet_stale = true;
  step_sums_current = false;
  if (old_factor_read && factor_values.size() != a.nonZeros()) {
    ar.fail("factor_values", "missing: the factor of record cannot be rebuilt");
  }
  if (chol_current || old_factor_read) {
    if (!chol.analyzed()) chol.analyze(a);
    bool ok = false;
    if (chol_current) {
      ok = chol.factorize(a);
      if (reuse_mode && a_is_step_matrix) factor_values = Eigen::Map<const Eigen::VectorXd>(
                                               a.valuePtr(), a.nonZeros());
    } else {
      Sparse source = a;
      Eigen::Map<Eigen::VectorXd>(source.valuePtr(), source.nonZeros()) = factor_values;
      ok = chol.factorize(source);
    }
    if (!ok) ar.fail("chol", "the factor of record could not be rebuilt (not positive definite)");
  }
  if (reuse.jobToRestart()) {
    if (background_factor_values.size() != a.nonZeros())
      ar.fail("background_factor_values", "missing: the background job cannot be restarted");
    if (!chol.analyzed()) chol.analyze(a);
    Sparse source = a;
    Eigen::Map<Eigen::VectorXd>(source.valuePtr(), source.nonZeros()) = background_factor_values;
    reuse.restartJob(source, chol);
  }
  // Not state: the background worker (`background`, a thread; its job restarted above), the
  // model (FemModel, with the rest factor built from it on demand), the step's
  // buffers (FemScratch, written before they are read, but node_rot above), the statistics
  // (counters, inversion_warned) and prepared_generation (prepareFreeMotion's factor: a load
  // that rebuilds chol above changes its generation, and the first step checks its A against
  // the prepared one to the bit).
}

void FemBody::transferState(StateArchive& ar) { impl_->transferState(ar); }

}  // namespace tactus::sim
