// Physics of the tetrahedral FEM body: corotational invariance, patch test, cantilever bending,
// energy behaviour of implicit Euler, inversion recovery, solver agreement, counters.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::sim {
namespace {

FemMaterial material(MaterialLaw law, double young = 1e4, double poisson = 0.3) {
  FemMaterial m;
  m.law = law;
  m.young_pa = young;
  m.poisson = poisson;
  m.density_kgpm3 = 1000.0;
  return m;
}

std::vector<int> nodesAtX(const TetMesh& mesh, double x) {
  std::vector<int> out;
  for (int i = 0; i < mesh.nodeCount(); ++i)
    if (std::abs(mesh.nodes(0, i) - x) < 1e-12) out.push_back(i);
  return out;
}

double maxNodeForce(const Eigen::VectorXd& f) {
  return f.reshaped(3, f.size() / 3).colwise().norm().maxCoeff();
}

TEST(MeshGen, BoxMeshesArePositiveAndFillTheVolume) {
  for (HexSplit split : {HexSplit::kSix, HexSplit::kFive}) {
    const Eigen::Vector3d size(0.3, 0.2, 0.1);
    const TetMesh mesh = makeBoxTetMesh(3, 2, 2, size, Eigen::Vector3d(1, 2, 3), split);
    EXPECT_EQ(mesh.nodeCount(), 4 * 3 * 3);
    EXPECT_EQ(mesh.tetCount(), 12 * (split == HexSplit::kSix ? 6 : 5));
    double total = 0.0;
    for (const auto& t : mesh.tets) {
      Eigen::Matrix3d d;
      d << mesh.nodes.col(t[1]) - mesh.nodes.col(t[0]), mesh.nodes.col(t[2]) - mesh.nodes.col(t[0]),
          mesh.nodes.col(t[3]) - mesh.nodes.col(t[0]);
      EXPECT_GT(d.determinant(), 0.0);
      total += d.determinant() / 6.0;
    }
    EXPECT_NEAR(total, size.prod(), 1e-12);
  }
  EXPECT_THROW(makeBoxTetMesh(0, 1, 1, Eigen::Vector3d::Ones()), tactus::Error);
}

// A rigidly rotated mesh carries no elastic force under the corotational law; the linear law
// produces a large spurious force.
TEST(Corotational, RigidRotationGivesZeroForce) {
  const double young = 1e4, edge = 0.1 / 3;
  const TetMesh mesh = makeBoxTetMesh(3, 3, 3, Eigen::Vector3d::Constant(0.1));
  FemBody corot(mesh, material(MaterialLaw::kCorotational, young), {}, nullptr);
  FemBody linear(mesh, material(MaterialLaw::kLinear, young), {}, nullptr);
  const double scale = young * edge * edge;
  const std::vector<Eigen::Vector3d> axes = {Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(),
                                             Eigen::Vector3d::UnitZ(),
                                             Eigen::Vector3d(1, -2, 0.5).normalized()};
  for (const auto& axis : axes)
    for (double deg : {90.0, 180.0}) {
      const Eigen::Matrix3d r = Eigen::AngleAxisd(deg * M_PI / 180.0, axis).toRotationMatrix();
      Eigen::VectorXd q(corot.dofCount());
      for (int i = 0; i < mesh.nodeCount(); ++i)
        q.segment<3>(3 * i) = r * mesh.nodes.col(i) + Eigen::Vector3d(0.3, -0.1, 0.2);
      Eigen::VectorXd f;
      corot.elasticForce(q, f);
      EXPECT_LT(maxNodeForce(f), 1e-9 * scale) << "axis " << axis.transpose() << " " << deg;
      linear.elasticForce(q, f);
      EXPECT_GT(maxNodeForce(f), 0.1 * scale) << "axis " << axis.transpose() << " " << deg;
    }
  EXPECT_GT(corot.counters().rotation_extractions, 0);
  EXPECT_EQ(linear.counters().rotation_extractions, 0);
}

// Affine displacement: every element carries the same stress, interior nodes no net force.
TEST(PatchTest, UniformStretchGivesUniformStress) {
  for (MaterialLaw law : {MaterialLaw::kLinear, MaterialLaw::kCorotational})
    for (HexSplit split : {HexSplit::kSix, HexSplit::kFive}) {
      const TetMesh mesh =
          makeBoxTetMesh(4, 3, 3, Eigen::Vector3d(0.2, 0.15, 0.1), Eigen::Vector3d::Zero(), split);
      FemBody body(mesh, material(law, 1e4, 0.3), {}, nullptr);
      Eigen::Matrix3d f_aff;
      f_aff << 1.05, 0.01, 0.0, 0.02, 0.98, 0.01, 0.0, 0.015, 1.03;
      for (int i = 0; i < mesh.nodeCount(); ++i)
        body.positions().segment<3>(3 * i) = f_aff * mesh.nodes.col(i);
      std::vector<Eigen::Matrix3d> s;
      body.stresses(s);
      const double ref = s[0].norm();
      ASSERT_GT(ref, 10.0);  // a real stress (E * strain ~ 500 Pa)
      for (const auto& se : s) EXPECT_LT((se - s[0]).norm(), 1e-9 * ref);
      Eigen::VectorXd f;
      body.elasticForce(body.positions(), f);
      const double force_scale = ref * 0.05 * 0.05;  // stress * element face area
      int interior = 0;
      for (int i = 0; i < mesh.nodeCount(); ++i) {
        const Eigen::Vector3d x = mesh.nodes.col(i);
        const bool inside = x.x() > 1e-9 && x.x() < 0.2 - 1e-9 && x.y() > 1e-9 &&
                            x.y() < 0.15 - 1e-9 && x.z() > 1e-9 && x.z() < 0.1 - 1e-9;
        if (!inside) continue;
        ++interior;
        EXPECT_LT(f.segment<3>(3 * i).norm(), 1e-9 * force_scale) << "node " << i;
      }
      EXPECT_EQ(interior, 3 * 2 * 2);
    }
}

// Tip deflection of a clamped beam under its own weight against Euler-Bernoulli
// w = q L^4 / (8 E I); direct static solve K u = f through the same assembly.
TEST(Cantilever, ConvergesToEulerBernoulli) {
  const double length = 0.5, side = 0.05, young = 5e7, rho = 1000.0, g = 9.81;
  const double inertia = side * side * side * side / 12.0;
  const double w_eb = rho * side * side * g * std::pow(length, 4) / (8.0 * young * inertia);
  ASSERT_LT(w_eb / length, 0.05);  // small deflection
  // Poisson 0: no lateral contraction at the clamp; Timoshenko shear adds
  // (E / (3 k G)) (b / L)^2 = 0.8% to w_eb at L/b = 10, inside the 5% band.
  // Linear tets lock in bending: cubic cells (aspect 1) with the 5-tet split, refined together
  // along and across the beam, converge from about 12% (4 through the thickness) down to ~3%.
  std::vector<double> errors;
  for (int t : {4, 6, 8}) {
    const TetMesh mesh = makeBoxTetMesh(10 * t, t, t, Eigen::Vector3d(length, side, side),
                                        Eigen::Vector3d::Zero(), HexSplit::kFive);
    FemMaterial mat = material(MaterialLaw::kLinear, young, 0.0);
    mat.density_kgpm3 = rho;
    const Eigen::Vector3d gravity(0, 0, -g);
    FemBody body(mesh, mat, nodesAtX(mesh, 0.0), &gravity);
    const FemStepStats st = body.solveStatic();
    ASSERT_TRUE(st.ok);
    double tip = 0.0;
    const auto tip_nodes = nodesAtX(mesh, length);
    for (int i : tip_nodes) tip += body.restPositions()[3 * i + 2] - body.positions()[3 * i + 2];
    tip /= static_cast<double>(tip_nodes.size());
    errors.push_back(std::abs(tip - w_eb) / w_eb);
    RecordProperty("err_" + std::to_string(t), std::to_string(errors.back()));
  }
  EXPECT_LT(errors[2], 0.05) << "finest error " << errors[2];
  EXPECT_LT(errors[1], errors[0]);
  EXPECT_LT(errors[2], errors[1]);
}

// A small corotational beam bent statically by Newton iterations agrees with the linear law for
// small loads (the rotations are small).
TEST(Cantilever, CorotationalStaticMatchesLinearForSmallLoad) {
  const TetMesh mesh = makeBoxTetMesh(10, 2, 2, Eigen::Vector3d(0.2, 0.04, 0.04));
  const Eigen::Vector3d gravity(0, 0, -9.81);
  FemBody lin(mesh, material(MaterialLaw::kLinear, 1e7), nodesAtX(mesh, 0.0), &gravity);
  FemBody cor(mesh, material(MaterialLaw::kCorotational, 1e7), nodesAtX(mesh, 0.0), &gravity);
  ASSERT_TRUE(lin.solveStatic().ok);
  ASSERT_TRUE(cor.solveStatic().ok);
  const Eigen::VectorXd ul = lin.positions() - lin.restPositions();
  const Eigen::VectorXd uc = cor.positions() - cor.restPositions();
  EXPECT_GT(ul.norm(), 0.0);
  EXPECT_LT((ul - uc).norm(), 1e-2 * ul.norm());
}

struct Block {
  TetMesh mesh = makeBoxTetMesh(4, 2, 2, Eigen::Vector3d(0.1, 0.05, 0.05));
  std::vector<int> fixed = nodesAtX(mesh, 0.0);
  void stretch(FemBody& body, double factor) const {
    for (int i = 0; i < mesh.nodeCount(); ++i) body.positions()[3 * i] *= factor;
  }
};

double totalEnergy(const FemBody& b) { return b.kineticEnergy() + b.elasticEnergy(); }

TEST(ImplicitEuler, DampedReleaseLosesEnergyMonotonicallyAndRests) {
  Block blk;
  FemMaterial mat = material(MaterialLaw::kCorotational, 1e4, 0.3);
  mat.damping = RayleighSpec{1.0, 0.01};
  FemBody body(blk.mesh, mat, blk.fixed, nullptr);
  blk.stretch(body, 1.2);
  double e_prev = totalEnergy(body);
  const double e0 = e_prev;
  ASSERT_GT(e0, 0.0);
  for (int step = 0; step < 400; ++step) {
    ASSERT_TRUE(body.freeMotion(0.01).ok);
    const double e = totalEnergy(body);
    ASSERT_TRUE(std::isfinite(e));
    EXPECT_LE(e, e_prev + 1e-12 * e0) << "step " << step;
    e_prev = e;
  }
  EXPECT_LT(e_prev, 1e-6 * e0);
  EXPECT_LT(body.velocities().norm(), 1e-4);
  EXPECT_EQ(body.counters().damping_evaluations, 400);
}

TEST(ImplicitEuler, UndampedEnergyNeverGrowsAndLossShrinksWithStep) {
  Block blk;
  std::vector<double> loss;
  for (double h : {0.004, 0.002}) {
    FemBody body(blk.mesh, material(MaterialLaw::kCorotational, 1e4, 0.3), blk.fixed, nullptr);
    blk.stretch(body, 1.1);
    const double e0 = totalEnergy(body);
    double e_prev = e0;
    const int steps = static_cast<int>(std::lround(0.2 / h));
    for (int s = 0; s < steps; ++s) {
      ASSERT_TRUE(body.freeMotion(h).ok);
      const double e = totalEnergy(body);
      EXPECT_LE(e, e_prev * (1.0 + 1e-9)) << "h " << h << " step " << s;
      e_prev = e;
    }
    loss.push_back((e0 - e_prev) / e0);
    EXPECT_EQ(body.counters().damping_evaluations, 0);  // absent damping: never computed
  }
  EXPECT_GT(loss[0], 0.0);
  EXPECT_LT(loss[1], loss[0]);
}

// A node pushed through the opposite face: the corotational element recovers its rest shape.
TEST(Inversion, InvertedElementsRecover) {
  for (int variant = 0; variant < 2; ++variant) {
    const TetMesh mesh = variant == 0
                             ? makeBoxTetMesh(1, 1, 1, Eigen::Vector3d::Constant(0.05),
                                              Eigen::Vector3d::Zero(), HexSplit::kFive)
                             : makeBoxTetMesh(2, 2, 2, Eigen::Vector3d::Constant(0.05));
    FemMaterial mat = material(MaterialLaw::kCorotational, 1e4, 0.3);
    mat.damping = RayleighSpec{2.0, 0.02};
    FemBody body(mesh, mat, {}, nullptr);
    // corner node 0 mirrored through the opposite side of the box: through several faces
    body.positions().segment<3>(0) = Eigen::Vector3d(0.07, 0.06, 0.065);
    EXPECT_GT(body.elasticEnergy(), 0.0);
    auto inverted = [&] {
      int count = 0;
      const auto& q = body.positions();
      for (const auto& t : mesh.tets) {
        Eigen::Matrix3d d;
        d << q.segment<3>(3 * t[1]) - q.segment<3>(3 * t[0]),
            q.segment<3>(3 * t[2]) - q.segment<3>(3 * t[0]),
            q.segment<3>(3 * t[3]) - q.segment<3>(3 * t[0]);
        count += d.determinant() <= 0.0;
      }
      return count;
    };
    ASSERT_GT(inverted(), 0);
    for (int s = 0; s < 600; ++s) {
      const FemStepStats st = body.freeMotion(0.01);
      ASSERT_TRUE(st.ok) << "step " << s;
      ASSERT_TRUE(body.positions().allFinite()) << "step " << s;
    }
    // rest shape up to a rigid motion: no strain energy left, every element positive
    EXPECT_LT(body.elasticEnergy(), 1e-10);
    EXPECT_EQ(inverted(), 0);
  }
}

// One tetrahedron flipped by hand: a node mirrored through the opposite face (F is then a pure
// reflection, det F = -1, all singular values 1: the polar decomposition's tie case). With no
// load and no fixed node, the corotational force must push it back: its signed volume becomes
// positive again and it returns to its rest shape; the inversion is counted while it lasts.
TEST(Inversion, AHandFlippedTetRecoversItsSignedVolume) {
  TetMesh mesh;
  mesh.source = "flipped tet";
  mesh.nodes.resize(3, 4);
  mesh.nodes.col(0) = Eigen::Vector3d(0.0, 0.0, 0.0);
  mesh.nodes.col(1) = Eigen::Vector3d(0.01, 0.0, 0.0);
  mesh.nodes.col(2) = Eigen::Vector3d(0.0, 0.012, 0.0);
  mesh.nodes.col(3) = Eigen::Vector3d(0.002, 0.003, 0.011);
  mesh.tets = {{0, 1, 2, 3}};
  const auto signedVolume = [](const Eigen::VectorXd& q) {
    Eigen::Matrix3d d;
    d << q.segment<3>(3) - q.segment<3>(0), q.segment<3>(6) - q.segment<3>(0),
        q.segment<3>(9) - q.segment<3>(0);
    return d.determinant() / 6.0;
  };
  for (int flipped_node = 0; flipped_node < 4; ++flipped_node) {
    SCOPED_TRACE(::testing::Message() << "node " << flipped_node);
    FemMaterial mat = material(MaterialLaw::kCorotational, 1e4, 0.3);
    mat.damping = RayleighSpec{2.0, 0.02};
    FemBody body(mesh, mat, {}, nullptr);
    const double rest_volume = signedVolume(body.positions());
    ASSERT_GT(rest_volume, 0.0);
    // mirror the node through the plane of the other three
    const auto& t = mesh.tets[0];
    int others[3], k = 0;
    for (int a = 0; a < 4; ++a) {
      if (t[a] != flipped_node) others[k++] = t[a];
    }
    const Eigen::Vector3d p0 = mesh.nodes.col(others[0]);
    const Eigen::Vector3d n =
        (Eigen::Vector3d(mesh.nodes.col(others[1])) - p0)
            .cross(Eigen::Vector3d(mesh.nodes.col(others[2])) - p0)
            .normalized();
    const Eigen::Vector3d x = mesh.nodes.col(flipped_node);
    body.positions().segment<3>(3 * flipped_node) = x - 2.0 * (x - p0).dot(n) * n;
    ASSERT_NEAR(signedVolume(body.positions()), -rest_volume, 1e-12 * rest_volume);
    EXPECT_EQ(body.invertedElementCount(), 1);
    Eigen::VectorXd ratio;
    body.volumeRatios(ratio);
    ASSERT_EQ(ratio.size(), 1);
    EXPECT_NEAR(ratio[0], -1.0, 1e-9);
    const Eigen::Vector3d centre_before =
        body.positions().reshaped(3, 4).rowwise().mean();
    int first_positive_step = -1;
    for (int s = 0; s < 400; ++s) {
      const FemStepStats st = body.freeMotion(0.005);
      ASSERT_TRUE(st.ok) << "step " << s;
      ASSERT_TRUE(body.positions().allFinite()) << "step " << s;
      if (s == 0) {
        EXPECT_EQ(st.inverted_elements, 1);
      }
      if (first_positive_step < 0 && signedVolume(body.positions()) > 0.0) first_positive_step = s;
    }
    EXPECT_GE(first_positive_step, 0) << "the flipped tet never recovered";
    EXPECT_EQ(body.invertedElementCount(), 0);
    // back to its rest shape (up to a rigid motion), without an external load moving it away
    EXPECT_NEAR(signedVolume(body.positions()), rest_volume, 1e-3 * rest_volume);
    EXPECT_LT(body.elasticEnergy(), 1e-9);
    const Eigen::Vector3d centre_after = body.positions().reshaped(3, 4).rowwise().mean();
    EXPECT_LT((centre_after - centre_before).norm(), 1e-9);   // no load: momentum conserved
  }
}

TEST(Solvers, PcgMatchesCholmod) {
  const TetMesh mesh = makeBoxTetMesh(6, 3, 3, Eigen::Vector3d(0.12, 0.06, 0.06));
  const Eigen::Vector3d gravity(0, 0, -9.81);
  FemMaterial mat = material(MaterialLaw::kCorotational, 5e3, 0.4);
  mat.damping = RayleighSpec{0.5, 0.005};
  const auto fixed = nodesAtX(mesh, 0.0);
  FemSolverOptions chol_opt;
  FemBody ref(mesh, mat, fixed, &gravity, chol_opt);
  for (PcgPreconditioner pre : {PcgPreconditioner::kJacobi, PcgPreconditioner::kRestCholesky,
                                PcgPreconditioner::kWarpedCholesky}) {
    FemSolverOptions pcg_opt;
    pcg_opt.linear = LinearSolverKind::kPcg;
    pcg_opt.cg_tolerance = 1e-12;
    pcg_opt.cg_max_iterations = 2000;
    pcg_opt.pcg_preconditioner = pre;
    FemBody ref_local(mesh, mat, fixed, &gravity, chol_opt);
    FemBody pcg(mesh, mat, fixed, &gravity, pcg_opt);
    // a few steps of large sag so rotations are non-trivial, then compare each step
    for (int s = 0; s < 5; ++s) {
      ASSERT_TRUE(ref_local.freeMotion(0.02).ok);
      const FemStepStats st = pcg.freeMotion(0.02);
      ASSERT_TRUE(st.ok) << "iterations " << st.cg_iterations << " residual " << st.cg_residual;
      EXPECT_GT(st.cg_iterations, 0);
      const double dv = (ref_local.velocities() - pcg.velocities()).norm();
      EXPECT_LT(dv, 1e-8 * ref_local.velocities().norm()) << "step " << s;
      EXPECT_LT((ref_local.positions() - pcg.positions()).norm(),
                1e-8 * (ref_local.positions() - ref_local.restPositions()).norm());
    }
  }
}

// nodeRotations (the warped compliance's rotations at the current positions) takes each element's
// polar factor by the element loop's Newton steps from the rotation the last step kept, instead of
// a cold decomposition: the same node rotations as the cold path (a body on the general element
// loop, which has no kept rotations, at the same positions), through a large bending swing.
TEST(Corotational, NodeRotationsFromTheKeptRotationsMatchTheColdDecomposition) {
  const TetMesh mesh = makeBoxTetMesh(8, 2, 2, Eigen::Vector3d(0.16, 0.04, 0.04));
  const Eigen::Vector3d gravity(0, 0, -9.81);
  FemMaterial warm_mat = material(MaterialLaw::kCorotational, 2e3, 0.3);
  warm_mat.damping = RayleighSpec{0.5, 0.002};
  FemMaterial cold_mat = warm_mat;
  cold_mat.tangent = TangentKind::kConsistent;   // the general element loop: cold polar factors
  FemBody warm(mesh, warm_mat, nodesAtX(mesh, 0.0), &gravity);
  FemBody cold(mesh, cold_mat, nodesAtX(mesh, 0.0), &gravity);
  std::vector<Eigen::Matrix3d> rw, rc;
  double worst = 0.0, max_angle = 0.0;
  for (int s = 0; s < 60; ++s) {
    ASSERT_TRUE(warm.freeMotion(0.01).ok) << "step " << s;
    cold.positions() = warm.positions();
    for (int passes : {0, 2}) {
      warm.nodeRotations(rw, nullptr, passes);
      cold.nodeRotations(rc, nullptr, passes);
      ASSERT_EQ(rw.size(), rc.size());
      for (std::size_t i = 0; i < rw.size(); ++i) {
        worst = std::max(worst, (rw[i] - rc[i]).norm());
        max_angle = std::max(max_angle, Eigen::AngleAxisd(rw[i]).angle());
      }
    }
  }
  EXPECT_GT(max_angle, 0.5);   // the tip swung through large rotations
  EXPECT_LT(worst, 1e-9);
  char figure[32];
  std::snprintf(figure, sizeof figure, "%.3g", worst);
  RecordProperty("worst_node_rotation_difference", figure);
}

// fittedNodeRotations (the warped compliance's rotations: polar factor of each node's sum of
// v_e F_e, no polar decomposition per element) is exact under a rigid rotation of a stretched
// body, whatever the stretch, and through a bending swing of a soft bar (the tip turning by up
// to 2.9 rad) stays within a few degrees of the element rotations' average (nodeRotations),
// with and without smoothing (0.074 rad at most when written).
TEST(Corotational, FittedNodeRotationsFollowTheElementRotations) {
  const TetMesh box = makeBoxTetMesh(3, 3, 3, Eigen::Vector3d::Constant(0.1));
  FemBody body(box, material(MaterialLaw::kCorotational), {}, nullptr);
  const Eigen::Matrix3d r = Eigen::AngleAxisd(2.0, Eigen::Vector3d(1, -2, 0.5).normalized())
                                .toRotationMatrix();
  const Eigen::Matrix3d stretch = Eigen::Vector3d(1.3, 0.6, 0.9).asDiagonal();
  for (int i = 0; i < box.nodeCount(); ++i)
    body.positions().segment<3>(3 * i) = r * stretch * box.nodes.col(i) + Eigen::Vector3d(0.3, -0.1, 0.2);
  const long polars = body.counters().rotation_extractions;
  std::vector<Eigen::Matrix3d> fitted;
  for (int passes : {0, 2}) {
    body.fittedNodeRotations(fitted, passes);
    ASSERT_EQ(fitted.size(), static_cast<std::size_t>(box.nodeCount()));
    for (const Eigen::Matrix3d& f : fitted) EXPECT_LT((f - r).norm(), 1e-12);
  }
  EXPECT_EQ(body.counters().rotation_extractions, polars);   // no decomposition per element
  EXPECT_THROW(body.fittedNodeRotations(fitted, -1), tactus::Error);

  const TetMesh mesh = makeBoxTetMesh(8, 2, 2, Eigen::Vector3d(0.16, 0.04, 0.04));
  const Eigen::Vector3d gravity(0, 0, -9.81);
  FemMaterial mat = material(MaterialLaw::kCorotational, 2e3, 0.3);
  mat.damping = RayleighSpec{0.5, 0.002};
  FemBody bar(mesh, mat, nodesAtX(mesh, 0.0), &gravity);
  std::vector<Eigen::Matrix3d> averaged;
  double worst = 0.0, max_angle = 0.0;
  for (int s = 0; s < 60; ++s) {
    ASSERT_TRUE(bar.freeMotion(0.01).ok) << "step " << s;
    for (int passes : {0, 2}) {
      bar.fittedNodeRotations(fitted, passes);
      bar.nodeRotations(averaged, nullptr, passes);
      for (std::size_t i = 0; i < fitted.size(); ++i) {
        worst = std::max(worst, Eigen::AngleAxisd(fitted[i] * averaged[i].transpose()).angle());
        max_angle = std::max(max_angle, Eigen::AngleAxisd(averaged[i]).angle());
      }
    }
  }
  std::printf("[fitted] largest node rotation %.3f rad, largest difference %.3g rad\n", max_angle,
              worst);
  EXPECT_GT(max_angle, 0.5);   // the tip swung through large rotations
  EXPECT_LT(worst, 0.1);
  char figure[32];
  std::snprintf(figure, sizeof figure, "%.3g", worst);
  RecordProperty("worst_fitted_rotation_difference_rad", figure);
}

TEST(Counters, AbsentEffectsAreNotComputed) {
  const TetMesh mesh = makeBoxTetMesh(2, 2, 2, Eigen::Vector3d::Constant(0.05));
  const Eigen::Vector3d gravity(0, 0, -9.81);
  FemBody lin(mesh, material(MaterialLaw::kLinear), nodesAtX(mesh, 0.0), &gravity);
  for (int s = 0; s < 3; ++s) ASSERT_TRUE(lin.freeMotion(0.01).ok);
  std::vector<Eigen::Matrix3d> rot;
  lin.nodeRotations(rot);
  EXPECT_EQ(lin.counters().rotation_extractions, 0);
  EXPECT_EQ(lin.counters().damping_evaluations, 0);
  EXPECT_EQ(lin.counters().general_domain_evaluations, 0);
  EXPECT_EQ(lin.counters().factorisations, 3);
  for (const auto& r : rot) EXPECT_TRUE(r.isIdentity(0.0));
  EXPECT_LT(lin.gravityEnergy(), 1e300);

  FemMaterial mat = material(MaterialLaw::kCorotational);
  mat.damping = RayleighSpec{1.0, 0.0};
  FemBody cor(mesh, mat, nodesAtX(mesh, 0.0), &gravity);
  ASSERT_TRUE(cor.freeMotion(0.01).ok);
  EXPECT_EQ(cor.counters().rotation_extractions, mesh.tetCount());
  EXPECT_EQ(cor.counters().damping_evaluations, 1);
  EXPECT_EQ(cor.counters().general_domain_evaluations, 0);  // R K0 R^T: the corotational loop
}

TEST(Material, RejectsBadInput) {
  const TetMesh mesh = makeBoxTetMesh(1, 1, 1, Eigen::Vector3d::Constant(0.05));
  EXPECT_THROW(FemBody(mesh, material(MaterialLaw::kLinear, -1.0), {}, nullptr), tactus::Error);
  EXPECT_THROW(FemBody(mesh, material(MaterialLaw::kLinear, 1e3, 0.5), {}, nullptr), tactus::Error);
  EXPECT_THROW(FemBody(mesh, material(MaterialLaw::kLinear), {99}, nullptr), tactus::Error);
  TetMesh flat = mesh;
  flat.nodes.row(2).setZero();
  EXPECT_THROW(FemBody(flat, material(MaterialLaw::kLinear), {}, nullptr), tactus::Error);
}

TEST(Transform, ScaleRotateTranslate) {
  TetMesh mesh = makeBoxTetMesh(1, 1, 1, Eigen::Vector3d::Ones());
  transformMesh(mesh, 0.1, Eigen::Vector3d(0, 0, 90), Eigen::Vector3d(1, 0, 0));
  // node (1,0,0) scaled to (0.1,0,0), rotated 90 deg about z to (0,0.1,0), shifted by x+1
  EXPECT_TRUE(mesh.nodes.col(1).isApprox(Eigen::Vector3d(1.0, 0.1, 0.0), 1e-12));
  BoxSpec box{Eigen::Vector3d(0.95, -1, -1), Eigen::Vector3d(1.05, 1, 1), {}};
  EXPECT_EQ(nodesInBoxes(mesh, {box}).size(), 4u);
}

}  // namespace
}  // namespace tactus::sim
