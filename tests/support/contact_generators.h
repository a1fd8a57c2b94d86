#pragma once
// More generated contact problems for the NSGS relaxation-rule tests and bench (see
// sphere_pile.h for DenseProblem and the sphere piles).
//
// capsulePile: a log pile of rigid capsules (crossed layers), W = H M^-1 H^T: two contacts per
// capsule on the floor, one per crossing, so the lower layers carry redundant support.
// redundantPatch: a tissue-like patch whose contacts fall on few surface nodes (several contacts
// per node, each with its own tangent frame), W = H C H^T of rank 3 x nodes, mu up to mu_max,
// pressed and dragged by a tool: the redundant frictional rows plain Gauss-Seidel can cycle on
// (the padded liver grasp has rank 31-43 for 204-432 rows).

#include <Eigen/Dense>

#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include "sphere_pile.h"

namespace tactus::test {

namespace detail {

/// Fills p (W, q, mu, row_offset) from the contact Jacobian, M^-1 and the free velocity.
inline DenseProblem fromJacobian(const Eigen::MatrixXd& H, const Eigen::MatrixXd& minv,
                                 const Eigen::VectorXd& vfree, const std::vector<double>& mu) {
  const Eigen::MatrixXd W = H * minv * H.transpose();
  const Eigen::VectorXd q = H * vfree;
  const int m = static_cast<int>(H.rows());
  DenseProblem p;
  for (int c = 0; c < m / 3; ++c) p.row_offset.push_back(3 * (c + 1));
  p.mu = mu;
  p.W.resize(static_cast<std::size_t>(m) * m);
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j < m; ++j) p.W[static_cast<std::size_t>(i) * m + j] = W(i, j);
  }
  p.q.assign(q.data(), q.data() + m);
  return p;
}

/// Tangent frame (n, t1, t2) of a unit normal.
inline void frameOf(const Eigen::Vector3d& n, Eigen::Vector3d frame[3]) {
  const Eigen::Vector3d aux =
      std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  frame[0] = n;
  frame[1] = n.cross(aux).normalized();
  frame[2] = n.cross(frame[1]);
}

}  // namespace detail

// `layers` crossed layers of `per_layer` capsules (radius 0.25, length 2 between the cap
// centres, masses 0.5-2, small jitter) on a floor. One 10 ms gravity step plus small lateral
// velocities, mu uniform in [0.2, mu_max].
inline DenseProblem capsulePile(int layers, int per_layer, unsigned seed, double mu_max) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.03, 0.03), mass_d(0.5, 2.0);
  std::uniform_real_distribution<double> mu_d(0.2, mu_max), vel_d(-0.05, 0.05);
  const double r = 0.25, half = 1.0, spacing = 2.0 * half / per_layer;
  struct Body { Eigen::Vector3d x, axis; double mass; };
  std::vector<Body> bodies;
  for (int l = 0; l < layers; ++l) {
    const Eigen::Vector3d axis = l % 2 == 0 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    const Eigen::Vector3d across = l % 2 == 0 ? Eigen::Vector3d::UnitY() : Eigen::Vector3d::UnitX();
    for (int k = 0; k < per_layer; ++k) {
      const double s = -half + spacing * (k + 0.5) + jitter(rng);
      bodies.push_back({across * s + Eigen::Vector3d(0, 0, r + 2 * r * l), axis, mass_d(rng)});
    }
  }
  struct Touch { int a, b; Eigen::Vector3d point, normal; };   // a = -1: the floor
  std::vector<Touch> touches;
  const int n = static_cast<int>(bodies.size());
  for (int i = 0; i < per_layer; ++i) {   // bottom layer: both caps on the floor
    for (const double end : {-half, half}) {
      const Eigen::Vector3d c = bodies[i].x + end * bodies[i].axis;
      touches.push_back({-1, i, {c.x(), c.y(), 0.0}, {0, 0, 1}});
    }
  }
  for (int l = 1; l < layers; ++l) {   // crossings with the layer below
    for (int a = (l - 1) * per_layer; a < l * per_layer; ++a) {
      for (int b = l * per_layer; b < (l + 1) * per_layer; ++b) {
        // crossing point: a's axis coordinate of b's line and vice versa
        const Body& ba = bodies[a];
        const Body& bb = bodies[b];
        const Eigen::Vector3d pa = ba.x + ba.axis * ba.axis.dot(bb.x - ba.x);
        const Eigen::Vector3d pb = bb.x + bb.axis * bb.axis.dot(ba.x - bb.x);
        touches.push_back({a, b, 0.5 * (pa + pb), (pb - pa).normalized()});
      }
    }
  }
  const int nc = static_cast<int>(touches.size()), nd = 6 * n;
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(3 * nc, nd);
  std::vector<double> mu;
  for (int c = 0; c < nc; ++c) {
    const Touch& t = touches[c];
    Eigen::Vector3d frame[3];
    detail::frameOf(t.normal, frame);
    for (int side = 0; side < 2; ++side) {
      const int body = side == 0 ? t.a : t.b;
      if (body < 0) continue;
      const double sign = side == 0 ? -1.0 : 1.0;
      const Eigen::Vector3d arm = t.point - bodies[body].x;
      for (int k = 0; k < 3; ++k) {
        H.block<1, 3>(3 * c + k, 6 * body) += sign * frame[k].transpose();
        H.block<1, 3>(3 * c + k, 6 * body + 3) += sign * arm.cross(frame[k]).transpose();
      }
    }
    mu.push_back(mu_d(rng));
  }
  Eigen::MatrixXd minv = Eigen::MatrixXd::Zero(nd, nd);
  Eigen::VectorXd vfree = Eigen::VectorXd::Zero(nd);
  for (int b = 0; b < n; ++b) {
    const double m = bodies[b].mass, len = 2 * half;
    const double i_axis = 0.5 * m * r * r, i_across = m * (3 * r * r + len * len) / 12.0;
    const Eigen::Vector3d ax = bodies[b].axis;
    const Eigen::Matrix3d inertia =
        i_across * Eigen::Matrix3d::Identity() + (i_axis - i_across) * ax * ax.transpose();
    minv.block<3, 3>(6 * b, 6 * b) = Eigen::Matrix3d::Identity() / m;
    minv.block<3, 3>(6 * b + 3, 6 * b + 3) = inertia.inverse();
    vfree[6 * b + 2] = -9.81 * 0.01;
    vfree[6 * b] = vel_d(rng);
    vfree[6 * b + 1] = vel_d(rng);
  }
  return detail::fromJacobian(H, minv, vfree, mu);
}

// side x side surface nodes on a unit patch, `per_node` contacts on each node inside the tool's
// radius 0.35 (each with a random tangent frame about the normal), node compliance
// C_ij = exp(-|p_i - p_j| / 0.2) + 0.3 delta_ij times a 3x3 normal/tangent block. The tool presses
// (-1 at the centre) and drags along x (0.5); mu uniform in [0.3, mu_max].
inline DenseProblem redundantPatch(int side, int per_node, unsigned seed, double mu_max) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u01(0.0, 1.0), jitter(-0.2, 0.2), mu_d(0.3, mu_max);
  std::vector<Eigen::Vector2d> nodes;
  for (int i = 0; i < side; ++i) {
    for (int j = 0; j < side; ++j) {
      nodes.emplace_back((i + 0.5 + jitter(rng)) / side, (j + 0.5 + jitter(rng)) / side);
    }
  }
  const int nn = static_cast<int>(nodes.size());
  Eigen::Matrix3d s;
  s << 1.0, 0.1, 0.0, 0.1, 0.6, 0.0, 0.0, 0.0, 0.6;
  Eigen::MatrixXd C(3 * nn, 3 * nn);
  for (int i = 0; i < nn; ++i) {
    for (int j = 0; j < nn; ++j) {
      const double k = std::exp(-(nodes[i] - nodes[j]).norm() / 0.2) + (i == j ? 0.3 : 0.0);
      C.block<3, 3>(3 * i, 3 * j) = k * s;   // node frame: z normal first
    }
  }
  std::vector<int> node_of;
  std::vector<double> phi;
  for (int i = 0; i < nn; ++i) {
    if ((nodes[i] - Eigen::Vector2d(0.5, 0.5)).norm() > 0.35) continue;
    for (int c = 0; c < per_node; ++c) {
      node_of.push_back(i);
      phi.push_back(2.0 * std::numbers::pi * u01(rng));
    }
  }
  const int nc = static_cast<int>(node_of.size());
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(3 * nc, 3 * nn);
  Eigen::VectorXd q(3 * nc);
  std::vector<double> mu;
  for (int c = 0; c < nc; ++c) {
    const int i = node_of[c];
    Eigen::Matrix3d rot;   // rows: n, t1, t2 in the node frame (n first)
    rot << 1, 0, 0, 0, std::cos(phi[c]), std::sin(phi[c]), 0, -std::sin(phi[c]), std::cos(phi[c]);
    H.block<3, 3>(3 * c, 3 * i) = rot;
    const double d2 = (nodes[i] - Eigen::Vector2d(0.5, 0.5)).squaredNorm();
    const Eigen::Vector3d v(-(1.0 - d2 / 0.2), 0.5, 0.0);   // press and drag (node frame)
    q.segment<3>(3 * c) = rot * v;
    mu.push_back(mu_d(rng));
  }
  // W = H C H^T: the same algebra as fromJacobian with C in place of M^-1, q given directly
  DenseProblem p = detail::fromJacobian(H, C, Eigen::VectorXd::Zero(3 * nn), mu);
  p.q.assign(q.data(), q.data() + 3 * nc);
  return p;
}

}  // namespace tactus::test
