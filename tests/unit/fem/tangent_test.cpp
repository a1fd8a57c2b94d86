// The implicit step's tangent against finite differences of the elastic force, through the
// public API: freeMotion leaves A = M/h + hK at its linearisation point, so the compliance
// C = (M/h^2 + K)^-1 applied to M d/h^2 + K_true d, with K_true d = -(f(q + d) - f(q)) from
// elasticForce, returns d exactly when K is the true tangent. Checked where the projection of
// the tangent (fem_constitutive.h) leaves nothing out: a stretched and turned block, every mode
// of it stiff. Also the laws in principal stretches: stress = d psi / d s above and below the
// invertible law's stretch floor.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>

#include "../../../sim_server/src/fem/fem_constitutive.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::sim {
namespace {

struct TangentCase {
  MaterialLaw law;
  TangentKind tangent;
  ElementKind element;
};

// Relative error |C r - d| / |d| for a small random d at a stretched, turned state.
double tangentError(const TangentCase& c) {
  const TetMesh mesh = makeBoxTetMesh(3, 2, 2, Eigen::Vector3d(0.03, 0.02, 0.02));
  FemMaterial mat;
  mat.law = c.law;
  mat.tangent = c.tangent;
  mat.element = c.element;
  mat.young_pa = 1e4;
  mat.poisson = 0.3;
  mat.density_kgpm3 = 1000.0;
  FemBody body(mesh, mat, {}, nullptr);
  const Eigen::Matrix3d turn =
      Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Matrix3d stretch = Eigen::Vector3d(1.25, 1.1, 1.15).asDiagonal();
  Eigen::VectorXd q0 = body.restPositions();
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> jitter(-2e-4, 2e-4);
  for (int i = 0; i < body.nodeCount(); ++i) {
    q0.segment<3>(3 * i) = turn * stretch * q0.segment<3>(3 * i);
    for (int k = 0; k < 3; ++k) q0[3 * i + k] += jitter(rng);
  }
  body.positions() = q0;
  body.velocities().setZero();
  const double h = 0.01;
  body.freeMotion(h);  // A at q0 (v = 0)
  Eigen::VectorXd d(body.dofCount());
  for (int k = 0; k < d.size(); ++k) d[k] = 1e-8 * jitter(rng) / 2e-4;
  Eigen::VectorXd f0, f1;
  body.elasticForce(q0, f0);
  body.elasticForce(q0 + d, f1);
  const Eigen::VectorXd r = body.lumpedMass().cwiseProduct(d) / (h * h) - (f1 - f0);
  Eigen::VectorXd x;
  body.solveCompliance(r, x);
  return (x - d).norm() / d.norm();
}

TEST(Tangent, TheConsistentCorotationalTangentIsTheForcesDerivative) {
  const double corotated = tangentError(
      {MaterialLaw::kCorotational, TangentKind::kCorotated, ElementKind::kLinearTet});
  const double consistent = tangentError(
      {MaterialLaw::kCorotational, TangentKind::kConsistent, ElementKind::kLinearTet});
  std::printf("[tangent] corotational, linear tets: error %.2e with R K0 R^T, %.2e consistent\n",
              corotated, consistent);
  EXPECT_LT(consistent, 1e-5);
  EXPECT_GT(corotated, 1e-3);  // R K0 R^T leaves out the rotation's stiffness under stress
}

TEST(Tangent, TheEdgeSmoothedTangentsAreTheForcesDerivative) {
  const double consistent = tangentError(
      {MaterialLaw::kCorotational, TangentKind::kConsistent, ElementKind::kEdgeSmoothedTet});
  const double neo = tangentError({MaterialLaw::kInvertibleNeoHookean, TangentKind::kCorotated,
                                   ElementKind::kEdgeSmoothedTet});
  std::printf("[tangent] edge-smoothed: corotational consistent %.2e, neo-Hookean %.2e\n",
              consistent, neo);
  EXPECT_LT(consistent, 1e-5);
  EXPECT_LT(neo, 1e-5);
}

TEST(Tangent, TheInvertibleNeoHookeanTangentIsTheForcesDerivative) {
  const double neo = tangentError(
      {MaterialLaw::kInvertibleNeoHookean, TangentKind::kCorotated, ElementKind::kLinearTet});
  std::printf("[tangent] neo-Hookean, linear tets: %.2e\n", neo);
  EXPECT_LT(neo, 1e-5);
}

TEST(PrincipalLaws, StressIsTheEnergysGradientAboveAndBelowTheFloor) {
  const double lambda = 2.0e4, mu = 1.0e4;
  for (const MaterialLaw law : {MaterialLaw::kCorotational, MaterialLaw::kInvertibleNeoHookean}) {
    for (const Eigen::Vector3d& s :
         {Eigen::Vector3d(1.2, 0.9, 1.05), Eigen::Vector3d(1.1, 0.25, 0.8),
          Eigen::Vector3d(0.9, 1.0, -0.4), Eigen::Vector3d(0.1, 0.2, 1.3)}) {
      fem_detail::PrincipalResponse resp;
      fem_detail::principalResponse(law, lambda, mu, s, true, resp);
      for (int i = 0; i < 3; ++i) {
        Eigen::Vector3d e = Eigen::Vector3d::Zero();
        e[i] = 1e-6;
        const double fd = (fem_detail::principalEnergy(law, lambda, mu, s + e) -
                           fem_detail::principalEnergy(law, lambda, mu, s - e)) / 2e-6;
        EXPECT_NEAR(resp.stress[i], fd, 1e-6 * (mu + std::abs(fd)))
            << "law " << static_cast<int>(law) << " s " << s.transpose() << " i " << i;
      }
    }
  }
}

TEST(PrincipalLaws, TheInvertibleLawPushesHarderTheDeeperAnElementIsInverted) {
  const double lambda = 2.0e4, mu = 1.0e4;
  double last = 0.0;
  for (double s3 : {0.5, 0.3, 0.0, -0.5, -1.0}) {
    fem_detail::PrincipalResponse resp;
    fem_detail::principalResponse(MaterialLaw::kInvertibleNeoHookean, lambda, mu,
                                  Eigen::Vector3d(1.0, 1.0, s3), true, resp);
    EXPECT_LT(resp.stress[2], last) << s3;   // ever more compressive
    last = resp.stress[2];
  }
  // at zero volume the stress is several times the corotational law's
  fem_detail::PrincipalResponse neo, corot;
  fem_detail::principalResponse(MaterialLaw::kInvertibleNeoHookean, lambda, mu,
                                Eigen::Vector3d(1.0, 1.0, 0.0), true, neo);
  fem_detail::principalResponse(MaterialLaw::kCorotational, lambda, mu,
                                Eigen::Vector3d(1.0, 1.0, 0.0), true, corot);
  EXPECT_LT(neo.stress[2], 3.0 * corot.stress[2]);
}

}  // namespace
}  // namespace tactus::sim
