// Pose math (tactus/shared/pose.h): log/exp, pose difference round trips, interpolation and
// the SO(3) Jacobians the instrument sensitivity relies on.
#include "tactus/shared/pose.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace {

using tactus::shared::Pose;
using tactus::shared::Vector6d;
namespace ts = tactus::shared;

Pose randomPose(std::mt19937& rng, double max_angle = 3.0) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Pose p;
  p.pos_m = Eigen::Vector3d(u(rng), u(rng), u(rng)) * 0.2;
  Eigen::Vector3d axis(u(rng), u(rng), u(rng));
  axis.normalize();
  p.rot = Eigen::Quaterniond(Eigen::AngleAxisd(0.5 * (u(rng) + 1.0) * max_angle, axis));
  return p;
}

double rotationError(const Eigen::Quaterniond& a, const Eigen::Quaterniond& b) {
  return a.angularDistance(b);
}

TEST(Pose, RotationVectorExpRoundTrip) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (double angle : {0.0, 1e-14, 1e-9, 1e-4, 0.3, 1.5, 3.0, M_PI - 1e-7}) {
    Eigen::Vector3d axis(u(rng), u(rng), u(rng));
    axis.normalize();
    const Eigen::Vector3d theta = angle * axis;
    const Eigen::Quaterniond q = ts::quaternionFromRotationVector(theta);
    EXPECT_NEAR(q.norm(), 1.0, 1e-14);
    EXPECT_LT((ts::rotationVector(q) - theta).norm(), 1e-9 * std::max(1.0, angle)) << angle;
    // against Eigen's AngleAxis
    EXPECT_LT(rotationError(q, Eigen::Quaterniond(Eigen::AngleAxisd(angle, axis))), 1e-12);
    // q and -q give the same (shortest) rotation vector
    Eigen::Quaterniond neg(-q.w(), -q.x(), -q.y(), -q.z());
    EXPECT_LT((ts::rotationVector(neg) - theta).norm(), 1e-9);
  }
  // an angle beyond pi comes back as the equivalent shorter rotation
  const Eigen::Vector3d big = 4.0 * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d back = ts::rotationVector(ts::quaternionFromRotationVector(big));
  EXPECT_NEAR(back.z(), 4.0 - 2.0 * M_PI, 1e-12);
}

TEST(Pose, DifferenceApplyRoundTrip) {
  std::mt19937 rng(2);
  for (int i = 0; i < 200; ++i) {
    const Pose a = randomPose(rng), b = randomPose(rng);
    const Vector6d d = ts::poseDifference(a, b);
    const Pose back = ts::applyTwist(b, d);
    EXPECT_LT((back.pos_m - a.pos_m).norm(), 1e-14);
    EXPECT_LT(rotationError(back.rot, a.rot), 1e-10);
    // the difference of a pose with itself is zero; antisymmetry of the rotation part
    EXPECT_LT(ts::poseDifference(a, a).norm(), 1e-12);
    EXPECT_LT((ts::poseDifference(b, a).tail<3>() + d.tail<3>()).norm(), 1e-9);
  }
}

TEST(Pose, TwistIsWorldFrame) {
  // a rotation of pi/2 about world z applied to a pose rotated about x: exp(w) * R
  Pose p;
  p.rot = Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitX()));
  Vector6d t = Vector6d::Zero();
  t(5) = M_PI / 2;
  const Pose out = ts::applyTwist(p, t);
  const Eigen::Quaterniond expected =
      Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ())) * p.rot;
  EXPECT_LT(rotationError(out.rot, expected), 1e-14);
}

TEST(Pose, Interpolation) {
  std::mt19937 rng(3);
  const Pose a = randomPose(rng, 2.0), b = randomPose(rng, 2.0);
  const Pose p0 = ts::interpolate(a, b, 0.0), p1 = ts::interpolate(a, b, 1.0);
  EXPECT_LT((p0.pos_m - a.pos_m).norm(), 1e-15);
  EXPECT_LT(rotationError(p0.rot, a.rot), 1e-12);
  EXPECT_LT((p1.pos_m - b.pos_m).norm(), 1e-15);
  EXPECT_LT(rotationError(p1.rot, b.rot), 1e-7);
  // the midpoint is half way along the geodesic
  const Pose mid = ts::interpolate(a, b, 0.5);
  EXPECT_LT((mid.pos_m - 0.5 * (a.pos_m + b.pos_m)).norm(), 1e-15);
  const Vector6d half = ts::poseDifference(b, a) * 0.5;
  EXPECT_LT(rotationError(mid.rot, ts::applyTwist(a, half).rot), 1e-9);
}

TEST(Pose, LeftJacobiansMatchFiniteDifferences) {
  const double eps = 1e-6;
  for (const Eigen::Vector3d& phi : {Eigen::Vector3d(0.3, -0.8, 1.1), Eigen::Vector3d(1e-8, 0, 0),
                                    Eigen::Vector3d(0.0, 2.5, 0.4)}) {
    const Eigen::Matrix3d jl = ts::leftJacobianSo3(phi);
    const Eigen::Quaterniond base = ts::quaternionFromRotationVector(phi);
    for (int i = 0; i < 3; ++i) {
      const Eigen::Vector3d e = Eigen::Vector3d::Unit(i) * eps;
      // exp(phi + e) exp(phi)^-1 = exp(J_l e)
      const Eigen::Vector3d fd =
          (ts::rotationVector(ts::quaternionFromRotationVector(phi + e) * base.conjugate()) -
           ts::rotationVector(ts::quaternionFromRotationVector(phi - e) * base.conjugate())) /
          (2 * eps);
      EXPECT_LT((fd - jl.col(i)).norm(), 1e-7) << phi.transpose();
    }
    EXPECT_LT((ts::leftJacobianInverseSo3(phi) * jl - Eigen::Matrix3d::Identity()).norm(), 1e-9);
  }
}

TEST(Pose, PointJacobianMatchesFiniteDifferences) {
  std::mt19937 rng(4);
  const Pose p = randomPose(rng);
  const Eigen::Vector3d point_local(0.01, -0.03, 0.05);
  const Eigen::Vector3d point = p.pos_m + p.rot * point_local;
  const Eigen::Matrix<double, 3, 6> j = ts::pointJacobian(p.pos_m, point);
  const double eps = 1e-6;
  for (int i = 0; i < 6; ++i) {
    Vector6d e = Vector6d::Zero();
    e(i) = eps;
    const Pose plus = ts::applyTwist(p, e), minus = ts::applyTwist(p, -e);
    const Eigen::Vector3d fd =
        ((plus.pos_m + plus.rot * point_local) - (minus.pos_m + minus.rot * point_local)) /
        (2 * eps);
    EXPECT_LT((fd - j.col(i)).norm(), 1e-8) << i;
  }
}

}  // namespace
