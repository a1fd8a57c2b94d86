// The simulation's display frames (DisplayLink) read back through a read-only subscriber on the
// liver-grasp scene: the topology is the tissue surface, the frame's vertices are the surface
// nodes' current positions and displacements, the contacts are the last problem's with forces
// pushing into the tissue, the tool is the grasper at its pose, the stress is filled, and the rate
// limit holds. Prints the time a publish takes (not asserted).
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <set>
#include <vector>

#include "../../../sim_server/src/app/display_publisher.h"
#include "../../support/liver_lobe.h"
#include "tactus/shared/segment.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

const std::string kPublisherScene = std::string(TACTUS_SOURCE_DIR) + "/scenes/liver_grasp.yaml";

TEST(DisplayLink, FramesMatchTheSimulation) {
  SceneSpec spec = loadScene(kPublisherScene);
  spec.haptics.enabled = false;
  test_support::useRoundKinematicJaws(spec);   // one drawn primitive per round-jaw feature
  for (auto& t : spec.tissues) t.compliance_cache_dir.clear();
  Simulation sim(spec);
  const std::string name = "tactus_test_" + std::to_string(::getpid()) + "_display_link";
  shared::Segment::remove(name);
  shared::Segment segment = shared::Segment::create(
      name, shared::SegmentCapacity::forContacts(spec.solver.max_contacts, true));
  DisplayOptions opts;
  opts.stress_every = 1;
  DisplayLink link(name, sim, opts);
  ASSERT_TRUE(link.enabled());

  const FemBody& liver = sim.tissue(0);
  const SurfaceMesh surface = extractSurface(liver.mesh());
  EXPECT_EQ(link.vertexCount(), static_cast<int>(surface.nodes.size()));
  EXPECT_EQ(link.triangleCount(), static_cast<int>(surface.triangles.size()));

  // the viewer's side: a read-only mapping
  shared::Segment viewer = shared::Segment::open(name, shared::Access::kReadOnly);
  shared::DisplaySubscriber sub = viewer.displaySubscriber();
  ASSERT_TRUE(sub.attached());
  shared::DisplayTopologyHeader th{};
  std::vector<std::uint32_t> tris(3 * static_cast<std::size_t>(sub.layout().capacity.max_triangles) + 2);
  ASSERT_EQ(sub.readTopology(&th, tris.data()), shared::DisplayRead::kOk);
  EXPECT_EQ(th.vertex_count, link.vertexCount());
  EXPECT_EQ(th.triangle_count, link.triangleCount());
  std::set<std::uint32_t> used;
  for (int i = 0; i < 3 * th.triangle_count; ++i) {
    ASSERT_LT(tris[static_cast<std::size_t>(i)], static_cast<std::uint32_t>(th.vertex_count));
    used.insert(tris[static_cast<std::size_t>(i)]);
  }
  EXPECT_EQ(static_cast<int>(used.size()), th.vertex_count);   // every vertex on a triangle

  // run until the jaws have closed on the lobe (t = 3 s), publishing as the runner does
  std::vector<std::uint64_t> words(sub.layout().frame_bytes / 8 + 1);
  shared::DisplayFrameRef frame(words.data(), sub.layout());
  double publish_s = 0.0;
  long publishes = 0;
  const int steps = static_cast<int>(std::lround(3.0 / spec.time_step_s));
  for (int k = 0; k < steps; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    const StepReport r = sim.step();
    const auto t0 = std::chrono::steady_clock::now();
    if (link.publishNow(sim, &r)) ++publishes;
    publish_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  std::printf("publish: %.1f us per frame (%d vertices, %d contacts)\n",
              1e6 * publish_s / static_cast<double>(publishes), link.vertexCount(),
              sim.lastProblem().contacts);

  ASSERT_EQ(sub.readFrame(frame), shared::DisplayRead::kOk);
  const shared::DisplayFrameHeader& h = frame.header();
  EXPECT_EQ(h.seq, link.framesPublished());
  EXPECT_EQ(h.step, static_cast<std::uint64_t>(sim.stepIndex()));
  EXPECT_EQ(h.topology_generation, th.generation);
  ASSERT_EQ(h.vertex_count, link.vertexCount());

  // vertices: the surface nodes, now
  double max_d = 0.0;
  for (std::size_t i = 0; i < surface.nodes.size(); ++i) {
    const int n = surface.nodes[i];
    const Eigen::Vector3d x = liver.positions().segment<3>(3 * n);
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(frame.positions()[3 * i + static_cast<std::size_t>(k)], x[k], 1e-6);
    }
    const double d = (x - liver.restPositions().segment<3>(3 * n)).norm();
    EXPECT_NEAR(frame.displacement()[i], d, 1e-6);
    max_d = std::max(max_d, d);
  }
  EXPECT_NEAR(h.max_displacement_m, max_d, 1e-9);
  EXPECT_GT(max_d, 0.005);   // the lobe sags under gravity

  // stress: the FEM's von Mises (which re-extracts the rotations) averaged onto the vertices
  EXPECT_TRUE(h.flags & shared::kDisplayHasStress);
  EXPECT_GT(h.max_stress_pa, 0.0);
  Eigen::VectorXd vm;
  liver.vonMises(vm);
  std::vector<double> sum(static_cast<std::size_t>(liver.nodeCount()), 0.0);
  std::vector<int> cnt(static_cast<std::size_t>(liver.nodeCount()), 0);
  for (int e = 0; e < liver.mesh().tetCount(); ++e) {
    for (int n : liver.mesh().tets[static_cast<std::size_t>(e)]) {
      sum[static_cast<std::size_t>(n)] += vm[e];
      ++cnt[static_cast<std::size_t>(n)];
    }
  }
  double worst = 0.0;
  for (std::size_t i = 0; i < surface.nodes.size(); ++i) {
    const auto n = static_cast<std::size_t>(surface.nodes[i]);
    worst = std::max(worst, std::abs(frame.stress()[i] - sum[n] / cnt[n]));
  }
  EXPECT_LT(worst, 0.05 * h.max_stress_pa) << "max stress " << h.max_stress_pa << " Pa";

  // contacts: the grasp's, each force pushing into the tissue along its normal
  const ContactProblemData& p = sim.lastProblem();
  ASSERT_GT(p.contacts, 0);
  EXPECT_EQ(h.contact_count, p.contacts);
  double total_push = 0.0;
  for (int i = 0; i < p.contacts; ++i) {
    const auto c = static_cast<std::size_t>(i);
    const Eigen::Vector3d f(frame.contactForce()[3 * c], frame.contactForce()[3 * c + 1],
                            frame.contactForce()[3 * c + 2]);
    const double fn = p.f[p.row_offset[c]];
    EXPECT_NEAR(f.dot(p.normal[c]), -fn, 1e-5 + 1e-5 * fn) << "contact " << i;
    EXPECT_GE(f.norm() + 1e-9, fn * (1.0 - 1e-5));
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(frame.contactPoint()[3 * c + static_cast<std::size_t>(k)], p.point_m[c][k], 1e-6);
    }
    total_push += fn;
  }
  EXPECT_GT(total_push, 0.0);

  // the tool: a grasper at the instrument's pose, one primitive per feature
  const Instrument& tool = *sim.instrument();
  EXPECT_TRUE(h.flags & shared::kDisplayHasTool);
  EXPECT_EQ(h.tool_type, static_cast<std::uint32_t>(shared::DisplayTool::kGrasper));
  EXPECT_EQ(h.tool_primitive_count, static_cast<int>(tool.features().size()));
  for (int k = 0; k < 3; ++k) EXPECT_DOUBLE_EQ(h.tool_pos_m[k], tool.pose().pos_m[k]);
  EXPECT_NEAR(h.gripper_opening, 0.25, 0.05);          // closed to 0.25 at t = 3 s
  EXPECT_GT(std::hypot(h.tool_force_n[0], h.tool_force_n[1], h.tool_force_n[2]), 0.0);

  // rate limit: a second publish right away is skipped
  link.publishNow(sim);
  const std::uint64_t n = link.framesPublished();
  EXPECT_FALSE(link.publish(sim));
  EXPECT_EQ(link.framesPublished(), n);
}

}  // namespace
}  // namespace tactus::sim
