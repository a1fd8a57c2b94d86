// Isotropic laws in principal stretches: energy, stresses and the projected tangent
// (fem_constitutive.h).
#include "fem_constitutive.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>

namespace tactus::sim::fem_detail {

namespace {

// Below this sum of two stretches the rotation mode's stiffness B = (P_i + P_j) / (s_i + s_j)
// is taken at this sum (positive numerator) or left out (B <= 0, or the sum <= 0: an inverted
// pair, whose rotation coordinate is singular): bounded instead of dividing by ~0.
constexpr double kRotationSumFloor = 0.1;

// Below this difference of two stretches A = (P_i - P_j) / (s_i - s_j) takes its limit.
constexpr double kEqualStretches = 1e-9;

double rotationStiffness(double stress_sum, double stretch_sum) {
  if (!(stretch_sum > 0.0) || !(stress_sum > 0.0)) return 0.0;
  return stress_sum / std::max(stretch_sum, kRotationSumFloor);
}

void projectPsd(Eigen::Matrix3d& h) {
  // cheap test first: a diagonally dominant matrix with a positive diagonal is PSD
  bool dominant = true;
  for (int i = 0; i < 3 && dominant; ++i) {
    double off = 0.0;
    for (int j = 0; j < 3; ++j)
      if (j != i) off += std::abs(h(i, j));
    dominant = h(i, i) >= off;
  }
  if (dominant) return;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(h);
  const Eigen::Vector3d ev = es.eigenvalues().cwiseMax(0.0);
  h = es.eigenvectors() * ev.asDiagonal() * es.eigenvectors().transpose();
}

// The logarithm of a stretch, extended linearly below the floor (C^1): value, first and second
// derivative.
struct FloorLog {
  double value, d1, d2;
  bool below;
};
FloorLog floorLog(double s) {
  const double c = kInvertibleStretchFloor;
  if (s >= c) return {std::log(s), 1.0 / s, -1.0 / (s * s), false};
  return {std::log(c) + (s - c) / c, 1.0 / c, 0.0, true};
}

// (l'(x) - l'(y)) / (x - y) for the floor logarithm: its derivative's difference quotient, the
// second derivative where the stretches are (nearly) equal.
double floorLogSlope(double x, double y, const FloorLog& lx, const FloorLog& ly) {
  if (std::abs(x - y) < kEqualStretches) return 0.5 * (lx.d2 + ly.d2);
  if (!lx.below && !ly.below) return -1.0 / (x * y);
  return (lx.d1 - ly.d1) / (x - y);
}

struct NeoHookeanAt {
  FloorLog l[3];
  double log_j = 0.0;                 // sum of the floor logarithms
  Eigen::Vector3d stress = Eigen::Vector3d::Zero();
  double energy = 0.0;
};

// psi = mu/2 (|s|^2 - 3) - mu sum l(s_i) + lambda/2 (sum l(s_i))^2 with l the floor logarithm:
// the neo-Hookean energy wherever every stretch is above the floor, and below it the stress
// P_i = mu s_i + (lambda L - mu) l'(s_i) continues linearly in the stretch (Irving et al.'s
// extrapolation, here as an energy, so the force is conservative everywhere).
NeoHookeanAt neoHookean(double lambda, double mu, const Eigen::Vector3d& s) {
  NeoHookeanAt r;
  for (int i = 0; i < 3; ++i) {
    r.l[i] = floorLog(s[i]);
    r.log_j += r.l[i].value;
  }
  const double lj = r.log_j;
  for (int i = 0; i < 3; ++i) r.stress[i] = mu * s[i] + (lambda * lj - mu) * r.l[i].d1;
  r.energy = 0.5 * mu * (s.squaredNorm() - 3.0) - mu * lj + 0.5 * lambda * lj * lj;
  return r;
}

}  // namespace

double principalEnergy(MaterialLaw law, double lambda, double mu, const Eigen::Vector3d& s) {
  if (law == MaterialLaw::kInvertibleNeoHookean) return neoHookean(lambda, mu, s).energy;
  const double t = s.sum() - 3.0;
  return mu * (s - Eigen::Vector3d::Ones()).squaredNorm() + 0.5 * lambda * t * t;
}

void principalResponse(MaterialLaw law, double lambda, double mu, const Eigen::Vector3d& s,
                       bool full_rotation_stiffness, PrincipalResponse& out) {
  if (law == MaterialLaw::kInvertibleNeoHookean) {
    const NeoHookeanAt r = neoHookean(lambda, mu, s);
    const double q = lambda * r.log_j - mu;
    out.stress = r.stress;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) out.h(i, j) = lambda * r.l[i].d1 * r.l[j].d1;
      out.h(i, i) += mu + q * r.l[i].d2;
    }
    projectPsd(out.h);
    for (int k = 0; k < 3; ++k) {
      const int i = kPairs[k][0], j = kPairs[k][1];
      // A = (P_i - P_j) / (s_i - s_j) = mu + q (l'_i - l'_j) / (s_i - s_j)
      const double a = std::max(mu + q * floorLogSlope(s[i], s[j], r.l[i], r.l[j]), 0.0);
      double b = 0.0;
      if (full_rotation_stiffness) {
        // B = (P_i + P_j) / (s_i + s_j) = mu + q / (s_i s_j) above the floor
        b = !r.l[i].below && !r.l[j].below
                ? std::max(mu + q / (s[i] * s[j]), 0.0)
                : rotationStiffness(r.stress[i] + r.stress[j], s[i] + s[j]);
      }
      out.p[k] = 0.5 * (a + b);
      out.m[k] = 0.5 * (a - b);
    }
    return;
  }
  // corotational: P^ = 2 mu (s - 1) + lambda (sum s - 3), H = 2 mu I + lambda 1 1^T (PSD for any
  // admissible Poisson ratio), A = 2 mu
  const double t = s.sum() - 3.0;
  for (int i = 0; i < 3; ++i) out.stress[i] = 2.0 * mu * (s[i] - 1.0) + lambda * t;
  out.h.setConstant(lambda);
  out.h.diagonal().array() += 2.0 * mu;
  for (int k = 0; k < 3; ++k) {
    const int i = kPairs[k][0], j = kPairs[k][1];
    const double a = 2.0 * mu;
    const double b = full_rotation_stiffness
                         ? rotationStiffness(out.stress[i] + out.stress[j], s[i] + s[j])
                         : 0.0;
    out.p[k] = 0.5 * (a + b);
    out.m[k] = 0.5 * (a - b);
  }
}

void rotationSvd(const Eigen::Matrix3d& F, const Eigen::Matrix3d& R, Eigen::Matrix3d& U,
                 Eigen::Vector3d& s, Eigen::Matrix3d& V) {
  const Eigen::Matrix3d st = R.transpose() * F;
  const Eigen::Matrix3d sym = 0.5 * (st + st.transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(sym);
  V = es.eigenvectors();
  if (V.determinant() < 0.0) V.col(0) = -V.col(0);
  s = es.eigenvalues();
  U = R * V;
}

}  // namespace tactus::sim::fem_detail
