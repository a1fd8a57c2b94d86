// FemBody's linear solves of the implicit Euler step: the CHOLMOD factorisations (current and rest
// shape, reuse between refactorisations) and the preconditioned conjugate gradient. The element
// loop that builds the system is in fem_assembly.cpp.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>

#include <spdlog/spdlog.h>

#include "fem_body_impl.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/grow_only_matrix.h"
#include "tactus/sim/fem.h"

namespace tactus::sim {

void FemBody::Impl::ensureRestFactor(double h) {
  if (rest_h == h && chol_rest.factorized()) return;
  const double alpha = material.damping ? material.damping->mass_alpha_per_s : 0.0;
  const double beta = material.damping ? material.damping->stiffness_beta_s : 0.0;
  evaluate(rest, nullptr, 0.0, 0.0, nullptr, &a_rest, h + beta, 1.0 / h + alpha, true);
  if (!chol_rest.analyzed()) chol_rest.analyze(a_rest);
  ++counters.factorisations;
  if (!chol_rest.factorize(a_rest))
    throw NumericalError("FemBody(" + mesh.source +
                         "): rest-shape system matrix is not positive definite; check the "
                         "material parameters and the time step");
  rest_h = h;
  // the correction's solves: their buffers written now, not at the first contact
  chol_rest.prepareSolveWorkspaces();
  rest_rhs.setZero(n_free);
  rest_x.setZero(n_free);
}

void FemBody::Impl::keepRestFactorResident() {
  if (!rest_solved && chol_rest.factorized()) {
    // the sum is stored so that the reads are made
    volatile double sink = chol_rest.touchPages();
    (void)sink;
  }
  rest_solved = false;
}

void FemBody::Impl::ensureCurrentFactor() {
  if (chol_current) return;
  if (compliance_scale == 0.0)
    throw Error("FemBody::solveCompliance: no system matrix yet; call freeMotion() first");
  if (!chol.analyzed()) chol.analyze(a);
  ++counters.factorisations;
  if (!chol.factorize(a))
    throw NumericalError("FemBody(" + mesh.source +
                         "): current system matrix is not positive definite");
  chol_current = true;
  if (a_is_step_matrix) {
    reuse.noteFactorised();
    keepFactorRotations();
    noteFactorSource();
  }
}

void FemBody::Impl::keepFactorRotations() {
  // node_rot holds this step's node rotations when kCholmodReuse computed them
  if (options.linear != LinearSolverKind::kCholmodReuse || !corotational) return;
  for (int i = 0; i < n; ++i)
    if (dof_base[i] >= 0) factor_node_rot[dof_base[i] / 3] = node_rot[i];
}

bool FemBody::Impl::factorizeAndSolve(FemStepStats& stats) {
  const std::int64_t t1 = shared::monotonicNs();
  ++counters.factorisations;
  const bool ok = chol.factorize(a);
  stats.factorisation_s = shared::secondsSinceNs(t1);
  chol_current = ok;
  if (!ok) return false;
  const std::int64_t t2 = shared::monotonicNs();
  chol.solve(rhs.data(), dv.data(), 1);
  stats.solve_s = shared::secondsSinceNs(t2);
  return true;
}

bool FemBody::Impl::solveStep(double h, FemStepStats& stats) {
  switch (options.linear) {
    case LinearSolverKind::kCholmod:
      return factorizeAndSolve(stats) && dv.allFinite();
    case LinearSolverKind::kCholmodReuse: {
      dv = 2.0 * dv_prev - dv_prev2;  // warm start
      double background_factor_s = 0.0;
      const bool taken =
          reuse.adoptDue(chol, stats.factor_wait_s, background_factor_s, after_contact);
      counters.background_not_ready = reuse.notReadySteps();
      counters.background_wait_s += stats.factor_wait_s;
      if (prepared_generation != 0) {
        // prepareFreeMotion's factor: used when nothing refactorised chol since and this
        // step's A is the one it factorised, to the bit (then the same factor as factorising
        // it here would give)
        const bool holds =
            prepared_generation == chol.generation() && reuse.ageSteps() < 0 &&
            chol.factorized() && factor_values.size() == a.nonZeros() &&
            std::memcmp(factor_values.data(), a.valuePtr(),
                        sizeof(double) * static_cast<std::size_t>(a.nonZeros())) == 0;
        prepared_generation = 0;
        if (holds) reuse.notePreparedFactor();
      }
      if (stats.factor_wait_s > 1e-4) {
        ++counters.background_waits;
        counters.background_wait_max_s = std::max(counters.background_wait_max_s, stats.factor_wait_s);
      }
      if (taken) {
        // the worker's factor of an earlier step's A: its rotations are that step's
        stats.background_factor_taken = true;
        ++counters.background_factorisations;
        if (corotational) factor_node_rot = background_node_rot;
        factor_values.swap(background_factor_values);   // the factor of record's source
      }
      const std::int64_t t_warp = shared::monotonicNs();
      if (corotational) {
        ensureStepNodeSums();
        work_acc = step_acc;
        work_w = step_w;
        finishNodeRotations(work_acc, work_w, node_rot, 0);
        relative_rot.resize(n_free / 3);
        if (factor_node_rot.size() != relative_rot.size())
          factor_node_rot.assign(relative_rot.size(), Eigen::Matrix3d::Identity());
        for (int i = 0; i < n; ++i)
          if (dof_base[i] >= 0)
            relative_rot[dof_base[i] / 3] = node_rot[i] * factor_node_rot[dof_base[i] / 3].transpose();
      }
      const double warp_s = shared::secondsSinceNs(t_warp);
      // A_f's values (the local correction compares them with A's): those of the factor of
      // record, kept by noteFactorSource
      const bool source_known = factor_values.size() == a.nonZeros();
      const fem_detail::ReuseSolveResult r =
          reuse.solve(chol, a, rhs, dv, corotational ? relative_rot.data() : nullptr,
                      corotational && source_known ? factor_values.data() : nullptr);
      if (r.refreshed) {
        keepFactorRotations();
        noteFactorSource();
      }
      if (r.background_started) {
        if (corotational) {
          background_node_rot.resize(n_free / 3);
          for (int i = 0; i < n; ++i)
            if (dof_base[i] >= 0) background_node_rot[dof_base[i] / 3] = node_rot[i];
        }
        background_factor_values = Eigen::Map<const Eigen::VectorXd>(a.valuePtr(), a.nonZeros());
      }
      stats.background_factorisation_started = r.background_started;
      stats.factorisation_s = r.factorisation_s + stats.factor_wait_s;
      stats.solve_s = warp_s + r.solve_s;
      stats.cg_iterations = r.cg_iterations;
      stats.pcg_local_nodes = r.local_nodes;
      stats.cg_residual = r.residual;
      stats.factor_refreshed = r.refreshed;
      stats.factor_prepared = r.prepared;
      if (r.refreshed && !r.prepared) ++counters.factorisations;
      chol_current = r.refreshed;
      return r.ok;
    }
    case LinearSolverKind::kPcg: {
      const std::int64_t t1 = shared::monotonicNs();
      if (options.pcg_preconditioner != PcgPreconditioner::kJacobi) ensureRestFactor(h);
      stats.factorisation_s = shared::secondsSinceNs(t1);
      const std::int64_t t2 = shared::monotonicNs();
      const bool ok = pcg(options.cg_tolerance, options.cg_max_iterations, stats);
      stats.solve_s = shared::secondsSinceNs(t2);
      if (!ok && !dv.allFinite()) return false;
      stats.ok = ok;
      return dv.allFinite();
    }
  }
  return false;
}

void FemBody::Impl::prepareStepBuffers() {
  using shared::reserveWritten;
  const auto nodes = static_cast<std::size_t>(n);
  const auto blocks = static_cast<std::size_t>(n_free / 3);
  const Eigen::Matrix3d zero = Eigen::Matrix3d::Zero();
  for (auto* v : {&step_acc, &work_acc, &node_rot}) reserveWritten(*v, nodes, zero);
  for (auto* v : {&step_w, &work_w}) reserveWritten(*v, nodes, 0.0);
  // (factor_node_rot is state, empty until the first step: only its storage is made)
  for (auto* v : {&relative_rot, &factor_node_rot}) reserveWritten(*v, blocks, zero);
  reserveWritten(group_acc, static_cast<std::size_t>(rot_group_count), zero);
  reserveWritten(group_w, static_cast<std::size_t>(rot_group_count), 0.0);
  reserveWritten(smooth_acc, nodes, zero);
  reserveWritten(smooth_w, nodes, 0.0);
}

void FemBody::Impl::prepareFreeMotion(double h) {
  // the step's buffers and (below) the factor's solve workspaces written now: the first step
  // took about 750 first-touch page faults on liver_grasp_23k sizing them, and the first
  // contact step 565 more for the warped compliance's smoothing (smooth_acc, smooth_w)
  prepareStepBuffers();
  // the rest factor read once more now, after the rest of the set-up (the compliance models'
  // reading of their blocks)
  rest_solved = false;
  keepRestFactorResident();
  if (options.linear != LinearSolverKind::kCholmodReuse || reuse.ageSteps() >= 0) return;
  const bool damped = material.damping.has_value();
  const double alpha = damped ? material.damping->mass_alpha_per_s : 0.0;
  const double beta = damped ? material.damping->stiffness_beta_s : 0.0;
  // freeMotion's A at the current state, into a copy: the state (A, the kept rotations: a
  // query's evaluation works on a copy of them) and the counters stay as they were
  Sparse next = a;
  Eigen::VectorXd force;
  const Counters kept = counters;
  int inverted = 0;
  evaluate(q, &v, h, beta, &force, &next, h + beta, 1.0 / h + alpha, false, &inverted, false);
  counters = kept;
  if (!chol.analyzed()) chol.analyze(next);
  prepared_generation = 0;
  if (!chol.factorize(next)) return;   // the first step factorises and reports it
  factor_values = Eigen::Map<const Eigen::VectorXd>(next.valuePtr(), next.nonZeros());
  chol.prepareSolveWorkspaces();
  reuse.prepareBuffers(n_free);
  prepared_generation = chol.generation();
  ++counters.prepared_factorisations;
  if (background != nullptr && !background->busy()) {
    // the worker made ready now too, not by the first steps that start and take a job: its
    // thread, its copy of the analysis and of A, and its factor's storage and float copy
    // written once (by a job on this A, dropped), and the step's copies of a job's A and
    // rotations sized (the first job's start and wait took 2000 page faults and a 0.1-0.2 s
    // wait on liver_grasp_23k)
    background->start(next, chol);
    background->discard();
    background_factor_values = factor_values;
    background_node_rot.assign(static_cast<std::size_t>(n_free / 3), Eigen::Matrix3d::Identity());
  }
}

bool FemBody::Impl::pcg(double tol, int max_iter, FemStepStats& stats) {
  const bool warped = options.pcg_preconditioner == PcgPreconditioner::kWarpedCholesky;
  const bool use_rest =
      options.pcg_preconditioner == PcgPreconditioner::kRestCholesky || warped;
  if (warped && corotational) {
    // per-node rotations from this step's element rotations (volume-weighted, re-orthonormalised)
    ensureStepNodeSums();
    work_acc = step_acc;
    work_w = step_w;
    finishNodeRotations(work_acc, work_w, node_rot, 0);
  }
  const bool rotate = warped && corotational;
  if (!use_rest) {
    jacobi_inv.resize(n_free);
    const double* vals = a.valuePtr();
    for (int d = 0; d < n_free; ++d) jacobi_inv[d] = 1.0 / vals[diag_offset[d]];
  }
  auto precond = [&](const Eigen::VectorXd& r, Eigen::VectorXd& z) {
    if (use_rest) {
      z.resize(n_free);
      if (rotate) {
        // z = R A0^-1 R^T r
        cg_t.resize(n_free);
        for (int i = 0; i < n; ++i)
          if (dof_base[i] >= 0)
            cg_t.segment<3>(dof_base[i]) = node_rot[i].transpose() * r.segment<3>(dof_base[i]);
        chol_rest.solve(cg_t.data(), cg_t.data(), 1);
        for (int i = 0; i < n; ++i)
          if (dof_base[i] >= 0) z.segment<3>(dof_base[i]) = node_rot[i] * cg_t.segment<3>(dof_base[i]);
      } else {
        chol_rest.solve(r.data(), z.data(), 1);
      }
    } else {
      z = jacobi_inv.cwiseProduct(r);
    }
  };
  dv = dv_prev;  // warm start
  const fem_detail::CgResult r = fem_detail::conjugateGradient(a, rhs, dv, tol, max_iter, cg, precond);
  stats.cg_iterations = r.iterations;
  stats.cg_residual = r.residual;
  return r.converged;
}

}  // namespace tactus::sim
