// The corotational element loop and the system matrix's pattern (see fem_body_impl.h).
#include <algorithm>
#include <array>
#include <limits>

#include "fem_body_impl.h"

namespace tactus::sim {

namespace {

// (a, b, i, j) of the kEntriesPerElement entries in buildPattern's order: blocks (a, b) with
// a >= b, rows i, columns j (j <= i inside a diagonal block).
struct Entry {
  unsigned char a, b, i, j;
};
constexpr std::array<Entry, kEntriesPerElement> makeEntries() {
  std::array<Entry, kEntriesPerElement> out{};
  int k = 0;
  for (int a = 0; a < 4; ++a)
    for (int b = 0; b <= a; ++b)
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < (a == b ? i + 1 : 3); ++j)
          out[k++] = {static_cast<unsigned char>(a), static_cast<unsigned char>(b),
                      static_cast<unsigned char>(i), static_cast<unsigned char>(j)};
  return out;
}
constexpr std::array<Entry, kEntriesPerElement> kEntries = makeEntries();

}  // namespace

void FemBody::Impl::buildPattern() {
  const int ne = mesh.tetCount();
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
  const int* outer = a.outerIndexPtr();
  const int* inner = a.innerIndexPtr();
  auto offsetOf = [&](int r, int c) {
    const int* lo = inner + outer[c];
    const int* hi = inner + outer[c + 1];
    const int* it = std::lower_bound(lo, hi, r);
    return static_cast<int>(it - inner);
  };
  std::vector<int> order(ne);
  std::vector<std::array<int, 4>> sorted_nodes(ne);
  for (int e = 0; e < ne; ++e) {
    order[e] = e;
    for (int k = 0; k < 4; ++k) {
      const int d = dof_base[mesh.tets[e][k]];
      sorted_nodes[e][k] = d >= 0 ? d : std::numeric_limits<int>::max();
    }
    std::sort(sorted_nodes[e].begin(), sorted_nodes[e].end());
  }
  std::stable_sort(order.begin(), order.end(),
                   [&](int x, int y) { return sorted_nodes[x] < sorted_nodes[y]; });
  assembly_elems.resize(ne);
  elem_offset.resize(static_cast<std::size_t>(ne) * kEntriesPerElement);
  for (int k_elem = 0; k_elem < ne; ++k_elem) {
    const int e = order[k_elem];
    AssemblyElement& el = assembly_elems[k_elem];
    el = {mesh.tets[e], e, false, grad[e], volume[e]};
    int* off = elem_offset.data() + static_cast<std::size_t>(k_elem) * kEntriesPerElement;
    int k = 0;
    forEntry(e, [&](int r, int c) {
      off[k] = r >= 0 ? offsetOf(r, c) : -1;
      el.has_fixed = el.has_fixed || off[k] < 0;
      ++k;
    });
  }
  diag_offset.resize(n_free);
  for (int d = 0; d < n_free; ++d) diag_offset[d] = offsetOf(d, d);
  a_rest = a;
}

void FemBody::Impl::evaluate(const Eigen::VectorXd& q, const Eigen::VectorXd* v, double h,
                             double beta, Eigen::VectorXd* f_out, Sparse* target, double c_k,
                             double c_m, bool use_rest_frame, int* inverted_at_q) {
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
      // block (a, b) = c_k V (lambda r_a r_b^T + mu r_b r_a^T + mu (g_a . g_b) I), r_a = R g_a
      const Eigen::Matrix<double, 3, 4> rg = rotate ? Eigen::Matrix<double, 3, 4>(r * g) : g;
      const Eigen::Matrix4d gg = (c_k * vol * mu) * (g.transpose() * g);
      const double cl = c_k * vol * lambda, cm = c_k * vol * mu;
      double ke[kEntriesPerElement];
#pragma GCC unroll 78
      for (int k = 0; k < kEntriesPerElement; ++k) {
        const Entry en = kEntries[k];
        ke[k] = cl * rg(en.i, en.a) * rg(en.j, en.b) + cm * rg(en.i, en.b) * rg(en.j, en.a) +
                (en.i == en.j ? gg(en.a, en.b) : 0.0);
      }
      const int* off = elem_offset.data() + static_cast<std::size_t>(slot) * kEntriesPerElement;
      if (el.has_fixed) {
        for (int k = 0; k < kEntriesPerElement; ++k)
          if (off[k] >= 0) vals[off[k]] += ke[k];
      } else {
        for (int k = 0; k < kEntriesPerElement; ++k) vals[off[k]] += ke[k];
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
