// The haptic local model (local_model.h): preparation of a snapshot off the real-time thread
// (copy and checks, storage, reach, converged solve, linearisation) and the real-time solve.
#include "tactus/haptic/local_model.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"

namespace tactus::haptic {
namespace {

using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
constexpr int kNoTool = -1;
constexpr int kMaxCols = 6 * shared::kMaxInstruments;

bool finiteAll(const double* v, std::size_t n) noexcept {
  double acc = 0.0;   // NaN/Inf propagate through the product with zero
  for (std::size_t i = 0; i < n; ++i) acc += v[i] * 0.0;
  return acc == 0.0;
}

// A pose sample as a pose; false when it is not finite or its quaternion is not usable.
bool toPose(const shared::PoseSample& s, shared::Pose& p) noexcept {
  if (!finiteAll(s.pos_m.data(), 3) || !finiteAll(s.quat_wxyz.data(), 4)) return false;
  p.pos_m = Eigen::Vector3d(s.pos_m[0], s.pos_m[1], s.pos_m[2]);
  p.rot = Eigen::Quaterniond(s.quat_wxyz[0], s.quat_wxyz[1], s.quat_wxyz[2], s.quat_wxyz[3]);
  const double n = p.rot.norm();
  if (!(n > 1e-12) || !std::isfinite(n)) {
    p.rot = Eigen::Quaterniond::Identity();
  } else {
    p.rot.coeffs() /= n;
  }
  return true;
}

const shared::PoseSample& devicePoseOf(const shared::ContactSnapshotHeader& h, int i) noexcept {
  return i == 0 ? h.device_pose : h.instrument[static_cast<std::size_t>(i)].device_pose;
}
const shared::PoseSample& toolPoseOf(const shared::ContactSnapshotHeader& h, int i) noexcept {
  return i == 0 ? h.tool_pose : h.instrument[static_cast<std::size_t>(i)].tool_pose;
}

// dx[6i .. 6i+6) = poses[i] [-] x_h*_i (zero without a pose)
void displacementsOf(const PreparedSnapshot& p, const shared::Pose* const* poses, std::size_t n,
                     const std::array<shared::Pose, shared::kMaxInstruments>& x_star, int tools,
                     std::array<double, kMaxCols>& dx) noexcept {
  (void)p;
  dx.fill(0.0);
  for (int i = 0; i < tools; ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (k >= n || poses[k] == nullptr) continue;
    const shared::Vector6d d = shared::poseDifference(*poses[k], x_star[k]);
    for (int j = 0; j < 6; ++j) dx[6 * k + static_cast<std::size_t>(j)] = d[j];
  }
}

// NSGS settings of the tick's re-solve.
shared::NsgsSettings tickNsgsSettings(const LocalModelSettings& settings,
                                      shared::NsgsCoupling coupling, std::int64_t deadline_ns,
                                      bool delta_current) noexcept {
  shared::NsgsSettings ns;
  ns.tolerance = settings.tolerance;
  ns.max_sweeps = settings.max_sweeps;
  ns.anderson_depth = settings.anderson_depth;
  ns.coupling = coupling;
  ns.deadline_ns = deadline_ns;
  ns.delta_is_current = delta_current;
  return ns;
}

void checkRange(const char* name, double v, double lo, bool lo_open, double hi) {
  const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
  if (ok) return;
  throw Error(std::string("local model settings: ") + name + " = " + std::to_string(v) +
              " must be a finite number in " + (lo_open ? "(" : "[") + std::to_string(lo) + ", " +
              std::to_string(hi) + "]");
}

}  // namespace

std::string_view toString(LocalModelKind kind) noexcept {
  switch (kind) {
    case LocalModelKind::kFull: return "full";
    case LocalModelKind::kLinearized: return "linearized";
    case LocalModelKind::kAutomatic: return "automatic";
  }
  return "unknown";
}

std::optional<LocalModelKind> parseLocalModelKind(std::string_view name) noexcept {
  if (name == "full") return LocalModelKind::kFull;
  if (name == "linearized") return LocalModelKind::kLinearized;
  if (name == "automatic") return LocalModelKind::kAutomatic;
  return std::nullopt;
}

std::string_view toString(LocalModelUsed used) noexcept {
  switch (used) {
    case LocalModelUsed::kNone: return "none";
    case LocalModelUsed::kFull: return "full";
    case LocalModelUsed::kLinearized: return "linearized";
    case LocalModelUsed::kFallback: return "fallback";
  }
  return "unknown";
}

std::string_view toString(FallbackReason reason) noexcept {
  switch (reason) {
    case FallbackReason::kNone: return "none";
    case FallbackReason::kNotLinearized: return "not_linearized";
    case FallbackReason::kOutOfRange: return "out_of_range";
    case FallbackReason::kContactCloses: return "contact_closes";
    case FallbackReason::kContactLifts: return "contact_lifts";
    case FallbackReason::kLeavesCone: return "leaves_cone";
    case FallbackReason::kSlipTurns: return "slip_turns";
  }
  return "unknown";
}

std::string_view toString(PrepareStatus status) noexcept {
  switch (status) {
    case PrepareStatus::kEmpty: return "empty";
    case PrepareStatus::kReady: return "ready";
    case PrepareStatus::kTooLarge: return "too_large";
    case PrepareStatus::kInconsistent: return "inconsistent";
    case PrepareStatus::kNonFinite: return "non_finite";
    case PrepareStatus::kIllPosed: return "ill_posed";
  }
  return "unknown";
}

void LocalModelSettings::validate() const {
  using L = LocalModelLimits;
  checkRange("tolerance", tolerance, 0.0, true, L::kMaxTolerance);
  checkRange("max_sweeps", max_sweeps, 1.0, false, L::kMaxSweeps);
  checkRange("anderson_depth", anderson_depth, 0.0, false, shared::kMaxAndersonDepth);
  checkRange("automatic_min_rows", automatic_min_rows, 0.0, false, L::kMaxAutomaticMinRows);
  checkRange("max_translation_m", max_translation_m, 0.0, false, L::kMaxTranslationM);
  checkRange("max_rotation_rad", max_rotation_rad, 0.0, false, L::kMaxRotationRad);
  checkRange("prepare_tolerance_factor", prepare_tolerance_factor, 0.0, true, 1.0);
  checkRange("prepare_max_sweeps", prepare_max_sweeps, 1.0, false, L::kMaxSweeps);
  if (kind != LocalModelKind::kFull && kind != LocalModelKind::kLinearized &&
      kind != LocalModelKind::kAutomatic) {
    throw Error("local model settings: unknown kind");
  }
}

// ---------------------------------------------------------------------------------------------
// PreparedSnapshot

PreparedSnapshot::PreparedSnapshot(int max_rows, int max_contacts) {
  resize(max_rows, max_contacts);
}

void PreparedSnapshot::resize(int max_rows, int max_contacts) {
  max_rows_ = std::max(max_rows, 0);
  max_contacts_ = std::max(max_contacts, 0);
  const auto r = static_cast<std::size_t>(max_rows_);
  const auto c = static_cast<std::size_t>(max_contacts_);
  row_offset_.assign(c + 1, 0);
  contact_id_.assign(c, 0);
  mu_.assign(c, 0.0);
  W_.assign(r * r, 0.0);
  delta_free_.assign(r, 0.0);
  f_star_.assign(r, 0.0);
  J_.assign(r * 6, 0.0);
  point_.assign(c * 3, 0.0);
  normal_.assign(c * 3, 0.0);
  tangent_.assign(c * 6, 0.0);
  contact_tool_.assign(c, kNoTool);
  row_tool_.assign(r, kNoTool);
  blocks_.reserve(max_rows_, max_contacts_);
  f0_.assign(r, 0.0);
  delta0_.assign(r, 0.0);
  state_.assign(c, ContactState::kSeparated);
  F_.assign(r * kMaxCols, 0.0);
  G_.assign(r * kMaxCols, 0.0);
  order_.assign(c, 0);
  order_reach_.assign(c, 0.0);
  ordered_row_offset_.assign(c + 1, 0);
  ordered_row_.assign(r, 0);
  ordered_mu_.assign(c, 0.0);
  Wo_.assign(r * r, 0.0);
}

shared::ContactProblemView PreparedSnapshot::problem() const noexcept {
  return shared::denseProblemView(contacts_, rows_, row_offset_.data(), W_.data(),
                                  std::max(rows_, 1), delta_free_.data(), mu_.data());
}

// ---------------------------------------------------------------------------------------------
// SnapshotPreparation

SnapshotPreparation::SnapshotPreparation(int max_rows, int max_contacts)
    : max_rows_(max_rows),
      max_contacts_(max_contacts),
      warm_start_(max_contacts, max_rows),
      last_f_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      workspace_(max_rows, max_contacts),
      reach_offset_(static_cast<std::size_t>(std::max(max_contacts, 0)) + 1, 0),
      dq_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      active_(static_cast<std::size_t>(std::max(max_rows, 0)), 0),
      pivots_(static_cast<std::size_t>(std::max(max_rows, 0)), 0),
      sort_(static_cast<std::size_t>(std::max(max_contacts, 0))) {}

void SnapshotPreparation::reset() noexcept {
  warm_start_.reset();
  have_last_ = false;
}

bool SnapshotPreparation::copyAndCheck(const shared::SnapshotView& snap,
                                       PreparedSnapshot& out) noexcept {
  const auto& hdr = snap.header();
  const int m = hdr.rows;
  const int nc = hdr.contacts;
  out.rows_ = 0;
  out.contacts_ = 0;
  out.linearized_ = false;
  out.ordered_count_ = 0;
  out.prepared_converged_ = false;
  out.prepared_sweeps_ = 0;
  const bool usable = (hdr.flags & shared::kSnapshotValid) != 0 &&
                      (hdr.flags & shared::kSnapshotShuttingDown) == 0;
  if (!usable || m <= 0 || nc <= 0) {
    out.status_ = PrepareStatus::kEmpty;
    return false;
  }
  const shared::SnapshotLayout& layout = snap.layout();
  if (m > out.max_rows_ || nc > out.max_contacts_ || m > max_rows_ || nc > max_contacts_ ||
      m > layout.max_rows || nc > layout.max_contacts) {
    out.status_ = PrepareStatus::kTooLarge;
    return false;
  }
  if (m > 3 * nc || m < nc) {
    out.status_ = PrepareStatus::kInconsistent;
    return false;
  }
  // row offsets: 0, steps of 1 or 3, ending at the rows
  const std::int32_t* ro = snap.rowOffset();
  if (ro[0] != 0 || ro[nc] != m) {
    out.status_ = PrepareStatus::kInconsistent;
    return false;
  }
  for (int c = 0; c < nc; ++c) {
    const std::int32_t step = ro[c + 1] - ro[c];
    if (step != 1 && step != 3) {
      out.status_ = PrepareStatus::kInconsistent;
      return false;
    }
    out.row_offset_[static_cast<std::size_t>(c)] = ro[c];
  }
  out.row_offset_[static_cast<std::size_t>(nc)] = m;
  // instruments: each contact names one of the snapshot's, or none (-1 obstacle, -2 unreachable)
  out.tools_ = std::clamp(hdr.instruments, 1, shared::kMaxInstruments);
  const std::int32_t* ci = snap.contactInstrument();
  for (int c = 0; c < nc; ++c) {
    const std::int32_t t = ci[c];
    if (t != -1 && t != shared::kContactUnreachable && (t < 0 || t >= out.tools_)) {
      out.status_ = PrepareStatus::kInconsistent;
      return false;
    }
    out.contact_tool_[static_cast<std::size_t>(c)] = t >= 0 ? t : kNoTool;
    for (int r = ro[c]; r < ro[c + 1]; ++r) {
      out.row_tool_[static_cast<std::size_t>(r)] = t >= 0 ? t : kNoTool;
    }
  }
  // numbers: copied, then checked finite
  const auto mm = static_cast<std::size_t>(m);
  const auto nn = static_cast<std::size_t>(nc);
  const double* W = snap.W();
  const auto ld = static_cast<std::size_t>(snap.ld());
  for (std::size_t r = 0; r < mm; ++r) {
    std::copy_n(W + r * ld, mm, out.W_.data() + r * mm);
  }
  std::copy_n(snap.deltaFree(), mm, out.delta_free_.data());
  std::copy_n(snap.f(), mm, out.f_star_.data());
  if ((hdr.flags & shared::kSnapshotHasJacobian) != 0) {
    std::copy_n(snap.J(), 6 * mm, out.J_.data());
  } else {
    std::fill_n(out.J_.data(), 6 * mm, 0.0);
  }
  std::copy_n(snap.contactId(), nn, out.contact_id_.data());
  std::copy_n(snap.mu(), nn, out.mu_.data());
  std::copy_n(snap.contactPoint(), 3 * nn, out.point_.data());
  std::copy_n(snap.contactNormal(), 3 * nn, out.normal_.data());
  std::copy_n(snap.contactTangent(), 6 * nn, out.tangent_.data());
  bool finite = finiteAll(out.W_.data(), mm * mm) && finiteAll(out.delta_free_.data(), mm) &&
                finiteAll(out.f_star_.data(), mm) && finiteAll(out.J_.data(), 6 * mm) &&
                finiteAll(out.mu_.data(), nn) && finiteAll(out.point_.data(), 3 * nn) &&
                finiteAll(out.normal_.data(), 3 * nn) && finiteAll(out.tangent_.data(), 6 * nn);
  for (std::size_t c = 0; c < nn && finite; ++c) finite = out.mu_[c] >= 0.0;
  for (int i = 0; i < out.tools_ && finite; ++i) {
    const auto k = static_cast<std::size_t>(i);
    finite = toPose(devicePoseOf(hdr, i), out.device_pose_[k]) &&
             toPose(toolPoseOf(hdr, i), out.tool_pose_[k]);
  }
  if (!finite) {
    out.status_ = PrepareStatus::kNonFinite;
    return false;
  }
  out.coupling_ = snap.coupling();
  out.rows_ = m;
  out.contacts_ = nc;
  return true;
}

PrepareStatus SnapshotPreparation::prepare(const shared::SnapshotView& snap,
                                           const LocalModelSettings& settings, DevicePoses poses,
                                           PreparedSnapshot& out) noexcept {
  const std::int64_t t0 = shared::monotonicNs();
  out.header_ = snap.header();
  out.generation_ = ++generation_;
  // the same snapshot again (at newer poses): its warm start is the last solution itself
  const bool again = snap.header().seq == last_seq_ && have_last_;
  last_seq_ = snap.header().seq;
  const bool copied = copyAndCheck(snap, out);
  const std::int64_t t1 = shared::monotonicNs();
  out.copy_ns_ = t1 - t0;
  out.storage_ns_ = out.solve_ns_ = out.linearize_ns_ = 0;
  if (!copied) {
    out.prepare_ns_ = t1 - t0;
    if (out.status_ != PrepareStatus::kEmpty) reset();
    return out.status_;
  }
  const int m = out.rows_;
  const int nc = out.contacts_;
  // the contacts a device can reach: solved alone when fewer than all and contiguous
  out.reach_only_ = false;
  {
    int first = nc, last = -1, reached = 0;
    for (int c = 0; c < nc; ++c) {
      if (snap.contactInstrument()[c] == shared::kContactUnreachable) continue;
      first = std::min(first, c);
      last = std::max(last, c);
      ++reached;
    }
    if (reached > 0 && reached < nc && last - first + 1 == reached) {
      out.reach_only_ = true;
      out.reach_begin_ = first;
      out.reach_end_ = last + 1;
    }
  }
  shared::ContactProblemView problem = out.problem();
  const int c_begin = out.reach_only_ ? out.reach_begin_ : 0;
  const int c_end = out.reach_only_ ? out.reach_end_ : nc;
  const int r_begin = out.row_offset_[static_cast<std::size_t>(c_begin)];
  const int r_end = out.row_offset_[static_cast<std::size_t>(c_end)];
  // the preparation's poses, and delta_free moved to them
  displacementsOf(out, poses.data(), poses.size(), out.device_pose_, out.tools_, out.dx0_);
  for (int r = 0; r < m; ++r) {
    double d = out.delta_free_[static_cast<std::size_t>(r)];
    const int t = out.row_tool_[static_cast<std::size_t>(r)];
    if (t != kNoTool) {
      const double* jr = out.J_.data() + 6 * r;
      for (int k = 0; k < 6; ++k) d += jr[k] * out.dx0_[static_cast<std::size_t>(6 * t + k)];
    }
    dq_[static_cast<std::size_t>(r)] = d;
  }
  problem.delta_free = dq_.data();
  if (out.reach_only_) {
    problem = shared::contiguousSubproblem(problem, c_begin, c_end, reach_offset_.data());
  }
  out.use_blocks_ = shared::chooseStorage(problem, out.blocks_).blocks != nullptr;
  if (out.use_blocks_) problem.blocks = &out.blocks_;
  const std::int64_t t2 = shared::monotonicNs();
  out.storage_ns_ = t2 - t1;
  // warm start: the snapshot's f* plus the last prepared solution's correction, by contact id
  if (again) {
    std::copy_n(last_f_.data(), m, out.f0_.data());
  } else {
    warm_start_.adopt(nc, m, out.row_offset_.data(), out.contact_id_.data(),
                      out.f_star_.data(), have_last_ ? last_f_.data() : nullptr, out.f0_.data());
  }
  shared::NsgsSettings ns;
  ns.tolerance = settings.tolerance * settings.prepare_tolerance_factor;
  ns.max_sweeps = settings.prepare_max_sweeps;
  ns.coupling = out.coupling_;
  ns.anderson_depth = shared::kMaxAndersonDepth;
  double* f = out.f0_.data() + r_begin;
  shared::NsgsResult res = shared::solveNsgs(problem, ns, workspace_, f);
  int sweeps = res.sweeps;
  if (res.status == shared::NsgsStatus::kMaxSweeps) {   // Anderson may stall: plain NSGS
    ns.anderson_depth = 0;
    res = shared::solveNsgs(problem, ns, workspace_, f);
    sweeps += res.sweeps;
  }
  out.prepared_sweeps_ = sweeps;
  out.prepared_converged_ = res.status == shared::NsgsStatus::kConverged;
  const std::int64_t t3 = shared::monotonicNs();
  out.solve_ns_ = t3 - t2;
  if (res.status == shared::NsgsStatus::kIllPosed || res.status == shared::NsgsStatus::kEmpty ||
      res.status == shared::NsgsStatus::kNonFinite) {
    out.status_ = res.status == shared::NsgsStatus::kIllPosed ? PrepareStatus::kIllPosed
                  : res.status == shared::NsgsStatus::kEmpty  ? PrepareStatus::kInconsistent
                                                               : PrepareStatus::kNonFinite;
    out.prepare_ns_ = t3 - t0;
    reset();
    return out.status_;
  }
  std::fill(out.delta0_.begin(), out.delta0_.begin() + m, 0.0);
  std::copy_n(workspace_.delta.data(), r_end - r_begin, out.delta0_.data() + r_begin);
  // carried into the next snapshot only from a converged solve (as the haptic warm start)
  have_last_ = out.prepared_converged_;
  if (have_last_) std::copy_n(out.f0_.data(), m, last_f_.data());
  out.status_ = PrepareStatus::kReady;
  const bool wanted = settings.kind == LocalModelKind::kLinearized ||
                      (settings.kind == LocalModelKind::kAutomatic &&
                       m >= settings.automatic_min_rows);
  if (wanted && out.prepared_converged_) linearize(settings, out);
  if (out.linearized_) orderForReducedFallback(settings, out);
  const std::int64_t t4 = shared::monotonicNs();
  out.linearize_ns_ = t4 - t3;
  out.prepare_ns_ = t4 - t0;
  return out.status_;
}

// The active-set linearisation (local_model.h): A df = B dx over the active rows of the reached
// contacts, then F = df/dx and G = W F + J.
void SnapshotPreparation::linearize(const LocalModelSettings& settings,
                                    PreparedSnapshot& out) noexcept {
  (void)settings;
  out.linearized_ = false;
  const int m = out.rows_;
  const int nc = out.contacts_;
  const int c_begin = out.reach_only_ ? out.reach_begin_ : 0;
  const int c_end = out.reach_only_ ? out.reach_end_ : nc;
  const int* ro = out.row_offset_.data();
  const double* W = out.W_.data();
  const double* f0 = out.f0_.data();
  const double* d0 = out.delta0_.data();
  const int cols = 6 * out.tools_;
  // contact states and the active rows
  int na = 0;
  out.sliding_ = 0;
  std::fill_n(out.state_.data(), nc, ContactState::kSeparated);
  for (int c = c_begin; c < c_end; ++c) {
    const int r = ro[c];
    const int k = ro[c + 1] - r;
    const double mu = out.mu_[static_cast<std::size_t>(c)];
    ContactState s = ContactState::kSeparated;
    if (f0[r] > 0.0) {
      if (k == 1 || mu == 0.0) {
        s = ContactState::kNormalOnly;
      } else {
        const double ft = std::hypot(f0[r + 1], f0[r + 2]);
        const double st = std::hypot(d0[r + 1], d0[r + 2]);
        s = ft >= mu * f0[r] * (1.0 - 1e-7) && st > 0.0 ? ContactState::kSliding
                                                          : ContactState::kSticking;
      }
    }
    out.state_[static_cast<std::size_t>(c)] = s;
    if (s == ContactState::kSeparated) continue;
    if (s == ContactState::kSliding) ++out.sliding_;
    const int unknowns = s == ContactState::kNormalOnly ? 1 : 3;
    for (int a = 0; a < unknowns; ++a) active_[static_cast<std::size_t>(na++)] = r + a;
  }
  out.active_rows_ = na;
  std::fill(out.F_.begin(), out.F_.begin() + static_cast<std::ptrdiff_t>(m) * kMaxCols, 0.0);
  std::fill(out.G_.begin(), out.G_.begin() + static_cast<std::ptrdiff_t>(m) * kMaxCols, 0.0);
  if (na > 0) {
    // position of each row among the active ones (-1: not active)
    std::vector<int>& pos = pivots_;
    std::fill_n(pos.data(), m, -1);
    for (int i = 0; i < na; ++i) pos[static_cast<std::size_t>(active_[static_cast<std::size_t>(i)])] = i;
    Eigen::MatrixXd A = Eigen::MatrixXd::Zero(na, na);
    Eigen::MatrixXd B = Eigen::MatrixXd::Zero(na, cols);
    auto jrow = [&](int row, double scale, int eq) {   // B(eq, :) += -scale * J(row) dq/dx
      const int t = out.row_tool_[static_cast<std::size_t>(row)];
      if (t == kNoTool) return;
      for (int k = 0; k < 6; ++k) B(eq, 6 * t + k) -= scale * out.J_[static_cast<std::size_t>(6 * row + k)];
    };
    auto wrow = [&](int row, double scale, int eq) {   // A(eq, :) += scale * W(row, active)
      const double* wr = W + static_cast<std::ptrdiff_t>(row) * m;
      for (int j = 0; j < na; ++j) A(eq, j) += scale * wr[active_[static_cast<std::size_t>(j)]];
    };
    for (int c = c_begin; c < c_end; ++c) {
      const ContactState s = out.state_[static_cast<std::size_t>(c)];
      if (s == ContactState::kSeparated) continue;
      const int r = ro[c];
      if (s == ContactState::kSticking || s == ContactState::kNormalOnly) {
        const int unknowns = s == ContactState::kNormalOnly ? 1 : 3;
        for (int a = 0; a < unknowns; ++a) {
          const int eq = pos[static_cast<std::size_t>(r + a)];
          wrow(r + a, 1.0, eq);
          jrow(r + a, 1.0, eq);
        }
        continue;
      }
      // sliding: delta_n = 0; df_t - mu u df_n + P d delta_t = 0, P = mu f_n / s (I - u u^T)
      const double mu = out.mu_[static_cast<std::size_t>(c)];
      const int en = pos[static_cast<std::size_t>(r)];
      wrow(r, 1.0, en);
      jrow(r, 1.0, en);
      const double ft = std::hypot(f0[r + 1], f0[r + 2]);
      const double u[2] = {f0[r + 1] / ft, f0[r + 2] / ft};
      const double st = std::hypot(d0[r + 1], d0[r + 2]);
      const double a = mu * f0[r] / st;
      for (int t = 0; t < 2; ++t) {
        const int eq = pos[static_cast<std::size_t>(r + 1 + t)];
        A(eq, eq) += 1.0;
        A(eq, en) -= mu * u[t];
        for (int t2 = 0; t2 < 2; ++t2) {
          const double P = a * ((t == t2 ? 1.0 : 0.0) - u[t] * u[t2]);
          if (P == 0.0) continue;
          wrow(r + 1 + t2, P, eq);
          jrow(r + 1 + t2, P, eq);
        }
      }
    }
    const Eigen::PartialPivLU<Eigen::MatrixXd> lu(A);
    const Eigen::MatrixXd X = lu.solve(B);
    if (!X.allFinite() || !((A * X - B).norm() <= 1e-6 * (B.norm() + 1e-300))) return;
    for (int i = 0; i < na; ++i) {
      const auto row = static_cast<std::size_t>(active_[static_cast<std::size_t>(i)]);
      for (int k = 0; k < cols; ++k) out.F_[row * kMaxCols + static_cast<std::size_t>(k)] = X(i, k);
    }
  }
  // G = W F + J over the reached rows
  const int r_begin = ro[c_begin];
  const int r_end = ro[c_end];
  const int mr = r_end - r_begin;
  const Eigen::Map<const RowMajor, 0, Eigen::OuterStride<>> Wr(
      W + static_cast<std::ptrdiff_t>(r_begin) * m + r_begin, mr, mr, Eigen::OuterStride<>(m));
  const Eigen::Map<const RowMajor> Fr(out.F_.data() + static_cast<std::ptrdiff_t>(r_begin) * kMaxCols,
                                      mr, kMaxCols);
  Eigen::Map<RowMajor> Gr(out.G_.data() + static_cast<std::ptrdiff_t>(r_begin) * kMaxCols, mr,
                          kMaxCols);
  Gr.leftCols(cols).noalias() = Wr * Fr.leftCols(cols);
  for (int r = r_begin; r < r_end; ++r) {
    const int t = out.row_tool_[static_cast<std::size_t>(r)];
    if (t == kNoTool) continue;
    for (int k = 0; k < 6; ++k) {
      out.G_[static_cast<std::size_t>(r) * kMaxCols + static_cast<std::size_t>(6 * t + k)] +=
          out.J_[static_cast<std::size_t>(6 * r + k)];
    }
  }
  out.linearized_ = finiteAll(out.G_.data(), static_cast<std::size_t>(m) * kMaxCols);
}

// The reduced fallback's order (local_model.h): the reached contacts by the device displacement
// at which each can first carry force, and W copied in that order.
void SnapshotPreparation::orderForReducedFallback(const LocalModelSettings& settings,
                                                  PreparedSnapshot& out) noexcept {
  const int m = out.rows_;
  const int c_begin = out.reach_only_ ? out.reach_begin_ : 0;
  const int c_end = out.reach_only_ ? out.reach_end_ : out.contacts_;
  const int n = c_end - c_begin;
  const int* ro = out.row_offset_.data();
  const double lever = settings.max_translation_m > 0.0 && settings.max_rotation_rad > 0.0
                           ? settings.max_translation_m / settings.max_rotation_rad
                           : 0.04;
  out.ordered_lever_m_ = lever;
  for (int c = c_begin; c < c_end; ++c) {
    double reach = 0.0;
    if (out.state_[static_cast<std::size_t>(c)] == ContactState::kSeparated) {
      // the gap over its closing rate per metre of displacement (G's normal row)
      const int r = ro[c];
      const double gap = out.delta0_[static_cast<std::size_t>(r)];
      const double* g = out.G_.data() + static_cast<std::ptrdiff_t>(r) * kMaxCols;
      double rate = 0.0;
      for (int t = 0; t < out.tools_; ++t) {
        rate += std::hypot(g[6 * t], g[6 * t + 1], g[6 * t + 2]) +
                std::hypot(g[6 * t + 3], g[6 * t + 4], g[6 * t + 5]) / lever;
      }
      reach = gap <= 0.0 ? 0.0
              : rate > 0.0 ? gap / rate
                           : std::numeric_limits<double>::infinity();
    }
    sort_[static_cast<std::size_t>(c - c_begin)] = {reach, c};
  }
  std::sort(sort_.begin(), sort_.begin() + n);
  int rows = 0;
  for (int i = 0; i < n; ++i) {
    const int c = sort_[static_cast<std::size_t>(i)].second;
    const auto k = static_cast<std::size_t>(i);
    out.order_[k] = c;
    out.order_reach_[k] = sort_[k].first;
    out.ordered_mu_[k] = out.mu_[static_cast<std::size_t>(c)];
    out.ordered_row_offset_[k] = rows;
    for (int r = ro[c]; r < ro[c + 1]; ++r) out.ordered_row_[static_cast<std::size_t>(rows++)] = r;
  }
  out.ordered_row_offset_[static_cast<std::size_t>(n)] = rows;
  const double* W = out.W_.data();
  for (int i = 0; i < rows; ++i) {
    const double* src = W + static_cast<std::ptrdiff_t>(out.ordered_row_[static_cast<std::size_t>(i)]) * m;
    double* dst = out.Wo_.data() + static_cast<std::ptrdiff_t>(i) * rows;
    for (int j = 0; j < rows; ++j) dst[j] = src[out.ordered_row_[static_cast<std::size_t>(j)]];
  }
  out.ordered_rows_ = rows;
  out.ordered_count_ = n;
}

// ---------------------------------------------------------------------------------------------
// LocalModel

LocalModel::LocalModel(int max_rows, int max_contacts)
    : max_rows_(max_rows),
      workspace_(max_rows, max_contacts),
      f_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      delta_free_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      last_delta_free_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      reach_offset_(static_cast<std::size_t>(std::max(max_contacts, 0)) + 1, 0),
      fo_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      qo_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      scratch_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0) {}

void LocalModel::adopt(const PreparedSnapshot* prepared) noexcept {
  prepared_ = prepared;
  delta_valid_ = false;
  if (prepared_ == nullptr || prepared_->status_ != PrepareStatus::kReady ||
      prepared_->rows_ > max_rows_ || prepared_->contacts_ > workspace_.maxContacts()) {
    return;
  }
  // start from the preparation's solution, whose W f + delta_free it also gives (no entry pass)
  const int m = prepared_->rows_;
  std::copy_n(prepared_->f0_.data(), m, f_.data());
  const int c_begin = prepared_->reach_only_ ? prepared_->reach_begin_ : 0;
  const int c_end = prepared_->reach_only_ ? prepared_->reach_end_ : prepared_->contacts_;
  const int r_begin = prepared_->row_offset_[static_cast<std::size_t>(c_begin)];
  const int r_end = prepared_->row_offset_[static_cast<std::size_t>(c_end)];
  std::copy(prepared_->delta0_.data() + r_begin, prepared_->delta0_.data() + r_end,
            workspace_.delta.data());
  dx_ = prepared_->dx0_;
  moveDeltaFree();
  std::copy_n(delta_free_.data(), m, last_delta_free_.data());
  delta_valid_ = true;
}

void LocalModel::displacements(DevicePoses poses) noexcept {
  displacementsOf(*prepared_, poses.data(), poses.size(), prepared_->device_pose_,
                  prepared_->tools_, dx_);
}

void LocalModel::moveDeltaFree() noexcept {
  const PreparedSnapshot& p = *prepared_;
  for (int r = 0; r < p.rows_; ++r) {
    double d = p.delta_free_[static_cast<std::size_t>(r)];
    const int t = p.row_tool_[static_cast<std::size_t>(r)];
    if (t != kNoTool) {
      const double* jr = p.J_.data() + 6 * r;
      for (int k = 0; k < 6; ++k) d += jr[k] * dx_[static_cast<std::size_t>(6 * t + k)];
    }
    delta_free_[static_cast<std::size_t>(r)] = d;
  }
}

// f = f0 + F (dx - dx0) on the reached rows; true when the active set still holds (local_model.h).
// Leaves workspace_.delta = delta0 + G (dx - dx0) = W f + delta_free (before the projection of
// sliding forces onto their cone, which only a valid evaluation applies).
FallbackReason LocalModel::evaluateLinearization(const LocalModelSettings& settings) noexcept {
  const PreparedSnapshot& p = *prepared_;
  const int cols = 6 * p.tools_;
  std::array<double, kMaxCols> ddx{};
  bool in_range = true;
  for (int i = 0; i < p.tools_; ++i) {
    double t2 = 0.0, w2 = 0.0;
    for (int k = 0; k < 3; ++k) {
      const auto a = static_cast<std::size_t>(6 * i + k);
      ddx[a] = dx_[a] - p.dx0_[a];
      ddx[a + 3] = dx_[a + 3] - p.dx0_[a + 3];
      t2 += ddx[a] * ddx[a];
      w2 += ddx[a + 3] * ddx[a + 3];
    }
    in_range = in_range && std::sqrt(t2) <= settings.max_translation_m &&
               std::sqrt(w2) <= settings.max_rotation_rad;
  }
  const int c_begin = p.reach_only_ ? p.reach_begin_ : 0;
  const int c_end = p.reach_only_ ? p.reach_end_ : p.contacts_;
  const int* ro = p.row_offset_.data();
  const int r_begin = ro[c_begin];
  const int r_end = ro[c_end];
  double* delta = workspace_.delta.data();
  for (int r = r_begin; r < r_end; ++r) {
    const double* Fr = p.F_.data() + static_cast<std::ptrdiff_t>(r) * kMaxCols;
    const double* Gr = p.G_.data() + static_cast<std::ptrdiff_t>(r) * kMaxCols;
    double fr = p.f0_[static_cast<std::size_t>(r)];
    double dr = p.delta0_[static_cast<std::size_t>(r)];
    for (int k = 0; k < cols; ++k) {
      fr += Fr[k] * ddx[static_cast<std::size_t>(k)];
      dr += Gr[k] * ddx[static_cast<std::size_t>(k)];
    }
    f_[static_cast<std::size_t>(r)] = fr;
    delta[r - r_begin] = dr;
  }
  if (!in_range) return FallbackReason::kOutOfRange;
  // the slack the tolerance allows: a violation of this size is a natural-map error of about
  // half the tolerance (the error is normalised by the largest of |q|, |f|, |delta|)
  double q2 = 0.0, f2 = 0.0, d2 = 0.0;
  for (int r = r_begin; r < r_end; ++r) {
    const auto k = static_cast<std::size_t>(r);
    q2 += delta_free_[k] * delta_free_[k];
    f2 += f_[k] * f_[k];
    d2 += delta[r - r_begin] * delta[r - r_begin];
  }
  const double slack = 0.5 * settings.tolerance * std::sqrt(std::max({q2, f2, d2})) /
                       std::sqrt(static_cast<double>(std::max(c_end - c_begin, 1)));
  for (int c = c_begin; c < c_end; ++c) {
    const int r = ro[c];
    double* fc = f_.data() + r;
    const double* dc = delta + (r - r_begin);
    const double mu = p.mu_[static_cast<std::size_t>(c)];
    switch (p.state_[static_cast<std::size_t>(c)]) {
      case ContactState::kSeparated:
        if (dc[0] < -slack) return FallbackReason::kContactCloses;
        break;
      case ContactState::kNormalOnly:
        if (fc[0] < -slack) return FallbackReason::kContactLifts;
        break;
      case ContactState::kSticking:
        if (fc[0] < -slack) return FallbackReason::kContactLifts;
        if (std::hypot(fc[1], fc[2]) > mu * fc[0] + slack) return FallbackReason::kLeavesCone;
        break;
      case ContactState::kSliding: {
        // still sliding, against the force: the force's direction within 18 degrees of -delta_t
        const double ft = std::hypot(fc[1], fc[2]);
        const double st = std::hypot(dc[1], dc[2]);
        if (fc[0] < -slack) return FallbackReason::kContactLifts;
        if (!(ft > 0.0) || !(st > 0.0)) return FallbackReason::kSlipTurns;
        if (-(fc[1] * dc[1] + fc[2] * dc[2]) < 0.95 * ft * st) return FallbackReason::kSlipTurns;
        break;
      }
    }
  }
  // valid: forces into their cone (sliding ones onto its boundary; the rest move by < slack)
  for (int c = c_begin; c < c_end; ++c) {
    const int r = ro[c];
    double* fc = f_.data() + r;
    const int k = ro[c + 1] - r;
    const double mu = p.mu_[static_cast<std::size_t>(c)];
    const ContactState s = p.state_[static_cast<std::size_t>(c)];
    fc[0] = std::max(fc[0], 0.0);
    if (k != 3) continue;
    if (s == ContactState::kSliding) {
      const double ft = std::hypot(fc[1], fc[2]);
      const double scale = mu * fc[0] / ft;
      fc[1] *= scale;
      fc[2] *= scale;
    } else if (s == ContactState::kSticking) {
      const double ft = std::hypot(fc[1], fc[2]);
      if (ft > mu * fc[0] && ft > 0.0) {
        fc[1] *= mu * fc[0] / ft;
        fc[2] *= mu * fc[0] / ft;
      }
    }
  }
  return FallbackReason::kNone;
}

shared::NsgsResult LocalModel::resolve(const LocalModelSettings& settings,
                                       std::int64_t deadline_ns, bool delta_current) noexcept {
  const PreparedSnapshot& p = *prepared_;
  shared::ContactProblemView problem = p.problem();
  problem.delta_free = delta_free_.data();
  int r_begin = 0;
  if (p.reach_only_) {
    r_begin = p.row_offset_[static_cast<std::size_t>(p.reach_begin_)];
    problem =
        shared::contiguousSubproblem(problem, p.reach_begin_, p.reach_end_, reach_offset_.data());
  }
  if (p.use_blocks_) problem.blocks = &p.blocks_;
  const shared::NsgsSettings ns =
      tickNsgsSettings(settings, p.coupling_, deadline_ns, delta_current);
  return shared::solveNsgs(problem, ns, workspace_, f_.data() + r_begin);
}

// The reduced fallback (local_model.h): from the linear prediction (f_, and W f + delta_free in
// workspace_.delta), NSGS on the leading ordered contacts, then the check of the others.
shared::NsgsResult LocalModel::resolveReduced(const LocalModelSettings& settings,
                                              std::int64_t deadline_ns,
                                              int& solved_contacts) noexcept {
  const PreparedSnapshot& p = *prepared_;
  const int n = p.ordered_count_;
  const int rows = p.ordered_rows_;
  const int* oro = p.ordered_row_offset_.data();
  const int* orow = p.ordered_row_.data();
  const double* Wo = p.Wo_.data();
  const int r_begin = p.reach_only_ ? p.row_offset_[static_cast<std::size_t>(p.reach_begin_)] : 0;
  // this tick's displacement from the linearisation point, as orderedReach() measures it
  double reach = 0.0;
  for (int t = 0; t < p.tools_; ++t) {
    const auto a = static_cast<std::size_t>(6 * t);
    const double tr = std::hypot(dx_[a] - p.dx0_[a], dx_[a + 1] - p.dx0_[a + 1],
                                 dx_[a + 2] - p.dx0_[a + 2]);
    const double rot = std::hypot(dx_[a + 3] - p.dx0_[a + 3], dx_[a + 4] - p.dx0_[a + 4],
                                  dx_[a + 5] - p.dx0_[a + 5]);
    reach = std::max({reach, tr, p.ordered_lever_m_ * rot});
  }
  reach *= kReducedReachFactor;
  int k = 0;
  while (k < n && p.order_reach_[static_cast<std::size_t>(k)] <= reach) ++k;
  // the prediction in the order (delta through scratch_: workspace_.delta is overwritten)
  double* delta = workspace_.delta.data();
  for (int j = 0; j < rows; ++j) {
    const auto row = static_cast<std::size_t>(orow[j]);
    fo_[static_cast<std::size_t>(j)] = f_[row];
    qo_[static_cast<std::size_t>(j)] = delta_free_[row];
    scratch_[static_cast<std::size_t>(j)] = delta[orow[j] - r_begin];
  }
  std::copy_n(scratch_.data(), rows, delta);
  shared::NsgsSettings ns = tickNsgsSettings(settings, p.coupling_, deadline_ns, true);
  // (W f + q) on ordered row j, f on the first rk ordered rows
  auto rowValue = [&](int j, int rk) {
    const double* w = Wo + static_cast<std::ptrdiff_t>(j) * rows;
    double d = qo_[static_cast<std::size_t>(j)];
    for (int a = 0; a < rk; ++a) d += w[a] * fo_[static_cast<std::size_t>(a)];
    return d;
  };
  shared::NsgsResult res;
  res.status = shared::NsgsStatus::kConverged;
  int sweeps = 0;
  constexpr int kCheckClockEvery = 16;   // contacts of the check between looks at the clock
  for (;;) {
    const int rk = oro[k];
    if (k > 0) {
      const shared::ContactProblemView view = shared::denseProblemView(
          k, rk, oro, Wo, rows, qo_.data(), p.ordered_mu_.data());
      ns.max_sweeps = std::max(settings.max_sweeps - sweeps, 1);
      res = shared::solveNsgs(view, ns, workspace_, fo_.data());
      sweeps += res.sweeps;
      if (res.status != shared::NsgsStatus::kConverged) break;
    }
    // the contacts left out: still open at this solution (then f = 0 is theirs)?
    int closed = -1;
    for (int i = k; i < n && closed < 0; ++i) {
      if (deadline_ns > 0 && (i - k) % kCheckClockEvery == kCheckClockEvery - 1 &&
          shared::monotonicNs() >= deadline_ns) {
        res.status = shared::NsgsStatus::kTimeBudget;
        break;
      }
      if (rowValue(oro[i], rk) < 0.0) closed = i;
    }
    if (closed < 0 || res.status != shared::NsgsStatus::kConverged) break;
    // take in the contacts up to the closed one, at zero force: delta = W f + q on their rows
    const int k2 = closed + 1;
    for (int j = rk; j < oro[k2]; ++j) {
      delta[j] = rowValue(j, rk);
      fo_[static_cast<std::size_t>(j)] = 0.0;
    }
    k = k2;
  }
  // back to the rows (the contacts left out at zero)
  const int rk = oro[k];
  for (int j = 0; j < rows; ++j) {
    f_[static_cast<std::size_t>(orow[j])] = j < rk ? fo_[static_cast<std::size_t>(j)] : 0.0;
  }
  res.sweeps = sweeps;
  solved_contacts = k;
  return res;
}

LocalModelResult LocalModel::solve(DevicePoses poses, const LocalModelSettings& settings,
                                   std::int64_t deadline_ns) noexcept {
  const std::int64_t t0 = shared::monotonicNs();
  LocalModelResult out;
  if (prepared_ == nullptr || prepared_->status_ != PrepareStatus::kReady ||
      prepared_->rows_ > max_rows_) {
    if (prepared_ != nullptr) out.contacts = prepared_->contacts_;
    return out;
  }
  const PreparedSnapshot& p = *prepared_;
  out.rows = p.rows_;
  out.contacts = p.contacts_;
  out.instruments = p.tools_;
  displacements(poses);
  moveDeltaFree();
  const int r_begin = p.reach_only_ ? p.row_offset_[static_cast<std::size_t>(p.reach_begin_)] : 0;
  const int r_end =
      p.reach_only_ ? p.row_offset_[static_cast<std::size_t>(p.reach_end_)] : p.rows_;
  const bool linear = p.linearized_ && settings.kind != LocalModelKind::kFull;
  bool delta_current = false;
  bool reduced = false;
  if (!linear && settings.kind != LocalModelKind::kFull &&
      (settings.kind == LocalModelKind::kLinearized ||
       p.rows_ >= settings.automatic_min_rows)) {
    out.fallback = FallbackReason::kNotLinearized;   // wanted, but not available
  }
  if (linear) {
    out.fallback = evaluateLinearization(settings);
    if (out.fallback == FallbackReason::kNone) {
      delta_valid_ = false;
      out.used = LocalModelUsed::kLinearized;
      out.status = shared::NsgsStatus::kConverged;
      out.error = 0.0;
      std::copy_n(delta_free_.data(), p.rows_, last_delta_free_.data());
      wrenches(out);
      out.elapsed_ns = shared::monotonicNs() - t0;
      return out;
    }
    // fall back: NSGS from the prediction, whose W f + delta_free is in workspace_.delta
    delta_current = true;
    out.used = LocalModelUsed::kFallback;
    reduced = settings.reduced_fallback && p.ordered_count_ > 0;
  } else {
    out.used = out.fallback == FallbackReason::kNotLinearized ? LocalModelUsed::kFallback
                                                               : LocalModelUsed::kFull;
    // same snapshot as the last solve: W f + delta_free only shifts by the change of delta_free
    if (delta_valid_) {
      double* delta = workspace_.delta.data();
      for (int r = r_begin; r < r_end; ++r) {
        delta[r - r_begin] += delta_free_[static_cast<std::size_t>(r)] -
                              last_delta_free_[static_cast<std::size_t>(r)];
      }
      delta_current = true;
    }
  }
  int solved_contacts =
      p.reach_only_ ? p.reach_end_ - p.reach_begin_ : p.contacts_;
  const shared::NsgsResult res = reduced
                                     ? resolveReduced(settings, deadline_ns, solved_contacts)
                                     : resolve(settings, deadline_ns, delta_current);
  out.solved_contacts = solved_contacts;
  std::copy_n(delta_free_.data(), p.rows_, last_delta_free_.data());
  out.status = res.status;
  out.sweeps = res.sweeps;
  out.error = res.error;
  out.ill_posed_contacts = res.ill_posed_contacts;
  // kEmpty: nothing solved; kNonFinite: NSGS zeroed f; both leave delta unusable
  delta_valid_ = !linear && res.status != shared::NsgsStatus::kEmpty &&
                 res.status != shared::NsgsStatus::kNonFinite &&
                 res.status != shared::NsgsStatus::kIllPosed;
  if (res.status == shared::NsgsStatus::kEmpty || res.status == shared::NsgsStatus::kNonFinite ||
      res.status == shared::NsgsStatus::kIllPosed) {
    out.elapsed_ns = shared::monotonicNs() - t0;
    return out;
  }
  wrenches(out);
  out.elapsed_ns = shared::monotonicNs() - t0;
  return out;
}

void LocalModel::wrenches(LocalModelResult& out) const noexcept {
  const PreparedSnapshot& p = *prepared_;
  std::array<Eigen::Vector3d, shared::kMaxInstruments> origin;
  std::array<Eigen::Vector3d, shared::kMaxInstruments> force;
  std::array<Eigen::Vector3d, shared::kMaxInstruments> torque;
  for (int i = 0; i < p.tools_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    origin[k] = p.tool_pose_[k].pos_m +
                Eigen::Vector3d(dx_[6 * k], dx_[6 * k + 1], dx_[6 * k + 2]);
    force[k].setZero();
    torque[k].setZero();
  }
  const double* nn = p.normal_.data();
  const double* tt = p.tangent_.data();
  const double* pt = p.point_.data();
  for (int c = 0; c < p.contacts_; ++c) {
    const int tool = p.contact_tool_[static_cast<std::size_t>(c)];
    if (tool == kNoTool) continue;
    const int r0 = p.row_offset_[static_cast<std::size_t>(c)];
    const int rows = p.row_offset_[static_cast<std::size_t>(c) + 1] - r0;
    const auto k = static_cast<std::size_t>(tool);
    Eigen::Vector3d fc = f_[static_cast<std::size_t>(r0)] *
                         Eigen::Vector3d(nn[3 * c], nn[3 * c + 1], nn[3 * c + 2]);
    if (rows == 3) {
      fc += f_[static_cast<std::size_t>(r0) + 1] *
            Eigen::Vector3d(tt[6 * c], tt[6 * c + 1], tt[6 * c + 2]);
      fc += f_[static_cast<std::size_t>(r0) + 2] *
            Eigen::Vector3d(tt[6 * c + 3], tt[6 * c + 4], tt[6 * c + 5]);
    }
    force[k] += fc;
    torque[k] += (Eigen::Vector3d(pt[3 * c], pt[3 * c + 1], pt[3 * c + 2]) - origin[k]).cross(fc);
  }
  for (int i = 0; i < p.tools_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    for (int j = 0; j < 3; ++j) {
      out.force_n[k][static_cast<std::size_t>(j)] = force[k][j];
      out.torque_nm[k][static_cast<std::size_t>(j)] = torque[k][j];
    }
  }
}

// ---------------------------------------------------------------------------------------------
// OfflineLocalModel

OfflineLocalModel::OfflineLocalModel(int max_rows, int max_contacts,
                                     const LocalModelSettings& settings)
    : settings_(settings),
      preparation_(max_rows, max_contacts),
      prepared_(max_rows, max_contacts),
      model_(max_rows, max_contacts) {
  settings_.validate();
}

PrepareStatus OfflineLocalModel::adopt(const shared::SnapshotView& snap,
                                       DevicePoses poses) noexcept {
  model_.adopt(nullptr);
  const PrepareStatus s = preparation_.prepare(snap, settings_, poses, prepared_);
  model_.adopt(&prepared_);
  return s;
}

}  // namespace tactus::haptic
