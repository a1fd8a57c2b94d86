#pragma once
// The instrument: a rigid 6-DOF god object coupled to the device (paper 4.1; docs/design.md,
// "The god object and its PD coupling"), and its collision geometry.
//
// Dynamics. State: pose x = (p, R), twist [v; w] (world frame, see tactus/shared/pose.h).
// The device target x_h = (p_h, R_h) with twist [v_h; w_h] pulls the god object through a PD
// coupling (isotropic gains):
//     F_c   = K_c (p_h - p) + B_c (v_h - v)
//     tau_c = K_r log(R_h R^-1) + B_r (w_h - w)
// Mass m and isotropic inertia I (so no gyroscopic term). Integration follows the tissue's
// scheme:
//  * free motion: implicit Euler with the coupling linearised at the start of the step (so any
//    K_c is stable; for K_c -> inf the god object lands on the target in one step):
//        (m/h + B_c + h K_c) v+ = m v/h + K_c (p_h - p) + B_c v_h,     p+ = p + h v+
//        (I/h + B_r + h K_r) w+ = I w/h + K_r log(R_h R^-1) + B_r w_h, R+ = exp(h w+) R
//  * correction from the contact wrench r (force at the tool origin, torque about it):
//        dx = C6 r,  C6 = (M_t/h^2 + B_c/h + K_c)^-1 = diag(c_l I3, c_r I3),
//        x <- x [+] dx,  [v; w] += dx / h.
// The force rendered to the hand is -(F_c, tau_c) at the current state and the last target.
//
// Workspace. Whatever the device or a caller sends, the target the god object follows is
// bounded: freeMotion clamps the target position into the workspace box (setWorkspace; the scene's
// instrument.workspace, else the scene's bounds grown by kWorkspaceMarginM, see
// instrumentWorkspace; the target velocity across a wall it was clamped to is zeroed) and the
// target twist to kMaxTargetSpeedMps / kMaxTargetAngularSpeedRadps, and counts the steps it had
// to clamp. A finite but absurd target (1e300 m) then parks the god
// object at the workspace's edge, finite, and it comes back as soon as the target does.
//
// Geometry (tool frame: origin at the tool point / hinge, z along the instrument):
//  * probe:   feature 0 = sphere of tip_radius at the origin (queried against tissue
//             triangles); feature 1 (only if shaft_length > 0) = capsule of radius tip_radius
//             from the origin to (0, 0, +shaft_length) (the shaft rises away from the tip;
//             queried against tissue vertices, ignoring vertices whose closest axis point is
//             the origin end, which belong to the tip).
//  * grasper: two jaws hinged at the origin pointing along -z. Jaw j in {0, 1}, side
//             s_j = +1 / -1: axis from a_j = (0, s_j r_jaw, 0) to a_j + L Rx(s_j phi)(0,0,-1),
//             phi = opening * max_opening_rad, Rx the rotation about the tool x axis. Opening 0:
//             the two parallel axes are 2 r_jaw apart, so the closed jaw surfaces touch along
//             the plane y = 0 (pinch); opening > 0 moves jaw 0's tip toward +y and jaw 1's
//             toward -y. Each jaw is one capsule (vertex queries) plus jaw_samples spheres of
//             jaw_radius centred on its axis at t = i/(n-1), i = 0..n-1 (t = 1 when n = 1), t
//             measured from the hinge end (triangle queries).
//             Ids: jaw 0 capsule 0, its samples 1..n; jaw 1 capsule n+1, samples n+2..2n+1.
//             Jaw pads (jaw_rows k > 1): each jaw is k such rows, row i's axis shifted along the
//             tool x axis (the hinge axis) by jaw_width (i/(k-1) - 1/2); ids run jaw-major,
//             then row: jaw j row i has capsule (j k + i)(n + 1) and samples after it.
//  Flat pads (pad_width_m > 0; both scenes): each jaw is a rounded box, the rectangle of
//             jaw_length x pad_width swept by a sphere of jaw_radius: jaw j's rectangle has its
//             length along the jaw axis above (a_j .. b_j, jaw_rows ignored) and its width
//             along the tool x axis (half-width vector e_j = (pad_width/2) x_tool), so the
//             closed pads touch face to face along y = 0. Features of jaw j (base j (1 + n k),
//             n = jaw_samples, k = pad_columns): the pad (kPad, queried against tissue
//             vertices: one contact per vertex and jaw) at base, then n k sample spheres of
//             jaw_radius centred on the rectangle's grid (length-major: sample i along the
//             length at t = i/(n-1), column c across the width at x = c/(k-1) - 1/2, 0 when
//             k = 1), queried against tissue triangles but kept only at interior and edge
//             points not already used (face_only: a vertex is the pad feature's, so no tissue
//             point gets two contacts from one jaw; collision.h (c)).
//  Grip. By default the jaws are kinematic: the opening follows the gripper value given to
//  freeMotion, whatever lies between them (a closing grasper squeezes tissue near the hinge
//  without limit). With grip_k_nmprad > 0 the jaw half-angle phi = opening * max_opening_rad is
//  a DOF of the god object, pulled toward the device's phi_h by a PD law and integrated like the
//  rotation (implicit Euler, coupling linearised at the start of the step):
//      (I_g/h + B_g + h K_g) w+ = I_g w/h + K_g (phi_h - phi) - (1 - g) S,  phi+ = phi + h w+,
//  with g the device's gripper value (phi_h = g max_opening_rad) and S the squeeze of a closed
//  handle (grip_squeeze_nm: the spring alone pulls with K_g phi, which vanishes as the jaws close
//  on a thin bite); phi+ is kept at most max_opening_rad, and the correction (called every step,
//  with or without contacts) clamps the angle to [0, max_opening_rad], so that a squeeze's free
//  motion past closed is opened by the tissue's torque. Its compliance
//  c_g = (I_g/h^2 + B_g/h + K_g)^-1 enters W with the contact rows' column
//  g_r = dir_r . dp/dphi (gripJacobian), and the correction turns the contact torque g^T f into
//  dphi = c_g g^T f: the jaws stop where the tissue pushes back as hard as the grip spring
//  pulls, as a real grasper's finite grip force does. The open stop, with grip_hold_open_stop
//  (else the angle is clamped after the solve):
//  when the last correction's contact torque tau would open this step's free jaws to
//  max_opening_rad (phi_free + c_g tau >= max_opening_rad), the stop holds them there for the
//  step: the free motion leaves them at the stop and c_g = 0 in W (the solve counts on no
//  yield where the jaws cannot yield; a clamp after the solve left the contacts penetrating by
//  what the jaws failed to open).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <span>
#include <vector>

#include "tactus/shared/pose.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {

class StateArchive;

using shared::Matrix6d;
using shared::Vector6d;

enum class FeatureShape : std::uint8_t {
  kSphere,    ///< centre a_m (== b_m): queried against tissue surface triangles
  kCapsule,   ///< segment a_m..b_m: queried against tissue surface vertices
  /// rectangle {a_m + s (b_m - a_m) + x half_width_m : s in [0, 1], x in [-1, 1]} swept by
  /// radius_m: queried against tissue surface vertices
  kPad,
};

/// One collision primitive of the tool, in world coordinates at the current pose and opening.
struct ToolFeature {
  int id = 0;                        ///< stable id (see the header comment)
  FeatureShape shape = FeatureShape::kSphere;
  int part = 0;                      ///< probe: 0; grasper: jaw index 0 or 1
  Eigen::Vector3d a_m = Eigen::Vector3d::Zero();
  Eigen::Vector3d b_m = Eigen::Vector3d::Zero();
  double radius_m = 0.0;
  bool skip_cap_a = false;           ///< capsule: ignore vertices whose closest axis point is a
  /// sphere: also query tissue vertices against it (a sphere not covered by a capsule, such as
  /// the probe tip: on a fine surface the triangle query's local minima leave the nodes between
  /// them free to sink into the sphere)
  bool query_vertices = false;
  /// sphere: drop contacts whose closest tissue point is a vertex or a point already used (pad
  /// samples; collision.h (c))
  bool face_only = false;
  /// pad: half of the rectangle's width, along the width (perpendicular to b_m - a_m)
  Eigen::Vector3d half_width_m = Eigen::Vector3d::Zero();
  /// grasper: the jaw's hinge point (its axis start) and the sign s_j of its opening (+1 jaw 0,
  /// -1 jaw 1): a jaw-fixed point p moves by s_j x_tool x (p - hinge) per radian of phi.
  Eigen::Vector3d hinge_m = Eigen::Vector3d::Zero();
  double opening_sign = 0.0;
};

/// Margin around the scene's bounds of the default workspace [m] (a haptic device's whole reach).
inline constexpr double kWorkspaceMarginM = 0.5;
/// Workspace before setWorkspace: a cube of this half-size around the origin [m].
inline constexpr double kDefaultWorkspaceHalfM = 10.0;
/// Bounds of the target twist: faster than any hand moves a tool.
inline constexpr double kMaxTargetSpeedMps = 10.0;
inline constexpr double kMaxTargetAngularSpeedRadps = 100.0;

/// The workspace of the scene's instrument: spec.workspace when the scene gives one, else the box
/// around `scene_bounds` (e.g. the tissues' rest positions; may be empty), the initial pose and
/// every trajectory key, grown by kWorkspaceMarginM on every side.
BoxSpec instrumentWorkspace(const InstrumentSpec& spec, const Eigen::AlignedBox3d& scene_bounds);

/// The liver scenes' grasper and approach before the flat pads, for the tests and the
/// accuracy study calibrated on it: round kinematic jaws of radius 2 mm with 8 samples each,
/// closing to 0.25, no contact compliance, and the trajectory keys at x = 0.100 m (the pads'
/// grasp point) moved back to the former 0.107 m.
void useFormerRoundJaws(SceneSpec& spec);

/// scenes/liver_grasp.yaml's script before its approach turned 60 deg toward the lobe's mass
/// (docs/measurements.md, "Grasps"): the tool's jaws along world -x at y = 10 mm, z = -4 mm,
/// the hinge from x = 135 mm to 100 mm, closing, a 2 cm lift, the hold, the release. For the
/// tests and the accuracy study written for it (useFormerRoundJaws then moves its grasp to the
/// round jaws' 107 mm).
void useFormerLiverGraspScript(SceneSpec& spec);

/// PoseSpec (scene file) -> Pose.
inline shared::Pose toPose(const PoseSpec& spec) {
  shared::Pose p;
  p.pos_m = spec.position_m;
  p.rot = spec.orientation.normalized();
  return p;
}

class Instrument {
 public:
  /// Validates the spec (throws tactus::SceneError naming the `instrument.<field>` at fault) and
  /// places the god object at spec.initial_pose, at rest, with the opening of the first
  /// trajectory key (or fully open).
  explicit Instrument(const InstrumentSpec& spec);

  const InstrumentSpec& spec() const { return spec_; }

  /// Places the god object at `pose` with zero twist; the target becomes that pose.
  void reset(const shared::Pose& pose, double gripper_opening = 1.0);

  /// Bounds the target position to `box` (see the header comment). Throws tactus::SceneError
  /// when the box is not finite or min > max in some coordinate.
  void setWorkspace(const BoxSpec& box);
  const BoxSpec& workspace() const { return workspace_; }
  /// Free motions whose target position or twist had to be clamped (see the header comment).
  long clampedTargets() const { return clamped_targets_; }

  /// Free motion over h_s toward the device target (pose, world twist [v; w]) and gripper
  /// opening (clamped to [0, 1]), the target bounded to the workspace first. Updates pose, twist
  /// and features. No allocation. h_s <= 0: no-op.
  void freeMotion(double h_s, const shared::Pose& target, const Vector6d& target_twist,
                  double gripper_opening);

  /// C6 = (M_t/h^2 + B_c/h + K_c)^-1 (6x6, [lin; ang] blocks, diagonal): pose increment per unit
  /// wrench.
  Matrix6d compliance6(double h_s) const;

  /// G = d(free pose) / d(target pose) of the last freeMotion (6x6; both sides as world twists,
  /// see poseDifference): lin block c_l K_c I3, rot block J_l(h w+) c_r K_r J_l^-1(theta0) with
  /// theta0 = log(R_h R^-1) at the start of that step. Before any freeMotion: for a target at the
  /// current pose. The lead forms J = H_tool G (d delta_free / d x_h).
  Matrix6d freeMotionSensitivity(double h_s) const;

  /// Constrained motion: dx = C6(h) wrench with h the last freeMotion step, pose <- pose [+] dx,
  /// twist += dx / h. Returns dx. Does nothing (returns zero) before the first freeMotion.
  Vector6d applyCorrection(const Vector6d& wrench);

  /// Grip (see the header comment): true when the jaw angle is a DOF (grasper, grip_k > 0).
  bool dynamicGrip() const { return grip_dynamic_; }
  /// c_g = (I_g/h^2 + B_g/h + K_g)^-1 [rad / (N m)]: what W counts on the jaws yielding per
  /// unit contact torque; 0 for kinematic jaws and while the jaws are held at their open stop
  /// (gripHeldOpen).
  double gripCompliance(double h_s) const;
  /// c_g whether or not the stop holds the jaws.
  double freeGripCompliance(double h_s) const;
  /// The open stop holds the jaws in this step (see the header comment): the last
  /// correction's contact torque would open the free jaws to it.
  bool gripHeldOpen() const { return grip_held_open_; }
  /// d(point)/d(phi) [m / rad] of a point attached to feature `feature_id` (zero for the probe and
  /// for kinematic jaws).
  Eigen::Vector3d gripJacobian(int feature_id, const Eigen::Vector3d& point_m) const;
  /// Constrained motion of the jaw angle: dphi = c_g(h) torque (clamped to the range), rate +=
  /// dphi / h. Returns dphi. No-op (0) for kinematic jaws or before the first freeMotion.
  double applyGripCorrection(double torque_nm);
  double gripRate() const { return grip_rate_; }   ///< d phi / dt [rad/s]

  /// The wrench on the hand [force_n; torque_nm] = -(coupling wrench on the god object), at the
  /// current state and the last target. This is what the device renders (before scaling).
  Vector6d couplingWrench() const;

  double kineticEnergy() const;
  const shared::Pose& pose() const { return pose_; }
  const Vector6d& twist() const { return twist_; }              ///< [v; w], world frame
  const shared::Pose& targetPose() const { return target_; }
  double gripperOpening() const { return opening_; }
  double lastStep() const { return h_s_; }

  /// Current features (world frame). Updated by reset/freeMotion/applyCorrection.
  std::span<const ToolFeature> features() const { return features_; }

  /// 3x6 map from a pose increment [dp; dtheta] to the displacement of the rigidly attached
  /// world point: [I, -[r]x], r = point - origin.
  Eigen::Matrix<double, 3, 6> toolPointJacobian(const Eigen::Vector3d& point_m) const;

  /// World point -> tool frame.
  Eigen::Vector3d toLocal(const Eigen::Vector3d& point_m) const;

  /// Writes or reads the god object's state (state_archive.h): pose, twist, target, opening,
  /// grip rate and what the last free motion left for the correction; reading recomputes the
  /// features. Throws StateError.
  void transferState(StateArchive& ar);

 private:
  void updateFeatures();
  void updatePadFeatures();

  // Model, state and scratch (docs/design.md, "Model, state, scratch"); the members stay in one
  // list (the god object is small and copied whole for the start-of-step contacts,
  // StepScratch::tool_start):
  //  * model, fixed after construction and setWorkspace: spec_, workspace_, grip_dynamic_;
  //  * state, changed by freeMotion / applyCorrection / applyGripCorrection / reset: pose_,
  //    twist_, target_, target_twist_, opening_, grip_rate_, and what the last free motion
  //    leaves for the correction and freeMotionSensitivity: h_s_, theta0_, rot_step_;
  //  * derived from the state: features_ (the geometry at pose_ and opening_, recomputed after
  //    every change; its storage is sized once, so no scratch reallocates in a step);
  //  * statistics: clamped_targets_.
  InstrumentSpec spec_;
  BoxSpec workspace_{Eigen::Vector3d::Constant(-kDefaultWorkspaceHalfM),
                     Eigen::Vector3d::Constant(kDefaultWorkspaceHalfM), {}};
  long clamped_targets_ = 0;
  shared::Pose pose_;
  Vector6d twist_ = Vector6d::Zero();
  shared::Pose target_;
  Vector6d target_twist_ = Vector6d::Zero();
  double opening_ = 1.0;
  bool grip_dynamic_ = false;
  double grip_rate_ = 0.0;                              ///< d phi / dt [rad/s]
  bool grip_held_open_ = false;                         ///< the open stop holds the jaws
  double grip_torque_last_nm_ = 0.0;   ///< the last correction's contact torque on the jaws
  double h_s_ = 0.0;
  Eigen::Vector3d theta0_ = Eigen::Vector3d::Zero();   ///< log(R_h R^-1) at the last free motion
  Eigen::Vector3d rot_step_ = Eigen::Vector3d::Zero(); ///< h w+ of the last free motion
  std::vector<ToolFeature> features_;                   ///< sized once in the constructor
};

}  // namespace tactus::sim
