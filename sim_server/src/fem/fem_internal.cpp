#include "fem_internal.h"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <array>
#include <cstring>

#include <spdlog/spdlog.h>

#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"

namespace tactus::sim::fem_detail {

namespace {

// Rotation maximising tr(R^T F) from the unit quaternion q maximising q^T N q (Horn's symmetric
// 4x4 N; its largest eigenvalue is s1 + s2 + s3, the sum of F's singular values). The eigenvalue
// is the largest root of N's characteristic polynomial l^4 + c2 l^2 + c1 l + c0, found by Newton
// from sqrt(3) |F|_F (an upper bound; the quartic is convex and increasing above the root, so
// the iterates decrease monotonically); the eigenvector is the largest column of adj(N - l I).
// Returns false when the answer cannot be trusted (checked: R^T F must be symmetric).
bool quaternionPolar(const Eigen::Matrix3d& F, double scale, double det, Eigen::Matrix3d& R) {
  const double sxx = F(0, 0), sxy = F(0, 1), sxz = F(0, 2);
  const double syx = F(1, 0), syy = F(1, 1), syz = F(1, 2);
  const double szx = F(2, 0), szy = F(2, 1), szz = F(2, 2);
  Eigen::Matrix4d n;
  n << sxx + syy + szz, szy - syz, sxz - szx, syx - sxy,
       szy - syz, sxx - syy - szz, sxy + syx, szx + sxz,
       sxz - szx, sxy + syx, -sxx + syy - szz, syz + szy,
       syx - sxy, szx + sxz, syz + szy, -sxx - syy + szz;
  const double c2 = -2.0 * scale * scale;
  const double c1 = -8.0 * det;
  const double c0 = n.determinant();
  double l = std::sqrt(3.0) * scale;
  for (int it = 0; it < 50; ++it) {
    const double l2 = l * l;
    const double p = (l2 + c2) * l2 + c1 * l + c0;
    const double dp = (4.0 * l2 + 2.0 * c2) * l + c1;
    if (!(dp > 0.0)) return false;
    const double step = p / dp;
    l -= step;
    if (step <= 1e-12 * l) break;   // quadratic: what is left is below 1e-20 l
  }
  Eigen::Matrix4d a = n;
  a.diagonal().array() -= l;
  // A = N - l I has rank 3 and adj(A) = c v v^T (v the eigenvector): take the column j of adj(A)
  // whose diagonal cofactor (the principal minor without row and column j) is largest
  auto minor3 = [&a](int skip_row, int skip_col) {
    int r[3], c[3];
    for (int k = 0, i = 0; k < 4; ++k) if (k != skip_row) r[i++] = k;
    for (int k = 0, i = 0; k < 4; ++k) if (k != skip_col) c[i++] = k;
    return a(r[0], c[0]) * (a(r[1], c[1]) * a(r[2], c[2]) - a(r[1], c[2]) * a(r[2], c[1])) -
           a(r[0], c[1]) * (a(r[1], c[0]) * a(r[2], c[2]) - a(r[1], c[2]) * a(r[2], c[0])) +
           a(r[0], c[2]) * (a(r[1], c[0]) * a(r[2], c[1]) - a(r[1], c[1]) * a(r[2], c[0]));
  };
  int best = 0;
  double best_abs = std::abs(minor3(0, 0));
  for (int j = 1; j < 4; ++j) {
    const double m = std::abs(minor3(j, j));
    if (m > best_abs) {
      best = j;
      best_abs = m;
    }
  }
  Eigen::Vector4d col;
  for (int i = 0; i < 4; ++i) col[i] = ((i + best) % 2 == 0 ? 1.0 : -1.0) * minor3(best, i);
  const double len = col.norm();
  if (!(len > 0.0)) return false;
  const Eigen::Vector4d q = col / len;
  R = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).toRotationMatrix();
  // trust check: R^T F is the symmetric stretch
  const Eigen::Matrix3d s = R.transpose() * F;
  return (s - s.transpose()).norm() <= 1e-12 * scale;
}

}  // namespace

Eigen::Matrix3d polarRotation(const Eigen::Matrix3d& F) {
  const double scale = F.norm();
  const double det = F.determinant();
  if (scale > 0.0 && det > 1e-3 * scale * scale * scale) {
    Eigen::Matrix3d r;
    if (quaternionPolar(F, scale, det, r)) return r;
  }
  // fast path: scaled Newton iteration X <- (g X + X^-T / g) / 2 (Higham), converges
  // quadratically to the polar factor when det F > 0 and F is not near-singular
  if (scale > 0.0 && det > 1e-3 * scale * scale * scale) {
    Eigen::Matrix3d x = F;
    for (int it = 0; it < 30; ++it) {
      const Eigen::Matrix3d x_inv_t = x.inverse().transpose();
      double g = 1.0;
      if (it < 6) g = std::sqrt(std::sqrt(x_inv_t.squaredNorm() / x.squaredNorm()));
      const Eigen::Matrix3d next = 0.5 * (g * x + x_inv_t / g);
      const double change = (next - x).squaredNorm();
      x = next;
      if (change < 1e-26) return x;
    }
  }
  // robust path: SVD with sign correction on the smallest singular value's vector
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d u = svd.matrixU();
  const Eigen::Matrix3d& v = svd.matrixV();
  if ((u * v.transpose()).determinant() < 0.0) u.col(2) *= -1.0;  // singular values descend
  return u * v.transpose();
}

// ---- CHOLMOD ----

namespace {

// CHOLMOD (Debian's build) runs parts of the supernodal factorisation in OpenMP parallel regions
// of up to 4 threads, and its BLAS may be the multi-threaded OpenBLAS. On our 2-core machine,
// where the haptic loop owns one core, those threads only contend (measured: liver2
// factorisation 5 ms -> 2.8 ms serial; a pthread OpenBLAS worker spinning in sched_yield cost
// sim_server 116 % CPU). See limitNumericThreads in fem.h.
NumericThreads applyNumericThreadLimitImpl() {
  using SetLevels = void (*)(int);
  if (auto* fn = reinterpret_cast<SetLevels>(dlsym(RTLD_DEFAULT, "omp_set_max_active_levels")))
    fn(0);
  using SetThreads = void (*)(int);
  if (auto* fn = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads")))
    fn(1);
  const NumericThreads now = queryNumericThreads();
  spdlog::info("numeric threads: BLAS {} ({}), OpenMP max active levels {}", now.blas_threads,
               now.blas_config.empty() ? "no OpenBLAS" : now.blas_config,
               now.omp_max_active_levels);
  return now;
}

}  // namespace

// ---- node order ----

std::vector<int> bandwidthOrder(const TetMesh& mesh, const std::vector<bool>& skip) {
  const int n = mesh.nodeCount();
  // node adjacency (CSR) over the edges of the elements, both directions, without skipped nodes
  std::vector<std::pair<int, int>> edges;
  edges.reserve(mesh.tets.size() * 12);
  for (const auto& t : mesh.tets)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) {
        if (a == b || t[a] < 0 || t[a] >= n || t[b] < 0 || t[b] >= n) continue;
        if (skip[t[a]] || skip[t[b]]) continue;
        edges.emplace_back(t[a], t[b]);
      }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  std::vector<int> start(n + 1, 0), adj(edges.size());
  for (const auto& e : edges) ++start[e.first + 1];
  for (int i = 0; i < n; ++i) start[i + 1] += start[i];
  for (std::size_t k = 0; k < edges.size(); ++k) adj[k] = edges[k].second;
  auto degree = [&](int i) { return start[i + 1] - start[i]; };
  std::vector<int> by_degree;
  for (int i = 0; i < n; ++i)
    if (!skip[i]) by_degree.push_back(i);
  std::stable_sort(by_degree.begin(), by_degree.end(),
                   [&](int x, int y) { return degree(x) < degree(y); });
  std::vector<int> order;
  order.reserve(by_degree.size());
  std::vector<char> seen(n, 0);
  std::vector<int> next;
  for (int root : by_degree) {
    if (seen[root]) continue;
    seen[root] = 1;
    std::size_t head = order.size();
    order.push_back(root);
    while (head < order.size()) {
      const int i = order[head++];
      next.assign(adj.begin() + start[i], adj.begin() + start[i + 1]);
      std::stable_sort(next.begin(), next.end(),
                       [&](int x, int y) { return degree(x) < degree(y); });
      for (int j : next)
        if (!seen[j]) {
          seen[j] = 1;
          order.push_back(j);
        }
    }
  }
  std::reverse(order.begin(), order.end());
  return order;
}

// ---- boundary ----

std::vector<int> boundaryNodes(const TetMesh& mesh) {
  struct Face {
    std::array<int, 3> key;
    bool operator<(const Face& o) const { return key < o.key; }
    bool operator==(const Face& o) const { return key == o.key; }
  };
  static constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  std::vector<Face> faces;
  faces.reserve(mesh.tets.size() * 4);
  for (const auto& t : mesh.tets)
    for (const auto& f : kFaces) {
      Face face{{t[f[0]], t[f[1]], t[f[2]]}};
      std::sort(face.key.begin(), face.key.end());
      faces.push_back(face);
    }
  std::sort(faces.begin(), faces.end());
  std::vector<int> nodes;
  for (std::size_t i = 0; i < faces.size();) {
    std::size_t j = i + 1;
    while (j < faces.size() && faces[j] == faces[i]) ++j;
    if (j - i == 1) nodes.insert(nodes.end(), faces[i].key.begin(), faces[i].key.end());
    i = j;
  }
  std::sort(nodes.begin(), nodes.end());
  nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
  return nodes;
}

std::uint64_t fnv1a(const void* data, std::size_t bytes, std::uint64_t seed) {
  const auto* p = static_cast<const unsigned char*>(data);
  std::uint64_t h = seed;
  for (std::size_t i = 0; i < bytes; ++i) {
    h ^= p[i];
    h *= 0x100000001b3ull;
  }
  return h;
}

}  // namespace tactus::sim::fem_detail

namespace tactus::sim {

NumericThreads queryNumericThreads() {
  NumericThreads out;
  using GetThreads = int (*)();
  using GetConfig = char* (*)();
  if (auto* fn = reinterpret_cast<GetThreads>(dlsym(RTLD_DEFAULT, "openblas_get_num_threads")))
    out.blas_threads = fn();
  if (auto* fn = reinterpret_cast<GetConfig>(dlsym(RTLD_DEFAULT, "openblas_get_config"))) {
    if (const char* c = fn()) out.blas_config = c;
  }
  using GetLevels = int (*)();
  if (auto* fn = reinterpret_cast<GetLevels>(dlsym(RTLD_DEFAULT, "omp_get_max_active_levels")))
    out.omp_max_active_levels = fn();
  return out;
}

NumericThreads limitNumericThreads() {
  static const NumericThreads applied = fem_detail::applyNumericThreadLimitImpl();
  return applied;
}

}  // namespace tactus::sim
