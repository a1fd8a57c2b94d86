// The corotational element loop and the system matrix's pattern (see fem_body_impl.h).
#include <algorithm>
#include <array>
#include <limits>

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
}

void FemBody::Impl::evaluate(const Eigen::VectorXd& q, const Eigen::VectorXd* v, double h,
                             double beta, Eigen::VectorXd* f_out, Sparse* target, double c_k,
                             double c_m, bool use_rest_frame, int* inverted_at_q) {
  if (general_loop) {
    evaluateGeneral(q, v, h, beta, f_out, target, c_k, c_m, use_rest_frame, inverted_at_q);
    return;
  }
  if (f_out) f_out->setZero(3 * n);
  double* vals = target ? target->valuePtr() : nullptr;
  if (target) std::fill(vals, vals + target->nonZeros(), 0.0);
  const bool rotate = corotational && !use_rest_frame;
  const bool damp_force = f_out && v && beta != 0.0;
  const double* qd = q.data();
  const double* vd = v ? v->data() : nullptr;
  double* fd = f_out ? f_out->data() : nullptr;
  const int ne = mesh.tetCount();
  int inverted = 0;
  for (int slot = 0; slot < ne; ++slot) {
    const AssemblyElement& el = assembly_elems[slot];
    const std::array<int, 4>& t = el.node;
    const Eigen::Matrix<double, 3, 4>& g = el.g;
    const double vol = el.vol;
    // deformation gradients: F_q = sum_k q_k g_k^T at q, F_v = sum_k v_k g_k^T
    Eigen::Matrix3d fq = Eigen::Matrix3d::Zero(), fv = Eigen::Matrix3d::Zero();
    for (int k = 0; k < 4; ++k) {
      fq.noalias() += Eigen::Map<const Eigen::Vector3d>(qd + 3 * t[k]) * g.col(k).transpose();
      if (vd) fv.noalias() += Eigen::Map<const Eigen::Vector3d>(vd + 3 * t[k]) * g.col(k).transpose();
    }
    if (inverted_at_q && !(fq.determinant() > 0.0)) ++inverted;
    const Eigen::Matrix3d f = vd ? Eigen::Matrix3d(fq + h * fv) : fq;
    Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
    if (rotate) {
      r = fem_detail::polarRotation(f);
      rotation[el.index] = r;
    }
    if (f_out) {
      // elastic force R V sigma(sym(R^T F) - I) g_a plus beta K v = R V sigma(sym(R^T F_v)) g_a:
      // sigma is linear, so one stress carries both
      Eigen::Matrix3d strain = rotate ? Eigen::Matrix3d(r.transpose() * f) : f;
      if (damp_force) strain.noalias() += beta * (rotate ? Eigen::Matrix3d(r.transpose() * fv) : fv);
      const Eigen::Matrix3d eps = 0.5 * (strain + strain.transpose()) - Eigen::Matrix3d::Identity();
      const Eigen::Matrix3d rs = rotate ? Eigen::Matrix3d(r * (vol * sigma(eps))) : vol * sigma(eps);
      const Eigen::Matrix<double, 3, 4> fe = rs * g;
      for (int k = 0; k < 4; ++k) Eigen::Map<Eigen::Vector3d>(fd + 3 * t[k]) += fe.col(k);
    }
    if (target) {
      // block (a, b) = c_k V (lambda r_a r_b^T + mu r_b r_a^T + mu (g_a . g_b) I), r_a = R g_a;
      // column j of a block goes to 3 (diagonal block: 3 - j) consecutive values
      const Eigen::Matrix<double, 3, 4> rg = rotate ? Eigen::Matrix<double, 3, 4>(r * g) : g;
      const double cl = c_k * vol * lambda, cm = c_k * vol * mu;
      const int* off = block_offset.data() + static_cast<std::size_t>(slot) * kBlockOffsetsPerElement;
#pragma GCC unroll 4
      for (int a = 0; a < 4; ++a) {
        const Eigen::Vector3d ra = rg.col(a);
#pragma GCC unroll 4
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
  }
  if (inverted_at_q) *inverted_at_q = inverted;
  if (rotate) counters.rotation_extractions += ne;
  if (target && c_m != 0.0)
    for (int i = 0; i < n; ++i)
      if (dof_base[i] >= 0)
        for (int c = 0; c < 3; ++c) vals[diag_offset[dof_base[i] + c]] += c_m * mass[3 * i + c];
}

}  // namespace tactus::sim
