// The corotational element loop and the system matrix's pattern (see fem_body_impl.h).
//
// The loop runs over the elements four at a time (FemModel::batches) in a kernel written with
// GCC vector extensions: compiled twice, for AVX and for the x86-64 baseline (SSE2), chosen at
// load (TACTUS_FEM_KERNEL=generic|avx forces one). Both do the same IEEE operations in the same
// order without fused multiply-adds (this file is built with -ffp-contract=off), so they give
// the same bits. The polar decomposition of each element starts from the rotation it had in the
// last kept loop (FemState::rotation) and takes Newton steps on the rotation (below); an element
// the steps do not finish goes through elementStep, the reference constitutive step.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>

#include <spdlog/spdlog.h>

#include "fem_body_impl.h"

namespace tactus::sim {

void FemBody::Impl::buildPattern() {
  const int ne = mesh.tetCount();
  if (!dom_vol.empty()) {
    buildDomainPattern();  // edge-smoothed domains: their pattern holds every element's
  } else {
    std::vector<Eigen::Triplet<double, int>> trip;
    trip.reserve(static_cast<std::size_t>(ne) * kEntriesPerElement + n_free);
    for (int d = 0; d < n_free; ++d) trip.emplace_back(d, d, 0.0);
    auto forEntry = [&](int e, auto&& fn) {
      const auto& t = mesh.tets[e];
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b <= a; ++b)
          for (int i = 0; i < 3; ++i)
            for (int j = 0; j < (a == b ? i + 1 : 3); ++j) {
              const int ra = dof_base[t[a]], cb = dof_base[t[b]];
              if (ra < 0 || cb < 0) {
                fn(-1, -1);
              } else {
                const int r = ra + i, c = cb + j;
                fn(std::max(r, c), std::min(r, c));
              }
            }
    };
    for (int e = 0; e < ne; ++e)
      forEntry(e, [&](int r, int c) {
        if (r >= 0) trip.emplace_back(r, c, 0.0);
      });
    a.resize(n_free, n_free);
    a.setFromTriplets(trip.begin(), trip.end());
    a.makeCompressed();
  }
  auto offsetOf = [&](int r, int c) { return valueOffset(r, c); };
  // assembly order: elements sorted by their nodes' reduced DOFs (lowest first, fixed last)
  std::vector<int> order(ne);
  std::vector<std::array<int, 4>> sorted_dofs(ne);
  for (int e = 0; e < ne; ++e) {
    order[e] = e;
    for (int k = 0; k < 4; ++k) {
      const int d = dof_base[mesh.tets[e][k]];
      sorted_dofs[e][k] = d >= 0 ? d : std::numeric_limits<int>::max();
    }
    std::sort(sorted_dofs[e].begin(), sorted_dofs[e].end());
  }
  std::stable_sort(order.begin(), order.end(),
                   [&](int x, int y) { return sorted_dofs[x] < sorted_dofs[y]; });
  assembly_elems.resize(ne);
  block_offset.resize(static_cast<std::size_t>(ne) * kBlockOffsetsPerElement);
  for (int slot = 0; slot < ne; ++slot) {
    const int e = order[slot];
    AssemblyElement& el = assembly_elems[slot];
    // local nodes by ascending reduced DOF (fixed nodes, DOF -1, first), gradients alike: then a
    // block (a, b) with a > b lies below the diagonal as it is
    std::array<int, 4> local = {0, 1, 2, 3};
    std::stable_sort(local.begin(), local.end(), [&](int x, int y) {
      return dof_base[mesh.tets[e][x]] < dof_base[mesh.tets[e][y]];
    });
    el.index = e;
    el.vol = volume[e];
    el.has_fixed = false;
    for (int k = 0; k < 4; ++k) {
      el.node[k] = mesh.tets[e][local[k]];
      el.g.col(k) = grad[e].col(local[k]);
    }
    int* off = block_offset.data() + static_cast<std::size_t>(slot) * kBlockOffsetsPerElement;
    for (int a = 0, bk = 0; a < 4; ++a)
      for (int b = 0; b <= a; ++b, ++bk) {
        const int p = dof_base[el.node[a]], q = dof_base[el.node[b]];
        for (int j = 0; j < 3; ++j) {
          // column q + j: rows p..p+2 (diagonal block: p+j..p+2) are consecutive in it
          off[3 * bk + j] = p < 0 || q < 0 ? -1 : offsetOf(a == b ? p + j : p, q + j);
        }
        el.has_fixed = el.has_fixed || p < 0 || q < 0;
      }
  }
  diag_offset.resize(n_free);
  for (int d = 0; d < n_free; ++d) diag_offset[d] = offsetOf(d, d);
  if (!dom_vol.empty()) buildDomainOffsets();
  a_rest = a;
  // the batches of four (the last one's missing lanes repeat its first element)
  const int nb = (ne + 3) / 4;
  batches.assign(static_cast<std::size_t>(nb), ElementBatch{});
  for (int b = 0; b < nb; ++b) {
    ElementBatch& bt = batches[static_cast<std::size_t>(b)];
    for (int lane = 0; lane < 4; ++lane) {
      const int slot = 4 * b + lane < ne ? 4 * b + lane : 4 * b;
      const AssemblyElement& el = assembly_elems[static_cast<std::size_t>(slot)];
      for (int k = 0; k < 4; ++k) {
        bt.x[k][lane] = 3 * el.node[k];
        for (int c = 0; c < 3; ++c) bt.g[c][k][lane] = el.g(c, k);
      }
      bt.vol[lane] = el.vol;
    }
  }
  rotation.assign(static_cast<std::size_t>(nb), RotationBatch{});
  for (RotationBatch& rb : rotation)
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        for (int lane = 0; lane < 4; ++lane) rb.r[i][j][lane] = i == j ? 1.0 : 0.0;
}


namespace {

// The four-lane type is passed only between always-inline functions: no call crosses the
// kernels' target boundary, so the ABI note GCC gives for it does not apply.
#pragma GCC diagnostic ignored "-Wpsabi"

// Four lanes of doubles (one element per lane) and their comparison masks.
typedef double V4 __attribute__((vector_size(32)));
typedef long long M4 __attribute__((vector_size(32)));

[[gnu::always_inline]] inline V4 load4(const double* p) {
  V4 r;
  std::memcpy(&r, p, sizeof r);
  return r;
}
[[gnu::always_inline]] inline void store4(double* p, const V4& v) { std::memcpy(p, &v, sizeof v); }
[[gnu::always_inline]] inline V4 splat(double x) { return V4{x, x, x, x}; }
[[gnu::always_inline]] inline V4 gather4(const double* base, const int* idx, int c) {
  return V4{base[idx[0] + c], base[idx[1] + c], base[idx[2] + c], base[idx[3] + c]};
}
typedef double V2 __attribute__((vector_size(16)));
// out[0..1] += in[0..1] (one two-lane add), out[0..2] += in[0..2]
[[gnu::always_inline]] inline void add2(double* out, const double* in) {
  V2 a, b;
  std::memcpy(&a, out, sizeof a);
  std::memcpy(&b, in, sizeof b);
  a += b;
  std::memcpy(out, &a, sizeof a);
}
[[gnu::always_inline]] inline void add3(double* out, const double* in) {
  add2(out, in);
  out[2] += in[2];
}
// Entries e..e+3 of a [entry][lane] buffer to out[lane][e..e+3]: a 4 x 4 transpose.
template <int kRowLength>
[[gnu::always_inline]] inline void transpose4(const double* in, double (*out)[kRowLength],
                                            int e) {
  const V4 a = load4(in), b = load4(in + 4), c = load4(in + 8), d = load4(in + 12);
  const V4 t0 = __builtin_shuffle(a, b, M4{0, 4, 2, 6});
  const V4 t1 = __builtin_shuffle(a, b, M4{1, 5, 3, 7});
  const V4 t2 = __builtin_shuffle(c, d, M4{0, 4, 2, 6});
  const V4 t3 = __builtin_shuffle(c, d, M4{1, 5, 3, 7});
  store4(out[0] + e, __builtin_shuffle(t0, t2, M4{0, 1, 4, 5}));
  store4(out[1] + e, __builtin_shuffle(t1, t3, M4{0, 1, 4, 5}));
  store4(out[2] + e, __builtin_shuffle(t0, t2, M4{2, 3, 6, 7}));
  store4(out[3] + e, __builtin_shuffle(t1, t3, M4{2, 3, 6, 7}));
}
[[gnu::always_inline]] inline V4 det3(const V4 (&m)[3][3]) {
  return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
         m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
         m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
}

using ElementBatch = FemModel::ElementBatch;
using RotationBatch = FemState::RotationBatch;

// What one call of the batched kernel reads and writes.
struct BatchLoop {
  const ElementBatch* batches = nullptr;
  RotationBatch* rotation = nullptr;   // warm starts in, rotations out when keep
  const FemModel::AssemblyElement* elems = nullptr;
  const int* block_offset = nullptr;
  int elements = 0;
  const double* q = nullptr;
  const double* v = nullptr;           // null: x = q
  double h = 0.0, beta = 0.0;          // beta != 0: the stress reads F + beta F_v
  double* force = nullptr;             // 3n or null
  double* vals = nullptr;              // A's values or null
  double c_k = 0.0, lambda = 0.0, mu = 0.0;
  bool rotate = false, keep = false, count_inverted = false;
  // out: elements left to elementStep (slots), and det F <= 0 at q
  int* fallback = nullptr;
  int fallback_count = 0;
  int inverted = 0;
};

// One Newton step on the rotation R of F = R S, four elements at once, with M = R^T F on entry
// and exit: S = sym(M) and a = axial(M - M^T); the rotation vector theta that makes Q^T M
// symmetric to first order solves (tr(S) I - S) theta = a; Q is the Cayley rotation of theta / 2
// (exactly orthogonal, no square root); then R <- R Q, M <- Q^T M. `ok` drops the lanes whose
// tr(S) I - S is not positive definite; `last` is |theta|^2.
template <bool kUpdateM>
[[gnu::always_inline]] inline void polarStep(V4 (&m)[3][3], V4 (&r)[3][3], M4& ok, V4& last) {
  const V4 a0 = m[2][1] - m[1][2], a1 = m[0][2] - m[2][0], a2 = m[1][0] - m[0][1];
  const V4 s01 = 0.5 * (m[0][1] + m[1][0]), s02 = 0.5 * (m[0][2] + m[2][0]),
           s12 = 0.5 * (m[1][2] + m[2][1]);
  // A = tr(S) I - S: diagonal a00, a11, a22, off-diagonal -s01, -s02, -s12; its adjugate
  const V4 a00 = m[1][1] + m[2][2], a11 = m[0][0] + m[2][2], a22 = m[0][0] + m[1][1];
  const V4 c00 = a11 * a22 - s12 * s12, c11 = a00 * a22 - s02 * s02, c22 = a00 * a11 - s01 * s01;
  const V4 c01 = s02 * s12 + s01 * a22, c02 = s01 * s12 + s02 * a11, c12 = s01 * s02 + a00 * s12;
  const V4 det = a00 * c00 - s01 * c01 - s02 * c02;
  ok &= det > 0.0;
  const V4 inv = 1.0 / (det > 0.0 ? det : splat(1.0));
  const V4 t0 = (c00 * a0 + c01 * a1 + c02 * a2) * inv;
  const V4 t1 = (c01 * a0 + c11 * a1 + c12 * a2) * inv;
  const V4 t2 = (c02 * a0 + c12 * a1 + c22 * a2) * inv;
  last = t0 * t0 + t1 * t1 + t2 * t2;
  const V4 u0 = 0.5 * t0, u1 = 0.5 * t1, u2 = 0.5 * t2;
  const V4 uu = 0.25 * last;
  const V4 c = 2.0 / (1.0 + uu);
  // Q = I + c ([u] + [u]^2), [u]^2 = u u^T - |u|^2 I
  V4 qm[3][3];
  qm[0][0] = 1.0 + c * (u0 * u0 - uu);
  qm[1][1] = 1.0 + c * (u1 * u1 - uu);
  qm[2][2] = 1.0 + c * (u2 * u2 - uu);
  qm[0][1] = c * (u0 * u1 - u2);
  qm[1][0] = c * (u0 * u1 + u2);
  qm[0][2] = c * (u0 * u2 + u1);
  qm[2][0] = c * (u0 * u2 - u1);
  qm[1][2] = c * (u1 * u2 - u0);
  qm[2][1] = c * (u1 * u2 + u0);
  V4 nr[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) nr[i][j] = r[i][0] * qm[0][j] + r[i][1] * qm[1][j] + r[i][2] * qm[2][j];
  if constexpr (kUpdateM) {
    V4 nm[3][3];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) nm[i][j] = qm[0][i] * m[0][j] + qm[1][i] * m[1][j] + qm[2][i] * m[2][j];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) m[i][j] = nm[i][j];
  }
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r[i][j] = nr[i][j];
}

// The rotation of the polar decomposition of F, four elements at once, by Newton steps from the
// warm start R (in: the element's last rotation; out: the new one): two steps, a third when a
// lane still moved more than 1e-7 rad. `done` is false where a lane's F is not well conditioned
// (det F > 1e-3 |F|^3, the reference path's own fast-path condition), a step's system was not
// positive definite, or the last step still exceeded 1e-7 rad: those lanes need the reference
// path.
[[gnu::always_inline]] inline void polarNewton(const V4 (&f)[3][3], V4 (&r)[3][3], M4& done) {
  V4 m[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) m[i][j] = r[0][i] * f[0][j] + r[1][i] * f[1][j] + r[2][i] * f[2][j];
  V4 s2 = splat(0.0);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) s2 += f[i][j] * f[i][j];
  const V4 detf = det3(f);
  M4 ok = (detf > 0.0) & (detf * detf > 1e-6 * s2 * s2 * s2);
  V4 last = splat(0.0);
  polarStep<true>(m, r, ok, last);
  polarStep<true>(m, r, ok, last);
  // the stretch must be positive definite: a symmetric M can also be a saddle of tr(R^T F)
  // (R off by a half turn), which the steps do not leave; its leading minors tell
  const V4 s01 = 0.5 * (m[0][1] + m[1][0]), s02 = 0.5 * (m[0][2] + m[2][0]),
           s12 = 0.5 * (m[1][2] + m[2][1]);
  const V4 minor2 = m[0][0] * m[1][1] - s01 * s01;
  const V4 minor3 = m[0][0] * (m[1][1] * m[2][2] - s12 * s12) - s01 * (s01 * m[2][2] - s12 * s02) +
                    s02 * (s01 * s12 - m[1][1] * s02);
  ok &= (m[0][0] > 0.0) & (minor2 > 0.0) & (minor3 > 0.0);
  const M4 moved = last > 1e-14;
  if (moved[0] | moved[1] | moved[2] | moved[3]) polarStep<false>(m, r, ok, last);
  done = ok & (last <= 1e-14);
}

// The 30 columns of an element's lower-triangle blocks (a, b), a >= b, in the order of its
// offsets (buildPattern): column j of block (a, b) holds rows `first`..2 (first = j on the
// diagonal, 0 below it), at the element's offset `offset`; its values start at `entry` in the
// 78 entries of the batch buffer.
struct ScatterColumn {
  int a, b, j, first, offset, entry;
};
constexpr std::array<ScatterColumn, 30> makeColumns() {
  std::array<ScatterColumn, 30> out{};
  int c = 0, entry = 0;
  for (int a = 0, bk = 0; a < 4; ++a)
    for (int b = 0; b <= a; ++b, ++bk)
      for (int j = 0; j < 3; ++j) {
        const int first = a == b ? j : 0;
        out[c++] = ScatterColumn{a, b, j, first, 3 * bk + j, entry};
        entry += 3 - first;
      }
  return out;
}
constexpr std::array<ScatterColumn, 30> kColumns = makeColumns();

// The batched element loop over all batches (BatchLoop says what to compute): per batch the
// deformation gradients at q and of v, the rotation, one stress for the elastic and the damping
// force, and the 78 lower-triangle entries of each element's c_k R K0 R^T; the lanes polarNewton
// could not finish are listed for the reference path and not scattered here.
[[gnu::always_inline]] inline void runBatches(BatchLoop& loop) {
  const int nb = (loop.elements + 3) / 4;
  const double* q = loop.q;
  const double* v = loop.v;
  const bool damp = loop.force != nullptr && v != nullptr && loop.beta != 0.0;
  // the tangent's 78 entries and the 12 force components, computed per entry across the lanes
  // ([entry][lane]), then transposed per lane ([lane][entry]) for the scatter
  alignas(32) double kbuf[80 * 4];
  alignas(32) double kl[4][80];
  alignas(32) double fbuf[12 * 4];
  alignas(32) double fl[4][12];
  std::fill(kbuf + 78 * 4, kbuf + 80 * 4, 0.0);   // the padding the transposes read
  for (int b = 0; b < nb; ++b) {
    const ElementBatch& bt = loop.batches[b];
    const int lanes = std::min(4, loop.elements - 4 * b);
    V4 g[3][4];
    for (int c = 0; c < 3; ++c)
      for (int k = 0; k < 4; ++k) g[c][k] = load4(bt.g[c][k]);
    // F_q = sum_k (q_k - q_0) g_k^T (the differences: no cancellation of the coordinates), F_v
    V4 fq[3][3], fv[3][3], d[3][3];
    for (int c = 0; c < 3; ++c) {
      const V4 x0 = gather4(q, bt.x[0], c);
      for (int k = 1; k < 4; ++k) d[k - 1][c] = gather4(q, bt.x[k], c) - x0;
    }
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        fq[i][j] = d[0][i] * g[j][1] + d[1][i] * g[j][2] + d[2][i] * g[j][3];
    if (loop.count_inverted) {
      const M4 inv = ~(det3(fq) > 0.0);
      for (int l = 0; l < lanes; ++l) loop.inverted += inv[l] != 0;
    }
    V4 f[3][3];
    if (v != nullptr) {
      for (int c = 0; c < 3; ++c) {
        const V4 x0 = gather4(v, bt.x[0], c);
        for (int k = 1; k < 4; ++k) d[k - 1][c] = gather4(v, bt.x[k], c) - x0;
      }
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          fv[i][j] = d[0][i] * g[j][1] + d[1][i] * g[j][2] + d[2][i] * g[j][3];
          f[i][j] = fq[i][j] + loop.h * fv[i][j];
        }
    } else {
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          fv[i][j] = splat(0.0);
          f[i][j] = fq[i][j];
        }
    }
    // the rotation (identity without rotation extraction)
    V4 r[3][3];
    M4 done = {-1, -1, -1, -1};
    if (loop.rotate) {
      RotationBatch& rb = loop.rotation[b];
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) r[i][j] = load4(rb.r[i][j]);
      polarNewton(f, r, done);
      if (loop.keep)
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j < 3; ++j) store4(rb.r[i][j], r[i][j]);
    } else {
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) r[i][j] = splat(i == j ? 1.0 : 0.0);
    }
    int lane_ok[4];
    for (int l = 0; l < 4; ++l) {
      lane_ok[l] = l < lanes && done[l] != 0;
      if (l < lanes && done[l] == 0) loop.fallback[loop.fallback_count++] = 4 * b + l;
    }
    const V4 vol = load4(bt.vol);
    if (loop.force != nullptr) {
      // R V sigma(sym(R^T G) - I) g_k with G = F + beta F_v: the elastic and the damping force
      V4 gs[3][3];
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) gs[i][j] = damp ? f[i][j] + loop.beta * fv[i][j] : f[i][j];
      V4 rg[3][3];
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) rg[i][j] = r[0][i] * gs[0][j] + r[1][i] * gs[1][j] + r[2][i] * gs[2][j];
      const V4 e00 = rg[0][0] - 1.0, e11 = rg[1][1] - 1.0, e22 = rg[2][2] - 1.0;
      const V4 lt = loop.lambda * (e00 + e11 + e22);
      const double m2 = 2.0 * loop.mu;
      V4 sg[3][3];
      sg[0][0] = vol * (lt + m2 * e00);
      sg[1][1] = vol * (lt + m2 * e11);
      sg[2][2] = vol * (lt + m2 * e22);
      sg[0][1] = sg[1][0] = vol * (loop.mu * (rg[0][1] + rg[1][0]));
      sg[0][2] = sg[2][0] = vol * (loop.mu * (rg[0][2] + rg[2][0]));
      sg[1][2] = sg[2][1] = vol * (loop.mu * (rg[1][2] + rg[2][1]));
      V4 p[3][3];
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) p[i][j] = r[i][0] * sg[0][j] + r[i][1] * sg[1][j] + r[i][2] * sg[2][j];
      for (int i = 0; i < 3; ++i) {
        V4 sum = splat(0.0);
        for (int k = 1; k < 4; ++k) {
          const V4 fk = p[i][0] * g[0][k] + p[i][1] * g[1][k] + p[i][2] * g[2][k];
          store4(fbuf + 4 * (3 * k + i), fk);
          sum += fk;
        }
        store4(fbuf + 4 * i, -sum);
      }
      for (int e = 0; e < 12; e += 4) transpose4(fbuf + 4 * e, fl, e);
      for (int l = 0; l < 4; ++l) {
        if (!lane_ok[l]) continue;
#pragma GCC unroll 4
        for (int k = 0; k < 4; ++k) add3(loop.force + bt.x[k][l], fl[l] + 3 * k);
      }
    }
    if (loop.vals != nullptr) {
      // block (a, b) = c_k V (lambda r_a r_b^T + mu r_b r_a^T + mu (g_a . g_b) I), r_a = R g_a
      V4 rv[4][3];
      for (int k = 0; k < 4; ++k)
        for (int i = 0; i < 3; ++i) rv[k][i] = r[i][0] * g[0][k] + r[i][1] * g[1][k] + r[i][2] * g[2][k];
      const V4 cl = (loop.c_k * loop.lambda) * vol, cm = (loop.c_k * loop.mu) * vol;
      V4 xl[4][3], ym[4][3];
#pragma GCC unroll 4
      for (int k = 0; k < 4; ++k)
#pragma GCC unroll 3
        for (int i = 0; i < 3; ++i) {
          xl[k][i] = cl * rv[k][i];
          ym[k][i] = cm * rv[k][i];
        }
      // entry (i, j) of block (a, b): cl r_a[i] r_b[j] + cm r_b[i] r_a[j] (+ gg on i == j), in
      // the scatter's order (kColumns)
#pragma GCC unroll 30
      for (int c = 0; c < 30; ++c) {
        const ScatterColumn& col = kColumns[c];
        const int a = col.a, bb = col.b, j = col.j;
        const V4 gg = cm * (g[0][a] * g[0][bb] + g[1][a] * g[1][bb] + g[2][a] * g[2][bb]);
#pragma GCC unroll 3
        for (int i = col.first; i < 3; ++i) {
          const V4 x = xl[a][i] * rv[bb][j] + ym[bb][i] * rv[a][j];
          store4(kbuf + 4 * (col.entry + i - col.first), i == j ? x + gg : x);
        }
      }
#pragma GCC unroll 20
      for (int e = 0; e < 80; e += 4) transpose4(kbuf + 4 * e, kl, e);
      for (int l = 0; l < 4; ++l) {
        if (!lane_ok[l]) continue;
        const int* off = loop.block_offset + static_cast<std::size_t>(4 * b + l) * kBlockOffsetsPerElement;
        const double* src = kl[l];
        if (loop.elems[4 * b + l].has_fixed) {
          for (int c = 0; c < 30; ++c) {
            const ScatterColumn& col = kColumns[c];
            if (off[col.offset] < 0) continue;
            double* out = loop.vals + off[col.offset] - col.first;
            for (int i = col.first; i < 3; ++i) out[i] += src[col.entry + i - col.first];
          }
          continue;
        }
        // column j of a block: rows first..2, consecutive in A's values and in the buffer
#pragma GCC unroll 30
        for (int c = 0; c < 30; ++c) {
          const ScatterColumn& col = kColumns[c];
          double* out = loop.vals + off[col.offset];
          const double* in = src + col.entry;
          if (col.first == 0) {
            add3(out, in);
          } else if (col.first == 1) {
            add2(out, in);
          } else {
            out[0] += in[0];
          }
        }
      }
    }
  }
}

void runBatchesGeneric(BatchLoop& loop) { runBatches(loop); }

#if defined(__x86_64__)
__attribute__((target("avx"))) void runBatchesAvx(BatchLoop& loop) { runBatches(loop); }
#endif

using BatchKernel = void (*)(BatchLoop&);

// The kernel this process uses: AVX when the CPU has it, unless TACTUS_FEM_KERNEL names another
// (setFemElementKernel changes it). "reference": no batches, every element through elementStep.
struct ChosenKernel {
  BatchKernel fn = &runBatchesGeneric;
  const char* name = "generic";
};

bool cpuHasAvx() {
#if defined(__x86_64__)
  return __builtin_cpu_supports("avx");
#else
  return false;
#endif
}

bool choose(ChosenKernel& k, const char* name) {
  if (std::strcmp(name, "generic") == 0) {
    k = ChosenKernel{&runBatchesGeneric, "generic"};
    return true;
  }
  if (std::strcmp(name, "reference") == 0) {
    k = ChosenKernel{nullptr, "reference"};
    return true;
  }
#if defined(__x86_64__)
  if (std::strcmp(name, "avx") == 0 && cpuHasAvx()) {
    k = ChosenKernel{&runBatchesAvx, "avx"};
    return true;
  }
#endif
  return false;
}

ChosenKernel& chosenKernel() {
  static ChosenKernel k = [] {
    ChosenKernel out;
    const char* env = std::getenv("TACTUS_FEM_KERNEL");
    if (env != nullptr && choose(out, env)) return out;
    if (!choose(out, "avx")) choose(out, "generic");
    return out;
  }();
  return k;
}

// Runs the CPU's batch kernel over `loop` (its fallback list sized for loop.elements in
// `fallback_slots`); without one, lists every element for the reference path. True when a kernel
// ran.
bool runBatchKernel(BatchLoop& loop, std::vector<int>& fallback_slots) {
  fallback_slots.resize(static_cast<std::size_t>(loop.elements));
  loop.fallback = fallback_slots.data();
  const BatchKernel kernel = chosenKernel().fn;
  if (kernel != nullptr) {
    kernel(loop);
    return true;
  }
  for (int slot = 0; slot < loop.elements; ++slot) loop.fallback[loop.fallback_count++] = slot;
  return false;
}

// Element `slot`'s rotation into its batch's lane.
void storeElementRotation(std::vector<RotationBatch>& rotation, int slot,
                          const Eigen::Matrix3d& r) {
  RotationBatch& rb = rotation[static_cast<std::size_t>(slot / 4)];
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) rb.r[a][b][slot % 4] = r(a, b);
}

}  // namespace

bool setFemElementKernel(const char* name) { return choose(chosenKernel(), name); }
const char* femElementKernelName() { return chosenKernel().name; }

Eigen::Matrix3d FemBody::Impl::elementStep(int slot, const double* qd, const double* vd, double h,
                                           double beta, double* fd, double* vals, double c_k,
                                           bool rotate) const {
  const AssemblyElement& el = assembly_elems[static_cast<std::size_t>(slot)];
  const std::array<int, 4>& t = el.node;
  const Eigen::Matrix<double, 3, 4>& g = el.g;
  const double vol = el.vol;
  // deformation gradients at q and of v from the node differences (as the batched kernel)
  Eigen::Matrix3d fq = Eigen::Matrix3d::Zero(), fv = Eigen::Matrix3d::Zero();
  for (int k = 1; k < 4; ++k) {
    fq.noalias() += (Eigen::Map<const Eigen::Vector3d>(qd + 3 * t[k]) -
                     Eigen::Map<const Eigen::Vector3d>(qd + 3 * t[0])) * g.col(k).transpose();
    if (vd)
      fv.noalias() += (Eigen::Map<const Eigen::Vector3d>(vd + 3 * t[k]) -
                       Eigen::Map<const Eigen::Vector3d>(vd + 3 * t[0])) * g.col(k).transpose();
  }
  const Eigen::Matrix3d f = vd ? Eigen::Matrix3d(fq + h * fv) : fq;
  const Eigen::Matrix3d r = rotate ? fem_detail::polarRotation(f) : Eigen::Matrix3d::Identity();
  if (fd) {
    // elastic force R V sigma(sym(R^T F) - I) g_a plus beta K v = R V sigma(sym(R^T F_v)) g_a:
    // sigma is linear, so one stress carries both
    Eigen::Matrix3d strain = r.transpose() * f;
    if (vd && beta != 0.0) strain.noalias() += beta * (r.transpose() * fv);
    const Eigen::Matrix3d eps = 0.5 * (strain + strain.transpose()) - Eigen::Matrix3d::Identity();
    const Eigen::Matrix3d rs = r * (vol * sigma(eps));
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (int k = 1; k < 4; ++k) {
      const Eigen::Vector3d fk = rs * g.col(k);
      Eigen::Map<Eigen::Vector3d>(fd + 3 * t[k]) += fk;
      sum += fk;
    }
    Eigen::Map<Eigen::Vector3d>(fd + 3 * t[0]) -= sum;
  }
  if (vals) {
    // block (a, b) = c_k V (lambda r_a r_b^T + mu r_b r_a^T + mu (g_a . g_b) I), r_a = R g_a;
    // column j of a block goes to 3 (diagonal block: 3 - j) consecutive values
    const Eigen::Matrix<double, 3, 4> rg = r * g;
    const double cl = c_k * vol * lambda, cm = c_k * vol * mu;
    const int* off = block_offset.data() + static_cast<std::size_t>(slot) * kBlockOffsetsPerElement;
    for (int a = 0; a < 4; ++a) {
      const Eigen::Vector3d ra = rg.col(a);
      for (int b = 0; b <= a; ++b) {
        const int* o = off + 3 * (a * (a + 1) / 2 + b);
        if (el.has_fixed && o[0] < 0) continue;
        const double gg = cm * g.col(a).dot(g.col(b));
        if (a == b) {
          const double c = cl + cm;
          for (int j = 0; j < 3; ++j)
            for (int i = j; i < 3; ++i)
              vals[o[j] + i - j] += c * ra[i] * ra[j] + (i == j ? gg : 0.0);
        } else {
          const Eigen::Vector3d rb = rg.col(b);
          Eigen::Matrix3d blk = cl * ra * rb.transpose() + cm * rb * ra.transpose();
          blk.diagonal().array() += gg;
          for (int j = 0; j < 3; ++j) Eigen::Map<Eigen::Vector3d>(vals + o[j]) += blk.col(j);
        }
      }
    }
  }
  return r;
}

void FemBody::Impl::evaluate(const Eigen::VectorXd& q, const Eigen::VectorXd* v, double h,
                             double beta, Eigen::VectorXd* f_out, Sparse* target, double c_k,
                             double c_m, bool use_rest_frame, int* inverted_at_q,
                             bool keep_rotations) {
  if (general_loop) {
    evaluateGeneral(q, v, h, beta, f_out, target, c_k, c_m, use_rest_frame, inverted_at_q,
                    keep_rotations);
    return;
  }
  if (f_out) f_out->setZero(3 * n);
  double* vals = target ? target->valuePtr() : nullptr;
  if (target) std::fill(vals, vals + target->nonZeros(), 0.0);
  const bool rotate = corotational && !use_rest_frame;
  const int ne = mesh.tetCount();
  // a query starts from the kept rotations but leaves them alone: it works on a copy
  std::vector<RotationBatch>* rot = &rotation;
  std::vector<RotationBatch> query_rotation;
  if (rotate && !keep_rotations) {
    query_rotation = rotation;
    rot = &query_rotation;
  }
  BatchLoop loop;
  loop.batches = batches.data();
  loop.rotation = rot->data();
  loop.elems = assembly_elems.data();
  loop.block_offset = block_offset.data();
  loop.elements = ne;
  loop.q = q.data();
  loop.v = v ? v->data() : nullptr;
  loop.h = h;
  loop.beta = f_out && v ? beta : 0.0;
  loop.force = f_out ? f_out->data() : nullptr;
  loop.vals = vals;
  loop.c_k = c_k;
  loop.lambda = lambda;
  loop.mu = mu;
  loop.rotate = rotate;
  loop.keep = rotate;
  loop.count_inverted = inverted_at_q != nullptr;
  const bool batched = runBatchKernel(loop, fallback_slots);
  if (!batched && inverted_at_q) {   // the reference path for every element: count here
    for (const AssemblyElement& el : assembly_elems) {
      Eigen::Matrix3d fq = Eigen::Matrix3d::Zero();
      for (int k = 1; k < 4; ++k)
        fq.noalias() += (q.segment<3>(3 * el.node[k]) - q.segment<3>(3 * el.node[0])) *
                        el.g.col(k).transpose();
      loop.inverted += !(fq.determinant() > 0.0);
    }
  }
  // the elements the batches left: the reference path, in slot order
  for (int i = 0; i < loop.fallback_count; ++i) {
    const int slot = loop.fallback[i];
    const Eigen::Matrix3d r = elementStep(slot, loop.q, loop.v, h, loop.beta, loop.force, vals,
                                          c_k, rotate);
    if (rotate) storeElementRotation(*rot, slot, r);
  }
  if (batched) counters.fallback_elements += loop.fallback_count;
  if (inverted_at_q) *inverted_at_q = loop.inverted;
  if (rotate) {
    counters.rotation_extractions += ne;
    if (keep_rotations) {
      rotation_current = true;
      rotation_by_tet_stale = true;
      step_sums_current = false;
    }
  }
  if (target && c_m != 0.0)
    for (int i = 0; i < n; ++i)
      if (dof_base[i] >= 0)
        for (int c = 0; c < 3; ++c) vals[diag_offset[dof_base[i] + c]] += c_m * mass[3 * i + c];
}

}  // namespace tactus::sim

namespace tactus::sim {

void FemBody::Impl::rotationsAt(const Eigen::VectorXd& x, std::vector<RotationBatch>& out) {
  out = rotation;   // the warm starts (same size: no allocation after the first call)
  const int ne = mesh.tetCount();
  BatchLoop loop;
  loop.batches = batches.data();
  loop.rotation = out.data();
  loop.elems = assembly_elems.data();
  loop.block_offset = block_offset.data();
  loop.elements = ne;
  loop.q = x.data();
  loop.rotate = true;
  loop.keep = true;   // into `out`
  (void)runBatchKernel(loop, fallback_slots);
  for (int i = 0; i < loop.fallback_count; ++i) {
    const int slot = loop.fallback[i];
    storeElementRotation(
        out, slot, elementStep(slot, loop.q, nullptr, 0.0, 0.0, nullptr, nullptr, 0.0, true));
  }
}

}  // namespace tactus::sim
