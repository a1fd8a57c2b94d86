// The haptic local model against the full simulation (docs/design.md, "The haptic local model"):
//  * at the snapshot's own device pose, re-solving the published problem gives the simulation's
//    contact forces;
//  * for a small device displacement dx, delta_free* + J dx re-solved gives the force a full
//    simulation step computes: the error is a small fraction of the force change and shrinks
//    like |dx| (measured order one; see the test for the figures).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <map>

#include "tactus/shared/nsgs.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

const std::string kPressCubeScene = std::string(TACTUS_TEST_DATA_DIR) + "/scenes/press_cube.yaml";

// The friction coefficient, and the tissue's element and law: the local model must hold for every
// element and law a scene can choose (the snapshot carries W, whatever built it).
struct Variant {
  double mu;
  ElementKind element = ElementKind::kLinearTet;
  MaterialLaw law = MaterialLaw::kCorotational;
  TangentKind tangent = TangentKind::kCorotated;
};

SceneSpec pressScene(const Variant& variant) {
  SceneSpec spec = loadScene(kPressCubeScene);
  spec.haptics.enabled = false;
  spec.instrument.friction_mu = variant.mu;
  spec.tissues[0].element = variant.element;
  spec.tissues[0].law = variant.law;
  spec.tissues[0].tangent = variant.tangent;
  spec.solver.nsgs_tolerance = 1e-12;
  spec.solver.nsgs_max_sweeps = 5000;
  return spec;
}

// Presses the probe 4 mm into the cube and lets it settle.
void settle(Simulation& sim, DeviceTarget& target) {
  target = sim.scriptedTarget(0.0);
  target.pose.pos_m.z() = 0.035 + 0.006 - 0.004;
  for (int k = 0; k < 150; ++k) {
    sim.setDeviceTarget(target);
    sim.step();
  }
}

Eigen::Vector3d contactForce(const ContactProblemData& p, const Eigen::VectorXd& f) {
  Eigen::Vector3d F = Eigen::Vector3d::Zero();
  for (int c = 0; c < p.contacts; ++c) {
    const int r0 = p.row_offset[c];
    F += f[r0] * p.normal[c];
    if (p.row_offset[c + 1] - r0 == 3) F += f[r0 + 1] * p.tangent1[c] + f[r0 + 2] * p.tangent2[c];
  }
  return F;
}

// Local-model prediction for a device displacement dx from problem p.
Eigen::VectorXd predict(const ContactProblemData& p, const shared::Vector6d& dx) {
  Eigen::VectorXd df = p.delta_free + p.J * dx;
  shared::ContactProblemView v = p.view();
  v.delta_free = df.data();
  shared::NsgsWorkspace ws(p.rows, p.contacts);
  shared::NsgsSettings s;
  s.tolerance = 1e-12;
  s.max_sweeps = 5000;
  Eigen::VectorXd f = p.f;   // warm start from the simulation's solution, as the haptic loop
  const auto res = shared::solveNsgs(v, s, ws, f.data());
  EXPECT_EQ(res.status, shared::NsgsStatus::kConverged);
  return f;
}

class HapticConsistencyTest : public ::testing::TestWithParam<Variant> {};

TEST_P(HapticConsistencyTest, AtTheSnapshotPoseTheLocalModelReproducesTheSimulation) {
  Simulation sim(pressScene(GetParam()));
  DeviceTarget target;
  settle(sim, target);
  const ContactProblemData& p = sim.lastProblem();
  ASSERT_GT(p.contacts, 0);
  const Eigen::VectorXd cold = [&] {
    Eigen::VectorXd f = Eigen::VectorXd::Zero(p.rows);
    shared::NsgsWorkspace ws(p.rows, p.contacts);
    shared::NsgsSettings s;
    s.tolerance = 1e-12;
    s.max_sweeps = 5000;
    shared::solveNsgs(p.view(), s, ws, f.data());
    return f;
  }();
  EXPECT_LT((contactForce(p, cold) - contactForce(p, p.f)).norm(),
            1e-6 * contactForce(p, p.f).norm());
  EXPECT_GT(contactForce(p, p.f).norm(), 0.05);
  // and the warm-started re-solve at dx = 0 returns the same forces
  const Eigen::VectorXd same = predict(p, shared::Vector6d::Zero());
  EXPECT_LT((same - p.f).norm(), 1e-8 * p.f.norm());
}

TEST_P(HapticConsistencyTest, ForASmallDeviceMotionTheLocalModelMatchesAFullStepToFirstOrder) {
  // two identical simulations (deterministic), one step apart in their device target only
  const Variant variant = GetParam();
  const double mu = variant.mu;
  std::vector<double> errors;
  std::vector<double> changes;
  for (double scale : {1.0, 0.5, 0.25}) {
    Simulation a(pressScene(variant));
    Simulation b(pressScene(variant));
    DeviceTarget ta, tb;
    settle(a, ta);
    settle(b, tb);
    shared::Vector6d dx;
    dx << 0.0, 0.0, -4e-4 * scale, 0.0, 0.0, 0.0;   // press 0.4 mm deeper (then 0.2, 0.1)
    tb.pose.pos_m += dx.head<3>();
    a.setDeviceTarget(ta);
    b.setDeviceTarget(tb);
    a.step();
    b.step();
    const ContactProblemData& pa = a.lastProblem();
    const ContactProblemData& pb = b.lastProblem();
    ASSERT_EQ(pa.contact_id, pb.contact_id) << "the contact set changed: dx too large";
    const Eigen::Vector3d f_pred = contactForce(pa, predict(pa, dx));
    const Eigen::Vector3d f_full = contactForce(pb, pb.f);
    const Eigen::Vector3d f_star = contactForce(pa, pa.f);
    errors.push_back((f_pred - f_full).norm());
    changes.push_back((f_full - f_star).norm());
  }
  for (std::size_t i = 0; i < errors.size(); ++i) {
    // the linearisation captures the change of force: the residual is a tiny fraction of it
    // (measured ~1e-5: the contact frame moves slightly with the tool, a higher-order effect)
    EXPECT_GT(changes[i], 1e-3) << "scale index " << i;
    EXPECT_LT(errors[i], 1e-3 * changes[i]) << "scale index " << i;
  }
  for (std::size_t i = 0; i < errors.size(); ++i) {
    std::printf("[consistency] mu=%.1f dx=%.2g m: |f_pred - f_full| = %.4e N (change %.4e N)\n",
                mu, 4e-4 / static_cast<double>(1 << i), errors[i], changes[i]);
  }
  // The decay order, from the ratio of the errors at dx and dx/2. Measured (2026-11-24):
  // |f_pred - f_full| = 1.77e-6, 8.43e-7, 4.11e-7 N at mu 0 and 2.05e-6, 9.72e-7, 4.73e-7 N at
  // mu 0.5 for dx = 0.4, 0.2, 0.1 mm, ratios 2.05-2.11: the local model is exact to FIRST order
  // only, with a tiny constant (the error is a steady 1.7e-5 of the force change), not to second
  // order as an exact linearisation would be (ratio 4). So J misses a term of relative size
  // ~1.7e-5 (e.g. the contact frame moving with the tool). Asserted: the order is one (band
  // [1.8, 2.4]: 1 would be an error that does not shrink, 4 an exact Jacobian - then tighten this
  // test to second order).
  for (std::size_t i = 1; i < errors.size(); ++i) {
    const double ratio = errors[i - 1] / errors[i];
    EXPECT_GT(ratio, 1.8) << "scale index " << i << ": the error does not shrink like |dx|";
    EXPECT_LT(ratio, 2.4) << "scale index " << i << ": decay order changed (exact Jacobian?)";
  }
}

INSTANTIATE_TEST_SUITE_P(
    Friction, HapticConsistencyTest,
    ::testing::Values(Variant{0.0}, Variant{0.5},
                      Variant{0.5, ElementKind::kEdgeSmoothedTet},
                      Variant{0.5, ElementKind::kLinearTet, MaterialLaw::kInvertibleNeoHookean},
                      Variant{0.5, ElementKind::kLinearTet, MaterialLaw::kCorotational,
                              TangentKind::kConsistent}));

}  // namespace
}  // namespace tactus::sim
