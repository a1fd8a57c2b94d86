// The contact passes' test of penetration beyond the contact compliance's give
// (sim_server/src/pipeline/step_stages.h, gapBeyondCompliance): a contact carrying f_n in the last
// solve may sit c f_n inside the tissue. A sphere's face contact (a pad sample's) is named after
// its triangle, so when its closest point crosses an edge of that triangle the same contact comes
// back under the neighbour triangle's id. It keeps the force of the contact it was: on the liver
// grasps every second pass was started by such a renamed contact, its give taken for penetration
// (docs/design.md, "Additions beyond the paper": contact passes). A contact whose point moved
// farther over the tissue (more than half the sphere's radius) is new: another pass re-linearises.
#include <gtest/gtest.h>

#include <vector>

#include "../../../sim_server/src/pipeline/step_stages.h"
#include "../contact/test_surfaces.h"
#include "tactus/sim/collision.h"
#include "tactus/sim/instrument.h"

namespace tactus::sim {
namespace {

constexpr double kPassCompliance = 3.0e-3;    // m/N, the liver grasps' contact compliance
constexpr double kPassTolerance = 1.0e-4;     // m, their penetration tolerance
constexpr double kPassRadius = 1.0e-3;        // m, the sample sphere
constexpr double kPassDepth = 0.15e-3;        // m, the sphere's depth in the plane: c f at 0.05 N

// One pad sample (a face-only sphere) over a flat 2 x 2 grid of 1 mm cells at z = 0, its centre
// at (x, y) and kPassDepth into the plane; its contacts.
std::vector<Contact> sampleContactsAt(Collision& collision, double x, double y) {
  ToolFeature sample;
  sample.id = 7;
  sample.shape = FeatureShape::kSphere;
  sample.a_m = sample.b_m = Eigen::Vector3d(x, y, kPassRadius - kPassDepth);
  sample.radius_m = kPassRadius;
  sample.face_only = true;
  const std::vector<ToolFeature> features{sample};
  return collision.detect(features, shared::Pose{});
}

// A flat 2 x 2 grid of 1 mm cells at z = 0 and its collision (3 mm alarm distance).
class ContactPasses : public ::testing::Test {
 protected:
  static CollisionOptions gridOptions() {
    CollisionOptions options;
    options.alarm_distance_m = 3e-3;
    return options;
  }
  const test::TestSurface grid_ = test::flatGrid(2, 2, 1e-3);
  Collision collision_{grid_.surface, grid_.q, gridOptions()};
};

TEST_F(ContactPasses, ASampleContactRenamedAcrossAnEdgeKeepsItsForcesGive) {
  // over the first cell's lower triangle, then 0.14 mm on across its diagonal over the upper one
  const std::vector<Contact> solved = sampleContactsAt(collision_, 0.55e-3, 0.45e-3);
  ASSERT_EQ(solved.size(), 1u);
  const std::vector<Contact> now = sampleContactsAt(collision_, 0.45e-3, 0.55e-3);
  ASSERT_EQ(now.size(), 1u);
  const Contact& renamed = now[0];
  EXPECT_NE(renamed.id, solved[0].id) << "the contact keeps its id: no rename to test";
  EXPECT_NEAR(renamed.gap_m, -kPassDepth, 1e-9);

  // the last solve held the sample's contact with 0.05 N: c f = 0.15 mm of give
  SimulationState state;
  state.warm_start_f[solved[0].id] = {0.05, 0.0, 0.0};
  EXPECT_DOUBLE_EQ(lastNormalForce(state, solved, renamed, grid_.q, kPassRadius), 0.05);
  const double beyond =
      gapBeyondCompliance(state, renamed, kPassCompliance, solved, grid_.q, kPassRadius);
  EXPECT_NEAR(beyond, 0.0, 1e-9);
  EXPECT_GT(beyond, -kPassTolerance) << "the renamed contact's give taken for penetration";
  // by id alone it is new and penetrates by its whole gap
  EXPECT_LT(gapBeyondCompliance(state, renamed, kPassCompliance), -kPassTolerance);
}

TEST_F(ContactPasses, ASampleContactThatMovedOverTheTissueIsNew) {
  // the sphere's closest point 0.57 mm from the solved contact's, more than half its radius
  // (0.5 mm): the contact has moved over the tissue, its row's nodes are no longer the right ones
  const std::vector<Contact> solved = sampleContactsAt(collision_, 0.8e-3, 0.2e-3);
  ASSERT_EQ(solved.size(), 1u);
  const std::vector<Contact> now = sampleContactsAt(collision_, 0.4e-3, 0.6e-3);
  ASSERT_EQ(now.size(), 1u);
  ASSERT_NE(now[0].id, solved[0].id);
  SimulationState state;
  state.warm_start_f[solved[0].id] = {0.05, 0.0, 0.0};
  EXPECT_EQ(lastNormalForce(state, solved, now[0], grid_.q, kPassRadius), 0.0);
  EXPECT_LT(gapBeyondCompliance(state, now[0], kPassCompliance, solved, grid_.q, kPassRadius),
            -kPassTolerance);
}

TEST_F(ContactPasses, OnlyTheSameSpheresContactAcrossAnEdgeLendsItsForce) {
  // hand-built: the solved contact on triangle (0, 1, 2) with 0.05 N, candidates on other
  // triangles and features, each 0.15 mm deep
  Contact held;
  held.id = 1;
  held.kind = ContactKind::kSphereTriangle;
  held.feature = 7;
  held.nodes = {0, 1, 2};
  SimulationState state;
  state.warm_start_f[held.id] = {0.05, 0.0, 0.0};
  const std::vector<Contact> solved{held};
  auto candidate = [&](std::uint64_t id, int feature, std::array<int, 3> nodes) {
    Contact k = held;
    k.id = id;
    k.feature = feature;
    k.nodes = nodes;
    k.gap_m = -kPassDepth;
    return k;
  };
  // every tissue point at the origin: within any radius of each other
  const Eigen::VectorXd q = Eigen::VectorXd::Zero(3 * 9);
  const auto beyond = [&](const Contact& k) {
    return gapBeyondCompliance(state, k, kPassCompliance, solved, q, kPassRadius);
  };
  EXPECT_NEAR(beyond(candidate(2, 7, {1, 2, 3})), 0.0, 1e-12);          // across an edge
  EXPECT_NEAR(beyond(candidate(3, 7, {2, 4, 5})), -kPassDepth, 1e-12);  // a shared vertex only
  EXPECT_NEAR(beyond(candidate(4, 8, {1, 2, 3})), -kPassDepth, 1e-12);  // another sphere's
  Contact vertex = candidate(5, 7, {1, -1, -1});                         // a pad's vertex contact
  vertex.kind = ContactKind::kVertexCapsule;
  EXPECT_NEAR(beyond(vertex), -kPassDepth, 1e-12);
  // two solved neighbours: the smaller force (the larger penetration)
  Contact light = held;
  light.id = 6;
  light.nodes = {1, 3, 8};
  state.warm_start_f[light.id] = {0.01, 0.0, 0.0};
  const std::vector<Contact> both{held, light};
  EXPECT_NEAR(gapBeyondCompliance(state, candidate(2, 7, {1, 2, 3}), kPassCompliance, both, q,
                                  kPassRadius),
              -kPassDepth + kPassCompliance * 0.01, 1e-12);
}

}  // namespace
}  // namespace tactus::sim
