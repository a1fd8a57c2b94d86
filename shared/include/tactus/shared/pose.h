#pragma once
// Rigid poses and twists, shared by the simulation and the haptic loop (header-only).
//
// Conventions (used everywhere in Tactus):
//  * A Pose is a position [m] and a unit quaternion, both in the world frame: a point p_tool in
//    the tool frame is at  pos_m + rot * p_tool  in the world.
//  * A twist / pose increment is a 6-vector [dp; dtheta] in the WORLD frame: dp [m] moves the
//    origin, dtheta [rad] is a rotation vector applied on the left (rot <- exp(dtheta) * rot).
//    A wrench is [force_n; torque_nm] in the same order, torque about the tool origin.
//  * poseDifference(a, b) = [a.pos - b.pos; log(a.rot * b.rot^-1)] is "a [-] b", the twist that
//    takes b to a: applyTwist(b, poseDifference(a, b)) == a.
//
// Every function here is noexcept and allocation-free (fixed-size Eigen types only), so the
// haptic tick may use them.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>

namespace tactus::shared {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

struct Pose {
  Eigen::Vector3d pos_m = Eigen::Vector3d::Zero();
  Eigen::Quaterniond rot = Eigen::Quaterniond::Identity();
};

/// [v]x: skew(v) * w == v.cross(w).
inline Eigen::Matrix3d skew(const Eigen::Vector3d& v) noexcept {
  Eigen::Matrix3d s;
  s << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return s;
}

/// SO(3) log: the rotation vector (axis * angle, angle in [0, pi]) of a quaternion. The
/// quaternion need not be normalised; the shortest rotation is returned (q and -q agree).
inline Eigen::Vector3d rotationVector(const Eigen::Quaterniond& q) noexcept {
  double w = q.w();
  Eigen::Vector3d v = q.vec();
  const double norm = std::sqrt(w * w + v.squaredNorm());
  if (!(norm > 0.0)) return Eigen::Vector3d::Zero();
  w /= norm;
  v /= norm;
  if (w < 0.0) {
    w = -w;
    v = -v;
  }
  const double s = v.norm();
  // 2 atan2(s, w) / s -> 2 / w as s -> 0 (error O(s^2))
  if (s < 1e-12) return (2.0 / w) * v;
  return (2.0 * std::atan2(s, w) / s) * v;
}

/// SO(3) exp: the unit quaternion of a rotation vector.
inline Eigen::Quaterniond quaternionFromRotationVector(const Eigen::Vector3d& theta) noexcept {
  const double angle = theta.norm();
  if (angle < 1e-12) {
    Eigen::Quaterniond q(1.0, 0.5 * theta.x(), 0.5 * theta.y(), 0.5 * theta.z());
    q.normalize();
    return q;
  }
  const double k = std::sin(0.5 * angle) / angle;
  return Eigen::Quaterniond(std::cos(0.5 * angle), k * theta.x(), k * theta.y(), k * theta.z());
}

/// Left Jacobian of SO(3): exp(phi + e) ~= exp(J_l(phi) e) exp(phi) for small e.
inline Eigen::Matrix3d leftJacobianSo3(const Eigen::Vector3d& phi) noexcept {
  const double a = phi.norm();
  const Eigen::Matrix3d k = skew(phi);
  if (a < 1e-6) return Eigen::Matrix3d::Identity() + 0.5 * k + (1.0 / 6.0) * k * k;
  const double a2 = a * a;
  return Eigen::Matrix3d::Identity() + ((1.0 - std::cos(a)) / a2) * k +
         ((a - std::sin(a)) / (a2 * a)) * k * k;
}

/// Inverse of leftJacobianSo3: log(exp(e) exp(phi)) ~= phi + J_l^-1(phi) e (|phi| < pi).
inline Eigen::Matrix3d leftJacobianInverseSo3(const Eigen::Vector3d& phi) noexcept {
  const double a = phi.norm();
  const Eigen::Matrix3d k = skew(phi);
  if (a < 1e-6) return Eigen::Matrix3d::Identity() - 0.5 * k + (1.0 / 12.0) * k * k;
  const double c = 1.0 / (a * a) - (1.0 + std::cos(a)) / (2.0 * a * std::sin(a));
  return Eigen::Matrix3d::Identity() - 0.5 * k + c * k * k;
}

/// a [-] b: the world-frame twist [a.pos - b.pos; log(a.rot * b.rot^-1)] taking b to a.
inline Vector6d poseDifference(const Pose& a, const Pose& b) noexcept {
  Vector6d t;
  t.head<3>() = a.pos_m - b.pos_m;
  t.tail<3>() = rotationVector(a.rot * b.rot.conjugate());
  return t;
}

/// pose [+] twist: pos + dp, exp(dtheta) * rot (renormalised).
inline Pose applyTwist(const Pose& pose, const Vector6d& twist) noexcept {
  Pose out;
  out.pos_m = pose.pos_m + twist.head<3>();
  out.rot = (quaternionFromRotationVector(twist.tail<3>()) * pose.rot).normalized();
  return out;
}

/// Interpolation at s in [0, 1]: linear on the position, shortest-path slerp on the rotation.
inline Pose interpolate(const Pose& a, const Pose& b, double s) noexcept {
  Pose out;
  out.pos_m = (1.0 - s) * a.pos_m + s * b.pos_m;
  out.rot = a.rot.slerp(s, b.rot).normalized();
  return out;
}

/// Point displacement of a rigidly attached point under a small world twist [dp; dtheta] of a
/// body whose origin is `origin_m`: d(point) = dp + dtheta x r = [I, -[r]x] [dp; dtheta],
/// r = point - origin.
inline Eigen::Matrix<double, 3, 6> pointJacobian(const Eigen::Vector3d& origin_m,
                                                 const Eigen::Vector3d& point_m) noexcept {
  Eigen::Matrix<double, 3, 6> j;
  j.leftCols<3>().setIdentity();
  j.rightCols<3>() = -skew(point_m - origin_m);
  return j;
}

}  // namespace tactus::shared
