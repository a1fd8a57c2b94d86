// The rotation of the polar decomposition (fem_detail::polarRotation, an internal of the FEM
// library) against an SVD reference: well-conditioned, strongly stretched, near-180-degree,
// flat and inverted deformation gradients.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <random>

#include "../../../sim_server/src/fem/fem_internal.h"

namespace {

using tactus::sim::fem_detail::polarRotation;

// argmax over SO(3) of tr(R^T F): U diag(1, 1, det(U V^T)) V^T
Eigen::Matrix3d svdRotation(const Eigen::Matrix3d& F) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d u = svd.matrixU();
  if ((u * svd.matrixV().transpose()).determinant() < 0.0) u.col(2) *= -1.0;
  return u * svd.matrixV().transpose();
}

Eigen::Matrix3d randomRotation(std::mt19937& rng) {
  std::normal_distribution<double> g;
  return Eigen::Quaterniond(Eigen::Vector4d(g(rng), g(rng), g(rng), g(rng)).normalized())
      .toRotationMatrix();
}

// symmetric stretch I + amplitude * (random symmetric), positive definite for amplitude < 1/3
Eigen::Matrix3d randomStretch(std::mt19937& rng, double amplitude) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::Matrix3d s = Eigen::Matrix3d::Identity();
  for (int a = 0; a < 3; ++a) {
    for (int b = a; b < 3; ++b) {
      const double e = amplitude * u(rng);
      s(a, b) += e;
      if (a != b) s(b, a) += e;
    }
  }
  return s;
}

void expectProperRotationEqualTo(const Eigen::Matrix3d& r, const Eigen::Matrix3d& ref,
                                 double tol) {
  EXPECT_LT((r.transpose() * r - Eigen::Matrix3d::Identity()).norm(), 1e-13);
  EXPECT_NEAR(r.determinant(), 1.0, 1e-13);
  EXPECT_LT((r - ref).norm(), tol);
}

TEST(PolarRotation, MatchesTheSvdForStretchedRotations) {
  std::mt19937 rng(11);
  for (double amplitude : {0.0, 0.01, 0.15, 0.3}) {
    for (int k = 0; k < 2000; ++k) {
      const Eigen::Matrix3d rot = randomRotation(rng);
      const Eigen::Matrix3d f = rot * randomStretch(rng, amplitude);
      const Eigen::Matrix3d r = polarRotation(f);
      expectProperRotationEqualTo(r, svdRotation(f), 1e-12);
      // the stretch R^T F is symmetric
      const Eigen::Matrix3d s = r.transpose() * f;
      EXPECT_LT((s - s.transpose()).norm(), 1e-12 * f.norm());
    }
  }
}

TEST(PolarRotation, ScaleAndHalfTurnsAndAnisotropy) {
  std::mt19937 rng(12);
  // rotations by nearly 180 degrees (quaternion w ~ 0), tiny and huge scales, strong anisotropy
  for (int k = 0; k < 500; ++k) {
    const Eigen::Vector3d axis = randomRotation(rng).col(0);
    const double angle = M_PI - 1e-9 * k;
    const Eigen::Matrix3d rot = Eigen::AngleAxisd(angle, axis).toRotationMatrix();
    const Eigen::Matrix3d d = Eigen::Vector3d(1.0, 0.2, 3.0).asDiagonal();
    const Eigen::Matrix3d q = randomRotation(rng);
    for (double scale : {1e-6, 1.0, 1e6}) {
      const Eigen::Matrix3d f = scale * rot * q * d * q.transpose();
      expectProperRotationEqualTo(polarRotation(f), svdRotation(f), 1e-11);
    }
  }
}

TEST(PolarRotation, FlatAndInvertedElementsGiveAProperRotation) {
  std::mt19937 rng(13);
  for (int k = 0; k < 500; ++k) {
    const Eigen::Matrix3d rot = randomRotation(rng);
    const Eigen::Matrix3d q = randomRotation(rng);
    // flat (one singular value 1e-9) and inverted (one negative)
    for (double s3 : {1e-9, -0.3}) {
      const Eigen::Matrix3d f = rot * q * Eigen::Vector3d(1.2, 0.9, s3).asDiagonal() * q.transpose();
      expectProperRotationEqualTo(polarRotation(f), svdRotation(f), 1e-9);
    }
  }
}

// Inverted F (det F < 0): the rotation stays proper and the stretch S = R^T F carries the
// inversion (Irving et al.'s reflection-aware polar decomposition: the smallest singular value's
// column is negated), so sym(R^T F) - I is a strong compression along the inverted direction and
// the linear corotational force pushes the element back. A reflection-blind polar (R = U V^T,
// then det R = -1 and S positive definite) fails every check here.
TEST(PolarRotation, InvertedGradientsPutTheInversionInTheStretch) {
  std::mt19937 rng(29);
  for (int k = 0; k < 300; ++k) {
    const Eigen::Matrix3d rot = randomRotation(rng);
    const Eigen::Matrix3d q = randomRotation(rng);
    std::uniform_real_distribution<double> u(0.2, 1.5);
    Eigen::Vector3d sv(u(rng), u(rng), u(rng));
    sv[k % 3] = -sv[k % 3];  // one direction inverted
    const Eigen::Matrix3d f = rot * q * sv.asDiagonal() * q.transpose();
    ASSERT_LT(f.determinant(), 0.0);
    const Eigen::Matrix3d r = polarRotation(f);
    EXPECT_NEAR(r.determinant(), 1.0, 1e-12);
    const Eigen::Matrix3d stretch = r.transpose() * f;
    EXPECT_LT((stretch - stretch.transpose()).norm(), 1e-9 * f.norm());
    const Eigen::Vector3d ev =
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(0.5 * (stretch + stretch.transpose()))
            .eigenvalues();
    EXPECT_LT(ev[0], 0.0);   // exactly one negative principal stretch: the inversion
    EXPECT_GT(ev[1], 0.0);
    EXPECT_NEAR(ev.prod(), f.determinant(), 1e-9);
  }
  // the tie: a pure reflection (a node mirrored through the opposite face), all |s_i| = 1
  for (int k = 0; k < 50; ++k) {
    const Eigen::Vector3d n = randomRotation(rng).col(0);
    const Eigen::Matrix3d f = Eigen::Matrix3d::Identity() - 2.0 * n * n.transpose();
    const Eigen::Matrix3d r = polarRotation(f);
    EXPECT_NEAR(r.determinant(), 1.0, 1e-12);
    const Eigen::Matrix3d stretch = r.transpose() * f;
    EXPECT_LT((stretch - stretch.transpose()).norm(), 1e-9);
    EXPECT_NEAR(stretch.determinant(), -1.0, 1e-9);
  }
}

}  // namespace
