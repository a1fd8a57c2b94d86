// FemBody: setup (element data, lumped mass, rotation groups), the free-motion and static steps
// and the public API; the linear solves are in fem_solve.cpp, the element loop in fem_assembly.cpp.
#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>
#include <string>

#include <spdlog/spdlog.h>

#include "fem_body_impl.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"

namespace tactus::sim {


namespace {

// An edge shorter than this fraction of its element's longest edge ties its two nodes into one
// rotation group (see FemBody::nodeRotations).
constexpr double kShortEdgeRatio = 0.05;

int findRoot(std::vector<int>& parent, int i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

}  // namespace


void FemBody::Impl::init(const TetMesh& m, const FemMaterial& mat,
                         const std::vector<int>& fixed_nodes, const Eigen::Vector3d* g,
                         const FemSolverOptions& opt) {
  mesh = m;
  material = mat;
  options = opt;
  if (opt.background_refactor_lag_steps < 0)
    throw Error("FemBody: background_refactor_lag_steps must be >= 0");
  if (opt.background_refactor_free_lag_steps < 0)
    throw Error("FemBody: background_refactor_free_lag_steps must be >= 0");
  if (!(opt.pcg_local_correction_threshold >= 0.0) ||
      !std::isfinite(opt.pcg_local_correction_threshold) ||
      opt.pcg_local_correction_max_nodes < 0 || opt.pcg_local_correction_max_nodes > 1000)
    throw Error("FemBody: pcg_local_correction_threshold must be finite and >= 0, "
                "pcg_local_correction_max_nodes in [0, 1000]");
  reuse = fem_detail::ReusedFactorSolver({opt.cg_tolerance, opt.refactor_iterations,
                                          opt.refactor_every_steps,
                                          opt.background_refactor_lag_steps,
                                          opt.background_refactor_when_ready,
                                          opt.background_refactor_free_lag_steps,
                                          opt.pcg_local_correction_threshold,
                                          opt.pcg_local_correction_max_nodes});
  if (opt.linear == LinearSolverKind::kCholmodReuse && opt.background_refactor_lag_steps > 0) {
    // the worker runs BLAS (CHOLMOD's supernodal factorisation) while the steps go on: the
    // step's own solves make no BLAS call (CholmodSolver::setBlasFreeSolves, linear_solver.h),
    // so none waits for the worker, whichever step takes its factor
    background = std::make_unique<fem_detail::BackgroundFactoriser>();
    reuse.setBackground(background.get());
    chol.setBlasFreeSolves(true);
    chol_rest.setBlasFreeSolves(true);
    // PCG's preconditioner solves in float or half on a copy the worker makes
    // (linear_solver.h); the compliance's and the direct solves stay in double
    switch (opt.preconditioner_precision) {
      case PreconditionerPrecision::kDouble:
        break;
      case PreconditionerPrecision::kFloat:
        chol.setSinglePrecisionPreconditioner(true);
        break;
      case PreconditionerPrecision::kHalf:
        if (fem_detail::halfSweepsPayOff()) {
          chol.setHalfPrecisionPreconditioner(true);
          break;
        }
        chol.setSinglePrecisionPreconditioner(true);
        static std::once_flag logged;
        std::call_once(logged, [] {
          spdlog::info("solver.preconditioner_precision half: this CPU has neither F16C nor "
                       "AVX-512F, whose conversions make the half sweeps faster than the float "
                       "ones; PCG's preconditioner uses the float copy instead");
        });
        break;
    }
  }
  corotational = mat.law != MaterialLaw::kLinear;
  rotation_stiffness =
      mat.law == MaterialLaw::kCorotational && mat.tangent == TangentKind::kConsistent;
  general_loop = rotation_stiffness || mat.law == MaterialLaw::kInvertibleNeoHookean ||
                 mat.element == ElementKind::kEdgeSmoothedTet;
  n = mesh.nodeCount();
  const std::string where = "FemBody(" + (mesh.source.empty() ? "mesh" : mesh.source) + "): ";
  if (n == 0 || mesh.tets.empty()) throw Error(where + "mesh has no nodes or no tetrahedra");
  if (!(mat.young_pa > 0.0)) throw Error(where + "young_pa must be > 0");
  if (!(mat.poisson > -1.0 && mat.poisson < 0.5))
    throw Error(where + "poisson must be in (-1, 0.5)");
  if (!(mat.density_kgpm3 > 0.0)) throw Error(where + "density_kgpm3 must be > 0");
  if (mat.damping && (mat.damping->mass_alpha_per_s < 0.0 || mat.damping->stiffness_beta_s < 0.0))
    throw Error(where + "Rayleigh coefficients must be >= 0");
  lambda = mat.young_pa * mat.poisson / ((1.0 + mat.poisson) * (1.0 - 2.0 * mat.poisson));
  mu = mat.young_pa / (2.0 * (1.0 + mat.poisson));
  if (g) {
    has_gravity = true;
    gravity = *g;
  }

  fixed.assign(n, false);
  for (int i : fixed_nodes) {
    if (i < 0 || i >= n)
      throw Error(where + "fixed node " + std::to_string(i) + " out of range [0, " +
                  std::to_string(n) + ")");
    fixed[i] = true;
  }
  // reduced DOFs in reverse Cuthill-McKee order of the free nodes: the element loop's scatter
  // into A and the products with A touch nearby memory (CHOLMOD orders the factor itself)
  dof_base.assign(n, -1);
  for (int i : fem_detail::bandwidthOrder(mesh, fixed)) {
    dof_base[i] = n_free;
    n_free += 3;
  }
  if (n_free == 0) throw Error(where + "every node is fixed");

  rest.resize(3 * n);
  for (int i = 0; i < n; ++i) rest.segment<3>(3 * i) = mesh.nodes.col(i);
  q = rest;
  v = Eigen::VectorXd::Zero(3 * n);
  mass = Eigen::VectorXd::Zero(3 * n);

  // element gradients, volumes and lumped mass
  const int ne = mesh.tetCount();
  grad.resize(ne);
  volume.resize(ne);
  for (int e = 0; e < ne; ++e) {
    const auto& t = mesh.tets[e];
    for (int k = 0; k < 4; ++k)
      if (t[k] < 0 || t[k] >= n)
        throw Error(where + "tet " + std::to_string(e) + " refers to node " +
                    std::to_string(t[k]) + " out of range");
    Eigen::Matrix3d dm;
    dm << rest.segment<3>(3 * t[1]) - rest.segment<3>(3 * t[0]),
        rest.segment<3>(3 * t[2]) - rest.segment<3>(3 * t[0]),
        rest.segment<3>(3 * t[3]) - rest.segment<3>(3 * t[0]);
    const double det = dm.determinant();
    const double edge = dm.colwise().norm().mean();
    if (!(std::abs(det) > 1e-12 * edge * edge * edge))
      throw NumericalError(where + "tet " + std::to_string(e) +
                           " is degenerate (zero volume): fix the mesh");
    const Eigen::Matrix3d dm_inv = dm.inverse();
    // gradient of the shape functions: rows of Dm^-1 for nodes 1..3, minus their sum for node 0
    grad[e].block<3, 3>(0, 1) = dm_inv.transpose();
    grad[e].col(0) = -grad[e].block<3, 3>(0, 1).rowwise().sum();
    volume[e] = std::abs(det) / 6.0;
    const double m4 = material.density_kgpm3 * volume[e] / 4.0;
    for (int k = 0; k < 4; ++k) mass.segment<3>(3 * t[k]).array() += m4;
  }

  if (mat.element == ElementKind::kEdgeSmoothedTet) buildEdgeDomains();
  buildPattern();
  buildRotationGroups();
  buildSmoothingRows();
  f_int.resize(3 * n);
  rhs_full.resize(3 * n);
  rhs.resize(n_free);
  dv = Eigen::VectorXd::Zero(n_free);
  dv_prev = Eigen::VectorXd::Zero(n_free);
  dv_prev2 = Eigen::VectorXd::Zero(n_free);

  // hash of what the rest compliance depends on (h excluded)
  using fem_detail::fnv1a;
  std::uint64_t hsh = fnv1a(rest.data(), sizeof(double) * rest.size());
  hsh = fnv1a(mesh.tets.data(), sizeof(int) * 4 * mesh.tets.size(), hsh);
  const double mat_vals[6] = {
      static_cast<double>(corotational), mat.young_pa, mat.poisson, mat.density_kgpm3,
      mat.damping ? mat.damping->mass_alpha_per_s : -1.0,
      mat.damping ? mat.damping->stiffness_beta_s : -1.0};
  hsh = fnv1a(mat_vals, sizeof(mat_vals), hsh);
  std::vector<int> fixed_sorted;
  for (int i = 0; i < n; ++i)
    if (fixed[i]) fixed_sorted.push_back(i);
  hsh = fnv1a(fixed_sorted.data(), sizeof(int) * fixed_sorted.size(), hsh);
  // the smoothed strain changes the rest stiffness (the law and its tangent do not: every law
  // linearises to the same K0 at rest); linear tets keep the hash they always had
  if (mat.element == ElementKind::kEdgeSmoothedTet) {
    const char tag[] = "edge_smoothed_tet";
    hsh = fnv1a(tag, sizeof(tag) - 1, hsh);
  }
  hash = hsh;
}

void FemBody::Impl::buildSmoothingRows() {
  // (i, j) once per tet holding both, sorted: the runs are the counts
  std::vector<std::pair<int, int>> pairs;
  pairs.reserve(16 * mesh.tets.size());
  for (const auto& t : mesh.tets)
    for (int a : t)
      for (int b : t) pairs.emplace_back(a, b);
  std::sort(pairs.begin(), pairs.end());
  smooth_ptr.assign(static_cast<std::size_t>(n) + 1, 0);
  smooth_node.clear();
  smooth_count.clear();
  for (std::size_t k = 0; k < pairs.size();) {
    std::size_t end = k;
    while (end < pairs.size() && pairs[end] == pairs[k]) ++end;
    smooth_node.push_back(pairs[k].second);
    smooth_count.push_back(static_cast<double>(end - k));
    ++smooth_ptr[static_cast<std::size_t>(pairs[k].first) + 1];
    k = end;
  }
  for (int i = 0; i < n; ++i) smooth_ptr[i + 1] += smooth_ptr[i];
}

void FemBody::Impl::buildRotationGroups() {
  static constexpr int kEdges[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
  std::vector<int> parent(n);
  for (int i = 0; i < n; ++i) parent[i] = i;
  bool any = false;
  for (const auto& t : mesh.tets) {
    double len[6];
    double longest = 0.0;
    for (int k = 0; k < 6; ++k) {
      len[k] = (rest.segment<3>(3 * t[kEdges[k][0]]) - rest.segment<3>(3 * t[kEdges[k][1]])).norm();
      longest = std::max(longest, len[k]);
    }
    for (int k = 0; k < 6; ++k) {
      if (len[k] >= kShortEdgeRatio * longest) continue;
      const int a = findRoot(parent, t[kEdges[k][0]]), b = findRoot(parent, t[kEdges[k][1]]);
      if (a != b) {
        parent[std::max(a, b)] = std::min(a, b);
        any = true;
      }
    }
  }
  rot_group.clear();
  rot_group_count = 0;
  if (!any) return;
  rot_group.assign(n, -1);
  std::vector<int> index(n, -1);
  for (int i = 0; i < n; ++i) {
    const int root = findRoot(parent, i);
    if (index[root] < 0) index[root] = rot_group_count++;
    rot_group[i] = index[root];
  }
  std::vector<int> size(rot_group_count, 0);
  for (int g : rot_group) ++size[g];
  int tied = 0, groups = 0;
  for (int c : size)
    if (c > 1) {
      tied += c;
      ++groups;
    }
  spdlog::info("FemBody({}): {} nodes tied into {} rotation groups by edges shorter than {} of "
               "their element's longest edge",
               mesh.source.empty() ? "mesh" : mesh.source, tied, groups, kShortEdgeRatio);
}

void FemBody::Impl::sumNodeRotations(const std::vector<Eigen::Matrix3d>* element_rot,
                                     std::vector<Eigen::Matrix3d>& acc, std::vector<double>& w) {
  acc.assign(n, Eigen::Matrix3d::Zero());
  w.assign(static_cast<std::size_t>(n), 0.0);
  if (element_rot != nullptr) {
    for (int e = 0; e < mesh.tetCount(); ++e) {
      for (int k = 0; k < 4; ++k) {
        acc[mesh.tets[e][k]] += volume[e] * (*element_rot)[e];
        w[mesh.tets[e][k]] += volume[e];
      }
    }
  } else {
    // the kept rotations, in assembly order
    for (std::size_t slot = 0; slot < assembly_elems.size(); ++slot) {
      const AssemblyElement& el = assembly_elems[slot];
      const Eigen::Matrix3d vr = el.vol * slotRotation(static_cast<int>(slot));
      for (int k = 0; k < 4; ++k) {
        acc[el.node[k]] += vr;
        w[el.node[k]] += el.vol;
      }
    }
  }
  sumRotationGroups(acc, w);
}

void FemBody::Impl::sumNodeGradients(const Eigen::VectorXd& x, std::vector<Eigen::Matrix3d>& acc,
                                     std::vector<double>& w) {
  acc.assign(n, Eigen::Matrix3d::Zero());
  w.assign(static_cast<std::size_t>(n), 0.0);
  for (int e = 0; e < mesh.tetCount(); ++e) {
    const Eigen::Matrix3d vf = volume[e] * elementF(e, x);
    for (int k = 0; k < 4; ++k) {
      acc[mesh.tets[e][k]] += vf;
      w[mesh.tets[e][k]] += volume[e];
    }
  }
  sumRotationGroups(acc, w);
}

void FemBody::Impl::sumRotationGroups(std::vector<Eigen::Matrix3d>& acc, std::vector<double>& w) {
  if (!rot_group.empty()) {
    // every member of a group gets the group's sum
    group_acc.assign(rot_group_count, Eigen::Matrix3d::Zero());
    group_w.assign(static_cast<std::size_t>(rot_group_count), 0.0);
    for (int i = 0; i < n; ++i) {
      group_acc[rot_group[i]] += acc[i];
      group_w[rot_group[i]] += w[i];
    }
    for (int i = 0; i < n; ++i) {
      acc[i] = group_acc[rot_group[i]];
      w[i] = group_w[rot_group[i]];
    }
  }
}

void FemBody::Impl::finishNodeRotations(std::vector<Eigen::Matrix3d>& acc, std::vector<double>& w,
                                        std::vector<Eigen::Matrix3d>& out, int smoothing_passes) {
  // smoothing: each pass gives every node the sum over its elements of their nodes' sums (one
  // element layer wider on each side), as sum_j c_ij acc_j over the node's row of
  // buildSmoothingRows (half the memory traffic of a pass through the tets and back);
  // rotations and weights alike, rescaled to the largest weight so that repeated passes cannot
  // overflow (the polar factor ignores the scale)
  if (smoothing_passes > 0) {
    smooth_acc.resize(static_cast<std::size_t>(n));
    smooth_w.resize(static_cast<std::size_t>(n));
    for (int pass = 0; pass < smoothing_passes; ++pass) {
      for (int i = 0; i < n; ++i) {
        Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
        double sum_w = 0.0;
        for (int p = smooth_ptr[i]; p < smooth_ptr[i + 1]; ++p) {
          sum += smooth_count[p] * acc[smooth_node[p]];
          sum_w += smooth_count[p] * w[smooth_node[p]];
        }
        smooth_acc[i] = sum;
        smooth_w[i] = sum_w;
      }
      const double largest = *std::max_element(smooth_w.begin(), smooth_w.end());
      const double divisor = largest > 0.0 ? largest : 1.0;
      for (int i = 0; i < n; ++i) {
        acc[i] = smooth_acc[i] / divisor;
        w[i] = smooth_w[i] / divisor;
      }
    }
  }
  out.resize(n);
  for (int i = 0; i < n; ++i)
    out[i] = acc[i].squaredNorm() > 0.0 ? fem_detail::polarRotation(acc[i])
                                        : Eigen::Matrix3d::Identity();
}

void FemBody::Impl::ensureStepNodeSums() {
  if (step_sums_current) return;
  sumNodeRotations(nullptr, step_acc, step_w);
  step_sums_current = true;
}

// ---- FemBody ----

FemBody::FemBody(const TetMesh& mesh, const FemMaterial& material,
                 const std::vector<int>& fixed_nodes, const Eigen::Vector3d* gravity_mps2,
                 const FemSolverOptions& options)
    : impl_(std::make_unique<Impl>()) {
  impl_->init(mesh, material, fixed_nodes, gravity_mps2, options);
  // symbolic analysis once, on the fixed pattern
  if (options.linear != LinearSolverKind::kPcg) impl_->chol.analyze(impl_->a);
}

FemBody::~FemBody() = default;

const TetMesh& FemBody::mesh() const { return impl_->mesh; }
int FemBody::nodeCount() const { return impl_->n; }
int FemBody::dofCount() const { return 3 * impl_->n; }
int FemBody::freeDofCount() const { return impl_->n_free; }
const std::vector<bool>& FemBody::fixedMask() const { return impl_->fixed; }
const Eigen::VectorXd& FemBody::restPositions() const { return impl_->rest; }
Eigen::VectorXd& FemBody::positions() { return impl_->q; }
Eigen::VectorXd& FemBody::velocities() { return impl_->v; }
const Eigen::VectorXd& FemBody::positions() const { return impl_->q; }
const Eigen::VectorXd& FemBody::velocities() const { return impl_->v; }
const Eigen::VectorXd& FemBody::lumpedMass() const { return impl_->mass; }
const std::vector<Eigen::Matrix3d>& FemBody::elementRotations() const {
  Impl& m = *impl_;
  if (m.rotation_by_tet_stale) {
    m.rotation_by_tet.assign(static_cast<std::size_t>(m.mesh.tetCount()),
                             Eigen::Matrix3d::Identity());
    if (m.corotational)
      for (std::size_t slot = 0; slot < m.assembly_elems.size(); ++slot)
        m.rotation_by_tet[static_cast<std::size_t>(m.assembly_elems[slot].index)] =
            m.slotRotation(static_cast<int>(slot));
    m.rotation_by_tet_stale = false;
  }
  return m.rotation_by_tet;
}
const FemBody::Counters& FemBody::counters() const { return impl_->counters; }
double FemBody::lastStepH() const { return impl_->last_h; }
std::uint64_t FemBody::restHash() const { return impl_->hash; }
std::size_t FemBody::factorNonzeros() const { return impl_->chol.factorNonzeros(); }

bool FemBody::backgroundFactorisationInFlight() const {
  return impl_->background != nullptr && impl_->background->busy();
}

const std::vector<int>& FemBody::surfaceNodes() const {
  if (!impl_->surface_ready) {
    impl_->surface = fem_detail::boundaryNodes(impl_->mesh);
    impl_->surface_ready = true;
  }
  return impl_->surface;
}

FemStepStats FemBody::freeMotion(double h, const Eigen::VectorXd* external_force_n) {
  Impl& m = *impl_;
  FemStepStats stats;
  if (!(h > 0.0)) throw Error("FemBody::freeMotion: time step must be > 0");
  const std::int64_t t0 = shared::monotonicNs();
  m.keepRestFactorResident();
  m.after_contact = m.compliance_solved;
  m.compliance_solved = false;
  const bool damped = m.material.damping.has_value();
  const double alpha = damped ? m.material.damping->mass_alpha_per_s : 0.0;
  const double beta = damped ? m.material.damping->stiffness_beta_s : 0.0;
  // linearise at q + h v: internal force, tangent, and K v for the damping force
  m.evaluate(m.q, &m.v, h, beta, &m.f_int, &m.a, h + beta, 1.0 / h + alpha, false,
             &stats.inverted_elements, true);
  if (stats.inverted_elements > 0 && !m.inversion_warned) {
    m.inversion_warned = true;
    spdlog::warn("{}: {} of {} tetrahedra inverted (det F <= 0); the corotational force pushes "
                 "them back. If the count stays up (stats inverted_elements, VTU cell field "
                 "volume_ratio), the mesh or the material cannot carry the load. Logged once.",
                 m.mesh.source, stats.inverted_elements, m.mesh.tetCount());
  }
  m.chol_current = false;
  m.a_is_step_matrix = true;
  m.compliance_scale = h;
  // p - F(q + h v, v) with F = f_int + B v
  m.rhs_full = -m.f_int;
  if (external_force_n) m.rhs_full += *external_force_n;
  if (m.has_gravity)
    for (int i = 0; i < m.n; ++i) m.rhs_full.segment<3>(3 * i) += m.mass[3 * i] * m.gravity;
  if (damped) {
    m.rhs_full -= alpha * m.mass.cwiseProduct(m.v);  // beta K v is in f_int
    ++m.counters.damping_evaluations;
  }
  m.reduce(m.rhs_full, m.rhs.data());
  stats.assembly_s = shared::secondsSinceNs(t0);

  if (!m.solveStep(h, stats)) {
    stats.ok = false;
    return stats;
  }
  m.dv_prev2 = m.dv_prev;
  m.dv_prev = m.dv;
  // v_free = v + dv, q_free = q + h v_free (free DOFs only)
  for (int i = 0; i < m.n; ++i) {
    const int d = m.dof_base[i];
    if (d < 0) continue;
    m.v.segment<3>(3 * i) += m.dv.segment<3>(d);
    m.q.segment<3>(3 * i) += h * m.v.segment<3>(3 * i);
  }
  m.last_h = h;
  return stats;
}

FemStepStats FemBody::solveStatic(const Eigen::VectorXd* external_force_n, int max_iterations,
                                  double tol_n) {
  Impl& m = *impl_;
  FemStepStats stats;
  m.v.setZero();
  if (!m.chol.analyzed()) m.chol.analyze(m.a);
  for (int it = 0; it < max_iterations; ++it) {
    const std::int64_t t0 = shared::monotonicNs();
    m.evaluate(m.q, nullptr, 0.0, 0.0, &m.f_int, &m.a, 1.0, 0.0, false, nullptr, true);
    m.rotation_current = false;   // not a step's linearisation point
    m.chol_current = false;
    m.a_is_step_matrix = false;
    m.reuse.forget();  // chol will hold K, not a step's A
    m.compliance_scale = 1.0;
    m.rhs_full = -m.f_int;
    if (external_force_n) m.rhs_full += *external_force_n;
    if (m.has_gravity)
      for (int i = 0; i < m.n; ++i) m.rhs_full.segment<3>(3 * i) += m.mass[3 * i] * m.gravity;
    m.reduce(m.rhs_full, m.rhs.data());
    stats.assembly_s = shared::secondsSinceNs(t0);
    if (m.rhs.norm() <= tol_n) break;
    if (!m.factorizeAndSolve(stats)) {
      stats.ok = false;
      return stats;
    }
    for (int i = 0; i < m.n; ++i)
      if (m.dof_base[i] >= 0) m.q.segment<3>(3 * i) += m.dv.segment<3>(m.dof_base[i]);
    if (!m.corotational) break;  // linear: one Newton step is exact
  }
  return stats;
}

void FemBody::elasticForce(const Eigen::VectorXd& q, Eigen::VectorXd& force_out) {
  impl_->evaluate(q, nullptr, 0.0, 0.0, &force_out, nullptr, 0.0, 0.0, false);
  force_out = -force_out;
}

void FemBody::solveCompliance(const Eigen::VectorXd& r, Eigen::VectorXd& x) const {
  Impl& m = *impl_;
  m.ensureCurrentFactor();
  Eigen::VectorXd rr(m.n_free), xr(m.n_free);
  m.reduce(r, rr.data());
  m.chol.solve(rr.data(), xr.data(), 1);
  m.compliance_solved = true;
  x.resize(3 * m.n);
  m.expand(xr.data(), m.compliance_scale, x.data());
}

void FemBody::solveComplianceBatch(const Eigen::MatrixXd& r, Eigen::MatrixXd& x) const {
  Impl& m = *impl_;
  m.ensureCurrentFactor();
  const int k = static_cast<int>(r.cols());
  Eigen::MatrixXd rr(m.n_free, k);
  for (int c = 0; c < k; ++c) m.reduce(r.col(c), rr.col(c).data());
  m.chol.solve(rr.data(), rr.data(), k);
  m.compliance_solved = true;
  x.resize(3 * m.n, k);
  for (int c = 0; c < k; ++c) m.expand(rr.col(c).data(), m.compliance_scale, x.col(c).data());
}

void FemBody::solveRestCompliance(double h, const Eigen::VectorXd& r, Eigen::VectorXd& x) {
  Impl& m = *impl_;
  m.ensureRestFactor(h);
  // (the buffers, written when the rest factor was made: no fresh page at the first contact)
  Eigen::VectorXd &rr = m.rest_rhs, &xr = m.rest_x;
  rr.resize(m.n_free);
  xr.resize(m.n_free);
  m.reduce(r, rr.data());
  m.chol_rest.solve(rr.data(), xr.data(), 1);
  m.rest_solved = true;
  m.compliance_solved = true;
  x.resize(3 * m.n);
  m.expand(xr.data(), h, x.data());
}

void FemBody::prepareRestCompliance(double h) { impl_->ensureRestFactor(h); }

void FemBody::prepareFreeMotion(double h) {
  if (!(h > 0.0)) throw Error("FemBody::prepareFreeMotion: time step must be > 0");
  impl_->prepareFreeMotion(h);
}

void FemBody::solveRestComplianceBatch(double h, const Eigen::MatrixXd& r, Eigen::MatrixXd& x) {
  Impl& m = *impl_;
  m.ensureRestFactor(h);
  const int k = static_cast<int>(r.cols());
  Eigen::MatrixXd rr(m.n_free, k);
  for (int c = 0; c < k; ++c) m.reduce(r.col(c), rr.col(c).data());
  m.chol_rest.solveWithBlas(rr.data(), rr.data(), k);
  m.rest_solved = true;
  x.resize(3 * m.n, k);
  for (int c = 0; c < k; ++c) m.expand(rr.col(c).data(), h, x.col(c).data());
}

}  // namespace tactus::sim
