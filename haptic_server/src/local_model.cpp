// The haptic tick's local model: the simulation's last contact problem with delta_free moved by
// the device's displacement since the snapshot (delta_free + J dx), re-solved by warm-started
// NSGS, and the wrench the contact forces put on the instrument. Allocation-free.
#include <algorithm>
#include <cmath>

#include "haptic_loop_internal.h"

namespace tactus::haptic {
namespace {

shared::Pose toPose(const shared::PoseSample& s) noexcept {
  shared::Pose p;
  p.pos_m = Eigen::Vector3d(s.pos_m[0], s.pos_m[1], s.pos_m[2]);
  p.rot = Eigen::Quaterniond(s.quat_wxyz[0], s.quat_wxyz[1], s.quat_wxyz[2], s.quat_wxyz[3]);
  const double n = p.rot.norm();
  if (n > 1e-12 && std::isfinite(n)) {
    p.rot.coeffs() /= n;
  } else {
    p.rot = Eigen::Quaterniond::Identity();
  }
  return p;
}

}  // namespace

void HapticLoop::solveLocalModel(AttachedSegment& link, const shared::SnapshotView& snap,
                                 const shared::Pose& device_pose, TickOutput& out) noexcept {
  shared::NsgsWorkspace& workspace = link.workspace;
  std::vector<double>& delta_free = link.delta_free;
  std::vector<double>& f = link.f;
  const auto& hdr = snap.header();
  const int m = hdr.rows;
  const int nc = hdr.contacts;
  out.contacts = nc;
  if (m <= 0 || nc <= 0) return;
  if (m > workspace.maxRows() || nc > workspace.maxContacts()) {
    pushEvent(kEventSnapshotTooLarge, m);
    return;
  }
  // delta_free(t) = delta_free* + J (x_h [-] x_h*)
  const shared::Pose x_star = toPose(hdr.device_pose);
  const shared::Vector6d dx = shared::poseDifference(device_pose, x_star);
  const double* df = snap.deltaFree();
  const double* J = snap.J();
  const bool move = (hdr.flags & shared::kSnapshotHasJacobian) != 0;
  for (int r = 0; r < m; ++r) {
    double d = df[r];
    if (move) {
      const double* jr = J + 6 * r;
      for (int k = 0; k < 6; ++k) d += jr[k] * dx[k];
    }
    delta_free[r] = d;
  }
  shared::NsgsSettings ns;
  ns.tolerance = settings_.tolerance;
  ns.max_sweeps = settings_.max_sweeps;
  ns.time_budget_ns = settings_.solve_budget_ns;
  // the row-update sweep needs an exactly symmetric W: only when the snapshot says so
  ns.coupling = (hdr.flags & shared::kSnapshotSymmetricW) != 0
                    ? shared::NsgsCoupling::kSymmetricRowUpdate
                    : shared::NsgsCoupling::kColumnUpdate;
  // same snapshot as the last solve: W and f are unchanged, so W f + delta_free only shifts by
  // the change of delta_free (saves a pass over W)
  if (link.delta_seq == hdr.seq) {
    double* delta = workspace.delta.data();
    for (int r = 0; r < m; ++r) delta[r] += delta_free[r] - link.last_delta_free[r];
    ns.delta_is_current = true;
  }
  // W's storage, chosen once per snapshot: dense (one tissue) or blocks (several bodies)
  shared::ContactProblemView problem = snap.problem(delta_free.data());
  if (link.blocks_seq != hdr.seq) {
    link.use_blocks = shared::chooseStorage(problem, link.blocks).blocks != nullptr;
    link.blocks_seq = hdr.seq;
  }
  if (link.use_blocks) problem.blocks = &link.blocks;
  const shared::NsgsResult res = shared::solveNsgs(problem, ns, workspace, f.data());
  link.delta_seq = res.status == shared::NsgsStatus::kEmpty ? 0 : hdr.seq;
  std::copy_n(delta_free.begin(), m, link.last_delta_free.begin());
  out.sweeps = res.sweeps;
  out.residual = res.error;
  out.solve_ns = res.elapsed_ns;
  // kEmpty: the view is inconsistent (row offsets, sizes): its offsets must not be used
  if (res.status == shared::NsgsStatus::kEmpty) return;
  if (res.status == shared::NsgsStatus::kNonFinite) {   // NSGS has zeroed f
    counters_.non_finite_input.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  // kIllPosed: W itself is unusable (a contact with a zero, negative or denormal diagonal). The
  // simulation never publishes such a W from a real scene, so the snapshot is corrupt: render no
  // force from it (the safety chain ramps the command down) and report it once per snapshot.
  if (res.status == shared::NsgsStatus::kIllPosed) {
    counters_.ill_posed_solves.fetch_add(1, std::memory_order_relaxed);
    out.flags |= shared::kStatsSolverNotConverged;
    if (link.ill_posed_seq != hdr.seq) {
      link.ill_posed_seq = hdr.seq;
      pushEvent(kEventIllPosedSnapshot, static_cast<double>(res.ill_posed_contacts),
                static_cast<double>(hdr.seq));
    }
    return;
  }
  const bool not_converged = res.status != shared::NsgsStatus::kConverged;
  if (not_converged) {
    out.flags |= shared::kStatsSolverNotConverged;
    counters_.solver_not_converged.fetch_add(1, std::memory_order_relaxed);
    if (!not_converged_) {
      pushRateLimited(kNoisyNotConverged, shared::kEventSolverNotConverged, last_tick_ns_,
                      res.sweeps, res.error);
    }
  }
  not_converged_ = not_converged;
  // wrench on the instrument from the contact forces (frame rows n, t1, t2)
  const std::int32_t* ro = snap.rowOffset();
  const double* pt = snap.contactPoint();
  const double* nn = snap.contactNormal();
  const double* tt = snap.contactTangent();
  const Eigen::Vector3d origin = toPose(hdr.tool_pose).pos_m + dx.head<3>();
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  Eigen::Vector3d torque = Eigen::Vector3d::Zero();
  for (int c = 0; c < nc; ++c) {
    const int r0 = ro[c];
    const int rows = ro[c + 1] - r0;
    Eigen::Vector3d fc = f[r0] * Eigen::Vector3d(nn[3 * c], nn[3 * c + 1], nn[3 * c + 2]);
    if (rows == 3) {
      fc += f[r0 + 1] * Eigen::Vector3d(tt[6 * c], tt[6 * c + 1], tt[6 * c + 2]);
      fc += f[r0 + 2] * Eigen::Vector3d(tt[6 * c + 3], tt[6 * c + 4], tt[6 * c + 5]);
    }
    force += fc;
    torque += (Eigen::Vector3d(pt[3 * c], pt[3 * c + 1], pt[3 * c + 2]) - origin).cross(fc);
  }
  for (int i = 0; i < 3; ++i) {
    out.force_n[i] = force[i];
    out.torque_nm[i] = torque[i];
  }
}

}  // namespace tactus::haptic
