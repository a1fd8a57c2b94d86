#pragma once
// Isotropic elastic laws in principal stretches, for the general element loop (fem_domains.cpp):
// the energy density, the principal stresses and the tangent, projected positive semi-definite,
// in the frame of the deformation gradient's rotation-valued SVD F = U diag(s) V^T (Irving, Teran
// and Fedkiw 2004: U, V proper rotations, an inverted element's smallest stretch negative).
//
// The tangent dP/dF of an isotropic law, written in that frame (dF^ = U^T dF V), splits
// (Teran, Sifakis, Irving and Fedkiw 2005, "Robust quasistatic finite elements and flesh
// simulation") into
//   dP^_ii = sum_j H_ij dF^_jj                    H_ij = d P^_i / d s_j (3 x 3)
//   dP^_ij = p_ij dF^_ij + m_ij dF^_ji  (i != j)  p = (A + B) / 2, m = (A - B) / 2,
// with A_ij = (P^_i - P^_j) / (s_i - s_j) the stiffness of the symmetric (shear) mode and
// B_ij = (P^_i + P^_j) / (s_i + s_j) that of the antisymmetric (rotation) mode of the pair. The
// corotational tangent R K0 R^T of the paper is this one with B = 0: the rotation is held. The
// projection clamps H's eigenvalues and every A and B at zero, so each element's tangent is
// positive semi-definite and at least the true one's positive part: a linearised implicit step
// with it is stable about a stable equilibrium (the part left out is negative, and leaving out
// negative stiffness only adds to the step's effective mass).

#include <Eigen/Core>

#include "tactus/sim/scene.h"

namespace tactus::sim::fem_detail {

/// Below this principal stretch the invertible neo-Hookean law's logarithm of the stretch is
/// continued linearly (value and slope at the floor), so the stress continues linearly in the
/// stretch (Irving et al. 2004's extrapolation, from an energy): finite and ever more compressive
/// through zero volume and inversion.
inline constexpr double kInvertibleStretchFloor = 0.3;

/// A law's response at principal stretches s (any order, the smallest possibly negative).
struct PrincipalResponse {
  Eigen::Vector3d stress = Eigen::Vector3d::Zero();  ///< P^_i = d psi / d s_i [Pa]
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();       ///< H projected PSD [Pa]
  /// per pair k = (0,1), (0,2), (1,2): p_k = (A + B) / 2, m_k = (A - B) / 2 with A, B >= 0 [Pa]
  double p[3] = {0.0, 0.0, 0.0};
  double m[3] = {0.0, 0.0, 0.0};
};

/// The pairs of principal directions in PrincipalResponse's order.
inline constexpr int kPairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};

/// Energy density psi(s) [J/m^3] of `law` (corotational: mu |s - 1|^2 + lambda/2 (sum s - 3)^2;
/// invertible neo-Hookean: mu/2 (|s|^2 - 3) - mu L + lambda/2 L^2 with L = sum l(s_i), l the
/// logarithm continued linearly below kInvertibleStretchFloor, so log J above it).
double principalEnergy(MaterialLaw law, double lambda, double mu, const Eigen::Vector3d& s);

/// Stresses and projected tangent at s. `full_rotation_stiffness` false: B = 0 (the rotation
/// held, as R K0 R^T), true: B from the stresses (clamped at 0). Linear law: not handled.
void principalResponse(MaterialLaw law, double lambda, double mu, const Eigen::Vector3d& s,
                       bool full_rotation_stiffness, PrincipalResponse& out);

/// Rotation-valued SVD of F from its polar rotation R (fem_internal.h polarRotation: a proper
/// rotation, the inversion in the stretch): F = U diag(s) V^T, U = R V, s the eigenvalues of the
/// symmetric R^T F (one of them negative for an inverted F), V a proper rotation.
void rotationSvd(const Eigen::Matrix3d& F, const Eigen::Matrix3d& R, Eigen::Matrix3d& U,
                 Eigen::Vector3d& s, Eigen::Matrix3d& V);

}  // namespace tactus::sim::fem_detail
