// The god-object instrument: PD coupling integrated implicitly, compliance, sensitivity to the
// device pose, correction, rendered wrench and the collision geometry of probe and grasper.
#include "tactus/sim/instrument.h"

#include <gtest/gtest.h>

#include <cmath>

#include "tactus/shared/error.h"

namespace {

using tactus::shared::Pose;
using tactus::sim::FeatureShape;
using tactus::sim::Instrument;
using tactus::sim::InstrumentKind;
using tactus::sim::InstrumentSpec;
using tactus::sim::Matrix6d;
using tactus::sim::Vector6d;
namespace ts = tactus::shared;

InstrumentSpec probeSpec() {
  InstrumentSpec s;
  s.present = true;
  s.kind = InstrumentKind::kProbe;
  s.mass_kg = 0.05;
  s.inertia_kgm2 = 1e-5;
  s.coupling_k_npm = 500.0;
  s.coupling_b_nspm = 5.0;
  s.coupling_k_rot_nmprad = 0.5;
  s.coupling_b_rot_nmsprad = 0.005;
  s.tip_radius_m = 0.003;
  s.shaft_length_m = 0.1;
  return s;
}

InstrumentSpec grasperSpec() {
  InstrumentSpec s = probeSpec();
  s.kind = InstrumentKind::kGrasper;
  s.jaw_length_m = 0.02;
  s.jaw_radius_m = 0.002;
  s.max_opening_rad = 0.6;
  s.jaw_samples = 5;
  return s;
}

Pose targetPose() {
  Pose t;
  t.pos_m = Eigen::Vector3d(0.05, -0.02, 0.03);
  t.rot = Eigen::Quaterniond(Eigen::AngleAxisd(0.8, Eigen::Vector3d(1, 2, -1).normalized()));
  return t;
}

TEST(Instrument, StiffCouplingConvergesWithoutBlowUp) {
  for (double k : {500.0, 1e5, 1e8}) {
    InstrumentSpec spec = probeSpec();
    spec.coupling_k_npm = k;
    spec.coupling_k_rot_nmprad = k * 1e-3;
    Instrument tool(spec);
    const Pose target = targetPose();
    const double h = 0.01;
    const double start_err = ts::poseDifference(target, tool.pose()).head<3>().norm();
    const double start_rot = ts::poseDifference(target, tool.pose()).tail<3>().norm();
    double max_pos_err = 0.0, max_rot_err = 0.0, max_energy = 0.0;
    for (int i = 0; i < 400; ++i) {
      tool.freeMotion(h, target, Vector6d::Zero(), 1.0);
      const Vector6d e = ts::poseDifference(target, tool.pose());
      ASSERT_TRUE(e.allFinite());
      max_pos_err = std::max(max_pos_err, e.head<3>().norm());
      max_rot_err = std::max(max_rot_err, e.tail<3>().norm());
      max_energy = std::max(max_energy, tool.kineticEnergy());
    }
    const Vector6d e = ts::poseDifference(target, tool.pose());
    EXPECT_LT(e.head<3>().norm(), 1e-6 * start_err) << "K=" << k;
    EXPECT_LT(e.tail<3>().norm(), 1e-6 * start_rot) << "K=" << k;
    // never farther than at the start (no overshoot growth), bounded energy
    EXPECT_LE(max_pos_err, start_err * (1.0 + 1e-12)) << "K=" << k;
    EXPECT_LE(max_rot_err, start_rot * (1.0 + 1e-12)) << "K=" << k;
    // the kinetic energy cannot exceed what the spring stored at the start
    EXPECT_LT(max_energy, 0.5 * k * start_err * start_err + 0.5 * k * 1e-3 * start_rot * start_rot)
        << "K=" << k;
    EXPECT_LT(tool.kineticEnergy(), 1e-12);
  }
}

TEST(Instrument, VeryStiffCouplingLandsOnTargetInOneStep) {
  InstrumentSpec spec = probeSpec();
  spec.coupling_k_npm = 1e12;
  spec.coupling_k_rot_nmprad = 1e9;
  Instrument tool(spec);
  const Pose target = targetPose();
  tool.freeMotion(0.01, target, Vector6d::Zero(), 1.0);
  const Vector6d e = ts::poseDifference(target, tool.pose());
  EXPECT_LT(e.head<3>().norm(), 1e-8);
  // the rotation is linearised (theta0 - h w), so it lands to first order
  EXPECT_LT(e.tail<3>().norm(), 1e-6);
}

TEST(Instrument, Compliance6IsTheInverseFormula) {
  Instrument tool(probeSpec());
  const InstrumentSpec& s = tool.spec();
  for (double h : {0.001, 0.01, 0.02}) {
    Matrix6d a = Matrix6d::Zero();
    a.topLeftCorner<3, 3>().diagonal().setConstant(s.mass_kg / (h * h) + s.coupling_b_nspm / h +
                                                   s.coupling_k_npm);
    a.bottomRightCorner<3, 3>().diagonal().setConstant(
        s.inertia_kgm2 / (h * h) + s.coupling_b_rot_nmsprad / h + s.coupling_k_rot_nmprad);
    const Matrix6d c = tool.compliance6(h);
    EXPECT_LT((c * a - Matrix6d::Identity()).norm(), 1e-12) << h;
    EXPECT_LT((c - c.transpose()).norm(), 1e-20);
  }
}

// A state with some velocity and a large rotation offset so the SO(3) Jacobians matter.
Instrument movingTool() {
  Instrument tool(probeSpec());
  Pose start;
  start.pos_m = Eigen::Vector3d(0.01, 0.0, 0.02);
  start.rot = Eigen::Quaterniond(Eigen::AngleAxisd(-0.6, Eigen::Vector3d::UnitY()));
  tool.reset(start, 0.5);
  Vector6d twist;
  twist << 0.1, -0.05, 0.02, 0.3, -0.2, 0.5;
  for (int i = 0; i < 3; ++i) tool.freeMotion(0.01, targetPose(), twist, 0.5);
  return tool;
}

TEST(Instrument, SensitivityMatchesFiniteDifferences) {
  const double h = 0.01;
  const Pose target = targetPose();
  Vector6d target_twist;
  target_twist << 0.02, 0.01, -0.03, 0.1, 0.0, -0.2;
  const Instrument base = movingTool();
  Instrument nominal = base;
  nominal.freeMotion(h, target, target_twist, 0.5);
  const Matrix6d g = nominal.freeMotionSensitivity(h);
  // rotational block is far from a multiple of the identity here: the test is not trivial
  EXPECT_GT((g.bottomRightCorner<3, 3>() - g(3, 3) * Eigen::Matrix3d::Identity()).norm(), 1e-3);
  const double eps = 1e-6;
  Matrix6d fd;
  for (int i = 0; i < 6; ++i) {
    Vector6d e = Vector6d::Zero();
    e(i) = eps;
    Instrument plus = base, minus = base;
    plus.freeMotion(h, ts::applyTwist(target, e), target_twist, 0.5);
    minus.freeMotion(h, ts::applyTwist(target, -e), target_twist, 0.5);
    fd.col(i) = ts::poseDifference(plus.pose(), minus.pose()) / (2 * eps);
  }
  EXPECT_LT((fd - g).norm(), 1e-6 * g.norm()) << "fd\n" << fd << "\nG\n" << g;
}

TEST(Instrument, ToolPointJacobianMatchesFiniteDifferences) {
  const Instrument tool = movingTool();
  const Eigen::Vector3d point = tool.pose().pos_m + Eigen::Vector3d(0.01, -0.02, 0.03);
  const Eigen::Vector3d local = tool.toLocal(point);
  const Eigen::Matrix<double, 3, 6> j = tool.toolPointJacobian(point);
  const double eps = 1e-6;
  for (int i = 0; i < 6; ++i) {
    Vector6d e = Vector6d::Zero();
    e(i) = eps;
    const Pose plus = ts::applyTwist(tool.pose(), e), minus = ts::applyTwist(tool.pose(), -e);
    const Eigen::Vector3d fd =
        ((plus.pos_m + plus.rot * local) - (minus.pos_m + minus.rot * local)) / (2 * eps);
    EXPECT_LT((fd - j.col(i)).norm(), 1e-8) << i;
  }
}

TEST(Instrument, CorrectionMovesByComplianceTimesWrench) {
  Instrument tool = movingTool();
  const double h = tool.lastStep();
  const Pose before = tool.pose();
  const Vector6d twist_before = tool.twist();
  Vector6d wrench;
  wrench << 0.5, -1.0, 2.0, 0.01, 0.0, -0.02;
  const Vector6d dx = tool.applyCorrection(wrench);
  EXPECT_LT((dx - tool.compliance6(h) * wrench).norm(), 1e-15);
  EXPECT_LT((ts::poseDifference(tool.pose(), before) - dx).norm(), 1e-12);
  EXPECT_LT((tool.twist() - twist_before - dx / h).norm(), 1e-12);
}

TEST(Instrument, CouplingWrenchIsTheForceOnTheHand) {
  Instrument tool(probeSpec());
  Pose target;
  target.pos_m = Eigen::Vector3d(0.01, 0.0, 0.0);
  target.rot = Eigen::Quaterniond(Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ()));
  // a contact holds the god object in place: the free motion moves it, the correction undoes it
  tool.freeMotion(0.01, target, Vector6d::Zero(), 1.0);
  const Vector6d back = ts::poseDifference(Pose{}, tool.pose());
  ASSERT_GT(back.norm(), 1e-4);
  tool.applyCorrection(tool.compliance6(0.01).inverse() * back);
  EXPECT_LT(ts::poseDifference(tool.pose(), Pose{}).norm(), 1e-12);
  EXPECT_LT(tool.twist().norm(), 1e-9);
  // the device is pulled back toward the god object (-x), twisted back (-z), plus damping
  const Vector6d w = tool.couplingWrench();
  EXPECT_NEAR(w(0), -tool.spec().coupling_k_npm * 0.01, 1e-9);
  EXPECT_NEAR(w(1), 0.0, 1e-12);
  EXPECT_NEAR(w(5), -tool.spec().coupling_k_rot_nmprad * 0.1, 1e-9);
}

TEST(Instrument, ProbeGeometry) {
  Instrument tool(probeSpec());
  Pose p;
  p.pos_m = Eigen::Vector3d(0.1, 0.2, 0.3);
  p.rot = Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitX()));
  tool.reset(p);
  ASSERT_EQ(tool.features().size(), 2u);
  const auto& tip = tool.features()[0];
  const auto& shaft = tool.features()[1];
  EXPECT_EQ(tip.shape, FeatureShape::kSphere);
  EXPECT_LT((tip.a_m - p.pos_m).norm(), 1e-15);
  EXPECT_DOUBLE_EQ(tip.radius_m, 0.003);
  EXPECT_EQ(shaft.shape, FeatureShape::kCapsule);
  EXPECT_TRUE(shaft.skip_cap_a);
  // the shaft rises along the tool +z, which the rotation maps to world -y
  EXPECT_LT((shaft.b_m - (p.pos_m + Eigen::Vector3d(0, -0.1, 0))).norm(), 1e-12);
  InstrumentSpec no_shaft = probeSpec();
  no_shaft.shaft_length_m = 0.0;
  EXPECT_EQ(Instrument(no_shaft).features().size(), 1u);
}

TEST(Instrument, GrasperGeometryPinchesWhenClosed) {
  InstrumentSpec spec = grasperSpec();
  Instrument tool(spec);
  const int n = spec.jaw_samples;
  tool.reset(Pose{}, 0.0);
  ASSERT_EQ(tool.features().size(), static_cast<std::size_t>(2 * (n + 1)));
  for (std::size_t i = 0; i < tool.features().size(); ++i) {
    EXPECT_EQ(tool.features()[i].id, static_cast<int>(i));
  }
  const auto& jaw0 = tool.features()[0];
  const auto& jaw1 = tool.features()[n + 1];
  EXPECT_EQ(jaw0.shape, FeatureShape::kCapsule);
  EXPECT_EQ(jaw0.part, 0);
  EXPECT_EQ(jaw1.part, 1);
  // closed: parallel axes along -z, 2 r apart: the jaw surfaces touch at y = 0
  EXPECT_LT((jaw0.a_m - Eigen::Vector3d(0, 0.002, 0)).norm(), 1e-15);
  EXPECT_LT((jaw0.b_m - Eigen::Vector3d(0, 0.002, -0.02)).norm(), 1e-15);
  EXPECT_LT((jaw1.b_m - Eigen::Vector3d(0, -0.002, -0.02)).norm(), 1e-15);
  // samples on the axis from hinge to tip
  EXPECT_LT((tool.features()[1].a_m - jaw0.a_m).norm(), 1e-15);
  EXPECT_LT((tool.features()[n].a_m - jaw0.b_m).norm(), 1e-15);
  EXPECT_EQ(tool.features()[n + 2].part, 1);
  // open: the tips separate symmetrically by L sin(phi) each
  tool.freeMotion(0.01, Pose{}, Vector6d::Zero(), 1.0);
  const double phi = spec.max_opening_rad;
  EXPECT_NEAR(tool.features()[0].b_m.y(), 0.002 + 0.02 * std::sin(phi), 1e-12);
  EXPECT_NEAR(tool.features()[n + 1].b_m.y(), -0.002 - 0.02 * std::sin(phi), 1e-12);
  EXPECT_NEAR(tool.features()[0].b_m.z(), -0.02 * std::cos(phi), 1e-12);
  // the opening is clamped to [0, 1]
  tool.freeMotion(0.01, Pose{}, Vector6d::Zero(), 3.0);
  EXPECT_DOUBLE_EQ(tool.gripperOpening(), 1.0);
}

// Jaw pads: rows of samples side by side along the hinge axis; the rows of one jaw are copies
// of the round jaw shifted along tool x, and the ids stay dense and jaw-major.
TEST(Instrument, GrasperPadRowsSpanTheWidthAlongTheHingeAxis) {
  InstrumentSpec round = grasperSpec();
  InstrumentSpec pad = grasperSpec();
  pad.jaw_rows = 3;
  pad.jaw_width_m = 0.006;
  Instrument a(round);
  Instrument b(pad);
  Pose pose = targetPose();
  a.reset(pose, 0.4);
  b.reset(pose, 0.4);
  a.freeMotion(0.01, pose, Vector6d::Zero(), 0.4);
  b.freeMotion(0.01, pose, Vector6d::Zero(), 0.4);
  const int n = pad.jaw_samples;
  ASSERT_EQ(b.features().size(), static_cast<std::size_t>(2 * 3 * (n + 1)));
  for (std::size_t i = 0; i < b.features().size(); ++i) {
    EXPECT_EQ(b.features()[i].id, static_cast<int>(i));
  }
  const Eigen::Vector3d hinge_axis = b.pose().rot * Eigen::Vector3d::UnitX();
  for (int j = 0; j < 2; ++j) {
    for (int row = 0; row < 3; ++row) {
      const double shift = 0.006 * (row / 2.0 - 0.5);
      for (int k = 0; k <= n; ++k) {
        const tactus::sim::ToolFeature& f = b.features()[(j * 3 + row) * (n + 1) + k];
        const tactus::sim::ToolFeature& g = a.features()[j * (n + 1) + k];
        EXPECT_EQ(f.part, j);
        EXPECT_EQ(f.shape, g.shape);
        EXPECT_LT((f.a_m - (g.a_m + shift * hinge_axis)).norm(), 1e-12);
        EXPECT_LT((f.b_m - (g.b_m + shift * hinge_axis)).norm(), 1e-12);
      }
    }
  }
  pad.jaw_width_m = 0.0;
  EXPECT_THROW(Instrument{pad}, tactus::SceneError);
  pad.jaw_rows = 0;
  pad.jaw_width_m = 0.006;
  EXPECT_THROW(Instrument{pad}, tactus::SceneError);
}

// Dynamic grip: without contacts the jaw angle follows the device's value through its PD law
// (implicit Euler, so it settles without overshoot for this damping), its compliance is the
// 1-DOF formula, and gripJacobian is the derivative of the jaw points with respect to the angle.
TEST(Instrument, DynamicGripFollowsTheTargetAndItsJacobianIsTheDerivative) {
  InstrumentSpec spec = grasperSpec();
  spec.grip_k_nmprad = 2.0;
  spec.grip_b_nmsprad = 0.05;
  spec.grip_inertia_kgm2 = 1e-6;
  Instrument tool(spec);
  ASSERT_TRUE(tool.dynamicGrip());
  const double h = 0.01;
  EXPECT_NEAR(tool.gripCompliance(h), 1.0 / (1e-6 / (h * h) + 0.05 / h + 2.0), 1e-15);
  const Pose pose = targetPose();
  tool.reset(pose, 1.0);
  // one step moves only part of the way (finite stiffness), many steps reach the target
  tool.freeMotion(h, pose, Vector6d::Zero(), 0.3);
  EXPECT_LT(tool.gripperOpening(), 1.0);
  EXPECT_GT(tool.gripperOpening(), 0.3 + 0.1);
  for (int k = 0; k < 400; ++k) tool.freeMotion(h, pose, Vector6d::Zero(), 0.3);
  EXPECT_NEAR(tool.gripperOpening(), 0.3, 1e-6);
  EXPECT_NEAR(tool.gripRate(), 0.0, 1e-6);
  // a torque opening the jaws: dphi = c_g torque, clamped at the range
  const double before = tool.gripperOpening();
  const double dphi = tool.applyGripCorrection(0.01);
  EXPECT_NEAR(dphi, tool.gripCompliance(h) * 0.01, 1e-15);
  EXPECT_NEAR(tool.gripperOpening(), before + dphi / spec.max_opening_rad, 1e-15);
  // Jacobian: finite difference of every jaw feature's centre over the opening
  Instrument a(spec), b(spec);
  const double eps = 1e-7;
  a.reset(pose, 0.4);
  b.reset(pose, 0.4 + eps / spec.max_opening_rad);
  for (std::size_t i = 0; i < a.features().size(); ++i) {
    const Eigen::Vector3d fd = (b.features()[i].b_m - a.features()[i].b_m) / eps;
    const Eigen::Vector3d jac = a.gripJacobian(static_cast<int>(i), a.features()[i].b_m);
    EXPECT_LT((jac - fd).norm(), 1e-6 * (1.0 + fd.norm())) << "feature " << i;
  }
  // kinematic jaws and the probe: no grip DOF
  Instrument kinematic(grasperSpec());
  EXPECT_FALSE(kinematic.dynamicGrip());
  EXPECT_EQ(kinematic.gripCompliance(h), 0.0);
  EXPECT_EQ(kinematic.gripJacobian(1, Eigen::Vector3d::Ones()).norm(), 0.0);
  kinematic.freeMotion(h, Pose{}, Vector6d::Zero(), 0.3);
  EXPECT_DOUBLE_EQ(kinematic.gripperOpening(), 0.3);
}

// The open stop in the solve: a correction whose contact torque pushes the jaws past their full
// opening is clamped there, and the next free motion leaves them at the stop with no grip
// compliance (W counts on no yield) while that torque would open the free jaws to the stop; once
// the torque falls below that, the stop lets go and the jaws close toward the device's value.
TEST(Instrument, TheOpenStopHoldsTheJawsWhileTheTissuePushesThemOpen) {
  InstrumentSpec spec = grasperSpec();
  spec.grip_k_nmprad = 0.015;
  spec.grip_b_nmsprad = 0.005;
  spec.grip_hold_open_stop = true;
  Instrument tool(spec);
  const double h = 0.01;
  const Pose pose = targetPose();
  tool.reset(pose, 1.0);
  const double c = tool.freeGripCompliance(h);
  // closing from the stop, a contact torque that more than undoes the free motion's closing
  tool.freeMotion(h, pose, Vector6d::Zero(), 0.5);
  EXPECT_FALSE(tool.gripHeldOpen());
  EXPECT_LT(tool.gripperOpening(), 1.0);
  EXPECT_EQ(tool.gripCompliance(h), c);
  const double push = 2.0 * (1.0 - tool.gripperOpening()) * spec.max_opening_rad / c;
  tool.applyGripCorrection(push);
  EXPECT_EQ(tool.gripperOpening(), 1.0);   // clamped at the stop
  // the next step: held at the stop, rigid in W, the correction moves nothing
  tool.freeMotion(h, pose, Vector6d::Zero(), 0.5);
  EXPECT_TRUE(tool.gripHeldOpen());
  EXPECT_EQ(tool.gripperOpening(), 1.0);
  EXPECT_EQ(tool.gripRate(), 0.0);
  EXPECT_EQ(tool.gripCompliance(h), 0.0);
  EXPECT_EQ(tool.applyGripCorrection(push), 0.0);
  EXPECT_EQ(tool.gripperOpening(), 1.0);
  // the tissue lets go: held for the step that learns it, then the jaws close
  tool.freeMotion(h, pose, Vector6d::Zero(), 0.5);
  EXPECT_TRUE(tool.gripHeldOpen());
  tool.applyGripCorrection(0.0);
  tool.freeMotion(h, pose, Vector6d::Zero(), 0.5);
  EXPECT_FALSE(tool.gripHeldOpen());
  EXPECT_LT(tool.gripperOpening(), 1.0);
  EXPECT_EQ(tool.gripCompliance(h), c);
  // without grip_hold_open_stop the stop never holds: clamped after the solve
  spec.grip_hold_open_stop = false;
  Instrument clamp(spec);
  clamp.reset(pose, 1.0);
  clamp.freeMotion(h, pose, Vector6d::Zero(), 0.5);
  clamp.applyGripCorrection(push);
  EXPECT_EQ(clamp.gripperOpening(), 1.0);
  clamp.freeMotion(h, pose, Vector6d::Zero(), 0.5);
  EXPECT_FALSE(clamp.gripHeldOpen());
  EXPECT_EQ(clamp.gripCompliance(h), c);
}

// grip_squeeze: a closed handle pulls with the spring plus the squeeze, so the jaws close on
// nothing as fast as on a thick bite's far side and end at 0 (the correction bounds the angle
// where the free motion carried it past closed); half-closed, half the squeeze.
TEST(Instrument, AClosedHandleSqueezesBeyondTheSpring) {
  InstrumentSpec spec = grasperSpec();
  spec.grip_k_nmprad = 0.015;
  spec.grip_b_nmsprad = 0.005;
  const double h = 0.01;
  const Pose pose = targetPose();
  Instrument spring(spec);
  spec.grip_squeeze_nm = 0.035;
  Instrument squeeze(spec);
  spring.reset(pose, 0.2);
  squeeze.reset(pose, 0.2);
  spring.freeMotion(h, pose, Vector6d::Zero(), 0.0);
  squeeze.freeMotion(h, pose, Vector6d::Zero(), 0.0);
  // the squeeze's extra rate: S / (I/h + B + h K) over the spring's
  const double extra = 0.035 / (spec.grip_inertia_kgm2 / h + 0.005 + h * 0.015);
  EXPECT_NEAR(squeeze.gripRate() - spring.gripRate(), -extra, 1e-9);
  // with nothing between them the jaws end closed, at 0, not beyond
  for (int k = 0; k < 50; ++k) {
    squeeze.freeMotion(h, pose, Vector6d::Zero(), 0.0);
    squeeze.applyGripCorrection(0.0);
    EXPECT_GE(squeeze.gripperOpening(), 0.0);
  }
  EXPECT_EQ(squeeze.gripperOpening(), 0.0);
  // an open handle adds nothing
  InstrumentSpec k_only = spec;
  k_only.grip_squeeze_nm = 0.0;
  Instrument open_spring(k_only), open_squeeze(spec);
  open_spring.reset(pose, 0.2);
  open_squeeze.reset(pose, 0.2);
  open_spring.freeMotion(h, pose, Vector6d::Zero(), 1.0);
  open_squeeze.freeMotion(h, pose, Vector6d::Zero(), 1.0);
  EXPECT_EQ(open_squeeze.gripRate(), open_spring.gripRate());
}

TEST(Instrument, RejectsBadSpec) {
  InstrumentSpec spec = probeSpec();
  spec.mass_kg = 0.0;
  EXPECT_THROW(Instrument{spec}, tactus::SceneError);
  spec = grasperSpec();
  spec.jaw_samples = 0;
  try {
    Instrument tool(spec);
    FAIL() << "no exception";
  } catch (const tactus::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("instrument.jaw_samples"), std::string::npos);
  }
}

}  // namespace
