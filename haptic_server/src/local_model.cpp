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

// Instrument i's block of the snapshot header (instrument 0: the header's own fields, which
// repeat block 0, so a snapshot of one instrument without blocks works too).
const shared::PoseSample& devicePoseOf(const shared::ContactSnapshotHeader& h, int i) noexcept {
  return i == 0 ? h.device_pose : h.instrument[static_cast<std::size_t>(i)].device_pose;
}
const shared::PoseSample& toolPoseOf(const shared::ContactSnapshotHeader& h, int i) noexcept {
  return i == 0 ? h.tool_pose : h.instrument[static_cast<std::size_t>(i)].tool_pose;
}

// The contacts a device can move: all but those the simulation marks kContactUnreachable (a
// group of bodies without instrument). Sets reach_only when they are fewer than all and
// contiguous; else the whole problem is solved. Allocation-free, O(contacts).
void findReach(AttachedSegment& link, const shared::SnapshotView& snap) noexcept {
  link.reach_only = false;
  const auto& hdr = snap.header();
  const int nc = hdr.contacts;
  const std::int32_t* ci = snap.contactInstrument();
  const std::int32_t* ro = snap.rowOffset();
  int first = nc, last = -1, reached = 0;
  for (int c = 0; c < nc; ++c) {
    if (ci[c] == shared::kContactUnreachable) continue;
    first = std::min(first, c);
    last = std::max(last, c);
    ++reached;
  }
  if (reached == 0 || reached == nc || last - first + 1 != reached) return;
  if (ro[first] < 0 || ro[last + 1] > hdr.rows || ro[first] > ro[last + 1]) return;
  link.reach_begin = first;
  link.reach_end = last + 1;
  link.reach_only = true;
}

}  // namespace

void HapticLoop::solveLocalModel(AttachedSegment& link, const shared::SnapshotView& snap,
                                 const shared::Pose& device_pose, TickOutput& out) noexcept {
  std::array<const shared::Pose*, shared::kMaxInstruments> poses{};
  for (int i = 1; i < device_count_; ++i) {
    const DeviceChannel& ch = channels_[static_cast<std::size_t>(i)];
    if (ch.have_pose) poses[static_cast<std::size_t>(i)] = &ch.last_pose;
  }
  poses[0] = &device_pose;
  solveLocalModel(link, snap, poses, out);
}

void HapticLoop::solveLocalModel(
    AttachedSegment& link, const shared::SnapshotView& snap,
    const std::array<const shared::Pose*, shared::kMaxInstruments>& poses,
    TickOutput& out) noexcept {
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
  // the instruments of the snapshot (0 or 1 blocks: one instrument) and each one's device
  // displacement since x_h* (zero for a device without a pose, or an instrument without device)
  const int tools = std::clamp(hdr.instruments, 1, shared::kMaxInstruments);
  std::array<shared::Vector6d, shared::kMaxInstruments> dx;
  for (int i = 0; i < tools; ++i) {
    const shared::Pose* pose = i < device_count_ ? poses[static_cast<std::size_t>(i)] : nullptr;
    dx[static_cast<std::size_t>(i)] =
        pose != nullptr ? shared::poseDifference(*pose, toPose(devicePoseOf(hdr, i)))
                        : shared::Vector6d::Zero();
  }
  // each row's instrument; a contact naming no instrument of the snapshot (corrupt) moves with
  // none and pushes none (kNoInstrument)
  constexpr int kNoInstrument = -1;
  int* row_tool = link.row_instrument.data();
  const std::int32_t* ro = snap.rowOffset();
  const std::int32_t* ci = snap.contactInstrument();
  // (-1: a static obstacle's contact, which moves with no device and pushes no hand)
  std::fill_n(row_tool, m, kNoInstrument);
  for (int c = 0; c < nc; ++c) {
    const int r0 = std::clamp(ro[c], 0, m);
    const int r1 = std::clamp(ro[c + 1], r0, m);
    const int tool = ci[c] >= 0 && ci[c] < tools ? ci[c] : kNoInstrument;
    for (int r = r0; r < r1; ++r) row_tool[r] = tool;
  }
  // delta_free(t) = delta_free* + J (x_h [-] x_h*), each row with its own instrument's device
  const double* df = snap.deltaFree();
  const double* J = snap.J();
  const bool move = (hdr.flags & shared::kSnapshotHasJacobian) != 0;
  for (int r = 0; r < m; ++r) {
    double d = df[r];
    if (move && row_tool[r] != kNoInstrument) {
      const double* jr = J + 6 * r;
      const shared::Vector6d& dxr = dx[static_cast<std::size_t>(row_tool[r])];
      for (int k = 0; k < 6; ++k) d += jr[k] * dxr[k];
    }
    delta_free[r] = d;
  }
  shared::NsgsSettings ns;
  ns.tolerance = settings_.tolerance;
  ns.max_sweeps = settings_.max_sweeps;
  ns.anderson_depth = settings_.anderson_depth;
  ns.time_budget_ns = settings_.solve_budget_ns;
  // the row-update sweep needs an exactly symmetric W: only when the snapshot says so
  ns.coupling = snap.coupling();
  // the contacts the devices can move, found once per snapshot (AttachedSegment::reach_only)
  if (link.reach_seq != hdr.seq) {
    findReach(link, snap);
    link.reach_seq = hdr.seq;
  }
  shared::ContactProblemView problem = snap.problem(delta_free.data());
  int r_begin = 0, r_end = m;   // the rows solved
  if (link.reach_only) {
    r_begin = ro[link.reach_begin];
    r_end = ro[link.reach_end];
    problem = shared::contiguousSubproblem(problem, link.reach_begin, link.reach_end,
                                           link.reach_offset.data());
  }
  // same snapshot as the last solve: W and f are unchanged, so W f + delta_free only shifts by
  // the change of delta_free (saves a pass over W)
  if (link.delta_seq == hdr.seq) {
    double* delta = workspace.delta.data();
    for (int r = r_begin; r < r_end; ++r) {
      delta[r - r_begin] += delta_free[r] - link.last_delta_free[r];
    }
    ns.delta_is_current = true;
  }
  // W's storage, chosen once per snapshot: dense (one tissue) or blocks (several bodies)
  if (link.blocks_seq != hdr.seq) {
    link.use_blocks = shared::chooseStorage(problem, link.blocks).blocks != nullptr;
    link.blocks_seq = hdr.seq;
  }
  if (link.use_blocks) problem.blocks = &link.blocks;
  const shared::NsgsResult res = shared::solveNsgs(problem, ns, workspace, f.data() + r_begin);
  link.solve_converged = res.status == shared::NsgsStatus::kConverged;
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
  // wrench on each instrument from its contacts' forces (frame rows n, t1, t2)
  const double* pt = snap.contactPoint();
  const double* nn = snap.contactNormal();
  const double* tt = snap.contactTangent();
  std::array<Eigen::Vector3d, shared::kMaxInstruments> origin;
  std::array<Eigen::Vector3d, shared::kMaxInstruments> force;
  std::array<Eigen::Vector3d, shared::kMaxInstruments> torque;
  for (int i = 0; i < tools; ++i) {
    const auto k = static_cast<std::size_t>(i);
    origin[k] = toPose(toolPoseOf(hdr, i)).pos_m + dx[k].head<3>();
    force[k].setZero();
    torque[k].setZero();
  }
  for (int c = 0; c < nc; ++c) {
    const int r0 = ro[c];
    const int rows = ro[c + 1] - r0;
    const int tool = row_tool[r0];   // NSGS checked the offsets
    if (tool == kNoInstrument) continue;
    const auto k = static_cast<std::size_t>(tool);
    Eigen::Vector3d fc = f[r0] * Eigen::Vector3d(nn[3 * c], nn[3 * c + 1], nn[3 * c + 2]);
    if (rows == 3) {
      fc += f[r0 + 1] * Eigen::Vector3d(tt[6 * c], tt[6 * c + 1], tt[6 * c + 2]);
      fc += f[r0 + 2] * Eigen::Vector3d(tt[6 * c + 3], tt[6 * c + 4], tt[6 * c + 5]);
    }
    force[k] += fc;
    torque[k] += (Eigen::Vector3d(pt[3 * c], pt[3 * c + 1], pt[3 * c + 2]) - origin[k]).cross(fc);
  }
  for (int i = 0; i < tools && i < device_count_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    for (int j = 0; j < 3; ++j) {
      out.device[k].force_n[j] = force[k][j];
      out.device[k].torque_nm[j] = torque[k][j];
    }
  }
  out.force_n = out.device[0].force_n;
  out.torque_nm = out.device[0].torque_nm;
}

}  // namespace tactus::haptic
