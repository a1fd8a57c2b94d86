#pragma once
// Generated contact problems for the NSGS tests and benchmarks (dense W, owning).
//
// spherePile: rigid multi-body problems, W = H M^-1 H^T. A contact couples only with the contacts
// of its two bodies, so W is block-sparse: 3 x 3 per layer (cols = 3) gives the small slowly
// converging piles of nsgs_stagnation_test; cols = 6 and 40-100 spheres give 240-600 contacts at 4-10 %
// non-zero blocks, the size and sparsity of FCLIB's larger multi-body problems.

#include <Eigen/Dense>

#include <cmath>
#include <random>
#include <vector>

#include "tactus/shared/nsgs.h"

namespace tactus::test {

/// Owning dense problem (W row-major, ld = rows).
struct DenseProblem {
  std::vector<int> row_offset{0};
  std::vector<double> W, q, mu;
  int rows() const { return row_offset.back(); }
  int contacts() const { return static_cast<int>(row_offset.size()) - 1; }
  shared::ContactProblemView view() const {
    return shared::denseProblemView(contacts(), rows(), row_offset.data(), W.data(), rows(),
                                    q.data(), mu.data());
  }
};

// A layered pile of n rigid spheres (radius 0.5, masses 0.5-2, cols x cols per layer, staggered)
// on a floor, contacts where centres are within 1.05 diameters: W = H M^-1 H^T (6 dof per
// sphere, solid-sphere inertia), q = H v_free (one 10 ms gravity step plus small lateral
// velocities), mu uniform in [0.2, mu_max]. Slowly converging, plateau-prone problems for
// Gauss-Seidel.
inline DenseProblem spherePile(int n, unsigned seed, double mu_max, int cols = 3) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.02, 0.02), mass_d(0.5, 2.0);
  std::uniform_real_distribution<double> mu_d(0.2, mu_max), vel_d(-0.05, 0.05);
  const double r = 0.5;
  std::vector<Eigen::Vector3d> x(n);
  std::vector<double> mass(n);
  for (int i = 0; i < n; ++i) {
    const int layer = i / (cols * cols), k = i % (cols * cols);
    const double off = layer % 2 != 0 ? 0.5 : 0.0;
    const double xi = (k % cols + off) * 2 * r + jitter(rng);
    const double yi = (k / cols + off) * 2 * r + jitter(rng);
    x[i] = Eigen::Vector3d(xi, yi, r + layer * 2 * r * 0.72);
    mass[i] = mass_d(rng);
  }
  struct Touch { int a, b; Eigen::Vector3d point, normal; };   // a = -1: the floor
  std::vector<Touch> touches;
  for (int i = 0; i < n; ++i) {
    if (x[i].z() < r * 1.01) touches.push_back({-1, i, {x[i].x(), x[i].y(), 0.0}, {0, 0, 1}});
  }
  for (int i = 0; i < n; ++i) {
    for (int j = i + 1; j < n; ++j) {
      const Eigen::Vector3d d = x[j] - x[i];
      if (d.norm() < 2 * r * 1.05) {
        touches.push_back({i, j, x[i] + r * d.normalized(), d.normalized()});
      }
    }
  }
  const int nc = static_cast<int>(touches.size()), m = 3 * nc, nd = 6 * n;
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m, nd);
  for (int c = 0; c < nc; ++c) {
    const Touch& t = touches[c];
    const Eigen::Vector3d& nrm = t.normal;
    const Eigen::Vector3d aux =
        std::abs(nrm.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    const Eigen::Vector3d t1 = nrm.cross(aux).normalized(), t2 = nrm.cross(t1);
    const Eigen::Vector3d frame[3] = {nrm, t1, t2};
    for (int side = 0; side < 2; ++side) {
      const int body = side == 0 ? t.a : t.b;
      if (body < 0) continue;
      const double sign = side == 0 ? -1.0 : 1.0;   // relative velocity of b with respect to a
      const Eigen::Vector3d arm = t.point - x[body];
      for (int k = 0; k < 3; ++k) {
        H.block<1, 3>(3 * c + k, 6 * body) += sign * frame[k].transpose();
        H.block<1, 3>(3 * c + k, 6 * body + 3) += sign * arm.cross(frame[k]).transpose();
      }
    }
  }
  Eigen::VectorXd minv(nd), vfree = Eigen::VectorXd::Zero(nd);
  for (int b = 0; b < n; ++b) {
    minv.segment<3>(6 * b).setConstant(1.0 / mass[b]);
    minv.segment<3>(6 * b + 3).setConstant(1.0 / (0.4 * mass[b] * r * r));
    vfree[6 * b + 2] = -9.81 * 0.01;
    vfree[6 * b] = vel_d(rng);
    vfree[6 * b + 1] = vel_d(rng);
  }
  const Eigen::MatrixXd W = H * minv.asDiagonal() * H.transpose();
  const Eigen::VectorXd q = H * vfree;
  DenseProblem p;
  for (int c = 0; c < nc; ++c) {
    p.row_offset.push_back(3 * (c + 1));
    p.mu.push_back(mu_d(rng));
  }
  p.W.resize(static_cast<std::size_t>(m) * m);
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j < m; ++j) p.W[static_cast<std::size_t>(i) * m + j] = W(i, j);
  }
  p.q.assign(q.data(), q.data() + m);
  return p;
}

}  // namespace tactus::test
