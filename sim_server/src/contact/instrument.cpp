#include "tactus/sim/instrument.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "tactus/shared/error.h"

namespace tactus::sim {
namespace {

void requirePositive(double value, const char* field) {
  if (!(value > 0.0) || !std::isfinite(value)) {
    throw SceneError(std::string("instrument.") + field + ": must be a finite value > 0 (got " +
                     std::to_string(value) + ")");
  }
}

void requireNonNegative(double value, const char* field) {
  if (!(value >= 0.0) || !std::isfinite(value)) {
    throw SceneError(std::string("instrument.") + field + ": must be a finite value >= 0 (got " +
                     std::to_string(value) + ")");
  }
}

// One PD-coupled DOF (translation, rotation or the jaw angle) under implicit Euler with the
// coupling linearised at the start of the step:
//     (M/h + B + hK) rate+ = M rate/h + K error + B target_rate
template <class T>
T implicitPdRate(double inertia, double b, double k, double h, const T& rate, const T& error,
                 const T& target_rate) {
  return (inertia / h * rate + k * error + b * target_rate) / (inertia / h + b + h * k);
}

// Its compliance (M/h^2 + B/h + K)^-1: the increment per unit generalised force.
double pdCompliance(double inertia, double b, double k, double h) {
  return 1.0 / (inertia / (h * h) + b / h + k);
}

// Scales `v` down to at most `max_norm` (a non-finite vector becomes zero). True if changed.
bool boundNorm(Eigen::Ref<Eigen::Vector3d> v, double max_norm) {
  if (!v.allFinite()) {
    v.setZero();
    return true;
  }
  // scale first so that the norm of a huge finite vector does not overflow
  const double m = v.cwiseAbs().maxCoeff();
  if (m <= max_norm / 2.0) return false;
  const double n = m * (v / m).norm();
  if (n <= max_norm) return false;
  v *= max_norm / n;
  return true;
}

// Jaw with opening side `side` (+1 jaw 0, -1 jaw 1) at half-angle phi: its axis a..b, a at
// (x, side r, 0) in the tool frame (see instrument.h).
void jawAxis(const shared::Pose& pose, const Eigen::Matrix3d& rot, double side, double phi,
             double x, double r, double length, Eigen::Vector3d& a, Eigen::Vector3d& b) {
  a = pose.pos_m + rot * Eigen::Vector3d(x, side * r, 0.0);
  // Rx(side phi) (0, 0, -1) = (0, sin(side phi), -cos(side phi))
  b = a + rot * (length * Eigen::Vector3d(0.0, std::sin(side * phi), -std::cos(side * phi)));
}

// A jaw feature: everything else at its default (ToolFeature{}).
void setJawFeature(ToolFeature& f, int id, FeatureShape shape, int part, const Eigen::Vector3d& a,
                   const Eigen::Vector3d& b, double r, const Eigen::Vector3d& hinge, double side) {
  f = ToolFeature{};
  f.id = id;
  f.shape = shape;
  f.part = part;
  f.a_m = a;
  f.b_m = b;
  f.radius_m = r;
  f.hinge_m = hinge;
  f.opening_sign = side;
}

}  // namespace

void useFormerLiverGraspScript(SceneSpec& spec) {
  InstrumentSpec& in = spec.instrument;
  // jaws along world -x, opening along world z
  const Eigen::Quaterniond along_x(0.5, 0.5, 0.5, 0.5);
  auto key = [&](double t, double x, double z, double gripper) {
    return TrajectoryKey{t, PoseSpec{Eigen::Vector3d(x, 0.010, z), along_x}, gripper};
  };
  in.initial_pose = PoseSpec{Eigen::Vector3d(0.135, 0.010, -0.004), along_x};
  in.trajectory = {key(0.0, 0.135, -0.004, 1.0), key(1.0, 0.135, -0.004, 1.0),
                   key(2.0, 0.100, -0.004, 1.0), key(3.0, 0.100, -0.004, 0.0),
                   key(4.5, 0.100, 0.016, 0.0),  key(6.0, 0.100, 0.016, 0.0),
                   key(6.5, 0.100, 0.016, 1.0),  key(7.5, 0.140, 0.016, 1.0)};
}

void useFormerRoundJaws(SceneSpec& spec) {
  InstrumentSpec& in = spec.instrument;
  in.pad_width_m = 0.0;
  in.contact_compliance_mpn = 0.0;
  in.jaw_radius_m = 0.002;
  in.jaw_samples = 8;
  in.grip_k_nmprad = 0.0;
  in.grip_b_nmsprad = 0.0;
  for (TrajectoryKey& k : in.trajectory) {
    if (k.gripper_opening < 1.0) k.gripper_opening = 0.25;
    if (std::abs(k.pose.position_m.x() - 0.100) < 1e-9) k.pose.position_m.x() = 0.107;
  }
}

BoxSpec instrumentWorkspace(const InstrumentSpec& spec, const Eigen::AlignedBox3d& scene_bounds) {
  if (spec.workspace) return *spec.workspace;
  Eigen::AlignedBox3d box = scene_bounds;
  box.extend(spec.initial_pose.position_m);
  for (const TrajectoryKey& k : spec.trajectory) box.extend(k.pose.position_m);
  BoxSpec out;
  out.min_m = box.min().array() - kWorkspaceMarginM;
  out.max_m = box.max().array() + kWorkspaceMarginM;
  return out;
}

Instrument::Instrument(const InstrumentSpec& spec) : spec_(spec) {
  requirePositive(spec.mass_kg, "mass_kg");
  requirePositive(spec.inertia_kgm2, "inertia_kgm2");
  requireNonNegative(spec.coupling_k_npm, "coupling_k_npm");
  requireNonNegative(spec.coupling_b_nspm, "coupling_b_nspm");
  requireNonNegative(spec.coupling_k_rot_nmprad, "coupling_k_rot_nmprad");
  requireNonNegative(spec.coupling_b_rot_nmsprad, "coupling_b_rot_nmsprad");
  requireNonNegative(spec.alarm_distance_m, "alarm_distance_m");
  requireNonNegative(spec.contact_distance_m, "contact_distance_m");
  if (spec.kind == InstrumentKind::kProbe) {
    requirePositive(spec.tip_radius_m, "tip_radius_m");
    requireNonNegative(spec.shaft_length_m, "shaft_length_m");
    features_.resize(spec.shaft_length_m > 0.0 ? 2 : 1);
  } else {
    requirePositive(spec.jaw_length_m, "jaw_length_m");
    requirePositive(spec.jaw_radius_m, "jaw_radius_m");
    requireNonNegative(spec.max_opening_rad, "max_opening_rad");
    if (spec.jaw_samples < 1) {
      throw SceneError("instrument.jaw_samples: must be >= 1 (got " +
                       std::to_string(spec.jaw_samples) + ")");
    }
    if (spec.jaw_rows < 1) {
      throw SceneError("instrument.jaw_rows: must be >= 1 (got " + std::to_string(spec.jaw_rows) +
                       ")");
    }
    requireNonNegative(spec.jaw_width_m, "jaw_width_m");
    if (spec.jaw_rows > 1 && !(spec.jaw_width_m > 0.0)) {
      throw SceneError("instrument.jaw_width_m: " + std::to_string(spec.jaw_rows) +
                       " rows of jaw samples need a width > 0");
    }
    requireNonNegative(spec.pad_width_m, "pad_width_m");
    if (spec.pad_columns < 1) {
      throw SceneError("instrument.pad_columns: must be >= 1 (got " +
                       std::to_string(spec.pad_columns) + ")");
    }
    features_.resize(spec.pad_width_m > 0.0
                         ? static_cast<std::size_t>(2 * (1 + spec.jaw_samples * spec.pad_columns))
                         : static_cast<std::size_t>(2 * spec.jaw_rows * (spec.jaw_samples + 1)));
    requireNonNegative(spec.grip_k_nmprad, "grip_k_nmprad");
    requireNonNegative(spec.grip_b_nmsprad, "grip_b_nmsprad");
    requireNonNegative(spec.grip_squeeze_nm, "grip_squeeze_nm");
    grip_dynamic_ = spec.grip_k_nmprad > 0.0;
    if (grip_dynamic_) {
      requirePositive(spec.grip_inertia_kgm2, "grip_inertia_kgm2");
      requirePositive(spec.max_opening_rad, "max_opening_rad");
    }
  }
  const double opening = spec.trajectory.empty() ? 1.0 : spec.trajectory.front().gripper_opening;
  reset(toPose(spec.initial_pose), opening);
}

void Instrument::reset(const shared::Pose& pose, double gripper_opening) {
  pose_ = pose;
  pose_.rot.normalize();
  twist_.setZero();
  target_ = pose_;
  target_twist_.setZero();
  opening_ = std::clamp(gripper_opening, 0.0, 1.0);
  grip_rate_ = 0.0;
  grip_held_open_ = false;
  grip_torque_last_nm_ = 0.0;
  theta0_.setZero();
  rot_step_.setZero();
  updateFeatures();
}

void Instrument::setWorkspace(const BoxSpec& box) {
  if (!box.min_m.allFinite() || !box.max_m.allFinite() ||
      (box.min_m.array() > box.max_m.array()).any()) {
    throw SceneError("instrument.workspace: must be a finite box with min <= max in every "
                     "coordinate");
  }
  workspace_ = box;
}

void Instrument::freeMotion(double h_s, const shared::Pose& target, const Vector6d& target_twist,
                            double gripper_opening) {
  if (!(h_s > 0.0)) return;   // no time step: nothing moves
  h_s_ = h_s;
  target_ = target;
  target_twist_ = target_twist;
  // bound the target (see the header comment): no absurd value reaches the dynamics
  const Eigen::Vector3d bounded =
      target.pos_m.cwiseMax(workspace_.min_m).cwiseMin(workspace_.max_m);
  bool clamped = false;
  for (int i = 0; i < 3; ++i) {
    if (bounded[i] == target.pos_m[i]) continue;
    clamped = true;
    target_twist_[i] = 0.0;   // held at the wall: no velocity across it
  }
  target_.pos_m = bounded;
  clamped = boundNorm(target_twist_.head<3>(), kMaxTargetSpeedMps) || clamped;
  clamped = boundNorm(target_twist_.tail<3>(), kMaxTargetAngularSpeedRadps) || clamped;
  if (clamped) ++clamped_targets_;
  const double h = h_s;
  if (grip_dynamic_) {
    // jaw angle, toward phi_h at rest
    const double phi_max = spec_.max_opening_rad;
    const double phi = opening_ * phi_max;
    const double gripper = std::clamp(gripper_opening, 0.0, 1.0);
    // a closing handle squeezes by (1 - gripper) grip_squeeze beyond the spring: as a target
    // that far past closed
    const double phi_h =
        gripper * phi_max - (1.0 - gripper) * spec_.grip_squeeze_nm / spec_.grip_k_nmprad;
    grip_rate_ = implicitPdRate(spec_.grip_inertia_kgm2, spec_.grip_b_nmsprad, spec_.grip_k_nmprad,
                                h, grip_rate_, phi_h - phi, 0.0);
    const double unheld = phi + h * grip_rate_;
    // the open stop holds the jaws in this step when the last correction's contact torque
    // would open the free jaws to it (so does the free motion alone past the stop)
    grip_held_open_ = spec_.grip_hold_open_stop &&
                      unheld + freeGripCompliance(h) * grip_torque_last_nm_ >= phi_max;
    grip_torque_last_nm_ = 0.0;   // this step's correction sets it
    // not held at 0 here: a squeezing handle's free motion may carry the jaws past closed, and
    // the tissue's torque in the correction opens them (applyGripCorrection clamps to [0, max];
    // the step calls it with or without contacts)
    const double next = grip_held_open_ ? phi_max : std::min(unheld, phi_max);
    grip_rate_ = (next - phi) / h;
    opening_ = next / phi_max;
  } else {
    opening_ = std::clamp(gripper_opening, 0.0, 1.0);
  }
  // translation, error p_h - p; rotation, error log(R_h R^-1)
  const Eigen::Vector3d v_new = implicitPdRate<Eigen::Vector3d>(
      spec_.mass_kg, spec_.coupling_b_nspm, spec_.coupling_k_npm, h, twist_.head<3>(),
      target_.pos_m - pose_.pos_m, target_twist_.head<3>());
  theta0_ = shared::rotationVector(target_.rot * pose_.rot.conjugate());
  const Eigen::Vector3d w_new = implicitPdRate<Eigen::Vector3d>(
      spec_.inertia_kgm2, spec_.coupling_b_rot_nmsprad, spec_.coupling_k_rot_nmprad, h,
      twist_.tail<3>(), theta0_, target_twist_.tail<3>());
  rot_step_ = h * w_new;
  twist_.head<3>() = v_new;
  twist_.tail<3>() = w_new;
  pose_.pos_m += h * v_new;
  pose_.rot = (shared::quaternionFromRotationVector(rot_step_) * pose_.rot).normalized();
  updateFeatures();
}

Matrix6d Instrument::compliance6(double h_s) const {
  const double cl =
      pdCompliance(spec_.mass_kg, spec_.coupling_b_nspm, spec_.coupling_k_npm, h_s);
  const double cr = pdCompliance(spec_.inertia_kgm2, spec_.coupling_b_rot_nmsprad,
                                 spec_.coupling_k_rot_nmprad, h_s);
  Matrix6d c = Matrix6d::Zero();
  c.topLeftCorner<3, 3>().diagonal().setConstant(cl);
  c.bottomRightCorner<3, 3>().diagonal().setConstant(cr);
  return c;
}

Matrix6d Instrument::freeMotionSensitivity(double h_s) const {
  const Matrix6d c = compliance6(h_s);
  Matrix6d g = Matrix6d::Zero();
  g.topLeftCorner<3, 3>() = c(0, 0) * spec_.coupling_k_npm * Eigen::Matrix3d::Identity();
  g.bottomRightCorner<3, 3>() = c(3, 3) * spec_.coupling_k_rot_nmprad *
                                shared::leftJacobianSo3(rot_step_) *
                                shared::leftJacobianInverseSo3(theta0_);
  return g;
}

Vector6d Instrument::applyCorrection(const Vector6d& wrench) {
  if (!(h_s_ > 0.0)) return Vector6d::Zero();
  const Vector6d dx = compliance6(h_s_) * wrench;
  pose_ = shared::applyTwist(pose_, dx);
  twist_ += dx / h_s_;
  updateFeatures();
  return dx;
}

double Instrument::gripCompliance(double h_s) const {
  if (grip_held_open_) return 0.0;   // at the stop: the jaws do not yield to the tissue
  return freeGripCompliance(h_s);
}

double Instrument::freeGripCompliance(double h_s) const {
  if (!grip_dynamic_ || !(h_s > 0.0)) return 0.0;
  return pdCompliance(spec_.grip_inertia_kgm2, spec_.grip_b_nmsprad, spec_.grip_k_nmprad, h_s);
}

Eigen::Vector3d Instrument::gripJacobian(int feature_id, const Eigen::Vector3d& point_m) const {
  if (!grip_dynamic_ || feature_id < 0 || feature_id >= static_cast<int>(features_.size())) {
    return Eigen::Vector3d::Zero();
  }
  const ToolFeature& f = features_[static_cast<std::size_t>(feature_id)];
  const Eigen::Vector3d axis = pose_.rot * Eigen::Vector3d::UnitX();
  return f.opening_sign * axis.cross(point_m - f.hinge_m);
}

double Instrument::applyGripCorrection(double torque_nm) {
  if (!grip_dynamic_ || !(h_s_ > 0.0)) return 0.0;
  const double phi_max = spec_.max_opening_rad;
  const double phi = opening_ * phi_max;
  grip_torque_last_nm_ = torque_nm;   // the next free motion's test of the stop
  // held at the open stop: rigid in this step's W, the jaws stay there
  if (grip_held_open_) return 0.0;
  const double next = std::clamp(phi + gripCompliance(h_s_) * torque_nm, 0.0, phi_max);
  const double dphi = next - phi;
  opening_ = next / phi_max;
  grip_rate_ += dphi / h_s_;
  updateFeatures();
  return dphi;
}

Vector6d Instrument::couplingWrench() const {
  Vector6d w;
  w.head<3>() = spec_.coupling_k_npm * (target_.pos_m - pose_.pos_m) +
                spec_.coupling_b_nspm * (target_twist_.head<3>() - twist_.head<3>());
  w.tail<3>() = spec_.coupling_k_rot_nmprad *
                    shared::rotationVector(target_.rot * pose_.rot.conjugate()) +
                spec_.coupling_b_rot_nmsprad * (target_twist_.tail<3>() - twist_.tail<3>());
  return -w;
}

double Instrument::kineticEnergy() const {
  return 0.5 * spec_.mass_kg * twist_.head<3>().squaredNorm() +
         0.5 * spec_.inertia_kgm2 * twist_.tail<3>().squaredNorm() +
         0.5 * spec_.grip_inertia_kgm2 * grip_rate_ * grip_rate_;
}

Eigen::Matrix<double, 3, 6> Instrument::toolPointJacobian(const Eigen::Vector3d& point_m) const {
  return shared::pointJacobian(pose_.pos_m, point_m);
}

Eigen::Vector3d Instrument::toLocal(const Eigen::Vector3d& point_m) const {
  return pose_.rot.conjugate() * (point_m - pose_.pos_m);
}

void Instrument::updateFeatures() {
  const Eigen::Matrix3d rot = pose_.rot.toRotationMatrix();
  const Eigen::Vector3d& o = pose_.pos_m;
  if (spec_.kind == InstrumentKind::kProbe) {
    ToolFeature& tip = features_[0];
    tip.id = 0;
    tip.shape = FeatureShape::kSphere;
    tip.part = 0;
    tip.a_m = o;
    tip.b_m = o;
    tip.radius_m = spec_.tip_radius_m;
    tip.query_vertices = true;
    if (features_.size() > 1) {
      ToolFeature& shaft = features_[1];
      shaft.id = 1;
      shaft.shape = FeatureShape::kCapsule;
      shaft.part = 0;
      shaft.a_m = o;
      shaft.b_m = o + rot.col(2) * spec_.shaft_length_m;
      shaft.radius_m = spec_.tip_radius_m;
      shaft.skip_cap_a = true;
    }
    return;
  }
  if (spec_.pad_width_m > 0.0) {
    updatePadFeatures();
    return;
  }
  // grasper: per jaw and row one capsule then its sample spheres
  const int n = spec_.jaw_samples;
  const int rows = spec_.jaw_rows;
  const double phi = opening_ * spec_.max_opening_rad;
  const double r = spec_.jaw_radius_m;
  for (int jr = 0; jr < 2 * rows; ++jr) {
    const int j = jr / rows;
    const int row = jr % rows;
    const double side = j == 0 ? 1.0 : -1.0;
    const double x = rows == 1 ? 0.0 : spec_.jaw_width_m * (static_cast<double>(row) / (rows - 1) - 0.5);
    Eigen::Vector3d a, b;
    jawAxis(pose_, rot, side, phi, x, r, spec_.jaw_length_m, a, b);
    const int base = jr * (n + 1);
    setJawFeature(features_[base], base, FeatureShape::kCapsule, j, a, b, r, a, side);
    for (int i = 0; i < n; ++i) {
      const double t = n == 1 ? 1.0 : static_cast<double>(i) / (n - 1);
      const Eigen::Vector3d c = a + t * (b - a);
      setJawFeature(features_[base + 1 + i], base + 1 + i, FeatureShape::kSphere, j, c, c, r, a,
                    side);
    }
  }
}

// Flat pads: per jaw the pad rectangle, then its grid of sample spheres (see the header comment).
void Instrument::updatePadFeatures() {
  const Eigen::Matrix3d rot = pose_.rot.toRotationMatrix();
  const int n = spec_.jaw_samples;
  const int k = spec_.pad_columns;
  const double phi = opening_ * spec_.max_opening_rad;
  const double r = spec_.jaw_radius_m;
  const Eigen::Vector3d half_width = rot.col(0) * (0.5 * spec_.pad_width_m);
  for (int j = 0; j < 2; ++j) {
    const double side = j == 0 ? 1.0 : -1.0;
    Eigen::Vector3d a, b;
    jawAxis(pose_, rot, side, phi, 0.0, r, spec_.jaw_length_m, a, b);
    const int base = j * (1 + n * k);
    ToolFeature& pad = features_[static_cast<std::size_t>(base)];
    setJawFeature(pad, base, FeatureShape::kPad, j, a, b, r, a, side);
    pad.half_width_m = half_width;
    for (int i = 0; i < n; ++i) {
      const double t = n == 1 ? 1.0 : static_cast<double>(i) / (n - 1);
      for (int c = 0; c < k; ++c) {
        const double x = k == 1 ? 0.0 : 2.0 * (static_cast<double>(c) / (k - 1) - 0.5);
        const int id = base + 1 + i * k + c;
        const Eigen::Vector3d centre = a + t * (b - a) + x * half_width;
        ToolFeature& sample = features_[static_cast<std::size_t>(id)];
        setJawFeature(sample, id, FeatureShape::kSphere, j, centre, centre, r, a, side);
        sample.face_only = true;
      }
    }
  }
}

}  // namespace tactus::sim
