// The general element loop (see fem_body_impl.h): integration domains that are either the
// tetrahedra or the edge-smoothed domains, each with the corotational law's tangent R K0 R^T or
// the full tangent of an isotropic law in principal stretches (fem_constitutive.h).
//
// Edge-smoothed strain (docs/design.md, "Element choice"): every mesh edge owns a sixth of the
// volume of each tetrahedron around it, and its deformation gradient is the volume average of
// theirs, F_d = sum_a x_a G_a^T with G_a = sum_e (V_e / 6) g_{e,a} / V_d. The stiffness is
// sum_d V_d B_d^T D B_d: linear elasticity on a piecewise constant strain field that is one
// element layer wider than the tetrahedra's, which removes the constant-strain tetrahedron's
// locking in bending (the domains' strain varies across an element layer).
#include <algorithm>
#include <cmath>
#include <utility>

#include "fem_body_impl.h"
#include "fem_constitutive.h"

namespace tactus::sim {

namespace {

// Adds a 3 x 3 block into A's values at its column offsets o (block_offset's layout): a
// diagonal block's lower triangle, or the whole block below the diagonal.
void addBlock(double* vals, const int* o, bool diagonal, const Eigen::Matrix3d& blk) {
  if (diagonal) {
    for (int j = 0; j < 3; ++j)
      for (int i = j; i < 3; ++i) vals[o[j] + i - j] += blk(i, j);
  } else {
    for (int j = 0; j < 3; ++j) Eigen::Map<Eigen::Vector3d>(vals + o[j]) += blk.col(j);
  }
}

}  // namespace

int FemBody::Impl::valueOffset(int r, int c) const {
  const int* outer = a.outerIndexPtr();
  const int* inner = a.innerIndexPtr();
  const int* lo = inner + outer[c];
  const int* hi = inner + outer[c + 1];
  return static_cast<int>(std::lower_bound(lo, hi, r) - inner);
}

void FemBody::Impl::buildEdgeDomains() {
  static constexpr int kEdges[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
  const int ne = mesh.tetCount();
  struct EdgeOfTet {
    int a, b, tet;
    bool operator<(const EdgeOfTet& o) const {
      return a != o.a ? a < o.a : (b != o.b ? b < o.b : tet < o.tet);
    }
  };
  std::vector<EdgeOfTet> all;
  all.reserve(static_cast<std::size_t>(ne) * 6);
  for (int e = 0; e < ne; ++e)
    for (const auto& k : kEdges) {
      const int x = mesh.tets[e][k[0]], y = mesh.tets[e][k[1]];
      all.push_back({std::min(x, y), std::max(x, y), e});
    }
  std::sort(all.begin(), all.end());
  dom_start.assign(1, 0);
  dom_node.clear();
  dom_grad.clear();
  dom_vol.clear();
  dom_max_nodes = 0;
  std::vector<int> nodes, order;
  std::vector<Eigen::Vector3d> g;
  for (std::size_t i = 0; i < all.size();) {
    std::size_t j = i;
    nodes.clear();
    g.clear();
    double vol = 0.0;
    for (; j < all.size() && all[j].a == all[i].a && all[j].b == all[i].b; ++j) {
      const int e = all[j].tet;
      const double w = volume[e] / 6.0;
      vol += w;
      for (int c = 0; c < 4; ++c) {
        const int node = mesh.tets[e][c];
        const auto it = std::find(nodes.begin(), nodes.end(), node);
        const std::size_t slot = static_cast<std::size_t>(it - nodes.begin());
        if (it == nodes.end()) {
          nodes.push_back(node);
          g.push_back(Eigen::Vector3d::Zero());
        }
        g[slot] += w * grad[e].col(c);
      }
    }
    // nodes by ascending reduced DOF (fixed first): block (a, b), a > b, lies below the diagonal
    order.resize(nodes.size());
    for (std::size_t k = 0; k < nodes.size(); ++k) order[k] = static_cast<int>(k);
    std::stable_sort(order.begin(), order.end(),
                     [&](int x, int y) { return dof_base[nodes[x]] < dof_base[nodes[y]]; });
    for (int k : order) {
      dom_node.push_back(nodes[k]);
      for (int c = 0; c < 3; ++c) dom_grad.push_back(g[k][c] / vol);
    }
    dom_vol.push_back(vol);
    dom_start.push_back(static_cast<int>(dom_node.size()));
    dom_max_nodes = std::max(dom_max_nodes, static_cast<int>(nodes.size()));
    i = j;
  }
}

void FemBody::Impl::buildDomainPattern() {
  // every pair of free nodes that share a domain: per node, the nodes of its domains
  const int nd = static_cast<int>(dom_vol.size());
  std::vector<int> inc_start(n + 1, 0), inc;
  for (int d = 0; d < nd; ++d)
    for (int s = dom_start[d]; s < dom_start[d + 1]; ++s) ++inc_start[dom_node[s] + 1];
  for (int i = 0; i < n; ++i) inc_start[i + 1] += inc_start[i];
  inc.resize(inc_start[n]);
  std::vector<int> fill(inc_start.begin(), inc_start.end() - 1);
  for (int d = 0; d < nd; ++d)
    for (int s = dom_start[d]; s < dom_start[d + 1]; ++s) inc[fill[dom_node[s]]++] = d;
  std::vector<Eigen::Triplet<double, int>> trip;
  std::vector<int> near;
  for (int j = 0; j < n; ++j) {
    const int cj = dof_base[j];
    if (cj < 0) continue;
    near.clear();
    for (int s = inc_start[j]; s < inc_start[j + 1]; ++s) {
      const int d = inc[s];
      for (int t = dom_start[d]; t < dom_start[d + 1]; ++t)
        if (dof_base[dom_node[t]] >= cj) near.push_back(dof_base[dom_node[t]]);
    }
    std::sort(near.begin(), near.end());
    near.erase(std::unique(near.begin(), near.end()), near.end());
    for (int ri : near)
      for (int c = 0; c < 3; ++c)
        for (int r = 0; r < 3; ++r)
          if (ri > cj || r >= c) trip.emplace_back(ri + r, cj + c, 0.0);
  }
  a.resize(n_free, n_free);
  a.setFromTriplets(trip.begin(), trip.end());
  a.makeCompressed();
}

void FemBody::Impl::buildDomainOffsets() {
  const int nd = static_cast<int>(dom_vol.size());
  dom_offset_start.assign(static_cast<std::size_t>(nd) + 1, 0);
  dom_offset.clear();
  for (int d = 0; d < nd; ++d) {
    const int* node = dom_node.data() + dom_start[d];
    const int k = dom_start[d + 1] - dom_start[d];
    for (int x = 0; x < k; ++x)
      for (int y = 0; y <= x; ++y) {
        const int p = dof_base[node[x]], q = dof_base[node[y]];
        for (int j = 0; j < 3; ++j)
          dom_offset.push_back(p < 0 || q < 0 ? -1 : valueOffset(x == y ? p + j : p, q + j));
      }
    dom_offset_start[d + 1] = dom_offset.size();
  }
}

Eigen::Matrix3d FemBody::Impl::domainKernel(int k, const int* node, const double* grad,
                                            double vol, const int* off, const double* qd,
                                            const double* vd, double h, double beta, double* fd,
                                            double* vals, double c_k, bool rotate) {
  using Vec3 = Eigen::Vector3d;
  using Map3 = Eigen::Map<const Vec3>;
  Eigen::Matrix3d fq = Eigen::Matrix3d::Zero(), fv = Eigen::Matrix3d::Zero();
  for (int a = 0; a < k; ++a) {
    fq.noalias() += Map3(qd + 3 * node[a]) * Map3(grad + 3 * a).transpose();
    if (vd) fv.noalias() += Map3(vd + 3 * node[a]) * Map3(grad + 3 * a).transpose();
  }
  const Eigen::Matrix3d f = vd ? Eigen::Matrix3d(fq + h * fv) : fq;
  const bool damp_force = fd && vd && beta != 0.0;
  const bool full =
      rotate && (rotation_stiffness || material.law == MaterialLaw::kInvertibleNeoHookean);
  const Eigen::Matrix3d r = rotate ? fem_detail::polarRotation(f) : Eigen::Matrix3d::Identity();
  dom_scratch.resize(static_cast<std::size_t>(k));
  if (!full) {
    // R K0 R^T (identity R: the linear law or the rest shape), as in the corotational loop
    if (fd) {
      Eigen::Matrix3d strain = r.transpose() * f;
      if (damp_force) strain.noalias() += beta * (r.transpose() * fv);
      const Eigen::Matrix3d eps = 0.5 * (strain + strain.transpose()) - Eigen::Matrix3d::Identity();
      const Eigen::Matrix3d rs = r * (vol * sigma(eps));
      for (int a = 0; a < k; ++a)
        Eigen::Map<Vec3>(fd + 3 * node[a]) += rs * Map3(grad + 3 * a);
    }
    if (vals) {
      for (int a = 0; a < k; ++a) dom_scratch[a] = r * Map3(grad + 3 * a);
      const double cl = c_k * vol * lambda, cm = c_k * vol * mu;
      for (int a = 0; a < k; ++a) {
        const Vec3& ra = dom_scratch[a];
        for (int b = 0; b <= a; ++b) {
          const int* o = off + 3 * (a * (a + 1) / 2 + b);
          if (o[0] < 0) continue;
          const double gg = cm * Map3(grad + 3 * a).dot(Map3(grad + 3 * b));
          const Vec3& rb = dom_scratch[b];
          Eigen::Matrix3d blk = cl * ra * rb.transpose() + cm * rb * ra.transpose();
          blk.diagonal().array() += gg;
          addBlock(vals, o, a == b, blk);
        }
      }
    }
    return r;
  }
  // full tangent in the frame of F = U diag(s) V^T (fem_constitutive.h)
  Eigen::Matrix3d u, vf;
  Vec3 s;
  fem_detail::rotationSvd(f, r, u, s, vf);
  fem_detail::PrincipalResponse resp;
  fem_detail::principalResponse(material.law, lambda, mu, s, true, resp);
  for (int a = 0; a < k; ++a) dom_scratch[a] = vf.transpose() * Map3(grad + 3 * a);
  if (fd) {
    Eigen::Matrix3d t = resp.stress.asDiagonal();
    if (damp_force) {
      // beta K v: the same tangent applied to the velocity gradient
      const Eigen::Matrix3d dfh = u.transpose() * fv * vf;
      const Vec3 dd = resp.h * dfh.diagonal();
      for (int i = 0; i < 3; ++i) t(i, i) += beta * dd[i];
      for (int p = 0; p < 3; ++p) {
        const int i = fem_detail::kPairs[p][0], j = fem_detail::kPairs[p][1];
        t(i, j) += beta * (resp.p[p] * dfh(i, j) + resp.m[p] * dfh(j, i));
        t(j, i) += beta * (resp.p[p] * dfh(j, i) + resp.m[p] * dfh(i, j));
      }
    }
    const Eigen::Matrix3d ut = vol * (u * t);
    for (int a = 0; a < k; ++a) Eigen::Map<Vec3>(fd + 3 * node[a]) += ut * dom_scratch[a];
  }
  if (vals) {
    const double c = c_k * vol;
    for (int a = 0; a < k; ++a) {
      const Vec3& ga = dom_scratch[a];
      for (int b = 0; b <= a; ++b) {
        const int* o = off + 3 * (a * (a + 1) / 2 + b);
        if (o[0] < 0) continue;
        const Vec3& gb = dom_scratch[b];
        // K^_ab[i][l] = sum_jm C_ijlm g^_a[j] g^_b[m]
        Eigen::Matrix3d kh = (ga.asDiagonal() * resp.h) * gb.asDiagonal();
        for (int p = 0; p < 3; ++p) {
          const int i = fem_detail::kPairs[p][0], j = fem_detail::kPairs[p][1];
          kh(i, i) += resp.p[p] * ga[j] * gb[j];
          kh(j, j) += resp.p[p] * ga[i] * gb[i];
          kh(i, j) += resp.m[p] * ga[j] * gb[i];
          kh(j, i) += resp.m[p] * ga[i] * gb[j];
        }
        const Eigen::Matrix3d blk = c * (u * kh * u.transpose());
        addBlock(vals, o, a == b, blk);
      }
    }
  }
  return r;
}

void FemBody::Impl::evaluateGeneral(const Eigen::VectorXd& q, const Eigen::VectorXd* v, double h,
                                    double beta, Eigen::VectorXd* f_out, Sparse* target,
                                    double c_k, double c_m, bool use_rest_frame,
                                    int* inverted_at_q, bool keep_rotations) {
  if (f_out) f_out->setZero(3 * n);
  double* vals = target ? target->valuePtr() : nullptr;
  if (target) std::fill(vals, vals + target->nonZeros(), 0.0);
  const bool rotate = corotational && !use_rest_frame;
  const double* qd = q.data();
  const double* vd = v ? v->data() : nullptr;
  double* fd = f_out ? f_out->data() : nullptr;
  const int ne = mesh.tetCount();
  int inverted = 0;
  long polars = 0;
  if (dom_vol.empty()) {
    for (int slot = 0; slot < ne; ++slot) {
      const AssemblyElement& el = assembly_elems[slot];
      if (inverted_at_q) {
        Eigen::Matrix3d fq = Eigen::Matrix3d::Zero();
        for (int c = 0; c < 4; ++c)
          fq.noalias() += Eigen::Map<const Eigen::Vector3d>(qd + 3 * el.node[c]) *
                          el.g.col(c).transpose();
        if (!(fq.determinant() > 0.0)) ++inverted;
      }
      const int* off =
          block_offset.data() + static_cast<std::size_t>(slot) * kBlockOffsetsPerElement;
      const Eigen::Matrix3d r = domainKernel(4, el.node.data(), el.g.data(), el.vol, off, qd, vd,
                                             h, beta, fd, vals, c_k, rotate);
      if (rotate && keep_rotations) setSlotRotation(slot, r);
    }
    if (rotate) polars += ne;
    counters.general_domain_evaluations += ne;
  } else {
    const int nd = static_cast<int>(dom_vol.size());
    for (int d = 0; d < nd; ++d)
      domainKernel(dom_start[d + 1] - dom_start[d], dom_node.data() + dom_start[d],
                   dom_grad.data() + 3 * static_cast<std::size_t>(dom_start[d]), dom_vol[d],
                   dom_offset.data() + dom_offset_start[d], qd, vd, h, beta, fd, vals, c_k,
                   rotate);
    // the elements' own rotations (node rotations, the warped compliance) and inversions
    const bool keep = rotate && keep_rotations;
    if (keep || inverted_at_q) {
      for (int slot = 0; slot < ne; ++slot) {
        const int e = assembly_elems[static_cast<std::size_t>(slot)].index;
        const Eigen::Matrix3d fq = elementF(e, q);
        if (inverted_at_q && !(fq.determinant() > 0.0)) ++inverted;
        if (keep) {
          const Eigen::Matrix3d f = vd ? Eigen::Matrix3d(fq + h * elementF(e, *v)) : fq;
          setSlotRotation(slot, fem_detail::polarRotation(f));
        }
      }
    }
    if (rotate) polars += nd + (keep ? ne : 0);
    counters.general_domain_evaluations += nd;
  }
  if (inverted_at_q) *inverted_at_q = inverted;
  counters.rotation_extractions += polars;
  if (rotate && keep_rotations) {
    rotation_current = true;
    rotation_by_tet_stale = true;
    step_sums_current = false;
  }
  if (target && c_m != 0.0)
    for (int i = 0; i < n; ++i)
      if (dof_base[i] >= 0)
        for (int c = 0; c < 3; ++c) vals[diag_offset[dof_base[i] + c]] += c_m * mass[3 * i + c];
}

double FemBody::Impl::generalEnergy(const Eigen::VectorXd& x) const {
  auto density = [&](const Eigen::Matrix3d& f) {
    if (!corotational) {
      const Eigen::Matrix3d eps = 0.5 * (f + f.transpose()) - Eigen::Matrix3d::Identity();
      return mu * eps.squaredNorm() + 0.5 * lambda * eps.trace() * eps.trace();
    }
    Eigen::Matrix3d u, vf;
    Eigen::Vector3d s;
    fem_detail::rotationSvd(f, fem_detail::polarRotation(f), u, s, vf);
    return fem_detail::principalEnergy(material.law, lambda, mu, s);
  };
  double energy = 0.0;
  if (dom_vol.empty()) {
    for (int e = 0; e < mesh.tetCount(); ++e) energy += volume[e] * density(elementF(e, x));
    return energy;
  }
  for (std::size_t d = 0; d < dom_vol.size(); ++d) {
    Eigen::Matrix3d f = Eigen::Matrix3d::Zero();
    for (int s = dom_start[d]; s < dom_start[d + 1]; ++s)
      f.noalias() += x.segment<3>(3 * dom_node[s]) *
                     Eigen::Map<const Eigen::Vector3d>(dom_grad.data() + 3 * s).transpose();
    energy += dom_vol[d] * density(f);
  }
  return energy;
}

}  // namespace tactus::sim
