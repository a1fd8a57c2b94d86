// Flat jaw pads (instrument.h "Flat pads", collision.h): the pad feature against tissue
// vertices gives one contact per vertex and jaw with the rectangle's exact gap; the pad's sample
// spheres keep triangle-interior and edge points, never a vertex or a point already used; and
// the contact compliance (instrument.contact_compliance) makes W positive definite where the
// pads' rows are redundant.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <set>

#include "tactus/sim/collision.h"
#include "tactus/sim/instrument.h"
#include "test_surfaces.h"

namespace tactus::sim {
namespace {

using test::TestSurface;

InstrumentSpec padGrasper(double opening) {
  InstrumentSpec spec;
  spec.kind = InstrumentKind::kGrasper;
  spec.jaw_length_m = 0.02;
  spec.jaw_radius_m = 0.0015;
  spec.pad_width_m = 0.0055;
  spec.jaw_samples = 10;
  spec.pad_columns = 4;
  spec.max_opening_rad = 0.5;
  spec.initial_pose.orientation = Eigen::Quaterniond::Identity();
  spec.trajectory.push_back({});
  spec.trajectory.back().gripper_opening = opening;
  return spec;
}

// A pad sample sphere at (t along the length, x across the width in [-1, 1]) of `pad`.
ToolFeature padSample(int id, const ToolFeature& pad, double t, double x) {
  ToolFeature sample;
  sample.id = id;
  sample.shape = FeatureShape::kSphere;
  sample.a_m = pad.a_m + t * (pad.b_m - pad.a_m) + x * pad.half_width_m;
  sample.b_m = sample.a_m;
  sample.radius_m = pad.radius_m;
  sample.face_only = true;
  return sample;
}

TEST(PadGeometry, FeaturesFormTwoRectanglesWithTheirSampleGrids) {
  const Instrument tool(padGrasper(0.0));
  const auto f = tool.features();
  ASSERT_EQ(f.size(), 2u * (1u + 10u * 4u));
  for (int j = 0; j < 2; ++j) {
    const ToolFeature& pad = f[static_cast<std::size_t>(j * 41)];
    EXPECT_EQ(pad.shape, FeatureShape::kPad);
    EXPECT_EQ(pad.part, j);
    EXPECT_NEAR((pad.b_m - pad.a_m).norm(), 0.02, 1e-15);
    EXPECT_NEAR(pad.half_width_m.norm(), 0.00275, 1e-15);
    EXPECT_NEAR(pad.half_width_m.dot(pad.b_m - pad.a_m), 0.0, 1e-18);
    // closed: the pad faces touch along y = 0 (mid-planes at y = +-r)
    EXPECT_NEAR(pad.a_m.y(), (j == 0 ? 1.0 : -1.0) * 0.0015, 1e-15);
    for (int s = 1; s <= 40; ++s) {
      const ToolFeature& sample = f[static_cast<std::size_t>(j * 41 + s)];
      EXPECT_TRUE(sample.face_only);
      EXPECT_EQ(sample.part, j);
      EXPECT_NEAR(sample.a_m.y(), pad.a_m.y(), 1e-15);   // on the pad's rectangle
      EXPECT_LE(std::abs(sample.a_m.x()), 0.00275 + 1e-15);
    }
  }
}

// A pad lying flat above a fine grid, pressed 0.5 mm into it: every grid vertex under the
// rectangle gets exactly one vertex contact with gap = (height above the grid) - r, normal +z;
// the face samples add triangle-interior contacts at distinct points; no tissue point is used
// twice.
TEST(PadCollision, PadOnAGridGivesOneContactPerVertexAndDistinctFacePoints) {
  const TestSurface s = test::flatGrid(40, 40, 0.001, -0.02, -0.02);
  ToolFeature pad;
  pad.id = 0;
  pad.shape = FeatureShape::kPad;
  pad.a_m = Eigen::Vector3d(-0.0101, -0.0024, 0.001);   // mid-plane 1 mm above the grid
  pad.b_m = pad.a_m + Eigen::Vector3d(0.02, 0.0, 0.0);
  pad.half_width_m = Eigen::Vector3d(0.0, 0.0027, 0.0);
  pad.radius_m = 0.0015;                                // so 0.5 mm into the grid
  std::vector<ToolFeature> features{pad};
  for (int i = 0; i < 10; ++i) {
    for (int c = 0; c < 4; ++c) {
      features.push_back(padSample(1 + 4 * i + c, pad, i / 9.0, 2.0 * c / 3.0 - 1.0));
    }
  }
  CollisionOptions o;
  o.alarm_distance_m = 0.0;
  o.max_contacts = 10000;
  Collision col(s.surface, s.q, o);
  const auto& contacts = col.detect(features, shared::Pose{});
  int vertex_contacts = 0, expected_vertices = 0;
  for (int n = 0; n < static_cast<int>(s.q.size() / 3); ++n) {
    const Eigen::Vector3d v = s.q.segment<3>(3 * n);
    // vertices under the rectangle and within its rounded rim (gap <= 0)
    const double dx = std::max({pad.a_m.x() - v.x(), v.x() - pad.b_m.x(), 0.0});
    const double dy = std::max(std::abs(v.y() - pad.a_m.y()) - 0.0027, 0.0);
    if (std::hypot(dx, dy, 0.001) <= 0.0015) ++expected_vertices;
  }
  std::set<int> nodes;
  std::set<std::array<long, 3>> points;
  for (const Contact& c : contacts) {
    points.insert({std::lround(c.tissue_point_m.x() * 1e9), std::lround(c.tissue_point_m.y() * 1e9),
                   std::lround(c.tissue_point_m.z() * 1e9)});
    if (c.kind == ContactKind::kVertexCapsule) {
      ++vertex_contacts;
      EXPECT_TRUE(nodes.insert(c.element).second) << "vertex " << c.element << " used twice";
      const Eigen::Vector3d v = s.q.segment<3>(3 * c.element);
      if (v.x() >= pad.a_m.x() && v.x() <= pad.b_m.x() && std::abs(v.y() - pad.a_m.y()) <= 0.0027) {
        EXPECT_NEAR(c.gap_m, -0.0005, 1e-12);
        EXPECT_NEAR(c.n.z(), 1.0, 1e-12);
      }
    } else {
      // a sample's triangle contact: inside the triangle or on an edge, never at a vertex
      EXPECT_LT(*std::max_element(c.weights.begin(), c.weights.end()), 1.0);
      EXPECT_NEAR(c.n.z(), 1.0, 1e-12);
      EXPECT_NEAR(c.gap_m, -0.0005, 1e-12);
    }
  }
  EXPECT_EQ(vertex_contacts, expected_vertices);
  EXPECT_GT(vertex_contacts, 100);
  EXPECT_GT(static_cast<int>(contacts.size()), vertex_contacts);
  EXPECT_EQ(points.size(), contacts.size()) << "two contacts on the same tissue point";
}

// The pads' rows are redundant (face points are affine combinations of the vertices with the
// same normal): W = H C H^T is singular; + c I is positive definite with smallest eigenvalue
// >= c.
TEST(PadCollision, ContactComplianceMakesTheRedundantRowsPositiveDefinite) {
  const TestSurface s = test::flatGrid(8, 8, 0.004, -0.016, -0.016);
  ToolFeature pad;
  pad.id = 0;
  pad.shape = FeatureShape::kPad;
  pad.a_m = Eigen::Vector3d(-0.01, -0.0027, 0.001);
  pad.b_m = pad.a_m + Eigen::Vector3d(0.02, 0.0, 0.0);
  pad.half_width_m = Eigen::Vector3d(0.0, 0.0027, 0.0);
  pad.radius_m = 0.0015;
  std::vector<ToolFeature> features{pad};
  for (int i = 0; i < 10; ++i) {
    features.push_back(padSample(1 + i, pad, i / 9.0, 0.3));
  }
  CollisionOptions o;
  o.alarm_distance_m = 0.0;
  Collision col(s.surface, s.q, o);
  const auto& contacts = col.detect(features, shared::Pose{});
  ContactRows rows;
  buildContactRows(contacts, 0.0, Eigen::Vector3d::Zero(), rows);
  const int m = rows.rows();
  ASSERT_GT(m, 0);
  // tissue compliance: every node a unit spring (C = I); H has one row per contact
  Eigen::MatrixXd h = Eigen::MatrixXd::Zero(m, s.q.size());
  for (int r = 0; r < m; ++r) {
    for (int k = 0; k < 3; ++k) {
      const int node = rows.tissue[static_cast<std::size_t>(r)].node[k];
      if (node >= 0) {
        h.block(r, 3 * node, 1, 3) +=
            rows.tissue[static_cast<std::size_t>(r)].weight[k] * rows.tissue[static_cast<std::size_t>(r)].dir.transpose();
      }
    }
  }
  const Eigen::MatrixXd w = h * h.transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(w);
  EXPECT_LT(eig.eigenvalues().minCoeff(), 1e-12) << "expected redundant rows, " << m << " contacts";
  const double c = 1e-4;
  const Eigen::MatrixXd wc = w + c * Eigen::MatrixXd::Identity(m, m);
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig_c(wc);
  EXPECT_GE(eig_c.eigenvalues().minCoeff(), c * (1.0 - 1e-9));
  EXPECT_EQ(Eigen::LLT<Eigen::MatrixXd>(wc).info(), Eigen::Success);
}

}  // namespace
}  // namespace tactus::sim
