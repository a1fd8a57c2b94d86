// The warped compliance's bound (ComplianceOptions::exact_below_coherence) and the rotation
// coherence it reads (FemBody::nodeRotations): coherence 1 under a rigid rotation, below 1 where
// the element rotations spread; a row on such a node makes the step use the exact compliance
// (W and correction), a row on coherent nodes keeps the warped one. The rotation smoothing
// (ComplianceOptions::rotation_smoothing_passes): a rigid rotation is kept, neighbouring nodes of
// a crushed region get closer rotations, and the warped model uses them.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cstdio>
#include <random>

#include "tactus/shared/error.h"
#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::sim {
namespace {

constexpr double kH = 0.01;

class ComplianceBound : public ::testing::Test {
 protected:
  ComplianceBound()
      : mesh_(makeBoxTetMesh(8, 2, 2, Eigen::Vector3d(0.08, 0.02, 0.02))) {
    for (int i = 0; i < mesh_.nodeCount(); ++i) {
      if (mesh_.nodes(0, i) < 1e-9) fixed_.push_back(i);
    }
    FemMaterial m;
    m.law = MaterialLaw::kCorotational;
    m.young_pa = 5000.0;
    m.poisson = 0.4;
    m.damping = RayleighSpec{0.1, 0.01};
    body_ = std::make_unique<FemBody>(mesh_, m, fixed_, nullptr);
  }

  /// Node (i, j, k) of the box's grid.
  int node(int i, int j, int k) const { return i + 9 * (j + 3 * k); }

  /// Nodes with x > 0.045 moved at random by up to 40 % of a cell: their elements turn every
  /// which way (a crushed region), the rest of the bar stays put.
  void crushTheFreeEnd() {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-0.004, 0.004);
    Eigen::VectorXd& q = body_->positions();
    for (int i = 0; i < mesh_.nodeCount(); ++i) {
      if (mesh_.nodes(0, i) > 0.045) {
        for (int c = 0; c < 3; ++c) q[3 * i + c] += u(rng);
      }
    }
  }

  /// Rows x, y, z at each node.
  static std::vector<TissueRow> rowsAt(const std::vector<int>& nodes) {
    std::vector<TissueRow> rows;
    for (int n : nodes) {
      for (int d = 0; d < 3; ++d) {
        TissueRow r;
        r.node = {n, -1, -1};
        r.weight = {1.0, 0.0, 0.0};
        r.dir = Eigen::Vector3d::Unit(d);
        rows.push_back(r);
      }
    }
    return rows;
  }

  static Eigen::MatrixXd buildW(TissueCompliance& model, const std::vector<TissueRow>& rows) {
    Eigen::MatrixXd w = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(rows.size()),
                                              static_cast<Eigen::Index>(rows.size()));
    model.addW(rows, w);
    return w;
  }

  std::unique_ptr<TissueCompliance> model(ComplianceKind kind, double bound, int passes = 0) {
    ComplianceOptions o;
    o.h_s = kH;
    o.show_progress = false;
    o.exact_below_coherence = bound;
    o.rotation_smoothing_passes = passes;
    auto m = makeCompliance(kind, *body_, o);
    m->update(*body_);
    return m;
  }

  TetMesh mesh_;
  std::vector<int> fixed_;
  std::unique_ptr<FemBody> body_;
};

TEST_F(ComplianceBound, CoherenceIsOneUnderARigidRotationAndDropsWhereElementsTurnApart) {
  const Eigen::Matrix3d rot =
      Eigen::AngleAxisd(1.1, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  Eigen::VectorXd& q = body_->positions();
  for (int i = 0; i < mesh_.nodeCount(); ++i) q.segment<3>(3 * i) = rot * q.segment<3>(3 * i);
  std::vector<Eigen::Matrix3d> r;
  std::vector<double> coherence;
  body_->nodeRotations(r, &coherence);
  for (int i = 0; i < mesh_.nodeCount(); ++i) {
    EXPECT_NEAR(coherence[i], 1.0, 1e-9) << "node " << i;
    EXPECT_LT((r[i] - rot).norm(), 1e-9) << "node " << i;
  }
  body_->positions() = body_->restPositions();
  crushTheFreeEnd();
  body_->nodeRotations(r, &coherence);
  double lowest = 1.0;
  for (int i = 0; i < mesh_.nodeCount(); ++i) {
    EXPECT_LE(coherence[i], 1.0 + 1e-12);
    if (mesh_.nodes(0, i) < 0.025) {
      EXPECT_NEAR(coherence[i], 1.0, 1e-12) << "untouched node " << i;
    }
    lowest = std::min(lowest, coherence[i]);
  }
  EXPECT_LT(lowest, 0.99);
}

TEST_F(ComplianceBound, RowsOnIncoherentNodesUseTheExactCompliance) {
  crushTheFreeEnd();
  ASSERT_TRUE(body_->freeMotion(kH).ok);
  std::vector<Eigen::Matrix3d> r;
  std::vector<double> coherence;
  body_->nodeRotations(r, &coherence);
  // the least coherent free-end node, and coherent nodes near the fixed end
  int worst = node(8, 1, 1);
  for (int i : body_->surfaceNodes()) {
    if (coherence[i] < coherence[worst]) worst = i;
  }
  const std::vector<int> near_end = {node(1, 0, 0), node(1, 2, 2), node(2, 1, 2)};
  double near_lowest = 1.0;
  for (int n : near_end) near_lowest = std::min(near_lowest, coherence[n]);
  ASSERT_LT(coherence[worst], near_lowest);
  const double bound = 0.5 * (coherence[worst] + near_lowest);

  const auto crushed = rowsAt({worst, node(8, 0, 0)});
  auto exact = model(ComplianceKind::kExact, 0.0);
  auto warped = model(ComplianceKind::kWarped, 0.0);
  auto bounded = model(ComplianceKind::kWarped, bound);
  const Eigen::MatrixXd w_exact = buildW(*exact, crushed);
  const Eigen::MatrixXd w_warped = buildW(*warped, crushed);
  ASSERT_GT((w_warped - w_exact).norm(), 1e-3 * w_exact.norm())
      << "warped equals exact here: the case cannot show the bound";
  EXPECT_LT((buildW(*bounded, crushed) - w_exact).norm(), 1e-12 * w_exact.norm());
  EXPECT_EQ(bounded->buildInfo().exact_fallbacks, 1);
  // the correction follows the model that built W
  Eigen::VectorXd f = Eigen::VectorXd::LinSpaced(static_cast<Eigen::Index>(crushed.size()), -1, 1);
  Eigen::VectorXd dq_exact, dq_bounded;
  exact->correction(*body_, crushed, f.data(), dq_exact);
  bounded->correction(*body_, crushed, f.data(), dq_bounded);
  EXPECT_LT((dq_bounded - dq_exact).norm(), 1e-12 * dq_exact.norm());

  // rows on coherent nodes: the warped W, no fallback
  const auto coherent = rowsAt(near_end);
  auto bounded2 = model(ComplianceKind::kWarped, bound);
  EXPECT_EQ(buildW(*bounded2, coherent), buildW(*warped, coherent));
  EXPECT_EQ(bounded2->buildInfo().exact_fallbacks, 0);
  // no bound: never
  EXPECT_EQ(buildW(*warped, crushed), w_warped);
  EXPECT_EQ(warped->buildInfo().exact_fallbacks, 0);
}

/// Largest |R_i - R_j|_F over the element edges with both nodes at x > 0.045 (the crushed end).
double largestNeighbourSpread(const TetMesh& mesh, const std::vector<Eigen::Matrix3d>& r) {
  double largest = 0.0;
  for (const auto& tet : mesh.tets) {
    for (int a = 0; a < 4; ++a) {
      for (int b = a + 1; b < 4; ++b) {
        const int i = tet[static_cast<std::size_t>(a)], j = tet[static_cast<std::size_t>(b)];
        if (mesh.nodes(0, i) > 0.045 && mesh.nodes(0, j) > 0.045) {
          const Eigen::Matrix3d& ri = r[static_cast<std::size_t>(i)];
          largest = std::max(largest, (ri - r[static_cast<std::size_t>(j)]).norm());
        }
      }
    }
  }
  return largest;
}

TEST_F(ComplianceBound, SmoothedRotationsKeepARigidRotationAndVaryLessBetweenNeighbours) {
  const Eigen::Matrix3d rot =
      Eigen::AngleAxisd(0.8, Eigen::Vector3d(0.3, 1, -0.4).normalized()).toRotationMatrix();
  Eigen::VectorXd& q = body_->positions();
  for (int i = 0; i < mesh_.nodeCount(); ++i) q.segment<3>(3 * i) = rot * q.segment<3>(3 * i);
  std::vector<Eigen::Matrix3d> r;
  std::vector<double> coherence;
  body_->nodeRotations(r, &coherence, 3);
  for (int i = 0; i < mesh_.nodeCount(); ++i) {
    EXPECT_LT((r[static_cast<std::size_t>(i)] - rot).norm(), 1e-9) << "node " << i;
    EXPECT_NEAR(coherence[static_cast<std::size_t>(i)], 1.0, 1e-9) << "node " << i;
  }
  body_->positions() = body_->restPositions();
  crushTheFreeEnd();
  std::vector<Eigen::Matrix3d> r0, r2;
  std::vector<double> c0, c2;
  body_->nodeRotations(r0, &c0, 0);
  body_->nodeRotations(r2, &c2, 2);
  const double spread0 = largestNeighbourSpread(mesh_, r0);
  const double spread2 = largestNeighbourSpread(mesh_, r2);
  std::printf("largest neighbour spread |R_i - R_j|_F in the crushed end: %.4f unsmoothed, "
              "%.4f with 2 passes\n", spread0, spread2);
  ASSERT_GT(spread0, 0.05) << "the crushed end does not turn its elements apart";
  EXPECT_LT(spread2, 0.5 * spread0);
  // every node's rotation is still a rotation; coherence stays in (0, 1]
  for (std::size_t i = 0; i < r2.size(); ++i) {
    EXPECT_LT((r2[i].transpose() * r2[i] - Eigen::Matrix3d::Identity()).norm(), 1e-9);
    EXPECT_GT(r2[i].determinant(), 0.0);
    EXPECT_GT(c2[i], 0.0);
    EXPECT_LE(c2[i], 1.0 + 1e-12);
  }
  EXPECT_THROW(body_->nodeRotations(r2, nullptr, -1), tactus::Error);
}

TEST_F(ComplianceBound, WarpedModelUsesTheSmoothedRotations) {
  crushTheFreeEnd();
  ASSERT_TRUE(body_->freeMotion(kH).ok);
  const auto rows = rowsAt({node(8, 1, 1), node(7, 2, 0), node(6, 0, 2)});
  auto plain = model(ComplianceKind::kWarped, 0.0, 0);
  auto smoothed = model(ComplianceKind::kWarped, 0.0, 2);
  const Eigen::MatrixXd w_plain = buildW(*plain, rows);
  const Eigen::MatrixXd w_smoothed = buildW(*smoothed, rows);
  EXPECT_GT((w_smoothed - w_plain).norm(), 1e-6 * w_plain.norm());
  EXPECT_LT((w_smoothed - w_smoothed.transpose()).norm(), 1e-12 * w_smoothed.norm());
  // the correction uses the same rotations as W: H dq = W f
  Eigen::VectorXd f = Eigen::VectorXd::LinSpaced(static_cast<Eigen::Index>(rows.size()), -1, 1);
  Eigen::VectorXd dq;
  smoothed->correction(*body_, rows, f.data(), dq);
  Eigen::VectorXd moved(static_cast<Eigen::Index>(rows.size()));
  for (std::size_t k = 0; k < rows.size(); ++k) {
    const Eigen::Vector3d dq_node = dq.segment<3>(3 * rows[k].node[0]);
    moved[static_cast<Eigen::Index>(k)] = rows[k].weight[0] * rows[k].dir.dot(dq_node);
  }
  EXPECT_LT((moved - w_smoothed * f).norm(), 1e-9 * (w_smoothed * f).norm());
  // out of range
  ComplianceOptions o;
  o.h_s = kH;
  o.show_progress = false;
  for (int passes : {-1, kMaxRotationSmoothingPasses + 1}) {
    o.rotation_smoothing_passes = passes;
    EXPECT_THROW(makeCompliance(ComplianceKind::kWarped, *body_, o), tactus::Error) << passes;
  }
}

}  // namespace
}  // namespace tactus::sim
