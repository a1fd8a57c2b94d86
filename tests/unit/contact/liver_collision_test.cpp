// Collision against a real organ surface (SOFA's liver, tests/data/meshes): tree queries equal
// brute force on the deformed liver, and a probe outside / pressed into it gets consistent
// normals and gaps.
#include <gtest/gtest.h>

#include <filesystem>
#include <random>

#include "tactus/sim/collision.h"
#include "tactus/sim/mesh.h"

namespace {

using tactus::shared::Pose;
using tactus::sim::Collision;
using tactus::sim::CollisionOptions;
using tactus::sim::Contact;
using tactus::sim::FeatureShape;
using tactus::sim::ToolFeature;

struct Liver {
  tactus::sim::TetMesh mesh;
  tactus::sim::SurfaceMesh surface;
  Eigen::VectorXd q;   // metres (the file is in decimetres)
};

Liver loadLiver(const char* name) {
  Liver l;
  // (a path, not string + literal + name: GCC 12 at -O1 warns about the latter's memcpy)
  l.mesh = tactus::sim::loadTetMesh(
      (std::filesystem::path(TACTUS_TEST_DATA_DIR) / "meshes" / name).string());
  l.surface = tactus::sim::extractSurface(l.mesh);
  l.q = Eigen::Map<const Eigen::VectorXd>(l.mesh.nodes.data(), 3 * l.mesh.nodeCount()) * 0.1;
  return l;
}

// Outward unit normal of a surface node (area-weighted, from the triangles).
Eigen::Vector3d nodeNormal(const Liver& l, int node) {
  Eigen::Vector3d n = Eigen::Vector3d::Zero();
  for (const auto& t : l.surface.triangles) {
    if (t[0] != node && t[1] != node && t[2] != node) continue;
    const Eigen::Vector3d a = l.q.segment<3>(3 * t[0]);
    n += (Eigen::Vector3d(l.q.segment<3>(3 * t[1])) - a)
             .cross(Eigen::Vector3d(l.q.segment<3>(3 * t[2])) - a);
  }
  return n.normalized();
}

TEST(LiverCollision, TreeEqualsBruteForceOnTheDeformedLiver) {
  const Liver l = loadLiver("liver2.msh");
  ASSERT_GT(l.surface.triangles.size(), 300u);
  CollisionOptions o;
  o.alarm_distance_m = 0.004;
  o.max_contacts = 100000;
  CollisionOptions ob = o;
  ob.brute_force = true;
  Collision tree(l.surface, l.q, o), brute(l.surface, l.q, ob);
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::uniform_int_distribution<std::size_t> pick(0, l.surface.nodes.size() - 1);
  std::size_t total = 0;
  for (int trial = 0; trial < 6; ++trial) {
    Eigen::VectorXd q = l.q;
    for (int i = 0; i < q.size(); ++i) q(i) += 0.002 * trial * std::sin(37.0 * l.q(i) + i);
    tree.refit(q);
    brute.refit(q);
    std::vector<ToolFeature> features;
    for (int i = 0; i < 24; ++i) {
      const int node = l.surface.nodes[pick(rng)];
      const Eigen::Vector3d p =
          q.segment<3>(3 * node) + Eigen::Vector3d(u(rng), u(rng), u(rng)) * 0.006;
      ToolFeature f;
      f.id = i;
      f.radius_m = 0.002 + 0.002 * (u(rng) + 1.0);
      f.a_m = p;
      f.b_m = p;
      if (i % 3 == 0) {
        f.shape = FeatureShape::kCapsule;
        f.b_m = p + Eigen::Vector3d(u(rng), u(rng), u(rng)) * 0.03;
      }
      features.push_back(f);
    }
    const std::vector<Contact> a = tree.detect(features, Pose{});
    const std::vector<Contact>& b = brute.detect(features, Pose{});
    ASSERT_EQ(a.size(), b.size()) << trial;
    for (std::size_t i = 0; i < a.size(); ++i) {
      EXPECT_EQ(a[i].id, b[i].id);
      EXPECT_EQ(a[i].gap_m, b[i].gap_m);
      EXPECT_LT((a[i].n - b[i].n).norm(), 1e-15);
    }
    total += a.size();
  }
  EXPECT_GT(total, 100u);
}

TEST(LiverCollision, ProbeOutsideAndPressedIn) {
  const Liver l = loadLiver("liver2.msh");
  CollisionOptions o;
  o.alarm_distance_m = 0.003;
  Collision col(l.surface, l.q, o);
  const double r = 0.003;
  int checked = 0;
  for (std::size_t i = 0; i < l.surface.nodes.size(); i += 17) {
    const int node = l.surface.nodes[i];
    const Eigen::Vector3d v = l.q.segment<3>(3 * node);
    const Eigen::Vector3d nv = nodeNormal(l, node);
    // sphere 1 mm off the surface, pressed 1.5 mm in, and its centre 1 mm inside the organ
    for (double offset : {r + 0.001, r - 0.0015, -0.001}) {
      ToolFeature tip;
      tip.shape = FeatureShape::kSphere;
      tip.radius_m = r;
      tip.a_m = v + offset * nv;
      tip.b_m = tip.a_m;
      const auto& contacts = col.detect(std::span<const ToolFeature>(&tip, 1), Pose{});
      ASSERT_FALSE(contacts.empty()) << "node " << node << " offset " << offset;
      double min_gap = 1.0, max_gap = -1.0;
      for (const Contact& k : contacts) {
        // every contact pushes the tool out of the organ, roughly along the local normal
        EXPECT_GT(k.n.dot(nv), 0.0) << "node " << node << " offset " << offset;
        min_gap = std::min(min_gap, k.gap_m);
        max_gap = std::max(max_gap, k.gap_m);
      }
      if (offset > 0.0) {
        // the nearest surface point is at most as far as the vertex we started from
        EXPECT_LE(min_gap, offset - r + 1e-12) << "node " << node;
        if (offset < r) {
          EXPECT_LT(min_gap, 0.0) << "node " << node;
        }
      } else {
        // centre inside: every contact reports more than the radius of penetration, the
        // nearest one at most the centre's depth more
        EXPECT_LT(max_gap, -r + 1e-12) << "node " << node;
        EXPECT_GE(max_gap, offset - r - 1e-12) << "node " << node;
      }
      ++checked;
    }
  }
  EXPECT_GT(checked, 20);
}

}  // namespace
