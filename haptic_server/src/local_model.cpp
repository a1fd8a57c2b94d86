// The haptic local model (local_model.h): preparation of a snapshot off the real-time thread
// (copy and checks, storage, reach, converged solve, linearisation) and the real-time solve.
#include "tactus/haptic/local_model.h"

#include <Eigen/Dense>

#if defined(__x86_64__) || defined(__i386__)
#define TACTUS_LOCAL_MODEL_X86 1
#include <immintrin.h>
#endif

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <string>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/nsgs_kernels.h"

namespace tactus::haptic {
namespace {

constexpr int kNoTool = -1;
constexpr int kMaxCols = 6 * shared::kMaxInstruments;

// |(a, b)| without std::hypot's care for overflow (the tick's forces and velocities are far
// from it), which costs tens of nanoseconds a call
inline double norm2(double a, double b) noexcept { return std::sqrt(a * a + b * b); }

bool finiteAll(const double* v, std::size_t n) noexcept {
  // NaN/Inf propagate through the product with zero; eight independent sums, so that the
  // additions do not wait on each other (one sum costs an addition's latency per element)
  double acc[8] = {};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    for (std::size_t j = 0; j < 8; ++j) acc[j] += v[i + j] * 0.0;
  }
  for (; i < n; ++i) acc[0] += v[i] * 0.0;
  return ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7])) == 0.0;
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

// One Gauss-Jordan step's update of the rows other than the pivot row k: with t_i = a(i, k),
// a(i, k) = 0 and then a(i, j) -= t_i rk[j] for every j. Four rows at a time, so that each rk[j]
// is loaded once for four rows (the update is bound by the matrix's traffic through the cache).
// The row kernels are generic (the baseline build) or AVX2 with fused multiply-add, chosen once
// at load by what the CPU reports; the two round differently, so the inverses differ in the last
// bits.
//   oneRow: ri[j] -= t rk[j], j < n;  fourRows: row r (r < 4, at r0 + r ld) -= t[r] rk[j], j < n
using OneRowFn = void (*)(double* ri, double t, const double* rk, int n) noexcept;
using FourRowsFn = void (*)(double* r0, std::ptrdiff_t ld, const double* t, const double* rk,
                            int n) noexcept;

void oneRowGeneric(double* ri, double t, const double* rk, int n) noexcept {
  for (int j = 0; j < n; ++j) ri[j] -= t * rk[j];
}

void fourRowsGeneric(double* r0, std::ptrdiff_t ld, const double* t, const double* rk,
                     int n) noexcept {
  double* r1 = r0 + ld;
  double* r2 = r1 + ld;
  double* r3 = r2 + ld;
  for (int j = 0; j < n; ++j) {
    const double v = rk[j];
    r0[j] -= t[0] * v;
    r1[j] -= t[1] * v;
    r2[j] -= t[2] * v;
    r3[j] -= t[3] * v;
  }
}

#ifdef TACTUS_LOCAL_MODEL_X86
__attribute__((target("avx2,fma"))) void oneRowAvx2(double* ri, double t, const double* rk,
                                                    int n) noexcept {
  const __m256d tv = _mm256_set1_pd(t);
  int j = 0;
  for (; j + 4 <= n; j += 4) {
    _mm256_storeu_pd(ri + j, _mm256_fnmadd_pd(tv, _mm256_loadu_pd(rk + j), _mm256_loadu_pd(ri + j)));
  }
  oneRowGeneric(ri + j, t, rk + j, n - j);
}

__attribute__((target("avx2,fma"))) void fourRowsAvx2(double* r0, std::ptrdiff_t ld,
                                                      const double* t, const double* rk,
                                                      int n) noexcept {
  double* r1 = r0 + ld;
  double* r2 = r1 + ld;
  double* r3 = r2 + ld;
  const __m256d t0 = _mm256_set1_pd(t[0]), t1 = _mm256_set1_pd(t[1]);
  const __m256d t2 = _mm256_set1_pd(t[2]), t3 = _mm256_set1_pd(t[3]);
  int j = 0;
  for (; j + 4 <= n; j += 4) {
    const __m256d v = _mm256_loadu_pd(rk + j);
    _mm256_storeu_pd(r0 + j, _mm256_fnmadd_pd(t0, v, _mm256_loadu_pd(r0 + j)));
    _mm256_storeu_pd(r1 + j, _mm256_fnmadd_pd(t1, v, _mm256_loadu_pd(r1 + j)));
    _mm256_storeu_pd(r2 + j, _mm256_fnmadd_pd(t2, v, _mm256_loadu_pd(r2 + j)));
    _mm256_storeu_pd(r3 + j, _mm256_fnmadd_pd(t3, v, _mm256_loadu_pd(r3 + j)));
  }
  fourRowsGeneric(r0 + j, ld, t, rk + j, n - j);
}
#endif  // TACTUS_LOCAL_MODEL_X86

void eliminate(double* a, int n, int k, OneRowFn one_row, FourRowsFn four_rows) noexcept {
  const auto N = static_cast<std::ptrdiff_t>(n);
  const double* rk = a + k * N;
  int i = 0;
  while (i < n) {
    if (i + 4 > n || (k >= i && k < i + 4)) {   // the pivot row's block and the tail: one by one
      double* ri = a + i * N;
      const double t = ri[k];
      if (i != k && t != 0.0) {
        ri[k] = 0.0;
        one_row(ri, t, rk, n);
      }
      ++i;
      continue;
    }
    double t[4];
    for (int r = 0; r < 4; ++r) {
      double* ri = a + (i + r) * N;
      t[r] = ri[k];
      ri[k] = 0.0;
    }
    four_rows(a + i * N, N, t, rk, n);
    i += 4;
  }
}

// sum a[k] b[k] over n: eight partial sums, so that the additions do not wait on each other
double dotGeneric(const double* a, const double* b, int n) noexcept {
  double p[8] = {};
  int k = 0;
  for (; k + 8 <= n; k += 8) {
    for (int j = 0; j < 8; ++j) p[j] += a[k + j] * b[k + j];
  }
  for (; k < n; ++k) p[0] += a[k] * b[k];
  return ((p[0] + p[1]) + (p[2] + p[3])) + ((p[4] + p[5]) + (p[6] + p[7]));
}

// y[k] += a x[k] over n
void axpyGeneric(double a, const double* x, double* y, int n) noexcept {
  for (int k = 0; k < n; ++k) y[k] += a * x[k];
}

#ifdef TACTUS_LOCAL_MODEL_X86
__attribute__((target("avx2,fma"))) void axpyAvx2(double a, const double* x, double* y,
                                                  int n) noexcept {
  const __m256d av = _mm256_set1_pd(a);
  int k = 0;
  for (; k + 4 <= n; k += 4) {
    _mm256_storeu_pd(y + k, _mm256_fmadd_pd(av, _mm256_loadu_pd(x + k), _mm256_loadu_pd(y + k)));
  }
  for (; k < n; ++k) y[k] += a * x[k];
}

__attribute__((target("avx2,fma"))) double dotAvx2(const double* a, const double* b,
                                                   int n) noexcept {
  __m256d s0 = _mm256_setzero_pd(), s1 = _mm256_setzero_pd();
  int k = 0;
  for (; k + 8 <= n; k += 8) {
    s0 = _mm256_fmadd_pd(_mm256_loadu_pd(a + k), _mm256_loadu_pd(b + k), s0);
    s1 = _mm256_fmadd_pd(_mm256_loadu_pd(a + k + 4), _mm256_loadu_pd(b + k + 4), s1);
  }
  if (k + 4 <= n) {
    s0 = _mm256_fmadd_pd(_mm256_loadu_pd(a + k), _mm256_loadu_pd(b + k), s0);
    k += 4;
  }
  alignas(32) double lanes[4];
  _mm256_store_pd(lanes, _mm256_add_pd(s0, s1));
  double sum = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]);
  for (; k < n; ++k) sum += a[k] * b[k];
  return sum;
}
#endif  // TACTUS_LOCAL_MODEL_X86

using DotFn = double (*)(const double* a, const double* b, int n) noexcept;
using AxpyFn = void (*)(double a, const double* x, double* y, int n) noexcept;
struct Kernels {
  OneRowFn one_row = &oneRowGeneric;
  FourRowsFn four_rows = &fourRowsGeneric;
  DotFn dot = &dotGeneric;
  AxpyFn axpy = &axpyGeneric;
};

// AVX2 with FMA where the CPU has both, unless TACTUS_NSGS_KERNEL=generic asks for the generic
// kernels (as for NSGS, shared/nsgs_kernels.h).
Kernels chooseKernels() noexcept {
  Kernels k;
#ifdef TACTUS_LOCAL_MODEL_X86
  const shared::NsgsKernel nsgs = shared::chooseNsgsKernel(std::getenv("TACTUS_NSGS_KERNEL"));
  if (nsgs != shared::NsgsKernel::kGeneric && __builtin_cpu_supports("fma") != 0) {
    k.one_row = &oneRowAvx2;
    k.four_rows = &fourRowsAvx2;
    k.dot = &dotAvx2;
    k.axpy = &axpyAvx2;
  }
#endif
  return k;
}
// chosen while the program loads, before any preparation or tick
const Kernels g_kernels = chooseKernels();

// In-place inverse of the n x n row-major matrix a (Gauss-Jordan with row pivoting; swap: n
// ints). False when a pivot is zero or not finite.
bool invertInPlace(double* a, int n, int* swap) noexcept {
  const auto N = static_cast<std::ptrdiff_t>(n);
  for (int k = 0; k < n; ++k) {
    int piv = k;
    double best = std::abs(a[k * N + k]);
    for (int i = k + 1; i < n; ++i) {
      const double v = std::abs(a[i * N + k]);
      if (v > best) {
        best = v;
        piv = i;
      }
    }
    if (!(best > 0.0) || !std::isfinite(best)) return false;
    swap[k] = piv;
    if (piv != k) std::swap_ranges(a + k * N, a + (k + 1) * N, a + piv * N);
    double* rk = a + k * N;
    const double d = 1.0 / rk[k];
    rk[k] = 1.0;
    for (int j = 0; j < n; ++j) rk[j] *= d;
    eliminate(a, n, k, g_kernels.one_row, g_kernels.four_rows);
  }
  for (int k = n - 1; k >= 0; --k) {
    if (swap[k] == k) continue;
    for (int i = 0; i < n; ++i) std::swap(a[i * N + k], a[i * N + swap[k]]);
  }
  return true;
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
    case LocalModelUsed::kCorrected: return "corrected";
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
  checkRange("prepare_coarse_factor", prepare_coarse_factor, 0.0, false,
             L::kMaxPrepareCoarseFactor);
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
  active_row_.assign(r, 0);
  active_pos_.assign(r, -1);
  Ainv_.assign(r * r, 0.0);
  WA_.assign(r * r, 0.0);
  wa_norm_.assign(r, 0.0);
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
      A_(static_cast<std::size_t>(std::max(max_rows, 0)) * static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      B_(static_cast<std::size_t>(std::max(max_rows, 0)) * kMaxCols, 0.0),
      X_(static_cast<std::size_t>(std::max(max_rows, 0)) * kMaxCols, 0.0),
      Xt_(static_cast<std::size_t>(std::max(max_rows, 0)) * kMaxCols, 0.0),
      f_coarse_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      polish_res_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      polish_y_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0),
      swap_(static_cast<std::size_t>(std::max(max_rows, 0)), 0),
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
  out.prepared_polished_ = false;
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
  // W row by row, each row checked while it is in the cache (one pass over W, not two)
  bool finite = true;
  for (std::size_t r = 0; r < mm && finite; ++r) {
    double* dst = out.W_.data() + r * mm;
    std::copy_n(W + r * ld, mm, dst);
    finite = finiteAll(dst, mm);
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
  finite = finite && finiteAll(out.delta_free_.data(), mm) &&
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
  // the linearisation is wanted: the solve stops at the coarse tolerance, and the
  // linearisation's Newton step on its active set takes the solution to the tight one
  const bool wanted = settings.kind == LocalModelKind::kLinearized ||
                      (settings.kind == LocalModelKind::kAutomatic &&
                       m >= settings.automatic_min_rows);
  const double tight = settings.tolerance * settings.prepare_tolerance_factor;
  const double coarse = settings.tolerance * settings.prepare_coarse_factor;
  const bool polish = wanted && coarse > tight;
  shared::NsgsSettings ns;
  ns.tolerance = polish ? coarse : tight;
  ns.max_sweeps = settings.prepare_max_sweeps;
  ns.coupling = out.coupling_;
  ns.anderson_depth = shared::kMaxAndersonDepth;
  double* f = out.f0_.data() + r_begin;
  // NSGS to ns.tolerance from f (Anderson, then plain where Anderson stalls)
  auto solve = [&]() {
    shared::NsgsResult r = shared::solveNsgs(problem, ns, workspace_, f);
    int n = r.sweeps;
    if (r.status == shared::NsgsStatus::kMaxSweeps) {   // Anderson may stall: plain NSGS
      ns.anderson_depth = 0;
      r = shared::solveNsgs(problem, ns, workspace_, f);
      n += r.sweeps;
      ns.anderson_depth = shared::kMaxAndersonDepth;
    }
    r.sweeps = n;
    return r;
  };
  shared::NsgsResult res = solve();
  int sweeps = res.sweeps;
  auto failed = [&](const shared::NsgsResult& r) {
    if (r.status != shared::NsgsStatus::kIllPosed && r.status != shared::NsgsStatus::kEmpty &&
        r.status != shared::NsgsStatus::kNonFinite) {
      return false;
    }
    out.status_ = r.status == shared::NsgsStatus::kIllPosed ? PrepareStatus::kIllPosed
                  : r.status == shared::NsgsStatus::kEmpty  ? PrepareStatus::kInconsistent
                                                             : PrepareStatus::kNonFinite;
    out.prepare_ns_ = shared::monotonicNs() - t0;
    reset();
    return true;
  };
  if (failed(res)) return out.status_;
  const int reached_rows = r_end - r_begin;
  auto keepDelta = [&]() {
    std::fill(out.delta0_.begin(), out.delta0_.begin() + m, 0.0);
    std::copy_n(workspace_.delta.data(), reached_rows, out.delta0_.data() + r_begin);
  };
  keepDelta();
  std::int64_t t3 = shared::monotonicNs();
  std::int64_t linearize_ns = 0;
  if (polish && res.status == shared::NsgsStatus::kConverged) {
    // the linearisation at the coarse solution, with the Newton step to the tight tolerance;
    // where that does not reach it, NSGS goes on from the coarse solution and the solution
    // it converges to is linearised
    std::copy_n(f, reached_rows, f_coarse_.data());
    linearize(settings, out, &problem, tight);
    const std::int64_t t = shared::monotonicNs();
    linearize_ns += t - t3;
    t3 = t;
    if (!out.prepared_polished_) {
      std::copy_n(f_coarse_.data(), reached_rows, f);
      ns.tolerance = tight;
      res = solve();
      sweeps += res.sweeps;
      if (failed(res)) return out.status_;
      keepDelta();
      out.linearized_ = false;
    }
  }
  out.prepared_sweeps_ = sweeps;
  out.prepared_converged_ = out.prepared_polished_ ||
                            (res.status == shared::NsgsStatus::kConverged && ns.tolerance == tight);
  const std::int64_t t3b = shared::monotonicNs();
  out.solve_ns_ = t3b - t2 - linearize_ns;
  // carried into the next snapshot only from a converged solve (as the haptic warm start)
  have_last_ = out.prepared_converged_;
  if (have_last_) std::copy_n(out.f0_.data(), m, last_f_.data());
  out.status_ = PrepareStatus::kReady;
  if (wanted && out.prepared_converged_ && !out.prepared_polished_) {
    linearize(settings, out, nullptr, tight);
  }
  if (out.linearized_) orderForReducedFallback(settings, out);
  const std::int64_t t4 = shared::monotonicNs();
  out.linearize_ns_ = t4 - t3b + linearize_ns;
  out.prepare_ns_ = t4 - t0;
  return out.status_;
}

// The active-set linearisation (local_model.h): A df = B dx over the active rows of the reached
// contacts, A inverted (kept for the tick's active-set correction), F = A^-1 B and G = W F + J.
// Allocation-free: everything lives in storage sized for the capacity.
void SnapshotPreparation::linearize(const LocalModelSettings& settings, PreparedSnapshot& out,
                                    const shared::ContactProblemView* polish,
                                    double tolerance) noexcept {
  (void)settings;
  out.linearized_ = false;
  out.prepared_polished_ = false;
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
  int* act = out.active_row_.data();
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
    for (int a = 0; a < unknowns; ++a) act[na++] = r + a;
  }
  out.active_rows_ = na;
  int* pos = out.active_pos_.data();   // position of each row among the active ones (-1: not)
  std::fill_n(pos, m, -1);
  for (int i = 0; i < na; ++i) pos[act[i]] = i;
  std::fill(out.F_.begin(), out.F_.begin() + static_cast<std::ptrdiff_t>(m) * kMaxCols, 0.0);
  std::fill(out.G_.begin(), out.G_.begin() + static_cast<std::ptrdiff_t>(m) * kMaxCols, 0.0);
  const auto NA = static_cast<std::ptrdiff_t>(na);
  double* A = A_.data();   // na x na, row-major: row eq is equation eq
  double* B = B_.data();   // na x kMaxCols, row-major
  double* X = X_.data();   // na x kMaxCols: df/dx on the active rows
  double* Xt = Xt_.data();  // cols x na: X transposed
  if (na > 0) {
    std::fill_n(A, NA * NA, 0.0);
    std::fill_n(B, NA * kMaxCols, 0.0);
    auto jrow = [&](int row, double scale, int eq) {   // B(eq, :) += -scale * J(row) dq/dx
      const int t = out.row_tool_[static_cast<std::size_t>(row)];
      if (t == kNoTool) return;
      for (int k = 0; k < 6; ++k) {
        B[eq * kMaxCols + 6 * t + k] -= scale * out.J_[static_cast<std::size_t>(6 * row + k)];
      }
    };
    auto wrow = [&](int row, double scale, int eq) {   // A(eq, :) += scale * W(row, active)
      const double* wr = W + static_cast<std::ptrdiff_t>(row) * m;
      double* ar = A + eq * NA;
      for (int j = 0; j < na; ++j) ar[j] += scale * wr[act[j]];
    };
    for (int c = c_begin; c < c_end; ++c) {
      const ContactState s = out.state_[static_cast<std::size_t>(c)];
      if (s == ContactState::kSeparated) continue;
      const int r = ro[c];
      if (s == ContactState::kSticking || s == ContactState::kNormalOnly) {
        const int unknowns = s == ContactState::kNormalOnly ? 1 : 3;
        for (int a = 0; a < unknowns; ++a) {
          const int eq = pos[r + a];
          wrow(r + a, 1.0, eq);
          jrow(r + a, 1.0, eq);
        }
        continue;
      }
      // sliding: delta_n = 0; df_t - mu u df_n + P d delta_t = 0, P = mu f_n / s (I - u u^T)
      const double mu = out.mu_[static_cast<std::size_t>(c)];
      const int en = pos[r];
      wrow(r, 1.0, en);
      jrow(r, 1.0, en);
      const double ft = std::hypot(f0[r + 1], f0[r + 2]);
      const double u[2] = {f0[r + 1] / ft, f0[r + 2] / ft};
      const double st = std::hypot(d0[r + 1], d0[r + 2]);
      const double a = mu * f0[r] / st;
      for (int t = 0; t < 2; ++t) {
        const int eq = pos[r + 1 + t];
        A[eq * NA + eq] += 1.0;
        A[eq * NA + en] -= mu * u[t];
        for (int t2 = 0; t2 < 2; ++t2) {
          const double P = a * ((t == t2 ? 1.0 : 0.0) - u[t] * u[t2]);
          if (P == 0.0) continue;
          wrow(r + 1 + t2, P, eq);
          jrow(r + 1 + t2, P, eq);
        }
      }
    }
    // A^-1, column-major (column p contiguous): the row-major inverse of A^T
    double* Ainv = out.Ainv_.data();
    for (int i = 0; i < na; ++i) {
      for (int j = 0; j < na; ++j) Ainv[j * NA + i] = A[i * NA + j];
    }
    if (!invertInPlace(Ainv, na, swap_.data())) return;
    if (polish != nullptr && !polishSolution(*polish, tolerance, out)) return;
    // X = A^-1 B, checked against A X = B: column by column of B (Xt row k = column k of X, so
    // that every product runs over contiguous storage)
    for (int k = 0; k < cols; ++k) {
      double* xk = Xt + k * NA;
      std::fill_n(xk, na, 0.0);
      for (int p = 0; p < na; ++p) {
        const double b = B[p * kMaxCols + k];
        if (b != 0.0) g_kernels.axpy(b, Ainv + p * NA, xk, na);
      }
    }
    std::fill_n(X, NA * kMaxCols, 0.0);
    for (int k = 0; k < cols; ++k) {
      for (int i = 0; i < na; ++i) X[i * kMaxCols + k] = Xt[k * NA + i];
    }
    double r2 = 0.0, b2 = 0.0;
    for (int i = 0; i < na; ++i) {
      const double* ai = A + i * NA;
      for (int k = 0; k < cols; ++k) {
        const double b = B[i * kMaxCols + k];
        const double v = g_kernels.dot(ai, Xt + k * NA, na) - b;
        r2 += v * v;
        b2 += b * b;
      }
    }
    if (!finiteAll(X, static_cast<std::size_t>(NA * kMaxCols)) ||
        !(std::sqrt(r2) <= 1e-6 * (std::sqrt(b2) + 1e-300))) {
      return;
    }
    for (int i = 0; i < na; ++i) {
      std::copy_n(X + i * kMaxCols, cols, out.F_.data() + static_cast<std::ptrdiff_t>(act[i]) * kMaxCols);
    }
  }
  if (na == 0 && polish != nullptr && !polishSolution(*polish, tolerance, out)) return;
  // W on the reached rows and the active columns; G = W F + J over the reached rows
  const int r_begin = ro[c_begin];
  const int r_end = ro[c_end];
  const int reached = r_end - r_begin;
  double* WA = out.WA_.data();
  if (out.coupling_ == shared::NsgsCoupling::kSymmetricRowUpdate) {
    // W = W^T: W(r, act[p]) = W(act[p], r), read from the active rows (contiguous, a quarter of
    // W on a grasp) rather than gathered from every row; transposed in blocks of reached rows
    constexpr int kBlock = 64;
    for (int i0 = 0; i0 < reached; i0 += kBlock) {
      const int i1 = std::min(i0 + kBlock, reached);
      for (int p = 0; p < na; ++p) {
        const double* wr = W + static_cast<std::ptrdiff_t>(act[p]) * m + r_begin;
        for (int i = i0; i < i1; ++i) WA[static_cast<std::ptrdiff_t>(i) * NA + p] = wr[i];
      }
    }
  } else {
    for (int i = 0; i < reached; ++i) {
      const double* wr = W + static_cast<std::ptrdiff_t>(r_begin + i) * m;
      double* dst = WA + static_cast<std::ptrdiff_t>(i) * NA;
      for (int p = 0; p < na; ++p) dst[p] = wr[act[p]];
    }
  }
  for (int r = r_begin; r < r_end; ++r) {
    const double* wa = WA + static_cast<std::ptrdiff_t>(r - r_begin) * NA;
    out.wa_norm_[static_cast<std::size_t>(r - r_begin)] = std::sqrt(dotGeneric(wa, wa, na));
    double* g = out.G_.data() + static_cast<std::ptrdiff_t>(r) * kMaxCols;
    for (int k = 0; k < cols; ++k) g[k] += g_kernels.dot(wa, Xt + k * NA, na);
    const int t = out.row_tool_[static_cast<std::size_t>(r)];
    if (t == kNoTool) continue;
    for (int k = 0; k < 6; ++k) g[6 * t + k] += out.J_[static_cast<std::size_t>(6 * r + k)];
  }
  out.linearized_ = finiteAll(out.G_.data(), static_cast<std::size_t>(m) * kMaxCols);
}

// The Newton step of the preparation (LocalModelSettings::prepare_coarse_factor): the active
// set's equations (linearize(): delta = 0 on sticking and normal-only rows and sliding contacts'
// normal rows; f_t + mu f_n delta_t / |delta_t| = 0 on sliding contacts' tangential rows) solved
// through the inverse of their Jacobian at the coarse solution, f0 -= A^-1 residual, then
// delta0 = W f0 + q afresh and the natural-map error over the reached contacts. Up to
// kPolishSteps steps (exact in one for sticking and separated contacts, where the equations are
// linear; sliding ones converge at the chord's rate); true when the error is within
// `tolerance`, then f0 and delta0 hold the polished solution.
bool SnapshotPreparation::polishSolution(const shared::ContactProblemView& problem,
                                         double tolerance, PreparedSnapshot& out) noexcept {
  constexpr int kPolishSteps = 3;
  const int c_begin = out.reach_only_ ? out.reach_begin_ : 0;
  const int c_end = out.reach_only_ ? out.reach_end_ : out.contacts_;
  const int* ro = out.row_offset_.data();
  const int r_begin = ro[c_begin];
  const int reached = ro[c_end] - r_begin;
  const int na = out.active_rows_;
  const auto NA = static_cast<std::ptrdiff_t>(na);
  const int* act = out.active_row_.data();
  const int* pos = out.active_pos_.data();
  const double* Ainv = out.Ainv_.data();
  double* f0 = out.f0_.data();
  double* d0 = out.delta0_.data();
  double* res = polish_res_.data();
  double* y = polish_y_.data();
  double* delta = workspace_.delta.data();
  // (the coarse solution's own error is above the tolerance unless nothing is active: the first
  // look is at the first step's)
  for (int step = na > 0 ? 1 : 0; step <= kPolishSteps; ++step) {
    if (step > 0) {
      for (int c = c_begin; c < c_end; ++c) {
        const ContactState st = out.state_[static_cast<std::size_t>(c)];
        const int r = ro[c];
        switch (st) {
          case ContactState::kSeparated:
            break;
          case ContactState::kNormalOnly:
            res[pos[r]] = d0[r];
            break;
          case ContactState::kSticking:
            for (int a = 0; a < 3; ++a) res[pos[r + a]] = d0[r + a];
            break;
          case ContactState::kSliding: {
            const double slip = norm2(d0[r + 1], d0[r + 2]);
            if (!(slip > 0.0)) return false;
            const double mu = out.mu_[static_cast<std::size_t>(c)];
            res[pos[r]] = d0[r];
            for (int t = 1; t < 3; ++t) res[pos[r + t]] = f0[r + t] + mu * f0[r] * d0[r + t] / slip;
            break;
          }
        }
      }
      std::fill_n(y, na, 0.0);
      for (int p = 0; p < na; ++p) g_kernels.axpy(res[p], Ainv + p * NA, y, na);
      for (int i = 0; i < na; ++i) f0[act[i]] -= y[i];
    }
    const double err = shared::naturalMapError(problem, f0 + r_begin, delta);
    if (!std::isfinite(err)) return false;
    std::copy_n(delta, reached, d0 + r_begin);
    if (err <= tolerance) {
      out.prepared_polished_ = true;
      return true;
    }
  }
  return false;
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
  // W in that order, contact by contact within a row (a contact's rows are contiguous in both)
  const double* W = out.W_.data();
  const int* orow = out.ordered_row_.data();
  const int* oro = out.ordered_row_offset_.data();
  for (int i = 0; i < rows; ++i) {
    const double* src = W + static_cast<std::ptrdiff_t>(orow[i]) * m;
    double* dst = out.Wo_.data() + static_cast<std::ptrdiff_t>(i) * rows;
    for (int j = 0; j < n; ++j) {
      const double* sj = src + orow[oro[j]];
      double* dj = dst + oro[j];
      dj[0] = sj[0];
      if (oro[j + 1] - oro[j] == 3) {
        dj[1] = sj[1];
        dj[2] = sj[2];
      }
    }
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
      scratch_(static_cast<std::size_t>(std::max(max_rows, 0)), 0.0) {
  const auto r = static_cast<std::size_t>(std::max(max_rows, 0));
  const auto c = static_cast<std::size_t>(std::max(max_contacts, 0));
  constexpr auto e = static_cast<std::size_t>(3 * kMaxCorrectedContacts);
  mode_.assign(c, 0);
  tried_.assign(c, 0);
  slide_u_.assign(2 * c, 0.0);
  new_row_.assign(e, 0);
  new_index_.assign(r, -1);
  eq_index_.assign(e, 0);
  eq_kind_.assign(e, 0);
  eq_row_.assign(e, 0);
  eq_contact_.assign(e, 0);
  Z_.assign((r + e) * e, 0.0);
  cnew_.assign(r * e, 0.0);
  znew_.assign(e, 0);
  RZ_.assign(e * e, 0.0);
  rhs_.assign(e, 0.0);
  dy_.assign(r + e, 0.0);
  fc_.assign(r, 0.0);
  dc_.assign(r, 0.0);
}

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
  slack_ = slack;
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
        if (norm2(fc[1], fc[2]) > mu * fc[0] + slack) return FallbackReason::kLeavesCone;
        break;
      case ContactState::kSliding: {
        // still sliding, against the force: the force's direction within 18 degrees of -delta_t
        const double ft = norm2(fc[1], fc[2]);
        const double st = norm2(dc[1], dc[2]);
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
      const double ft = norm2(fc[1], fc[2]);
      const double scale = mu * fc[0] / ft;
      fc[1] *= scale;
      fc[2] *= scale;
    } else if (s == ContactState::kSticking) {
      const double ft = norm2(fc[1], fc[2]);
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

// ---------------------------------------------------------------------------------------------
// The active-set correction (local_model.h, top)

namespace {

// A contact's state in the correction: the linearisation's, or switched.
enum CorrectionMode : std::uint8_t {
  kModeOpen,         // separated: f = 0
  kModeStick,        // delta = 0
  kModeNormal,       // normal-only: delta_n = 0
  kModeSlide,        // sliding as linearised (the prepared equations)
  kModeSlideFixed,   // sliding in the fixed direction slide_u_: delta_n = 0, f_t = mu f_n u
};
// The equation that replaces a prepared one (or the "f = 0" of a new unknown).
enum EquationKind : int { kEqStick, kEqZero, kEqSlide };
constexpr int kMaxCorrectionEquations = 3 * kMaxCorrectedContacts;

CorrectionMode modeOf(ContactState s) noexcept {
  switch (s) {
    case ContactState::kSeparated: return kModeOpen;
    case ContactState::kSticking: return kModeStick;
    case ContactState::kSliding: return kModeSlide;
    case ContactState::kNormalOnly: return kModeNormal;
  }
  return kModeOpen;
}


// Solves the s x s row-major system a x = b in place (x in b), partial pivoting. False when a
// pivot is below 1e-12 of the largest entry.
bool solveSmall(double* a, double* b, int s) noexcept {
  double scale = 0.0;
  for (int i = 0; i < s * s; ++i) scale = std::max(scale, std::abs(a[i]));
  if (!(scale > 0.0) || !std::isfinite(scale)) return false;
  for (int k = 0; k < s; ++k) {
    int piv = k;
    for (int i = k + 1; i < s; ++i) {
      if (std::abs(a[i * s + k]) > std::abs(a[piv * s + k])) piv = i;
    }
    if (!(std::abs(a[piv * s + k]) > 1e-12 * scale)) return false;
    if (piv != k) {
      std::swap_ranges(a + k * s, a + (k + 1) * s, a + piv * s);
      std::swap(b[k], b[piv]);
    }
    for (int i = k + 1; i < s; ++i) {
      const double t = a[i * s + k] / a[k * s + k];
      if (t == 0.0) continue;
      for (int j = k; j < s; ++j) a[i * s + j] -= t * a[k * s + j];
      b[i] -= t * b[k];
    }
  }
  for (int k = s - 1; k >= 0; --k) {
    double v = b[k];
    for (int j = k + 1; j < s; ++j) v -= a[k * s + j] * b[j];
    b[k] = v / a[k * s + k];
  }
  for (int k = 0; k < s; ++k) {
    if (!std::isfinite(b[k])) return false;
  }
  return true;
}

}  // namespace

// One round: fc_ and dc_ = the prediction corrected for the contacts whose mode_ differs from
// the linearisation's (dc_ on the rows correctionCheck() reads). Returns the contacts changed,
// or -1 when the corrected system is singular.
int LocalModel::correctionSolve() noexcept {
  const PreparedSnapshot& p = *prepared_;
  const int m = p.rows_;
  const int na = p.active_rows_;
  const int c_begin = p.reach_only_ ? p.reach_begin_ : 0;
  const int c_end = p.reach_only_ ? p.reach_end_ : p.contacts_;
  const int* ro = p.row_offset_.data();
  const int r_begin = ro[c_begin];
  const int r_end = ro[c_end];
  const int* pos = p.active_pos_.data();
  const int* act = p.active_row_.data();
  const double* W = p.W_.data();
  const double* Ainv = p.Ainv_.data();
  const double* WA = p.WA_.data();
  const double* delta = workspace_.delta.data();
  for (int r = r_begin; r < r_end; ++r) {
    fc_[static_cast<std::size_t>(r)] = f_[static_cast<std::size_t>(r)];
    dc_[static_cast<std::size_t>(r)] = delta[r - r_begin];
  }
  // the new unknowns (rows of contacts that close) and the replaced equations
  int nn = 0, s = 0, changed = 0;
  auto equation = [&](int index, int kind, int row, int c) {
    const auto i = static_cast<std::size_t>(s++);
    eq_index_[i] = index;
    eq_kind_[i] = kind;
    eq_row_[i] = row;
    eq_contact_[i] = c;
  };
  for (int c = c_begin; c < c_end; ++c) {
    const CorrectionMode base = modeOf(p.state_[static_cast<std::size_t>(c)]);
    const auto mode = static_cast<CorrectionMode>(mode_[static_cast<std::size_t>(c)]);
    if (mode == base && mode != kModeSlideFixed) continue;
    ++changed;
    const int r = ro[c];
    if (base == kModeOpen) {
      const int rows = mode == kModeNormal ? 1 : 3;
      for (int a = 0; a < rows; ++a) {
        new_index_[static_cast<std::size_t>(r + a)] = na + nn;
        new_row_[static_cast<std::size_t>(nn++)] = r + a;
        equation(na + nn - 1, a == 0 || mode == kModeStick ? kEqStick : kEqSlide, r + a, c);
      }
    } else if (mode == kModeOpen) {
      for (int row = r; row < ro[c + 1]; ++row) {
        if (pos[row] >= 0) equation(pos[row], kEqZero, row, c);
      }
    } else {   // the tangential equations: sticking <-> sliding
      for (int t = 1; t <= 2; ++t) {
        equation(pos[r + t], mode == kModeStick ? kEqStick : kEqSlide, r + t, c);
      }
    }
  }
  if (changed == 0) return 0;
  const int D = na + nn;
  const auto DD = static_cast<std::ptrdiff_t>(D);
  const auto NA = static_cast<std::ptrdiff_t>(na);
  auto index = [&](int row) { return pos[row] >= 0 ? pos[row] : new_index_[static_cast<std::size_t>(row)]; };
  // Z: the prepared system's inverse on the replaced equations' columns (a new unknown j:
  // [-A^-1 C_j; e_j], C_j its coefficients in the prepared equations). The new unknowns' products
  // with A^-1 share one pass over it. With a symmetric W (the simulation's), C_j's entries
  // W(active, j) are W(j, active), row j of the prepared WA, instead of a strided column of W.
  const bool symmetric = p.coupling_ == shared::NsgsCoupling::kSymmetricRowUpdate;
  auto wAt = [&](int row, int col) {   // W(row, col), read along a row when W is symmetric
    return symmetric ? W[static_cast<std::ptrdiff_t>(col) * m + row]
                     : W[static_cast<std::ptrdiff_t>(row) * m + col];
  };
  int nz = 0;
  for (int i = 0; i < s; ++i) {
    double* z = Z_.data() + i * DD;
    const int q = eq_index_[static_cast<std::size_t>(i)];
    std::fill_n(z, DD, 0.0);
    if (q < na) {
      std::copy_n(Ainv + q * NA, na, z);
      continue;
    }
    const int j = new_row_[static_cast<std::size_t>(q - na)];
    double* cj = cnew_.data() + nz * NA;
    znew_[static_cast<std::size_t>(nz++)] = i;
    if (symmetric) {
      std::copy_n(WA + static_cast<std::ptrdiff_t>(j - r_begin) * NA, na, cj);
    } else {
      for (int e = 0; e < na; ++e) cj[e] = W[static_cast<std::ptrdiff_t>(act[e]) * m + j];
    }
    for (int c = c_begin; c < c_end; ++c) {   // sliding equations: P (W_t df)
      if (p.state_[static_cast<std::size_t>(c)] != ContactState::kSliding) continue;
      const int r = ro[c];
      const double* f0 = p.f0_.data() + r;
      const double* d0 = p.delta0_.data() + r;
      const double ft = norm2(f0[1], f0[2]);
      const double u[2] = {f0[1] / ft, f0[2] / ft};
      const double a = p.mu_[static_cast<std::size_t>(c)] * f0[0] / norm2(d0[1], d0[2]);
      const double w1 = wAt(r + 1, j);
      const double w2 = wAt(r + 2, j);
      cj[pos[r + 1]] = a * ((1.0 - u[0] * u[0]) * w1 - u[0] * u[1] * w2);
      cj[pos[r + 2]] = a * (-u[1] * u[0] * w1 + (1.0 - u[1] * u[1]) * w2);
    }
    z[q] = 1.0;
  }
  for (int e = 0; e < na && nz > 0; ++e) {
    const double* ae = Ainv + e * NA;
    for (int k = 0; k < nz; ++k) {
      const double c = cnew_[static_cast<std::size_t>(k * NA + e)];
      if (c == 0.0) continue;
      g_kernels.axpy(-c, ae, Z_.data() + znew_[static_cast<std::size_t>(k)] * DD, na);
    }
  }
  // R Z, and the right-hand side: minus the new equations' residuals at the prediction
  double* RZ = RZ_.data();
  for (int i = 0; i < s; ++i) {
    const int row = eq_row_[static_cast<std::size_t>(i)];
    const int kind = eq_kind_[static_cast<std::size_t>(i)];
    if (kind == kEqStick) {
      const double* wa = WA + static_cast<std::ptrdiff_t>(row - r_begin) * NA;
      const double* wr = W + static_cast<std::ptrdiff_t>(row) * m;
      rhs_[static_cast<std::size_t>(i)] = -dc_[static_cast<std::size_t>(row)];
      for (int j = 0; j < s; ++j) {
        const double* z = Z_.data() + j * DD;
        double v = g_kernels.dot(wa, z, na);
        for (int k = 0; k < nn; ++k) v += wr[new_row_[static_cast<std::size_t>(k)]] * z[na + k];
        RZ[i * s + j] = v;
      }
    } else if (kind == kEqZero) {
      rhs_[static_cast<std::size_t>(i)] = -fc_[static_cast<std::size_t>(row)];
      for (int j = 0; j < s; ++j) RZ[i * s + j] = Z_[static_cast<std::size_t>(j * DD + index(row))];
    } else {
      const int c = eq_contact_[static_cast<std::size_t>(i)];
      const int rn = ro[c];
      const double mu_u = p.mu_[static_cast<std::size_t>(c)] *
                          slide_u_[static_cast<std::size_t>(2 * c + (row - rn - 1))];
      rhs_[static_cast<std::size_t>(i)] =
          mu_u * fc_[static_cast<std::size_t>(rn)] - fc_[static_cast<std::size_t>(row)];
      const int it = index(row), in = index(rn);
      for (int j = 0; j < s; ++j) {
        const double* z = Z_.data() + j * DD;
        RZ[i * s + j] = z[it] - mu_u * z[in];
      }
    }
  }
  const bool solved = solveSmall(RZ, rhs_.data(), s);
  if (solved) {
    // dy = Z w: the forces on the unknowns' rows, and delta on the rows the check reads
    std::fill_n(dy_.data(), DD, 0.0);
    for (int i = 0; i < s; ++i) {
      const double w = rhs_[static_cast<std::size_t>(i)];
      const double* z = Z_.data() + i * DD;
      for (int k = 0; k < D; ++k) dy_[static_cast<std::size_t>(k)] += w * z[k];
    }
    for (int e = 0; e < na; ++e) fc_[static_cast<std::size_t>(act[e])] += dy_[static_cast<std::size_t>(e)];
    for (int k = 0; k < nn; ++k) {
      fc_[static_cast<std::size_t>(new_row_[static_cast<std::size_t>(k)])] += dy_[static_cast<std::size_t>(na + k)];
    }
    // the new unknowns' part of W dy on a row
    auto newPart = [&](int row) {
      const double* wr = W + static_cast<std::ptrdiff_t>(row) * m;
      double v = 0.0;
      for (int k = 0; k < nn; ++k) v += wr[new_row_[static_cast<std::size_t>(k)]] * dy_[static_cast<std::size_t>(na + k)];
      return v;
    };
    auto moveDelta = [&](int row) {
      const double* wa = WA + static_cast<std::ptrdiff_t>(row - r_begin) * NA;
      dc_[static_cast<std::size_t>(row)] += g_kernels.dot(wa, dy_.data(), na) + newPart(row);
    };
    // |W(row, active) dy| <= |W(row, active)| |dy|: a separated contact whose gap stays above
    // -slack by that bound passes the check whatever the product (its delta is read nowhere
    // else), so the product is skipped (1 % margin for rounding)
    const double dy_norm = std::sqrt(g_kernels.dot(dy_.data(), dy_.data(), na));
    const double* wa_norm = p.wa_norm_.data();
    const double slack = slack_;
    for (int c = c_begin; c < c_end; ++c) {
      const auto mode = static_cast<CorrectionMode>(mode_[static_cast<std::size_t>(c)]);
      const int r = ro[c];
      if (mode == kModeOpen) {
        const double extra = newPart(r);
        const double bound = wa_norm[r - r_begin] * dy_norm + std::abs(extra);
        if (dc_[static_cast<std::size_t>(r)] - 1.01 * bound >= -slack) continue;
        const double* wa = WA + static_cast<std::ptrdiff_t>(r - r_begin) * NA;
        dc_[static_cast<std::size_t>(r)] += g_kernels.dot(wa, dy_.data(), na) + extra;
      }
      if (mode == kModeSlide || mode == kModeSlideFixed) {
        moveDelta(r + 1);
        moveDelta(r + 2);
      }
    }
  }
  for (int k = 0; k < nn; ++k) new_index_[static_cast<std::size_t>(new_row_[static_cast<std::size_t>(k)])] = -1;
  return solved ? changed : -1;
}

// Checks fc_ and dc_ as evaluateLinearization() checks the prediction, and switches the state of
// every contact that fails: a contact that closes sticks (slides against its slip if sticking
// was tried), one whose normal force turns negative separates (slides if that was tried), one
// that leaves its cone slides along its tangential force, a sliding one whose slip turns sticks
// (slides against the slip if that was tried). Returns how many failed, or -1 when a contact would return to a state tried before
// in this tick (cycling) or more than kMaxCorrectedContacts would differ from the linearisation.
int LocalModel::correctionCheck() noexcept {
  const PreparedSnapshot& p = *prepared_;
  const int c_begin = p.reach_only_ ? p.reach_begin_ : 0;
  const int c_end = p.reach_only_ ? p.reach_end_ : p.contacts_;
  const int* ro = p.row_offset_.data();
  const double slack = slack_;
  int failed = 0, changed = 0;
  for (int c = c_begin; c < c_end; ++c) {
    const auto k = static_cast<std::size_t>(c);
    const int r = ro[c];
    const double* fc = fc_.data() + r;
    const double* dc = dc_.data() + r;
    const double mu = p.mu_[k];
    const bool frictional = ro[c + 1] - r == 3 && mu > 0.0;
    const auto before = static_cast<CorrectionMode>(mode_[k]);
    CorrectionMode mode = before;
    bool aim = false;          // set slide_u_ to (u1, u2)
    double u1 = 0.0, u2 = 0.0;
    auto along = [&](double a, double b) {   // slide along (a, b); false when it is zero
      const double n = norm2(a, b);
      if (!(n > 0.0)) return false;
      mode = kModeSlideFixed;
      aim = true;
      u1 = a / n;
      u2 = b / n;
      return true;
    };
    auto tried = [&](CorrectionMode m) { return (tried_[k] & (1u << m)) != 0; };
    bool cycle = false;
    switch (before) {
      case kModeOpen:
        if (dc[0] < -slack) {
          const CorrectionMode closed = frictional ? kModeStick : kModeNormal;
          if (!tried(closed)) {
            mode = closed;
          } else if (!frictional || tried(kModeSlideFixed) || !along(-dc[1], -dc[2])) {
            cycle = true;
          }
        }
        break;
      case kModeNormal:
        if (fc[0] < -slack) {
          mode = kModeOpen;
          cycle = tried(kModeOpen);
        }
        break;
      case kModeStick: {
        const double ft = norm2(fc[1], fc[2]);
        if (fc[0] < -slack) {
          if (!tried(kModeOpen)) {
            mode = kModeOpen;
          } else if (tried(kModeSlideFixed) ||
                     (!along(-dc[1], -dc[2]) && !along(fc[1], fc[2]))) {
            cycle = true;   // (a contact that closed slides against its slip while open)
          }
        } else if (ft > mu * fc[0] + slack) {
          (void)along(fc[1], fc[2]);
        }
        break;
      }
      case kModeSlide: {
        const double ft = norm2(fc[1], fc[2]);
        const double st = norm2(dc[1], dc[2]);
        if (fc[0] < -slack) {
          mode = kModeOpen;
        } else if (st <= slack) {
          // on the cone's boundary without slip (within the tolerance): sticking and sliding
        } else if (!(ft > 0.0) || -(fc[1] * dc[1] + fc[2] * dc[2]) < 0.95 * ft * st) {
          if (!tried(kModeStick)) {
            mode = kModeStick;
          } else if (!along(-dc[1], -dc[2])) {
            cycle = true;
          }
        }
        break;
      }
      case kModeSlideFixed: {
        const double st = norm2(dc[1], dc[2]);
        const double a = -(slide_u_[2 * k] * dc[1] + slide_u_[2 * k + 1] * dc[2]);
        if (fc[0] < -slack) {
          mode = kModeOpen;
          cycle = tried(kModeOpen);
        } else if (st <= slack) {
          // on the cone's boundary without slip (within the tolerance): sticking and sliding
        } else if (a <= 0.0 && !tried(kModeStick)) {
          mode = kModeStick;
        } else if (a < 0.95 * st) {   // slipping elsewhere: slide against the slip
          (void)along(-dc[1], -dc[2]);
          ++failed;
        }
        break;
      }
    }
    if (cycle) return -1;
    if (aim) {
      slide_u_[2 * k] = u1;
      slide_u_[2 * k + 1] = u2;
    }
    if (mode != before) {
      mode_[k] = mode;
      tried_[k] = static_cast<std::uint8_t>(tried_[k] | (1u << mode));
      ++failed;
    }
    const CorrectionMode base = modeOf(p.state_[k]);
    if (mode != base || mode == kModeSlideFixed) ++changed;
  }
  return changed > kMaxCorrectedContacts ? -1 : failed;
}

// Called where the prediction failed within the range: f_ and workspace_.delta hold it
// (unprojected). True when a corrected active set passes every check; f_ then holds its forces,
// projected as a valid linearisation's are.
bool LocalModel::correctActiveSet(std::int64_t deadline_ns, LocalModelResult& out) noexcept {
  const PreparedSnapshot& p = *prepared_;
  const int c_begin = p.reach_only_ ? p.reach_begin_ : 0;
  const int c_end = p.reach_only_ ? p.reach_end_ : p.contacts_;
  const int* ro = p.row_offset_.data();
  for (int c = c_begin; c < c_end; ++c) {
    const CorrectionMode base = modeOf(p.state_[static_cast<std::size_t>(c)]);
    mode_[static_cast<std::size_t>(c)] = base;
    tried_[static_cast<std::size_t>(c)] = static_cast<std::uint8_t>(1u << base);
  }
  // round 0 checks the prediction itself (every contact that fails, not only the first)
  bool valid = false;
  for (int round = 0; round <= kMaxCorrectionRounds; ++round) {
    if (round > 0 && deadline_ns > 0 && shared::monotonicNs() >= deadline_ns) return false;
    const int changed = correctionSolve();
    if (changed < 0) return false;
    out.corrected_contacts = changed;
    out.correction_rounds = round;
    const int failed = correctionCheck();
    if (failed < 0) return false;
    if (failed == 0) {
      valid = round > 0;
      break;
    }
  }
  if (!valid) return false;
  for (int c = c_begin; c < c_end; ++c) {
    const int r = ro[c];
    const int k = ro[c + 1] - r;
    double* fc = fc_.data() + r;
    const double mu = p.mu_[static_cast<std::size_t>(c)];
    const auto mode = static_cast<CorrectionMode>(mode_[static_cast<std::size_t>(c)]);
    fc[0] = mode == kModeOpen ? 0.0 : std::max(fc[0], 0.0);
    if (k == 3) {
      const double ft = norm2(fc[1], fc[2]);
      if (mode == kModeOpen || mu == 0.0) {
        fc[1] = fc[2] = 0.0;
      } else if (mode == kModeSlideFixed) {
        fc[1] = mu * fc[0] * slide_u_[2 * static_cast<std::size_t>(c)];
        fc[2] = mu * fc[0] * slide_u_[2 * static_cast<std::size_t>(c) + 1];
      } else if (ft > 0.0 && (mode == kModeSlide || ft > mu * fc[0])) {
        fc[1] *= mu * fc[0] / ft;
        fc[2] *= mu * fc[0] / ft;
      }
    }
    std::copy_n(fc, k, f_.data() + r);
  }
  return true;
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
    // the linearisation (or its corrected form) answered exactly: no sweep, no warm start kept
    const auto exact = [&](LocalModelUsed used) {
      delta_valid_ = false;
      out.used = used;
      out.status = shared::NsgsStatus::kConverged;
      out.error = 0.0;
      std::copy_n(delta_free_.data(), p.rows_, last_delta_free_.data());
      wrenches(out);
      out.elapsed_ns = shared::monotonicNs() - t0;
    };
    out.fallback = evaluateLinearization(settings);
    if (out.fallback == FallbackReason::kNone) {
      exact(LocalModelUsed::kLinearized);
      return out;
    }
    // a few contacts changed state: the linearisation with its active set corrected
    if (settings.active_set_correction && out.fallback != FallbackReason::kOutOfRange &&
        correctActiveSet(deadline_ns, out)) {
      exact(LocalModelUsed::kCorrected);
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
