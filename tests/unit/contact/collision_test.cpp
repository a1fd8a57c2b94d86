// Collision detection (tactus/sim/collision.h): BVH against brute force, exact gaps and normals
// on analytic configurations, the grasper pinch, id stability, capping, and the contact rows
// checked against finite differences of the detected gaps.
#include "tactus/sim/collision.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <random>

#include "tactus/shared/error.h"
#include "test_surfaces.h"

namespace {

using tactus::shared::Pose;
using tactus::sim::Collision;
using tactus::sim::CollisionOptions;
using tactus::sim::Contact;
using tactus::sim::ContactKind;
using tactus::sim::ContactRows;
using tactus::sim::FeatureShape;
using tactus::sim::Instrument;
using tactus::sim::InstrumentKind;
using tactus::sim::InstrumentSpec;
using tactus::sim::ToolFeature;
using tactus::sim::Vector6d;
using tactus::sim::test::TestSurface;
namespace ts = tactus::shared;

ToolFeature sphere(int id, const Eigen::Vector3d& c, double r) {
  ToolFeature f;
  f.id = id;
  f.shape = FeatureShape::kSphere;
  f.a_m = c;
  f.b_m = c;
  f.radius_m = r;
  return f;
}

ToolFeature capsule(int id, const Eigen::Vector3d& a, const Eigen::Vector3d& b, double r) {
  ToolFeature f;
  f.id = id;
  f.shape = FeatureShape::kCapsule;
  f.a_m = a;
  f.b_m = b;
  f.radius_m = r;
  return f;
}

CollisionOptions options(double alarm = 0.004, int max_contacts = 10000) {
  CollisionOptions o;
  o.alarm_distance_m = alarm;
  o.max_contacts = max_contacts;
  return o;
}

void expectFrame(const Contact& c) {
  EXPECT_NEAR(c.n.norm(), 1.0, 1e-12);
  EXPECT_NEAR(c.t1.norm(), 1.0, 1e-12);
  EXPECT_NEAR(c.n.dot(c.t1), 0.0, 1e-12);
  EXPECT_LT((c.n.cross(c.t1) - c.t2).norm(), 1e-12);
  EXPECT_NEAR(c.weights[0] + c.weights[1] + c.weights[2], 1.0, 1e-12);
}

void expectSameContacts(const std::vector<Contact>& a, const std::vector<Contact>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].id, b[i].id);
    EXPECT_NEAR(a[i].gap_m, b[i].gap_m, 1e-14);
    EXPECT_LT((a[i].n - b[i].n).norm(), 1e-12);
    EXPECT_LT((a[i].tissue_point_m - b[i].tissue_point_m).norm(), 1e-14);
  }
}

TEST(Collision, SphereAbovePlaneGivesOneContactWithExactGap) {
  TestSurface s = tactus::sim::test::flatGrid(20, 20, 0.002, -0.02, -0.02);
  Collision col(s.surface, s.q, options());
  const double r = 0.003;
  for (const Eigen::Vector3d& xy : {Eigen::Vector3d(0.0013, -0.0021, 0), Eigen::Vector3d(0, 0, 0),
                                    Eigen::Vector3d(0.001, 0.0, 0)}) {   // face, vertex, edge
    for (double height : {0.005, 0.0031, 0.003, 0.0025}) {
      const Eigen::Vector3d c = xy + Eigen::Vector3d(0, 0, height);
      const std::vector<ToolFeature> f{sphere(7, c, r)};
      const auto& contacts = col.detect(f, Pose{});
      ASSERT_EQ(contacts.size(), 1u) << xy.transpose() << " h=" << height;
      const Contact& k = contacts[0];
      EXPECT_EQ(k.kind, ContactKind::kSphereTriangle);
      EXPECT_EQ(k.feature, 7);
      EXPECT_NEAR(k.gap_m, height - r, 1e-12);
      EXPECT_LT((k.n - Eigen::Vector3d::UnitZ()).norm(), 1e-9);
      EXPECT_LT((k.tissue_point_m - xy).norm(), 1e-12);
      EXPECT_LT((k.tool_point_m - (c - r * Eigen::Vector3d::UnitZ())).norm(), 1e-12);
      expectFrame(k);
    }
  }
  // beyond the alarm distance: nothing
  const std::vector<ToolFeature> far{sphere(0, Eigen::Vector3d(0, 0, 0.0071), r)};
  EXPECT_TRUE(col.detect(far, Pose{}).empty());
}

TEST(Collision, SphereBelowPlaneGivesPenetrationAlongTheOutwardNormal) {
  TestSurface s = tactus::sim::test::flatGrid(20, 20, 0.002, -0.02, -0.02);
  Collision col(s.surface, s.q, options());
  const double r = 0.003;
  for (double depth : {0.0005, 0.002}) {
    const Eigen::Vector3d c(0.0013, 0.0007, -depth);
    const std::vector<ToolFeature> f{sphere(0, c, r)};
    const auto& contacts = col.detect(f, Pose{});
    ASSERT_EQ(contacts.size(), 1u) << depth;
    EXPECT_NEAR(contacts[0].gap_m, -depth - r, 1e-12);
    EXPECT_LT((contacts[0].n - Eigen::Vector3d::UnitZ()).norm(), 1e-12);
  }
}

TEST(Collision, SphereAboveThinSlabIgnoresTheFarSide) {
  // 1 mm thick slab: the bottom face is within the alarm distance of a sphere above the top
  TestSurface s = tactus::sim::test::boxSurface(Eigen::Vector3d(-0.02, -0.02, -0.001),
                                                Eigen::Vector3d(0.02, 0.02, 0.0), 10, 10, 1);
  Collision col(s.surface, s.q, options());
  for (double z : {0.004, 0.0025, -0.0002}) {   // above, touching, centre inside near the top
    const std::vector<ToolFeature> f{sphere(0, Eigen::Vector3d(0.0011, 0.0013, z), 0.003)};
    const auto& contacts = col.detect(f, Pose{});
    ASSERT_FALSE(contacts.empty());
    for (const Contact& k : contacts) {
      EXPECT_GT(k.n.z(), 0.99) << "z=" << z;
      EXPECT_NEAR(k.gap_m, z - 0.003, 1e-12);
    }
  }
}

TEST(Collision, CapsuleAgainstVerticesMatchesTheAnalyticDistance) {
  TestSurface s = tactus::sim::test::flatGrid(30, 30, 0.001, -0.015, -0.015);
  CollisionOptions o = options(0.002);
  Collision col(s.surface, s.q, o);
  const double r = 0.002, height = 0.0025;
  const Eigen::Vector3d a(-0.008, 0.0003, height), b(0.006, 0.0003, height);
  const std::vector<ToolFeature> f{capsule(3, a, b, r)};
  const auto& contacts = col.detect(f, Pose{});
  // expected: every grid vertex within alarm of the capsule surface
  std::map<int, double> expected;
  for (int node = 0; node < static_cast<int>(s.q.size() / 3); ++node) {
    const Eigen::Vector3d v = s.q.segment<3>(3 * node);
    const double t = std::clamp((v - a).dot(b - a) / (b - a).squaredNorm(), 0.0, 1.0);
    const double gap = (a + t * (b - a) - v).norm() - r;
    if (gap <= o.alarm_distance_m) expected[node] = gap;
  }
  ASSERT_GT(expected.size(), 50u);
  ASSERT_EQ(contacts.size(), expected.size());
  for (const Contact& k : contacts) {
    EXPECT_EQ(k.kind, ContactKind::kVertexCapsule);
    ASSERT_TRUE(expected.count(k.element));
    EXPECT_NEAR(k.gap_m, expected[k.element], 1e-14);
    EXPECT_EQ(k.nodes[0], k.element);
    EXPECT_EQ(k.weights[0], 1.0);
    // n points from the vertex toward the axis, the tool point lies on the capsule surface
    const Eigen::Vector3d v = s.q.segment<3>(3 * k.element);
    const double t = std::clamp((v - a).dot(b - a) / (b - a).squaredNorm(), 0.0, 1.0);
    const Eigen::Vector3d axis = a + t * (b - a);
    EXPECT_LT((k.n - (axis - v).normalized()).norm(), 1e-12);
    EXPECT_NEAR((k.tool_point_m - axis).norm(), r, 1e-14);
    expectFrame(k);
  }
  // skip_cap_a: vertices beyond the a end are ignored
  std::vector<ToolFeature> shaft{capsule(3, a, b, r)};
  shaft[0].skip_cap_a = true;
  const auto& cut = col.detect(shaft, Pose{});
  EXPECT_LT(cut.size(), expected.size());
  for (const Contact& k : cut) EXPECT_GT(k.tissue_point_m.x(), a.x());
}

TEST(Collision, CapsuleBelowTheSurfaceIgnoresBackFacingVertices) {
  // vertices seen from behind (the capsule under the sheet) do not face the tool
  TestSurface s = tactus::sim::test::flatGrid(20, 20, 0.001, -0.01, -0.01);
  Collision col(s.surface, s.q, options());
  const std::vector<ToolFeature> f{
      capsule(0, Eigen::Vector3d(-0.005, 0, -0.003), Eigen::Vector3d(0.005, 0, -0.003), 0.002)};
  EXPECT_TRUE(col.detect(f, Pose{}).empty());
}

// Random smooth + noisy deformation of a box surface.
Eigen::VectorXd deform(const Eigen::VectorXd& q0, std::mt19937& rng, double amplitude) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Eigen::Vector3d k(u(rng) * 200, u(rng) * 200, u(rng) * 200);
  Eigen::VectorXd q = q0;
  for (int i = 0; i < q.size() / 3; ++i) {
    const Eigen::Vector3d x = q0.segment<3>(3 * i);
    const double wave = std::sin(k.dot(x));
    q.segment<3>(3 * i) += amplitude * Eigen::Vector3d(wave + 0.3 * u(rng), 0.5 * wave + 0.3 * u(rng),
                                                       std::cos(k.dot(x)) + 0.3 * u(rng));
  }
  return q;
}

std::vector<ToolFeature> randomFeatures(std::mt19937& rng, int count) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<ToolFeature> f;
  for (int i = 0; i < count; ++i) {
    const Eigen::Vector3d c(u(rng) * 0.025, u(rng) * 0.025, u(rng) * 0.015);
    const double r = 0.001 + 0.003 * (u(rng) + 1.0);
    if (i % 2 == 0) {
      f.push_back(sphere(i, c, r));
    } else {
      const Eigen::Vector3d d = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized() * 0.015;
      f.push_back(capsule(i, c - d, c + d, r));
    }
  }
  return f;
}

TEST(Collision, TreeQueriesEqualBruteForceAfterRefit) {
  TestSurface s = tactus::sim::test::boxSurface(Eigen::Vector3d(-0.02, -0.02, -0.01),
                                                Eigen::Vector3d(0.02, 0.02, 0.01), 12, 12, 6);
  std::mt19937 rng(11);
  CollisionOptions tree_opt = options(0.003);
  CollisionOptions brute_opt = tree_opt;
  brute_opt.brute_force = true;
  Collision tree(s.surface, s.q, tree_opt);
  Collision brute(s.surface, s.q, brute_opt);
  std::size_t total = 0;
  int kinds[2] = {0, 0};
  for (int trial = 0; trial < 12; ++trial) {
    // the tree keeps the topology it was built with; positions drift further each refit
    const Eigen::VectorXd q = deform(s.q, rng, 0.0005 * (trial + 1));
    tree.refit(q);
    brute.refit(q);
    const std::vector<ToolFeature> features = randomFeatures(rng, 30);
    const std::vector<Contact> a = tree.detect(features, Pose{});
    const std::vector<Contact>& b = brute.detect(features, Pose{});
    expectSameContacts(a, b);
    EXPECT_LT(tree.stats().candidates, brute.stats().candidates);
    total += a.size();
    for (const Contact& k : a) {
      ++kinds[static_cast<int>(k.kind)];
      expectFrame(k);
      EXPECT_LE(k.gap_m, tree_opt.alarm_distance_m);
    }
  }
  // the comparison is not vacuous
  EXPECT_GT(total, 200u);
  EXPECT_GT(kinds[0], 50);
  EXPECT_GT(kinds[1], 20);
}

TEST(Collision, GrasperClosingOnASlabTouchesWithBothJaws) {
  // slab 4 mm thick in y, the grasper above it with its jaws straddling it
  TestSurface s = tactus::sim::test::boxSurface(Eigen::Vector3d(-0.02, -0.002, -0.03),
                                                Eigen::Vector3d(0.02, 0.002, 0.0), 20, 4, 15);
  InstrumentSpec spec;
  spec.kind = InstrumentKind::kGrasper;
  spec.jaw_length_m = 0.02;
  spec.jaw_radius_m = 0.002;
  spec.max_opening_rad = 0.6;
  spec.jaw_samples = 6;
  Instrument grasper(spec);
  Pose pose;
  pose.pos_m = Eigen::Vector3d(0.0005, 0.0, 0.012);
  Collision col(s.surface, s.q, options(0.002));
  // open wide: nothing; closing: both jaws press on the slab's faces
  grasper.reset(pose, 1.0);
  EXPECT_TRUE(col.detect(grasper).empty());
  double previous_min_gap = 1.0;
  for (double opening : {0.3, 0.2, 0.1}) {
    grasper.reset(pose, opening);
    const auto& contacts = col.detect(grasper);
    int per_jaw[2] = {0, 0};
    double min_gap = 1.0;
    const Contact* deepest[2] = {nullptr, nullptr};
    for (const Contact& k : contacts) {
      const int jaw = grasper.features()[k.feature].part;
      ++per_jaw[jaw];
      const double side = jaw == 0 ? 1.0 : -1.0;
      // vertices beside a round jaw see it obliquely, but always toward that jaw's side
      EXPECT_GT(side * k.n.y(), 0.0) << "jaw " << jaw << " n " << k.n.transpose();
      if (!deepest[jaw] || k.gap_m < deepest[jaw]->gap_m) deepest[jaw] = &k;
      min_gap = std::min(min_gap, k.gap_m);
      // the tool-local point maps back to the world tool point
      EXPECT_LT((pose.pos_m + pose.rot * k.tool_local_m - k.tool_point_m).norm(), 1e-15);
    }
    EXPECT_GT(per_jaw[0], 3) << opening;
    ASSERT_TRUE(deepest[0] && deepest[1]);
    // the deepest points of the two jaws push the tissue in opposite directions (pinch)
    EXPECT_LT(deepest[0]->n.dot(deepest[1]->n), -0.95) << opening;
    EXPECT_EQ(per_jaw[0], per_jaw[1]) << opening;   // symmetric set-up
    EXPECT_LT(min_gap, previous_min_gap);
    previous_min_gap = min_gap;
  }
  EXPECT_LT(previous_min_gap, 0.0);   // pinching: penetration that the solver will resolve
}

TEST(Collision, IdsAreStableWhenTheTissueMovesSlightly) {
  TestSurface s = tactus::sim::test::flatGrid(30, 30, 0.001, -0.015, -0.015);
  Collision col(s.surface, s.q, options(0.002));
  const std::vector<ToolFeature> f{
      sphere(0, Eigen::Vector3d(0.0012, -0.0033, 0.0021), 0.002),
      capsule(1, Eigen::Vector3d(-0.006, 0.004, 0.0016), Eigen::Vector3d(0.007, 0.0045, 0.0017),
              0.0015)};
  std::vector<std::uint64_t> before;
  for (const Contact& k : col.detect(f, Pose{})) before.push_back(k.id);
  ASSERT_GT(before.size(), 5u);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::VectorXd q = s.q;
  for (int i = 0; i < q.size(); ++i) q(i) += 1e-7 * u(rng);
  q += Eigen::Vector3d(2e-6, -1e-6, 3e-7).replicate(q.size() / 3, 1);
  col.refit(q);
  std::vector<std::uint64_t> after;
  for (const Contact& k : col.detect(f, Pose{})) after.push_back(k.id);
  EXPECT_EQ(before, after);
  // ids encode (kind, feature, element): distinct within one detection
  std::vector<std::uint64_t> sorted = after;
  EXPECT_TRUE(std::adjacent_find(sorted.begin(), sorted.end()) == sorted.end());
}

TEST(Collision, HundredsOfContactsAndCappingKeepsTheDeepest) {
  TestSurface s = tactus::sim::test::flatGrid(80, 80, 0.0005, -0.02, -0.02);
  // a large capsule lying in the surface
  const std::vector<ToolFeature> f{
      capsule(0, Eigen::Vector3d(-0.015, 0.0, 0.004), Eigen::Vector3d(0.015, 0.0, 0.004), 0.005),
      sphere(1, Eigen::Vector3d(0.0, 0.012, 0.002), 0.003)};
  Collision all(s.surface, s.q, options(0.002, 100000));
  const std::vector<Contact> every = all.detect(f, Pose{});
  ASSERT_GE(every.size(), 300u);
  EXPECT_EQ(all.stats().overflow, 0);
  const int cap = 300;
  Collision capped(s.surface, s.q, options(0.002, cap));
  const auto& kept = capped.detect(f, Pose{});
  ASSERT_EQ(kept.size(), static_cast<std::size_t>(cap));
  EXPECT_EQ(capped.stats().overflow, static_cast<int>(every.size()) - cap);
  EXPECT_EQ(capped.stats().overflow_total, static_cast<int>(every.size()) - cap);
  // the kept ones are exactly the cap smallest gaps of the full set
  std::vector<double> gaps;
  for (const Contact& k : every) gaps.push_back(k.gap_m);
  std::sort(gaps.begin(), gaps.end());
  double kept_max = -1.0;
  for (const Contact& k : kept) kept_max = std::max(kept_max, k.gap_m);
  EXPECT_LE(kept_max, gaps[cap - 1]);
  EXPECT_LT(gaps.front(), 0.0);
  EXPECT_TRUE(std::is_sorted(kept.begin(), kept.end(),
                             [](const Contact& a, const Contact& b) { return a.id < b.id; }));
}

// Gap of one contact id, recomputed by a fresh detection.
double gapOf(Collision& col, std::span<const ToolFeature> f, const Pose& pose, std::uint64_t id) {
  for (const Contact& k : col.detect(f, pose)) {
    if (k.id == id) return k.gap_m;
  }
  ADD_FAILURE() << "contact " << id << " lost";
  return 0.0;
}

TEST(Collision, RowsAreTheGapDerivatives) {
  // a probe (tip + shaft) tilted over a bumpy grid; check H_tool and H_tissue against finite
  // differences of the detected gaps
  TestSurface s = tactus::sim::test::flatGrid(20, 20, 0.002, -0.02, -0.02);
  for (int i = 0; i < s.q.size() / 3; ++i) {
    const Eigen::Vector3d x = s.q.segment<3>(3 * i);
    s.q(3 * i + 2) = 0.002 * std::sin(80 * x.x()) * std::cos(60 * x.y());
  }
  InstrumentSpec spec;
  spec.tip_radius_m = 0.003;
  spec.shaft_length_m = 0.03;
  Instrument probe(spec);
  Pose pose;
  pose.pos_m = Eigen::Vector3d(0.0013, -0.0017, 0.0035);
  pose.rot = Eigen::Quaterniond(Eigen::AngleAxisd(1.2, Eigen::Vector3d(1, 0.3, 0).normalized()));
  probe.reset(pose);
  Collision col(s.surface, s.q, options(0.003));
  const std::vector<Contact> contacts = col.detect(probe);
  int kinds[2] = {0, 0};
  for (const Contact& k : contacts) ++kinds[static_cast<int>(k.kind)];
  ASSERT_GT(kinds[0], 0);
  ASSERT_GT(kinds[1], 0);
  ContactRows rows;
  tactus::sim::buildContactRows(contacts, 0.0, pose.pos_m, rows);
  ASSERT_EQ(rows.rows(), static_cast<int>(contacts.size()));
  tactus::sim::buildContactRows(contacts, 0.4, pose.pos_m, rows);
  ASSERT_EQ(rows.rows(), 3 * static_cast<int>(contacts.size()));
  const double eps = 1e-7;
  for (std::size_t i = 0; i < contacts.size(); ++i) {
    const Contact& k = contacts[i];
    const int r = rows.row_offset[i];
    EXPECT_EQ(rows.row_offset[i + 1] - r, 3);
    EXPECT_EQ(rows.delta_free[r], k.gap_m);
    EXPECT_EQ(rows.delta_free[r + 1], 0.0);
    EXPECT_LT((rows.tissue[r + 1].dir - k.t1).norm(), 1e-15);
    // tool: a twist of the probe changes the gap by H_tool . twist
    for (int d = 0; d < 6; ++d) {
      Vector6d e = Vector6d::Zero();
      e(d) = eps;
      Instrument plus = probe, minus = probe;
      plus.reset(ts::applyTwist(pose, e));
      minus.reset(ts::applyTwist(pose, -e));
      const double fd =
          (gapOf(col, plus.features(), plus.pose(), k.id) -
           gapOf(col, minus.features(), minus.pose(), k.id)) / (2 * eps);
      EXPECT_NEAR(fd, rows.tool(r, d), 1e-6) << "contact " << i << " dof " << d;
    }
    // tissue: moving one node changes the gap by the tissue row
    for (int n = 0; n < 3; ++n) {
      const int node = rows.tissue[r].node[n];
      if (node < 0 || k.weights[n] == 0.0) continue;
      for (int axis = 0; axis < 3; ++axis) {
        Eigen::VectorXd q = s.q;
        q(3 * node + axis) += eps;
        col.refit(q);
        const double g_plus = gapOf(col, probe.features(), pose, k.id);
        q(3 * node + axis) -= 2 * eps;
        col.refit(q);
        const double g_minus = gapOf(col, probe.features(), pose, k.id);
        col.refit(s.q);
        const double expected = rows.tissue[r].weight[n] * rows.tissue[r].dir[axis];
        EXPECT_NEAR((g_plus - g_minus) / (2 * eps), expected, 1e-6)
            << "contact " << i << " node " << node << " axis " << axis;
      }
    }
  }
}

TEST(Collision, RejectsInconsistentInput) {
  TestSurface s = tactus::sim::test::flatGrid(2, 2, 0.01);
  Eigen::VectorXd short_q = s.q.head(6);
  EXPECT_THROW(Collision(s.surface, short_q, options()), tactus::Error);
  Collision col(s.surface, s.q, options());
  EXPECT_THROW(col.refit(short_q), tactus::Error);
  CollisionOptions bad = options();
  bad.alarm_distance_m = -1.0;
  EXPECT_THROW(col.setOptions(bad), tactus::Error);
}

}  // namespace
